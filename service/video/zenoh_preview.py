"""The preview over Zenoh: tracked frames as JPEG on `<prefix>/camera/preview`.

Each sample is one frame in the frame wire format of service.sources.zenoh_wire (32-byte "JFR1"
header, pixel format b"JPEG", width, height, frame id, capture time, then the JPEG stream). The
frame id and capture time are the tracked frame's own, exactly those the `<prefix>/track` telemetry
carries for it (`frame_id`, `capture_time`), so a ground station draws each box on its own frame.
Frames are scaled down to fit the configured size (aspect kept, never enlarged); encoding and
publishing run on the worker's thread (service.video.latest_frame_worker), never on the loop's.
"""
from __future__ import annotations

import cv2
import numpy as np
import zenoh

from service.config import PreviewConfig
from service.sources.base import Frame
from service.sources.zenoh_wire import encode_frame
from service.video.latest_frame_worker import LatestFrameWorker, WorkerOutput, fit_size

PREVIEW_KEY = "camera/preview"  # under the service's Zenoh prefix


def preview_payload(frame: Frame, config: PreviewConfig) -> bytes:
    """One preview sample: `frame` scaled to fit max_width_px x max_height_px, JPEG at jpeg_quality."""
    image = frame.image
    size = (image.shape[1], image.shape[0])
    out = fit_size(size, (config.max_width_px, config.max_height_px))
    if out != size:
        image = cv2.resize(image, out, interpolation=cv2.INTER_AREA)
    return encode_frame(np.ascontiguousarray(image), frame.frame_id, frame.capture_time_s, b"JPEG",
                        config.jpeg_quality)


class ZenohPreview(WorkerOutput):
    """Publishes the newest tracked frame as a JPEG preview sample, at most max_fps per second."""

    def __init__(self, session: zenoh.Session, prefix: str, config: PreviewConfig) -> None:
        self.key = f"{prefix}/{PREVIEW_KEY}"
        self.config = config
        # DROP: a congested link loses preview samples instead of blocking the publishing thread
        self._publisher = session.declare_publisher(self.key, congestion_control=zenoh.CongestionControl.DROP)
        self.worker = LatestFrameWorker("preview", self._publish, config.max_fps, close=self._undeclare)

    def _publish(self, frame: Frame) -> None:
        self._publisher.put(preview_payload(frame, self.config))

    def _undeclare(self) -> None:
        self._publisher.undeclare()

    def status(self) -> dict[str, object]:
        return {"key": self.key, **self.worker.counters()}
