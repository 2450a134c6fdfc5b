"""Export the synthetic scene as an OTB-style sequence (img/0001.jpg ..., groundtruth_rect.txt), seen by
a camera that follows the car perfectly (open loop), so trackers can be evaluated offline on exactly
the occlusions the closed loop meets.

    python -m sim.export out/synthetic_seed0 --seconds 12 --seed 0

groundtruth_rect.txt: MATLAB 1-based x,y,w,h of the car's projected outline; NaN,NaN,NaN,NaN where
less than half of the car is visible (OTB convention for 'target not visible').
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

import cv2

from sim.scene import CameraConfig, CameraPose, Scene, SceneConfig


def follow_pose(scene: Scene, t: float, altitude_m: float = 30.0, behind_m: float = 30.0) -> CameraPose:
    """Camera `behind_m` metres behind the car (along north), `altitude_m` up, looking at it."""
    target = scene.path.pose(t)
    return CameraPose(target.north - behind_m, target.east, altitude_m, 0.0, -math.atan2(altitude_m, behind_m))


def export(folder: Path, seconds: float, seed: int = 0, fps: float = 30.0, jpeg_quality: int = 95) -> int:
    """Write the sequence; returns the number of frames."""
    if seconds <= 0 or fps <= 0:
        raise ValueError(f"seconds and fps must be > 0, got {seconds}, {fps}")
    scene = Scene(SceneConfig(seed=seed), CameraConfig())
    (folder / "img").mkdir(parents=True, exist_ok=True)
    lines = []
    frames = int(round(seconds * fps))
    for k in range(frames):
        t = k / fps
        frame, truth = scene.render(follow_pose(scene, t), t)
        cv2.imwrite(str(folder / "img" / f"{k + 1:04d}.jpg"), frame, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
        if truth.visible:
            x, y, w, h = truth.box
            lines.append(f"{x + 1:.2f},{y + 1:.2f},{w:.2f},{h:.2f}")
        else:
            lines.append("NaN,NaN,NaN,NaN")
    (folder / "groundtruth_rect.txt").write_text("\n".join(lines) + "\n", encoding="utf-8")
    (folder / "SOURCE.txt").write_text(f"sim.scene synthetic sequence, seed {seed}, {fps:g} fps, "
                                       f"ground texture: {scene.texture_source}\n", encoding="utf-8")
    return frames


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--seconds", type=float, default=12.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--fps", type=float, default=30.0)
    args = parser.parse_args(argv)
    n = export(args.folder, args.seconds, args.seed, args.fps)
    print(f"wrote {n} frames to {args.folder}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
