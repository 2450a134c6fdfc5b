"""`make run`: the whole system on this machine, without a drone.

Starts the mock autopilot, the sim and the daemon (config.yaml + the sim's overrides), selects the
target through the mavsdk ground station, runs about 30 s with a live status line, prints a summary
and writes an annotated video under out/.

    python -m sim.demo                                  # closed loop, ArduPilot flavour, real time
    python -m sim.demo --flavour px4 --guidance velocity
    python -m sim.demo --replay UAVDT_S0310             # a shared sequence from $JSAR_DATA_ROOT
    python -m sim.demo --coast-s 0                      # hold the gimbal at once when lost (no coasting)
"""
from __future__ import annotations

import argparse
import math
import os
import tempfile
import threading
import time
from pathlib import Path

import cv2
import numpy as np

from sim.closed_loop import (BOX_COLOUR, LEGEND, LOST_COLOUR, TRUTH_COLOUR, ClosedLoop, ClosedLoopConfig, draw_legend,
                              draw_status_line, free_port)
from sim.daemon import exit_on_sigterm
from sim.scene import SceneConfig
from sim.summary import camera_command_rows, counter_rows, format_rows, run_rows

OUT_DIR = Path(__file__).resolve().parent.parent / "out"
REPLAY_LEGEND = tuple((colour, label.replace("car", "target")) for colour, label in LEGEND[:3])  # no centring goal


def print_summary(title: str, summary: dict, status: dict | None = None) -> None:
    """Each figure with what it means, then the daemon's counters (sim.summary); status: the daemon's
    status answer (counters, mavlink_refusals)."""
    status = status or {}
    counters = status.get("counters", {})
    rows = run_rows(summary) + camera_command_rows(counters, status.get("mavlink_refusals", [])) + counter_rows(counters)
    print("\n" + format_rows(title, rows))


def run_closed_loop(args: argparse.Namespace) -> int:
    video = OUT_DIR / f"demo_closed_loop_{args.flavour}.avi"
    overrides = {"gimbal": {"coast_s": args.coast_s}} if args.coast_s is not None else {}
    cfg = ClosedLoopConfig(flavour=args.flavour, duration_s=args.duration, pace=args.pace,
                           guidance=args.guidance, tracker=args.tracker, scene=SceneConfig(seed=args.seed),
                           video_path=video, daemon_overrides=overrides)
    print(f"closed loop: mock {args.flavour} autopilot, synthetic scene (seed {args.seed}), daemon with "
          f"guidance {args.guidance}, {args.pace} pacing, {args.duration:.0f} s", flush=True)
    with ClosedLoop(cfg) as loop:
        print(f"ground texture: {loop.scene.texture_source}; selecting the car through the mavsdk ground station",
              flush=True)
        result = loop.run(live=True)
        summary = result.summary()
        summary["autopilot_events"] = "; ".join(e for _, e in loop.autopilot.model.events[-5:]) or "none"
        summary["annotated_video"] = str(video.relative_to(OUT_DIR.parent))
        print_summary("closed loop summary", summary, {"counters": result.counters, "mavlink_refusals": result.refusals})
    return 0 if result.daemon_alive else 1


def run_replay(args: argparse.Namespace) -> int:
    """Replay a shared sequence as the camera; the target = the sequence's first ground-truth box."""
    from sim.autopilot import MockAutopilot, run_realtime
    from sim.daemon import Daemon
    from sim.gcs import GroundStation
    from sim.replay import iter_frames, open_recording
    from sim.vehicle_model import VehicleConfig
    from sim.zenoh_link import SimCamera, ZenohEndpoints

    path = Path(args.replay)
    if not path.exists():
        root = os.environ.get("JSAR_DATA_ROOT")
        if not root:
            raise SystemExit(f"--replay {args.replay}: not a path, and JSAR_DATA_ROOT is not set")
        path = Path(root) / args.replay
    recording = open_recording(path)
    if not recording.groundtruth:
        raise SystemExit(f"{path.name} has no groundtruth_rect.txt: nothing to select")
    service_port, gcs_port, zenoh_port = free_port(2), free_port(2), free_port(1)
    video = OUT_DIR / f"demo_replay_{path.name}.avi"
    stop = threading.Event()
    with tempfile.TemporaryDirectory(prefix="jsar-demo-") as workdir, \
            MockAutopilot(VehicleConfig(flavour=args.flavour), service_port, gcs_port) as autopilot, \
            SimCamera(ZenohEndpoints(listen=(f"tcp/127.0.0.1:{zenoh_port}",))) as camera:
        stepper = threading.Thread(target=run_realtime, args=(autopilot, stop), daemon=True)
        stepper.start()
        overrides = {"source": {"kind": "zenoh"}, "gimbal": {"backend": args.flavour},
                     "zenoh": {"enabled": True, "mode": "peer", "listen": [],
                               "connect": [f"tcp/127.0.0.1:{zenoh_port}"], "multicast_scouting": False}}
        if args.tracker:
            overrides["tracker"] = {"name": args.tracker, "params": {}}
        daemon = Daemon(Path(workdir), overrides, f"udpout:127.0.0.1:{service_port}").start()
        try:
            if not autopilot.wait_for_heartbeat(100, 60.0):
                raise SystemExit(f"daemon did not come up; log:\n{daemon.log_tail()}")
            frames = list(iter_frames(recording))
            first = frames[0]
            frame_id = 0
            print(f"replay {path.name}: {len(frames)} frames {first.shape[1]}x{first.shape[0]} at "
                  f"{recording.fps:.0f} fps; selecting the first ground-truth box via the mavsdk ground station")
            gcs = GroundStation(f"udpout://127.0.0.1:{gcs_port}", 30.0)
            try:
                info = None
                while info is None:  # keep the first frame flowing while mavsdk discovers the camera
                    frame_id += 1
                    camera.publish(first, frame_id)
                    camera.telemetry.wait_frame(frame_id, 0.5)
                    try:
                        info = gcs.wait_for_camera(0.2)
                    except TimeoutError:
                        pass
                gcs.set_status_interval(info.component_id, 0.5)
                x, y, w, h = recording.groundtruth[0]
                H, W = first.shape[:2]
                result = gcs.track_rectangle(info.component_id, x / W, y / H, (x + w) / W, (y + h) / H)
                print(f"track_rectangle: {result.name}")
                while (camera.telemetry.last or {}).get("state") != "tracking":
                    frame_id += 1
                    camera.publish(first, frame_id)
                    if camera.telemetry.wait_frame(frame_id, 5.0) is None:
                        raise SystemExit(f"daemon did not start tracking; log:\n{daemon.log_tail()}")
                start_id = frame_id + 1
                ids: list[int] = []
                period = 1.0 / recording.fps
                start = time.monotonic()
                index = 0
                while time.monotonic() - start < args.duration:
                    image = frames[index % len(frames)] if args.loop else frames[index]
                    frame_id += 1
                    ids.append(index)
                    camera.publish(image, frame_id)
                    if args.pace == "lockstep":
                        camera.telemetry.wait_frame(frame_id, 10.0)
                    else:
                        delay = start + (len(ids)) * period - time.monotonic()
                        if delay > 0:
                            time.sleep(delay)  # camera pacing, not synchronisation
                    last = camera.telemetry.last or {}
                    if len(ids) % 10 == 0:
                        print(f"\rframe {len(ids):5d}  {len(ids) / (time.monotonic() - start):5.1f} fps sent  "
                              f"daemon frame {last.get('frame_id', '-')}  state {last.get('state', '-'):9s}  "
                              f"dropped {last.get('dropped_frames', 0)}", end="", flush=True)
                    index += 1
                    if not args.loop and index >= len(frames):
                        break
                camera.telemetry.wait_frame(frame_id, 3.0)
                wall = time.monotonic() - start
                status = camera.status(2.0) or {}
                gcs.track_stop(info.component_id)
            finally:
                gcs.close()
            errors, answered, states = [], 0, []
            OUT_DIR.mkdir(exist_ok=True)
            writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), recording.fps, (W, H))
            for offset, index in enumerate(ids):
                sample = camera.telemetry.by_frame.get(start_id + offset)
                image = frames[index].copy()
                truth = recording.groundtruth[index] if index < len(recording.groundtruth) else (math.nan,) * 4
                if all(math.isfinite(v) for v in truth):
                    tx, ty, tw, th = truth
                    cv2.rectangle(image, (int(tx), int(ty)), (int(tx + tw), int(ty + th)), TRUTH_COLOUR, 2)
                if sample is not None:
                    answered += 1
                    states.append(sample.get("state"))
                    if sample.get("box_px"):
                        bx, by, bw, bh = sample["box_px"]
                        colour = LOST_COLOUR if sample.get("state") == "lost" else BOX_COLOUR
                        cv2.rectangle(image, (int(bx), int(by)), (int(bx + bw), int(by + bh)), colour, 2)
                        if all(math.isfinite(v) for v in truth):
                            errors.append(math.hypot(bx + bw / 2 - truth[0] - truth[2] / 2,
                                                     by + bh / 2 - truth[1] - truth[3] / 2))
                draw_legend(image, REPLAY_LEGEND)
                draw_status_line(image, f"frame {index}  {(sample or {}).get('state') or 'not answered'}")
                writer.write(image)
            writer.release()
            lost = sum(1 for a, b in zip(states, states[1:]) if b == "lost" and a != "lost")
            recovered = sum(1 for a, b in zip(states, states[1:]) if a == "lost" and b in ("recovered", "tracking"))
            print_summary(f"replay summary ({path.name})", {
                "frames_sent": len(ids), "frames_processed": answered, "wall_s": round(wall, 2),
                "send_fps": round(len(ids) / wall, 1), "processed_fps": round(answered / wall, 1),
                "dropped_frames": (camera.telemetry.last or {}).get("dropped_frames"),
                "lost": lost, "recovered": recovered,
                "centre_error_px_median": round(float(np.median(errors)), 1) if errors else None,
                "annotated_video": str(video.relative_to(OUT_DIR.parent))}, status)
        finally:
            stop.set()
            daemon.stop()
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--flavour", choices=("ardupilot", "px4"), default="ardupilot")
    parser.add_argument("--duration", type=float, default=30.0, help="seconds (simulated in lockstep)")
    parser.add_argument("--pace", choices=("realtime", "lockstep"), default="realtime")
    parser.add_argument("--guidance", choices=("off", "velocity", "follow_target"), default="velocity")
    parser.add_argument("--tracker", default=None, help="override config.yaml's tracker.name")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--coast-s", type=float, default=None,
                        help="closed loop: override config.yaml's gimbal.coast_s (0 = hold when lost)")
    parser.add_argument("--replay", default=None, help="sequence folder (or name under JSAR_DATA_ROOT) or video")
    parser.add_argument("--loop", action="store_true", help="replay: loop the sequence for the whole duration")
    args = parser.parse_args(argv)
    exit_on_sigterm()
    cv2.setNumThreads(1)
    if args.replay:
        return run_replay(args)
    return run_closed_loop(args)


if __name__ == "__main__":
    raise SystemExit(main())
