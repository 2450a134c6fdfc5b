"""Service threads the OS can tell apart: each names its kernel thread after its Python name.

Python's thread names live only inside the interpreter; `top -H`, `ps -L` and /proc/PID/task/*/comm
show every thread as the process name. Each service thread therefore sets its kernel name (Linux
prctl PR_SET_NAME, at most 15 bytes) when it starts. Threads that a named thread creates inherit
its kernel name unless they set their own (Zenoh's runtime and FFmpeg / OpenCV pools name theirs).
"""
from __future__ import annotations

import ctypes
import ctypes.util
import sys
import threading
from typing import Callable

OS_NAME_MAX_BYTES = 15  # the kernel keeps 16 bytes of a thread's name, the last one NUL (TASK_COMM_LEN)
PR_SET_NAME = 15  # linux/prctl.h


def os_thread_name(name: str) -> bytes:
    """The kernel name for a thread called `name`: UTF-8 cut to OS_NAME_MAX_BYTES, never inside a character."""
    return name.encode("utf-8")[:OS_NAME_MAX_BYTES].decode("utf-8", "ignore").encode("utf-8")


def name_os_thread(name: str) -> bool:
    """Give the calling thread the kernel name for `name`; False where the OS has no prctl or refused it."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
    except OSError:
        return False
    return libc.prctl(PR_SET_NAME, ctypes.c_char_p(os_thread_name(name)), 0, 0, 0) == 0


def service_thread(target: Callable[[], None], name: str) -> threading.Thread:
    """A daemon thread called `name` (not started) that names its OS thread before running `target`."""

    def named() -> None:
        name_os_thread(name)
        target()

    return threading.Thread(target=named, name=name, daemon=True)
