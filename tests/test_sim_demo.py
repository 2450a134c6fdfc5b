"""`python -m sim.demo` as a command: a daemon that dies at start is reported at once with its own error, and
Ctrl-C (SIGINT to the whole foreground process group, as a terminal sends it under `make run`) stops the run
and its children cleanly: an "interrupted" line, exit 130, no traceback."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from sim.closed_loop import ClosedLoop, ClosedLoopConfig
from sim.daemon import DaemonExited

REPO = Path(__file__).resolve().parent.parent
pytestmark = pytest.mark.skipif(not hasattr(os, "killpg"), reason="needs POSIX process groups")


class Demo:
    """`python -m sim.demo ARGS` in its own process group, its output read as it comes (bytes, so the live status
    line's \\r stays a \\r); `wait_for(text)` waits on the output, by event."""

    def __init__(self, *args: str) -> None:
        env = dict(os.environ, MAVLINK20="1", PYTHONUNBUFFERED="1")
        env.pop("JSAR_DATA_ROOT", None)  # the procedural ground: no data needed
        self.process = subprocess.Popen([sys.executable, "-m", "sim.demo", *args], cwd=REPO, env=env,
                                        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
        self.text = ""
        self._changed = threading.Condition()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        while chunk := self.process.stdout.read1(4096):
            with self._changed:
                self.text += chunk.decode("utf-8", errors="replace")
                self._changed.notify_all()

    def wait_for(self, text: str, timeout_s: float) -> bool:
        with self._changed:
            return self._changed.wait_for(lambda: text in self.text, timeout=timeout_s)

    def finish(self, timeout_s: float) -> int:
        code = self.process.wait(timeout=timeout_s)
        self._reader.join(timeout=10)
        return code

    def kill_group(self) -> None:
        try:
            os.killpg(self.process.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.process.wait(timeout=10)


def group_gone(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return True
    return False


def test_a_daemon_that_dies_at_start_ends_the_wait_with_its_own_error(tmp_path: Path) -> None:
    # gimbal.coast_s out of range: the service exits 2 naming the key. The wait for its heartbeat must end on
    # the exit, not after startup_timeout_s (then it would be a RuntimeError "no heartbeat ... within 300 s").
    cfg = ClosedLoopConfig(duration_s=1.0, startup_timeout_s=300.0, daemon_overrides={"gimbal": {"coast_s": -1}})
    loop = ClosedLoop(cfg, workdir=tmp_path)
    with pytest.raises(DaemonExited) as exited:
        with loop:
            pass
    assert exited.value.code == 2
    assert "gimbal.coast_s" in str(exited.value) and "at start" in str(exited.value)


def test_the_demo_reports_a_daemon_that_dies_at_start_without_a_traceback() -> None:
    demo = Demo("--pace", "lockstep", "--no-web", "--duration", "5", "--coast-s", "-1")
    try:
        code = demo.finish(timeout_s=120)
    finally:
        demo.kill_group()
    assert code == 1, demo.text
    assert "gimbal.coast_s: must be in" in demo.text and "exit code 2" in demo.text
    assert demo.text.rstrip().splitlines()[-1].startswith("VERDICT FAIL: the daemon exited (code 2)")
    assert "Traceback" not in demo.text


def test_ctrl_c_stops_the_demo_and_its_children_cleanly() -> None:
    demo = Demo("--pace", "lockstep", "--duration", "600", "--guidance", "off", "--web-port", "0")
    try:
        assert demo.wait_for("web ground station: http", 120), demo.text[-3000:]
        assert demo.wait_for("\rframe ", 120), demo.text[-3000:]  # the run's live status line: mid-run
        os.killpg(demo.process.pid, signal.SIGINT)  # what Ctrl-C in a terminal does: the whole group
        code = demo.finish(timeout_s=60)
        assert code == 130, demo.text[-3000:]
        assert "interrupted (Ctrl-C)" in demo.text.splitlines()[-1]
        assert "Traceback" not in demo.text and "KeyboardInterrupt" not in demo.text
        # the daemon, the web station and everything else the demo started were stopped before it exited
        assert group_gone(demo.process.pid), subprocess.run(["ps", "-o", "pid,cmd", "-g", str(demo.process.pid)],
                                                            capture_output=True, text=True).stdout
    finally:
        demo.kill_group()
