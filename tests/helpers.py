"""Shared test helpers that are not fixtures: skip-or-fail on a missing peer, frame folders, the real sequences,
background threads that run until close(), and the drone's local camera over Zenoh.

(Loopback ports come from sim.ports; the fixtures and hooks stay in tests/conftest.py.)"""
from __future__ import annotations

import os
import threading
from pathlib import Path
from typing import Any, Callable, Self

import numpy as np
import pytest


def require(missing: str | None) -> None:
    """Skip with the reason `missing` (a peer the test needs is absent) outside CI; fail in CI (env CI set)."""
    if missing is None:
        return
    if os.environ.get("CI"):
        pytest.fail(f"CI needs it: {missing}")
    pytest.skip(missing)


def write_square_frames(folder: Path, count: int, start: tuple[float, float], side: int = 20) -> Path:
    """`count` 160x120 PNG frames of bench.fuzz.scene in `folder`, 0000.png on: the square (side pixels) at
    `start` (centre, pixels) moving 1 px left a frame; the folder."""
    import cv2

    from bench.fuzz import scene

    for i in range(count):
        cv2.imwrite(str(folder / f"{i:04d}.png"), scene((160, 120), (start[0] - i, start[1]), side))
    return folder


def real_sequence(data_root: Path, name: str):
    """Sequence `name` under the data root, read by jsar.eval.dataset.load_sequence (frame paths; ground truth
    (N, 4) 0-based x, y, w, h pixels, NaN rows = target not visible); skip when it is not there."""
    from jsar.eval.dataset import load_sequence

    folder = data_root / name
    if not folder.is_dir():
        pytest.skip(f"sequence {name} is not under JSAR_DATA_ROOT")
    return load_sequence(folder)


class Background:
    """Daemon threads running `targets` (each loops until `_stop` is set): start() starts them; close() sets
    `_stop`, waits up to join_s seconds for each, then release() frees what they used."""

    def __init__(self, *targets: Callable[[], None], join_s: float = 1.0) -> None:
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=target, daemon=True) for target in targets]
        self._join_s = join_s

    def start(self) -> Self:
        for thread in self._threads:
            thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(self._join_s)
        self.release()

    def release(self) -> None:
        """What the threads used (sockets, connections), freed once they stopped; nothing here."""


class LocalCamera(Background):
    """The drone's own camera on a sim.zenoh_link.SimCamera (`sim`): a grey 160x120 frame 15 times a second,
    ids from 1; runs from construction until close()."""

    def __init__(self, sim: Any) -> None:
        super().__init__(self._run, join_s=5.0)
        self.sim = sim
        self.image = np.full((120, 160, 3), 90, np.uint8)
        self.frame_id = 0
        self.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            self.frame_id += 1
            self.sim.publish(self.image, self.frame_id)
            self._stop.wait(1 / 15)  # camera pacing, not synchronisation
