"""Render speed of the synthetic scene on one thread (frames per second at the configured size).

    OMP_NUM_THREADS=1 python -m bench.scene [--frames 300] [--width 640 --height 480]
"""
from __future__ import annotations

import argparse
import math
import statistics
import time

import cv2

from sim.scene import CameraConfig, CameraPose, Scene, SceneConfig


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--texture", choices=("auto", "data", "procedural"), default="auto")
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    scene = Scene(SceneConfig(texture=args.texture), CameraConfig(args.width, args.height))
    times = []
    for k in range(args.frames):
        t = k / 30.0
        target = scene.path.pose(t)
        # Follow the car from 30 m up, 30 m behind: the view the closed loop mostly renders.
        pose = CameraPose(target.north - 30.0, target.east, 30.0, 0.0, -math.pi / 4)
        start = time.perf_counter()
        scene.render(pose, t)
        times.append(time.perf_counter() - start)
    median = statistics.median(times)
    print(f"scene render {args.width}x{args.height} ({scene.texture_source}), one thread: median "
          f"{median * 1e3:.2f} ms/frame = {1.0 / median:.0f} fps; p90 {sorted(times)[int(0.9 * len(times))] * 1e3:.2f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
