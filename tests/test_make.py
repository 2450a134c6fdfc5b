"""The Makefile's user-facing commands behave as documented."""
from __future__ import annotations

import shlex
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_make_test_says_why_tests_were_skipped(tmp_path: Path) -> None:
    """`make test` runs pytest so that a user without JSAR_DATA_ROOT reads what the skipped tests need,
    not only how many were skipped: the recipe's pytest command, run on a test that skips, prints the reason."""
    dry = subprocess.run(["make", "-s", "-n", "test"], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert dry.returncode == 0, dry.stderr
    (command,) = [line for line in dry.stdout.splitlines() if " -m pytest" in line]
    (tmp_path / "test_needs_data.py").write_text(
        "import pytest\n\ndef test_needs_data():\n    pytest.skip('JSAR_DATA_ROOT is not set: the shared UAV data')\n")
    argv = shlex.split(command.split("#")[0])
    argv[0] = sys.executable  # the venv's interpreter, whatever the recipe calls it
    run = subprocess.run([*argv, str(tmp_path / "test_needs_data.py"), "-p", "no:cacheprovider"], cwd=tmp_path,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "SKIPPED" in run.stdout and "JSAR_DATA_ROOT is not set: the shared UAV data" in run.stdout, run.stdout
