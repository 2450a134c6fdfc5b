"""`make test`'s two xdist workers keep each `xdist_group` on one worker (`--dist loadgroup`).

The firmware tests rely on it (tests/conftest.py: two firmware instances side by side compete for the
CPU and miss real-time deadlines), and so do the closed-loop scenarios (one run per flavour, not one per
worker). pytest 9.2.0 broke it without an error (pytest-dev/pytest-xdist#1386): this test notices.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

GROUPED = '''
import os
import pytest

def record(tmp_dir, name):
    (tmp_dir / name).write_text(os.environ.get("PYTEST_XDIST_WORKER", "none"))

@pytest.mark.xdist_group("together")
@pytest.mark.parametrize("i", range(6))
def test_grouped(i):
    record(OUT, f"grouped-{i}")

@pytest.mark.parametrize("i", range(6))
def test_free(i):
    record(OUT, f"free-{i}")
'''


def test_a_group_runs_on_one_worker(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (tmp_path / "test_grouped.py").write_text(f"from pathlib import Path\nOUT = Path({str(out)!r})\n{GROUPED}")
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-n", "2", "--dist", "loadgroup", "-p",
                           "no:cacheprovider", str(tmp_path / "test_grouped.py")],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    grouped = {path.read_text() for path in out.glob("grouped-*")}
    assert len(list(out.glob("grouped-*"))) == 6 and len(list(out.glob("free-*"))) == 6
    assert len(grouped) == 1 and grouped <= {"gw0", "gw1"}, f"the group ran on {sorted(grouped)}"
