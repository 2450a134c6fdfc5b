"""The container image as built by `make image`, run with podman: the daemon starts as the non-root
user, answers the MAVLink handshake of a ground station (through an autopilot peer on loopback,
`--network host`), reads a mounted video file, tracks the target selected with TRACK_RECTANGLE, and
stops within 2 s on `podman stop`.

Skipped where podman is absent or the image is not built. The image of another architecture (arm64
on an x86-64 machine) runs under qemu-user emulation only with JSAR_TEST_EMULATED=1 (`make image`
sets it): it is slow.
"""
from __future__ import annotations

import os
import shutil
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

from sim.ports import free_tcp_port, free_udp_ports
from tests.deploy_helpers import (FPS, IMAGE, SIZE, host_arch, podman, podman_limits, select_and_track, write_config,
                                  write_target_video, zenoh_session)
from tests.service_peers import AutopilotPeer, GroundStation, camera_handshake

SYSTEM_ID = 3


def _arches() -> list:
    """The architectures `make image` built this time (JSAR_IMAGE_ARCHES): an image of another one may be older."""
    emulated = os.environ.get("JSAR_TEST_EMULATED") == "1"
    built = os.environ.get("JSAR_IMAGE_ARCHES", "amd64 arm64").split()
    return [pytest.param(a, marks=[
        pytest.mark.skipif(a not in built, reason=f"the {a} image was not built in this run (JSAR_IMAGE_ARCHES)"),
        pytest.mark.skipif(a != host_arch() and not emulated,
                           reason=f"the {a} image runs under emulation: set JSAR_TEST_EMULATED=1")])
            for a in ("amd64", "arm64")]


# Under emulation the daemon processes a few frames per second: the video plays at 2 fps there, so
# that it does not skip frames (latest frame wins) and the target moves as far between processed frames
# as natively at 30 fps.
EMULATED_FPS = 2.0


@pytest.mark.slow
@pytest.mark.parametrize("arch", _arches())
def test_image_runs_the_daemon_as_non_root_tracks_a_mounted_video_and_stops_within_2s(arch: str, tmp_path: Path) -> None:
    if os.environ.get("JSAR_CHECK_IMAGE") != "1":  # an image left from an older tree would test that tree
        pytest.skip("image check: run `make image` (builds the image from this tree, then runs this test)")
    if shutil.which("podman") is None:
        pytest.skip("podman is not installed: `make image` installs it and builds the image")
    image = f"{IMAGE}:{arch}"
    if podman("image", "exists", image).returncode != 0:
        pytest.skip(f"image {image} is not built: run `make image`")

    emulated = arch != host_arch()
    video_dir = tmp_path / "video"
    video_dir.mkdir()
    write_target_video(video_dir, EMULATED_FPS if emulated else FPS)
    (service_port, gcs_port), zenoh_port = free_udp_ports(2), free_tcp_port()
    config_dir = tmp_path / "etc"
    write_config(config_dir, service_port, zenoh_port, "imagetest")
    autopilot = AutopilotPeer(service_port, gcs_port, system_id=SYSTEM_ID).start()
    gcs = GroundStation(gcs_port).start()
    name = f"jsar-image-test-{uuid.uuid4().hex[:8]}"
    run = podman("run", "-d", "--name", name, "--arch", arch, "--network", "host", *podman_limits(),
                 "-v", f"{video_dir}:/data:ro", "-v", f"{config_dir}:/etc/jsar:ro", image)
    assert run.returncode == 0, run.stderr
    session = None
    try:
        # the handshake once the daemon is up (container start + imports: minutes under emulation)
        info = camera_handshake(gcs, SYSTEM_ID, timeout_s=300.0 if emulated else 60.0)
        assert (info.resolution_h, info.resolution_v) == SIZE

        # the daemon is the container's main process and runs as the image's user
        pid = int(podman("inspect", "--format", "{{.State.Pid}}", name).stdout.strip())
        proc_status = Path(f"/proc/{pid}/status").read_text()
        uid = int(next(line for line in proc_status.splitlines() if line.startswith("Uid:")).split()[1])
        assert uid == 10001, f"daemon runs as uid {uid}"
        assert "jsar-service" in Path(f"/proc/{pid}/cmdline").read_text().replace("\0", " ")

        session = zenoh_session(zenoh_port)
        errors = select_and_track(gcs, session, "imagetest", SYSTEM_ID, frames_wanted=30 if emulated else 90,
                                  timeout_s=30 / EMULATED_FPS + 120.0 if emulated else 20.0)
        assert gcs.received.wait_for(lambda: any(r.msg.tracking_status == 1 for r in
                                                 gcs.received.of("CAMERA_TRACKING_IMAGE_STATUS")), 5.0)
        assert autopilot.from_service.of("GIMBAL_MANAGER_SET_PITCHYAW"), "no gimbal commands to the autopilot"

        # podman stop sends SIGTERM (the image's STOPSIGNAL); the daemon exits by itself within 2 s
        sent = time.time()
        stop = podman("stop", "--time", "10", name, timeout=30.0)
        stop_call_s = time.time() - sent
        assert stop.returncode == 0, stop.stderr
        exit_code, finished_ns = podman("inspect", "--format", "{{.State.ExitCode}} {{.State.FinishedAt.UnixNano}}",
                                        name).stdout.split()
        stopped_s = int(finished_ns) / 1e9 - sent
        assert int(exit_code) == 0, f"exit code {exit_code} (137: killed after the stop timeout)"
        assert stopped_s < 2.0, f"stopped {stopped_s:.2f} s after SIGTERM (podman stop took {stop_call_s:.2f} s)"
        logs = podman("logs", name)
        text = logs.stdout + logs.stderr
        assert "event=started" in text and "event=stopped" in text and "Traceback" not in text, text[-3000:]
        print(f"\n{arch}: median centre error {np.median(errors):.1f} px over {len(errors)} tracked frames; "
              f"exited {stopped_s:.2f} s after SIGTERM (podman stop returned after {stop_call_s:.2f} s)")
    finally:
        if session is not None:
            session.close()
        gcs.close()
        autopilot.close()
        podman("rm", "--force", "--time", "0", name)
