"""A stopped sim command (SIGTERM: systemd, a CI timeout, `kill`) stops the daemon it started."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


def _children(pid: int) -> list[int]:
    """PIDs whose parent is `pid` (Linux /proc)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        # pid (comm) state ppid ...: comm may hold spaces, so split after its closing parenthesis
        if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
            found.append(int(entry.name))
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc to find the daemon")
def test_sigterm_to_the_demo_stops_its_daemon():
    env = dict(os.environ, MAVLINK20="1")
    demo = subprocess.Popen([sys.executable, "-m", "sim.demo", "--pace", "lockstep", "--duration", "600",
                             "--guidance", "off"], cwd=REPO, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    started = threading.Event()
    output: list[str] = []

    def read() -> None:
        assert demo.stdout is not None
        for line in demo.stdout:
            output.append(line)
            if line.startswith("ground texture:"):  # printed inside the closed loop, daemon running
                started.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    daemons: list[int] = []
    try:
        assert started.wait(timeout=90), "demo did not start:\n" + "".join(output[-20:])
        daemons = [pid for pid in _children(demo.pid)
                   if b"-m\x00service" in Path(f"/proc/{pid}/cmdline").read_bytes()]
        assert len(daemons) == 1, f"expected one daemon child, found {daemons}"
        demo.send_signal(signal.SIGTERM)
        assert demo.wait(timeout=30) == 128 + signal.SIGTERM
        assert not _alive(daemons[0]), "the daemon outlived the demo"
    finally:
        if demo.poll() is None:
            demo.kill()
            demo.wait(timeout=10)
        for pid in daemons:
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
