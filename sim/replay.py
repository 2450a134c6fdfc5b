"""Publish a recorded video as the camera over Zenoh: an OTB-style sequence folder or a video file.

Pacing: `realtime` sends at the recording's frame rate (like a camera; the daemon drops what it cannot
keep up with), `lockstep` sends frame N+1 only after the daemon's telemetry for frame N arrived (as
fast as the daemon consumes; nothing dropped, reproducible).

    python -m sim.replay $JSAR_DATA_ROOT/UAVDT_S0310 --connect tcp/127.0.0.1:7447 --pace realtime

RecordingWorld serves a recording to the closed loop instead (`python -m sim.demo --replay`).
"""
from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Literal

import cv2
import numpy as np

from sim.scene import CameraPose, GroundTruth
from sim.zenoh_link import SimCamera, ZenohEndpoints

Pace = Literal["realtime", "lockstep"]
FOLDER_FPS = 30.0  # OTB folders carry no rate; UAV123@10fps etc. are still replayed as a 30 fps camera


@dataclass(frozen=True)
class Recording:
    """A sequence on disk: frame paths (folder) or a video path; fps; OTB ground truth if present."""

    path: Path
    frames: tuple[Path, ...]
    fps: float
    groundtruth: tuple[tuple[float, float, float, float], ...]  # 0-based (x, y, w, h) pixels, NaN = absent

    @property
    def is_video(self) -> bool:
        return not self.frames


def read_groundtruth(path: Path) -> tuple[tuple[float, float, float, float], ...]:
    """OTB groundtruth_rect.txt (1-based x,y,w,h; commas, tabs or spaces; NaN rows) as 0-based boxes."""
    boxes = []
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        if not line.strip():
            continue
        parts = line.replace(",", " ").replace("\t", " ").split()
        if len(parts) != 4:
            raise ValueError(f"{path.name} line {number}: expected 4 values, got {len(parts)}")
        x, y, w, h = (float(p) for p in parts)
        boxes.append((x - 1.0, y - 1.0, w, h))  # MATLAB 1-based -> pixel 0-based
    return tuple(boxes)


def open_recording(path: Path) -> Recording:
    """An OTB folder (img/*.jpg + groundtruth_rect.txt) or a video file (ValueError if neither)."""
    if path.is_dir():
        frames = tuple(sorted((path / "img").glob("*.jpg"))) or tuple(sorted(path.glob("*.jpg")))
        if not frames:
            raise ValueError(f"{path} has no img/*.jpg frames")
        gt_file = path / "groundtruth_rect.txt"
        groundtruth = read_groundtruth(gt_file) if gt_file.exists() else ()
        return Recording(path, frames, FOLDER_FPS, groundtruth)
    if path.is_file():
        capture = cv2.VideoCapture(str(path))
        try:
            if not capture.isOpened():
                raise ValueError(f"cannot open video {path}")
            fps = capture.get(cv2.CAP_PROP_FPS)
        finally:
            capture.release()
        return Recording(path, (), fps if fps and math.isfinite(fps) and fps > 0 else FOLDER_FPS, ())
    raise ValueError(f"{path} is neither a sequence folder nor a video file")


def iter_frames(recording: Recording) -> Iterator[np.ndarray]:
    """BGR uint8 frames in order (ValueError on an unreadable image)."""
    if not recording.is_video:
        for frame_path in recording.frames:
            image = cv2.imread(str(frame_path), cv2.IMREAD_COLOR)
            if image is None:
                raise ValueError(f"unreadable frame {frame_path.name}")
            yield image
        return
    capture = cv2.VideoCapture(str(recording.path))
    try:
        while True:
            ok, image = capture.read()
            if not ok:
                return
            yield image
    finally:
        capture.release()


class RecordingWorld:
    """A recording as the closed loop's world (sim.closed_loop.World), open loop: at simulated time t the
    frame round(t * fps) whatever the camera's pose (the recorded camera does not follow the gimbal), with
    its ground-truth box (the car's ground position unknown). After the last frame the recording starts
    over when `loop`, else the last frame holds."""

    def __init__(self, recording: Recording, loop: bool = False) -> None:
        self.recording = recording
        self.loop = loop
        self.frames = list(iter_frames(recording))
        if not self.frames:
            raise ValueError(f"{recording.path} has no frames")

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) pixels of the frames."""
        return self.frames[0].shape[1], self.frames[0].shape[0]

    def render(self, pose: CameraPose, t: float) -> tuple[np.ndarray, GroundTruth]:
        index = int(round(t * self.recording.fps))
        index = index % len(self.frames) if self.loop else min(index, len(self.frames) - 1)
        truth = self.recording.groundtruth
        box = truth[index] if index < len(truth) else (math.nan,) * 4
        seen = 1.0 if all(math.isfinite(v) for v in box) else 0.0
        return self.frames[index], GroundTruth(box, seen, seen, None)


@dataclass
class ReplayStats:
    """What a replay did: frames sent, telemetry samples matched, frames the daemon skipped."""

    sent: int = 0
    acknowledged: int = 0
    skipped: int = 0
    timeouts: int = 0
    seconds: float = 0.0


def replay(recording: Recording, camera: SimCamera, pace: Pace = "realtime", first_frame_id: int = 1,
           ack_timeout_s: float = 5.0, max_frames: int | None = None, stop: "object | None" = None) -> ReplayStats:
    """Publish the recording once; `stop` (a threading.Event) ends it early."""
    if pace not in ("realtime", "lockstep"):
        raise ValueError(f"pace must be realtime or lockstep, got {pace!r}")
    stats = ReplayStats()
    period = 1.0 / recording.fps
    start = time.monotonic()
    for index, image in enumerate(iter_frames(recording)):
        if max_frames is not None and index >= max_frames:
            break
        if stop is not None and stop.is_set():  # type: ignore[attr-defined]
            break
        frame_id = first_frame_id + index
        if pace == "realtime":
            delay = start + index * period - time.monotonic()
            if delay > 0 and stop is not None and stop.wait(delay):  # type: ignore[attr-defined]
                break
            elif delay > 0 and stop is None:
                time.sleep(delay)  # pacing a camera, not synchronisation
        camera.publish(image, frame_id)
        stats.sent += 1
        if pace == "lockstep":
            sample = camera.telemetry.wait_frame(frame_id, ack_timeout_s)
            if sample is None:
                stats.timeouts += 1
            elif int(sample["frame_id"]) == frame_id:
                stats.acknowledged += 1
            else:
                stats.skipped += 1
    stats.seconds = time.monotonic() - start
    return stats


def main(argv: list[str] | None = None) -> int:
    """Command line: replay a sequence folder or video over Zenoh."""
    parser = argparse.ArgumentParser(description="Publish a sequence folder or a video file as the camera over Zenoh")
    parser.add_argument("path", type=Path)
    parser.add_argument("--pace", choices=("realtime", "lockstep"), default="realtime")
    parser.add_argument("--prefix", default="jsar")
    parser.add_argument("--connect", action="append", default=[], help="zenoh endpoint, e.g. tcp/127.0.0.1:7447")
    parser.add_argument("--listen", action="append", default=[])
    parser.add_argument("--loop", action="store_true", help="repeat until Ctrl-C")
    args = parser.parse_args(argv)
    recording = open_recording(args.path)
    endpoints = ZenohEndpoints(listen=tuple(args.listen), connect=tuple(args.connect), prefix=args.prefix)
    with SimCamera(endpoints) as camera:
        next_id = 1
        try:
            while True:
                stats = replay(recording, camera, args.pace, first_frame_id=next_id)
                next_id += stats.sent
                print(f"replayed {stats.sent} frames in {stats.seconds:.1f} s "
                      f"({stats.sent / max(stats.seconds, 1e-9):.1f} fps), daemon acknowledged {stats.acknowledged}, "
                      f"skipped {stats.skipped}, timeouts {stats.timeouts}", flush=True)
                if not args.loop:
                    break
        except KeyboardInterrupt:
            pass
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
