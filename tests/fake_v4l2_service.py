"""`python -m tests.fake_v4l2_service ARGS`: the daemon with OpenCV's V4L2 capture replaced by a fake, for the
camera fault test (issue 42): the V4L2 adapter (service.sources.v4l2) runs unchanged on a fake device.

The device node is a file named by `source.device`; the fake's open fails while `<device>.busy` exists (a
driver that refuses the device) and reads fail while `<device>.unplugged` exists; otherwise it delivers
the textured test scene (160x120, a bright square) about 30 times a second.
"""
from __future__ import annotations

import os
import sys
import threading

import cv2
import numpy as np

import service.__main__
from service.sources import v4l2

FRAME_PERIOD_S = 1 / 30  # the fake camera's own pacing


def scene() -> np.ndarray:
    """160x120 BGR: textured background (fixed seed), a bright checkered 24-px square at (80, 60)."""
    rng = np.random.default_rng(7)
    image = cv2.resize(rng.integers(0, 120, (16, 21, 3), dtype=np.uint8), (160, 120), interpolation=cv2.INTER_NEAREST)
    patch = np.full((24, 24, 3), 250, np.uint8)
    patch[::8, :, 1] = 30
    image[48:72, 68:92] = patch
    return image


class FakeCapture:
    """cv2.VideoCapture(device, cv2.CAP_V4L2) on a file standing for the device node."""

    def __init__(self, device: object, api: int) -> None:
        self.device = str(device)
        self.opened = not os.path.exists(self.device + ".busy") and os.path.exists(self.device)
        self.image = scene()
        self.pace = threading.Event()  # never set: its timed wait is the camera's frame interval

    def isOpened(self) -> bool:  # noqa: N802 - OpenCV's name
        return self.opened

    def set(self, prop: int, value: float) -> bool:
        return True

    def read(self) -> tuple[bool, np.ndarray | None]:
        self.pace.wait(FRAME_PERIOD_S)
        if os.path.exists(self.device + ".unplugged") or not os.path.exists(self.device):
            return False, None
        return True, self.image.copy()

    def release(self) -> None:
        self.opened = False


if __name__ == "__main__":
    v4l2.cv2.VideoCapture = FakeCapture  # type: ignore[attr-defined,misc] - the module's cv2 is OpenCV's
    sys.exit(service.__main__.main())
