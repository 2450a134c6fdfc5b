"""`python -m gcs.router` as a process for the tests (no tests here)."""
from __future__ import annotations

import os
import subprocess
import sys
import threading

from sim.daemon import REPO_ROOT


class Router:
    """`python -m gcs.router --listen ENDPOINT` as a process; start() waits for its listening line."""

    def __init__(self, endpoint: str, extra_args: tuple[str, ...] = ()) -> None:
        self.endpoint = endpoint
        self.extra_args = extra_args  # e.g. --tls-ca/--tls-cert/--tls-key, --access FILE
        self.process: subprocess.Popen | None = None

    def start(self, timeout_s: float = 30.0) -> "Router":
        self.process = subprocess.Popen([sys.executable, "-m", "gcs.router", "--listen", self.endpoint,
                                         *self.extra_args],
                                        cwd=REPO_ROOT, env=dict(os.environ, PYTHONUNBUFFERED="1"),
                                        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        ready = threading.Event()
        self.lines: list[str] = []

        def read() -> None:
            assert self.process is not None and self.process.stdout is not None
            for line in self.process.stdout:  # drained to the end, so the pipe never fills
                self.lines.append(line.rstrip("\n"))
                if "zenoh router listening" in line:
                    ready.set()
            ready.set()  # ended: start() reports its output
        threading.Thread(target=read, name="router-output", daemon=True).start()
        started = ready.wait(timeout_s) and any("zenoh router listening" in line for line in self.lines)
        assert started, "the router did not start:\n" + "\n".join(self.lines)
        return self

    def kill(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait(timeout=10.0)
