"""Run the onboard service as a subprocess, configured from the top-level config.yaml plus overrides.

`python -m service --config FILE --source zenoh --mavlink URL` (service <-> sim contract). The sim
writes FILE; the daemon's log goes to a file next to it, so a failing test can show it.
"""
from __future__ import annotations

import copy
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any, Callable

import yaml

REPO_ROOT = Path(__file__).resolve().parent.parent  # the source tree (for an installed package: site-packages' parent)


def default_config() -> Path:
    """The top-level config.yaml the sim starts from: the source tree's, else the current directory's (an
    installed harness run from a folder holding the project's config, as `make check-arm64` does);
    FileNotFoundError naming both places when neither has one."""
    places = [REPO_ROOT / "config.yaml", Path.cwd() / "config.yaml"]
    for place in places:
        if place.is_file():
            return place
    raise FileNotFoundError(f"no config.yaml for the sim: looked in {places[0].parent} (source tree) and "
                            f"{places[1].parent} (current directory)")


def exit_on_sigterm() -> None:
    """Turn SIGTERM into SystemExit in the main thread, so a stopped sim command (systemd, CI timeout,
    `kill`) unwinds its `with` blocks and stops the daemon subprocess instead of orphaning it."""
    def _exit(signum: int, _frame: object) -> None:
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, _exit)


def deep_merge(base: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """A copy of `base` with `overrides` applied key by key (nested dicts merged, the rest replaced)."""
    merged = copy.deepcopy(base)
    for key, value in overrides.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = deep_merge(merged[key], value)
        else:
            merged[key] = copy.deepcopy(value)
    return merged


def write_config(path: Path, overrides: dict[str, Any], base_file: Path | None = None) -> dict[str, Any]:
    """Write base_file (default_config() if None) + overrides as YAML to `path`; returns the merged mapping."""
    with open(base_file if base_file is not None else default_config(), encoding="utf-8") as handle:
        base = yaml.safe_load(handle)
    merged = deep_merge(base, overrides)
    path.write_text(yaml.safe_dump(merged, sort_keys=False), encoding="utf-8")
    return merged


def rss_kib(pid: int) -> int:
    """Resident set size of process `pid` in KiB (Linux /proc), ValueError if it is gone."""
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as handle:
            for line in handle:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except FileNotFoundError as exc:
        raise ValueError(f"process {pid} is gone") from exc
    raise ValueError(f"no VmRSS for process {pid}")


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of process `pid` (all its threads) in seconds (Linux /proc), ValueError if
    it is gone."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as handle:
            fields = handle.read().rsplit(")", 1)[1].split()  # after the command name, which may hold spaces
    except FileNotFoundError as exc:
        raise ValueError(f"process {pid} is gone") from exc
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime, stime (fields 14, 15)


class DaemonExited(RuntimeError):
    """The daemon process ended while the sim was waiting on it: its exit code and its last log lines (a
    configuration error at start is the daemon's own message, e.g. `gimbal.coast_s: must be in ...`)."""

    def __init__(self, code: int | None, log_tail: str, during: str) -> None:
        self.code = code
        self.log_tail = log_tail
        super().__init__(f"the daemon exited {during} (exit code {code}); its log ends:\n{log_tail}")


class Daemon:
    """The service subprocess: start(), alive(), rss_kib(), stop() (SIGTERM, then kill after a grace).

    A watcher thread waits on the process from start() on: `exited` is set the moment it ends and the
    `on_exit` callbacks run, so whoever waits on the daemon (its heartbeat, its telemetry) can wait on that
    event too instead of sitting out a timeout."""

    def __init__(self, workdir: Path, overrides: dict[str, Any], mavlink_url: str, module: str = "service",
                 source: str | None = "zenoh", env: dict[str, str] | None = None) -> None:
        self.workdir = workdir
        self.module = module  # `python -m module`: the service, or a test's instrumented wrapper of it
        self.source = source  # --source: zenoh (the sim's camera), a file / image folder, /dev/videoN; None: the config's
        self.extra_env = dict(env or {})  # added to the daemon's environment (e.g. RUNTIME_DIRECTORY)
        self.config_path = workdir / "service-config.yaml"
        self.log_path = workdir / "service.log"
        self.config = write_config(self.config_path, overrides)
        self.mavlink_url = mavlink_url
        self.process: subprocess.Popen | None = None
        self._log_handle = None
        self.exited = threading.Event()  # set by the watcher when the process has ended
        self._on_exit: list[Callable[[], None]] = []

    def on_exit(self, callback: Callable[[], None]) -> None:
        """Call `callback()` (on the watcher thread) when the process ends; at once if it already has (a
        callback registered just as the process ends may run twice: it must not mind)."""
        self._on_exit.append(callback)
        if self.exited.is_set():
            callback()

    def _watch(self, process: subprocess.Popen) -> None:
        process.wait()
        self.exited.set()
        for callback in list(self._on_exit):
            callback()

    def start(self) -> "Daemon":
        env = dict(os.environ, MAVLINK20="1", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1",
                   MKL_NUM_THREADS="1", PYTHONUNBUFFERED="1", **self.extra_env)
        if self._log_handle is not None:
            self._log_handle.close()
        # a restart (start() after the process ended) appends to the same log
        self._log_handle = open(self.log_path, "a" if self.process is not None else "w", encoding="utf-8")
        self.exited.clear()
        source = ["--source", self.source] if self.source is not None else []
        self.process = subprocess.Popen(
            [sys.executable, "-m", self.module, "--config", str(self.config_path), *source,
             "--mavlink", self.mavlink_url],
            cwd=REPO_ROOT, env=env, stdout=self._log_handle, stderr=subprocess.STDOUT)
        threading.Thread(target=self._watch, args=(self.process,), name="daemon-exit", daemon=True).start()
        return self

    @property
    def pid(self) -> int:
        if self.process is None:
            raise ValueError("daemon not started")
        return self.process.pid

    def alive(self) -> bool:
        """True while the subprocess runs."""
        return self.process is not None and not self.exited.is_set() and self.process.poll() is None

    def exited_error(self, during: str) -> DaemonExited:
        """The DaemonExited to raise for a process that has ended (exit code, last log lines)."""
        code = self.process.returncode if self.process is not None else None
        return DaemonExited(code, self.log_tail(), during)

    def rss_kib(self) -> int:
        """Current RSS of the daemon in KiB."""
        return rss_kib(self.pid)

    def cpu_s(self) -> float:
        """CPU seconds the daemon has used so far."""
        return cpu_seconds(self.pid)

    def log_tail(self, lines: int = 40) -> str:
        """The last lines of the daemon's log (for failure messages)."""
        try:
            return "\n".join(self.log_path.read_text(encoding="utf-8", errors="replace").splitlines()[-lines:])
        except FileNotFoundError:
            return "(no log)"

    def stop(self, grace_s: float = 5.0) -> int | None:
        """SIGTERM and wait; SIGKILL if it does not stop in grace_s. Returns the exit code."""
        code = None
        if self.process is not None:
            if self.process.poll() is None:
                self.process.send_signal(signal.SIGTERM)
                try:
                    self.process.wait(timeout=grace_s)
                except subprocess.TimeoutExpired:
                    self.process.kill()
                    self.process.wait(timeout=grace_s)
            code = self.process.returncode
        if self._log_handle is not None:
            self._log_handle.close()
            self._log_handle = None
        return code
