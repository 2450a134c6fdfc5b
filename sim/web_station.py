"""The web ground station next to the sim: as a subprocess (`python -m gcs.web`), and a closed loop that
runs in real time waiting for the operator's click instead of selecting the car itself.

Used by `make run` (sim.demo prints the page's address) and the browser tests.
"""
from __future__ import annotations

import collections
import contextlib
import os
import subprocess
import sys
import threading
import time
from typing import Callable, Iterator

from sim.closed_loop import ClosedLoop
from sim.daemon import REPO_ROOT
from sim.scene import GroundTruth

ADDRESS_LINE = "web station: "


class WebStation:
    """`python -m gcs.web` as a subprocess: start() waits for its address line; url; stop()."""

    def __init__(self, mavlink_urls: list[str], zenoh_connect: list[str], port: int = 0,
                 extra_args: tuple[str, ...] = ()) -> None:
        self.args = [sys.executable, "-m", "gcs.web", "--port", str(port)]
        for url in mavlink_urls:
            self.args += ["--mavlink", url]
        for endpoint in zenoh_connect:
            self.args += ["--zenoh", endpoint]
        self.args += list(extra_args)
        self.process: subprocess.Popen | None = None
        self.lines: collections.deque[str] = collections.deque(maxlen=300)
        self.url: str | None = None
        self._announced = threading.Event()
        self._reader: threading.Thread | None = None
        self._line_added = threading.Condition()
        self.line_count = 0  # lines read so far (wait_line counts from a given one)

    def start(self, timeout_s: float = 30.0) -> "WebStation":
        """Start it and wait (event, timeout_s) for `web station: URL`; RuntimeError with its output otherwise."""
        env = dict(os.environ, MAVLINK20="1", PYTHONUNBUFFERED="1")
        self.process = subprocess.Popen(self.args, cwd=REPO_ROOT, env=env, stdout=subprocess.PIPE,
                                        stderr=subprocess.STDOUT, text=True, bufsize=1)
        self._reader = threading.Thread(target=self._read, name="web-station-output", daemon=True)
        self._reader.start()
        if not self._announced.wait(timeout_s) or self.url is None:
            self.stop()
            raise RuntimeError(f"the web station did not start within {timeout_s} s; output:\n{self.output()}")
        return self

    def _read(self) -> None:
        assert self.process is not None and self.process.stdout is not None
        for line in self.process.stdout:  # drained to the end, so the pipe never fills
            line = line.rstrip("\n")
            with self._line_added:
                self.lines.append(line)
                self.line_count += 1
                self._line_added.notify_all()
            if line.startswith(ADDRESS_LINE) and self.url is None:
                self.url = line[len(ADDRESS_LINE):].strip()
                self._announced.set()
        self._announced.set()  # ended without its address: start() reports the output

    def output(self) -> str:
        return "\n".join(self.lines)

    def wait_line(self, text: str, timeout_s: float, after: int = 0) -> str | None:
        """The first output line containing `text` among lines number > `after` (see line_count) still held,
        waiting (event, timeout_s) for it; None on timeout."""
        def found() -> str | None:
            held = list(self.lines)
            first = self.line_count - len(held)  # number of lines already dropped from the deque
            return next((line for i, line in enumerate(held) if first + i >= after and text in line), None)

        with self._line_added:
            self._line_added.wait_for(lambda: found() is not None, timeout=timeout_s)
            return found()

    def alive(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def stop(self, timeout_s: float = 10.0) -> int | None:
        """SIGTERM, then kill after timeout_s; returns the exit code."""
        if self.process is None:
            return None
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        if self._reader is not None:
            self._reader.join(timeout=2.0)
        return self.process.returncode

    def __enter__(self) -> "WebStation":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


class OperatorRun:
    """A started ClosedLoop run in real time for an operator: the scene waits at t = 0 (the car where it
    starts) until the daemon reports a track, i.e. until someone selected the car, then moves on; the
    mock autopilot steps one frame period per frame. Keeps each published frame's ground truth by frame id."""

    def __init__(self, loop: ClosedLoop, keep_frames: int = 3000) -> None:
        self.loop = loop
        self.keep_frames = keep_frames
        self.truths: collections.OrderedDict[int, GroundTruth] = collections.OrderedDict()
        self.scene_time_s = 0.0
        self.selected = False  # the daemon has reported a track: the scene moves
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="operator-run", daemon=True)
        self.error: BaseException | None = None

    def start(self) -> "OperatorRun":
        self._thread.start()
        return self

    def _run(self) -> None:
        loop = self.loop
        dt = 1.0 / loop.cfg.fps
        next_wall = time.monotonic()
        try:
            while not self._stop.is_set():
                frame, truth = loop.render(self.scene_time_s)
                frame_id = loop.publish(frame)
                last = loop.camera.telemetry.last or {}
                with self._cond:
                    self.truths[frame_id] = truth
                    while len(self.truths) > self.keep_frames:
                        self.truths.popitem(last=False)
                    if last.get("state") in ("tracking", "recovered", "lost"):
                        self.selected = True
                    if self.selected:
                        self.scene_time_s += dt
                    self._cond.notify_all()
                loop.autopilot.step(dt)
                next_wall += dt
                delay = next_wall - time.monotonic()
                if delay > 0:
                    self._stop.wait(delay)  # camera pacing, not synchronisation
                else:
                    next_wall = time.monotonic()  # behind: carry on from now rather than burst
        except BaseException as exc:  # noqa: BLE001 - reported to the caller by wait_for / stop
            self.error = exc
            with self._cond:
                self._cond.notify_all()

    def truth(self, frame_id: int) -> GroundTruth | None:
        """The ground truth of a frame this run published (None if unknown or too old)."""
        with self._cond:
            return self.truths.get(frame_id)

    def wait_for(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Block until predicate() holds (re-checked after every frame) or timeout_s passes."""
        with self._cond:
            ok = self._cond.wait_for(lambda: self.error is not None or predicate(), timeout=timeout_s)
        if self.error is not None:
            raise RuntimeError("the operator run failed") from self.error
        return ok

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)


def free_tcp_port(preferred: int) -> int:
    """`preferred` if it can be bound on 127.0.0.1 now, else 0 (any free port)."""
    import socket
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        try:
            sock.bind(("127.0.0.1", preferred))
        except OSError:
            return 0
    return preferred



def daemon_listen(port: int) -> dict:
    """Daemon config overrides: listen for Zenoh on tcp/127.0.0.1:port, as a drone's daemon does for ground
    stations (config.yaml zenoh.listen), so the web station can connect to it."""
    return {"zenoh": {"listen": [f"tcp/127.0.0.1:{port}"]}}


@contextlib.contextmanager
def web_station_beside(loop: ClosedLoop, daemon_zenoh_port: int, web_port: int = 8080) -> Iterator[WebStation]:
    """The web station on the loop's ground-station link and the daemon's Zenoh endpoint (see daemon_listen),
    serving on web_port if free, else on any free port."""
    station = WebStation([f"udpout:127.0.0.1:{loop.gcs_port}"], [f"tcp/127.0.0.1:{daemon_zenoh_port}"],
                         port=free_tcp_port(web_port)).start()
    try:
        yield station
    finally:
        station.stop()
