"""Keep freed memory in the process, so a tracking loop's per-frame temporaries do not page-fault.

A JSAR-Re frame allocates and frees the same arrays every frame; a lost frame several MiB of them (the
search windows' features and spectra). glibc's malloc by default gives freed memory at the top of its
heap back to the kernel and serves blocks above its mmap threshold by mmap, so the next frame's arrays
land on fresh pages and the kernel zero-fills each one on first touch: a lost frame paid for its own
temporaries twice (docs/results-tracker.md, "Where a lost frame's time goes"). A loop that runs for
hours wants the opposite, the usual setting for real-time Linux processes: freed memory stays with
the process (never trimmed) and blocks up to MMAP_THRESHOLD_BYTES come from the heap, so the pages
are touched once and reused. The cost is that the process keeps its peak heap resident.

The setting is process-wide: entry points that run a tracker in a loop call `retain_freed_memory()`
once (the daemon, `python -m jsar.eval`, the benchmarks, the demo); the library itself never does.
"""
from __future__ import annotations

import ctypes
import platform

# glibc's mallopt parameters (malloc.h).
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
TRIM_NEVER = -1  # mallopt's int -1 is the largest trim threshold: the heap is never trimmed
# glibc's own ceiling for its dynamic mmap threshold (32 MiB on 64-bit; mallopt refuses more): larger blocks are
# one-offs, mapped and unmapped as before.
MMAP_THRESHOLD_BYTES = 4 * 1024 * 1024 * ctypes.sizeof(ctypes.c_long)


def retain_freed_memory() -> str:
    """Set glibc's malloc to keep freed memory (no trimming; mmap only above MMAP_THRESHOLD_BYTES) and
    say what is in force, for the caller's log. Under another C library nothing is changed and the
    text says so; RuntimeError if glibc refuses a value."""
    libc_name, version = platform.libc_ver()
    if libc_name != "glibc":
        return f"not glibc ({libc_name or 'unknown C library'}): malloc left as it is"
    libc = ctypes.CDLL(None)
    for name, param, value in (("M_TRIM_THRESHOLD", M_TRIM_THRESHOLD, TRIM_NEVER),
                               ("M_MMAP_THRESHOLD", M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)):
        if libc.mallopt(ctypes.c_int(param), ctypes.c_int(value)) != 1:
            raise RuntimeError(f"glibc {version} refused mallopt({name}, {value})")
    return f"glibc {version} keeps freed memory (never trimmed; mmap above {MMAP_THRESHOLD_BYTES >> 20} MiB)"
