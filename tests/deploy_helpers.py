"""Helpers for the deployment tests (container image, systemd): podman, a synthetic target video with
known ground truth, the service config for a container, selecting the target and checking the track.
No tests here."""
from __future__ import annotations

import json
import math
import os
import resource
import subprocess
from pathlib import Path

import cv2
import numpy as np
import yaml

from tests.service_peers import GroundStation, Recorder
from tests.test_service_sources import scene

REPO = Path(__file__).resolve().parents[1]
IMAGE = os.environ.get("JSAR_IMAGE", "localhost/jsar-service")
SIZE, SIDE, N_FRAMES, FPS = (320, 240), 40, 120, 30.0
TRACK_RECT, INTERVAL = 2005, 511


def host_arch() -> str:
    """Debian's name for this machine's architecture (amd64, arm64)."""
    return {"x86_64": "amd64", "aarch64": "arm64"}.get(os.uname().machine, os.uname().machine)


def podman(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    return subprocess.run(["podman", *args], capture_output=True, text=True, timeout=timeout)


def podman_limits() -> list[str]:
    """--ulimit options where the hard limits are below rootful podman's defaults (as deploy/lib.sh)."""
    options = []
    nofile = resource.getrlimit(resource.RLIMIT_NOFILE)[1]
    nproc = resource.getrlimit(resource.RLIMIT_NPROC)[1]
    if nofile != resource.RLIM_INFINITY and nofile < 1048576:
        options.append(f"--ulimit=nofile={nofile}:{nofile}")
    if nproc != resource.RLIM_INFINITY and nproc < 4194304:
        options.append("--ulimit=nproc=4096:4096")
    return options


def target_centre(index: int) -> tuple[float, float]:
    """Ground truth of the synthetic video: the square's centre (pixels) in frame `index` (periodic, no jump at the loop)."""
    phase = 2 * math.pi * (index % N_FRAMES) / N_FRAMES
    return 160.0 + 60.0 * math.sin(phase), 120.0 + 25.0 * math.sin(2 * phase)


def write_target_video(folder: Path, fps: float = FPS) -> Path:
    """folder/target.avi (MJPG, SIZE, N_FRAMES at `fps`: the daemon paces the file at its own rate);
    folder and file readable by the container's user."""
    path = folder / "target.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, SIZE)
    for i in range(N_FRAMES):
        writer.write(scene(SIZE, target_centre(i), SIDE))
    writer.release()
    folder.chmod(0o755)  # the container's user (uid 10001) reads the bind mount
    path.chmod(0o644)
    return path


def write_config(folder: Path, mavlink_port: int, zenoh_port: int, prefix: str) -> Path:
    """folder/config.yaml: the documented defaults, source /data/target.avi looping, loopback MAVLink and Zenoh."""
    config = yaml.safe_load((REPO / "config.yaml").read_text())
    config["source"].update({"kind": "file", "path": "/data/target.avi", "loop": True, "realtime": True})
    config["mavlink"]["url"] = f"udpout:127.0.0.1:{mavlink_port}"
    config["zenoh"].update({"listen": [f"tcp/127.0.0.1:{zenoh_port}"], "prefix": prefix})
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "config.yaml"
    path.write_text(yaml.safe_dump(config))
    folder.chmod(0o755)
    path.chmod(0o644)
    return path


def zenoh_session(port: int):  # type: ignore[no-untyped-def]
    import zenoh

    zc = zenoh.Config()
    zc.insert_json5("mode", '"peer"')
    zc.insert_json5("scouting/multicast/enabled", "false")
    zc.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    return zenoh.open(zc)


def status(session, prefix: str) -> dict | None:  # type: ignore[no-untyped-def]
    """The daemon's <prefix>/status reply, None when it does not answer within 1 s."""
    replies = list(session.get(f"{prefix}/status", timeout=1.0))
    if replies and replies[0].ok is not None:
        return json.loads(replies[0].ok.payload.to_string())
    return None


def select_and_track(gcs: GroundStation, session, prefix: str, system_id: int, frames_wanted: int,
                     timeout_s: float) -> list[float]:  # type: ignore[no-untyped-def]
    """Select the synthetic target where the video shows it (frame ids from <prefix>/track, as a ground
    station sees them) with TRACK_RECTANGLE, wait for `frames_wanted` tracked frames; returns their
    centre errors (pixels). AssertionError when the selection is refused or too few frames are tracked."""
    reports = Recorder()
    subscriber = session.declare_subscriber(f"{prefix}/track", lambda s: reports.add(json.loads(s.payload.to_string())))
    try:
        def frames() -> list[dict]:
            with reports._cond:
                return [r.msg for r in reports.items]

        def tracked() -> list[dict]:
            return [f for f in frames() if f["state"] != "idle"]
        assert reports.wait_for(lambda: len(frames()) > 0, 30.0), f"no track reports on {prefix}/track"
        latest = max(f["frame_id"] for f in frames())
        cx, cy = target_centre(latest + 1)
        before = gcs.ack_count(TRACK_RECT)
        gcs.command_long(INTERVAL, [275, 100_000, 0, 0, 0, 0, 0], target=(system_id, 100))
        gcs.command_long(TRACK_RECT, [(cx - SIDE / 2) / SIZE[0], (cy - SIDE / 2) / SIZE[1],
                                      (cx + SIDE / 2) / SIZE[0], (cy + SIDE / 2) / SIZE[1], 0, 0, 0],
                         target=(system_id, 100))
        ack = gcs.wait_ack(TRACK_RECT, before, 30.0)
        assert ack is not None and ack.result == 0, f"TRACK_RECTANGLE not accepted: {ack}"
        assert reports.wait_for(lambda: len(tracked()) >= frames_wanted, timeout_s), f"{len(tracked())} tracked frames"
    finally:
        subscriber.undeclare()
    errors = []
    for f in tracked():
        x, y, w, h = f["box_px"]
        gx, gy = target_centre(f["frame_id"])
        errors.append(math.hypot(x + w / 2 - gx, y + h / 2 - gy))
    assert np.mean(np.array(errors) < 10.0) >= 0.9, f"centre errors {np.round(errors, 1)}"
    return errors
