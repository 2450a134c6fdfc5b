"""jsar.memory_policy: freed memory stays in the process under glibc; other C libraries are left alone."""
from __future__ import annotations

import platform
import subprocess
import sys
import textwrap

import pytest

from jsar import memory_policy

# A child process allocates, touches and frees a 16 MiB array and prints its resident set (KiB) before
# and after the free; with the policy it first calls retain_freed_memory().
_CHILD = textwrap.dedent("""
    import sys
    import numpy as np
    from jsar.memory_policy import retain_freed_memory

    def rss_kib():
        with open("/proc/self/statm") as handle:
            return int(handle.read().split()[1]) * 4

    if sys.argv[1] == "policy":
        retain_freed_memory()
    block = np.ones(16 * 1024 * 1024, np.uint8)
    held = rss_kib()
    del block
    print(held, rss_kib())
""")

needs_glibc = pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="the policy applies to glibc's malloc only")


def _resident_before_and_after_free(mode: str) -> tuple[int, int]:
    out = subprocess.run([sys.executable, "-c", _CHILD, mode], capture_output=True, text=True, check=True, timeout=60)
    held, after = (int(v) for v in out.stdout.split())
    return held, after


@needs_glibc
def test_freed_block_stays_resident_with_the_policy_and_returns_to_the_kernel_without() -> None:
    held, after = _resident_before_and_after_free("default")
    assert held - after > 12 * 1024  # glibc's default: a 16 MiB block is mapped and unmapped
    held, after = _resident_before_and_after_free("policy")
    assert held - after < 1024  # kept for the next frame's arrays


@needs_glibc
def test_says_what_is_in_force() -> None:
    text = memory_policy.retain_freed_memory()
    assert text.startswith("glibc ") and "never trimmed" in text and f"{memory_policy.MMAP_THRESHOLD_BYTES >> 20} MiB" in text


def test_other_c_libraries_are_left_alone(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(memory_policy.platform, "libc_ver", lambda: ("", ""))
    monkeypatch.setattr(memory_policy.ctypes, "CDLL", lambda *_: pytest.fail("mallopt called outside glibc"))
    assert memory_policy.retain_freed_memory() == "not glibc (unknown C library): malloc left as it is"


@needs_glibc
def test_a_refused_value_is_an_error_naming_it(monkeypatch: pytest.MonkeyPatch) -> None:
    class Refusing:
        @staticmethod
        def mallopt(_param: object, _value: object) -> int:
            return 0

    monkeypatch.setattr(memory_policy.ctypes, "CDLL", lambda *_: Refusing())
    with pytest.raises(RuntimeError, match="M_TRIM_THRESHOLD"):
        memory_policy.retain_freed_memory()
