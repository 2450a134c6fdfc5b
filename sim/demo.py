"""`make run`: the whole system on this machine, without a drone.

Starts the mock autopilot, the sim and the daemon (config.yaml + the sim's overrides), selects the
target through the mavsdk ground station, runs about 30 s with a live status line, prints a summary
and writes an annotated video under out/. The web ground station runs beside it: open the address it
prints to watch the video with the track, click on the car to select it again, Escape to stop.

    python -m sim.demo                                  # closed loop, ArduPilot flavour, real time
    python -m sim.demo --flavour px4 --guidance velocity
    python -m sim.demo --autopilot sitl --flavour px4   # real firmware: PX4 SIH (ArduCopter SITL for ardupilot)
    python -m sim.demo --replay UAVDT_S0310             # a shared sequence from $JSAR_DATA_ROOT
    python -m sim.demo --coast-s 0                      # hold the gimbal at once when lost (no coasting)
    python -m sim.demo --duration 600 --web-port 8081   # ten minutes to click around, page on port 8081

The summary ends with a VERDICT line against the run's bar (sim.summary); the exit status follows it (0 pass,
1 fail), so a script or CI can tell a run that lost the car. `--help` lists runs that pass and runs that fail.
"""
from __future__ import annotations

import argparse
import contextlib
import os
import signal
from pathlib import Path

import cv2
import numpy as np

from sim.closed_loop import ClosedLoop, ClosedLoopConfig, free_port
from sim.daemon import DaemonExited, deep_merge, exit_on_sigterm
from sim.scene import CameraConfig, SceneConfig
from sim.summary import (Verdict, camera_command_rows, counter_rows, format_rows, frame_accounting_row,
                         replay_verdict, run_rows, verdict)
from sim.web_station import WebStation, daemon_listen, web_station_beside

OUT_DIR = Path(__file__).resolve().parent.parent / "out"
EPILOG = """\
The summary ends with the web station's address again and a VERDICT line: PASS when the car was kept in
view and centred (sim.summary's bar: in view on >= 95 % of the frames, centred on >= 90 % of the frames it
was visible on, no false lock -- tracking reported with the box off the car for 1 s or more --, the daemon
alive), FAIL with every reason otherwise, and then the exit status is 1. Ctrl-C: exit status 130.

Runs that pass and runs that fail (procedural ground, JSAR_DATA_ROOT unset; lockstep, so load cannot decide):
  python -m sim.demo --pace lockstep --duration 20              PASS
  python -m sim.demo --pace lockstep --seed 1                   PASS (another path for the car)
  python -m sim.demo --pace lockstep --duration 40              PASS (before the drift check the track slid
                                                                onto grass at 23 s while reporting tracking)
  python -m sim.demo --pace lockstep --tracker kcf --coast-s 0  FAIL: KCF loses the car, the gimbal holds
  python -m sim.demo --pace lockstep --guidance off --seed 4 --duration 40
                                                                FAIL: centred on 85 %: the car back from
                                                                the second canopy turned is lost for seconds
  python -m sim.demo --coast-s -1                               FAIL at once: the daemon refuses the config
"""


def print_summary(title: str, summary: dict, status: dict | None = None) -> None:
    """Each figure with what it means, then the daemon's counters (sim.summary), its frame count reconciled
    with the sim's right under it; status: the daemon's status answer (counters, mavlink_refusals)."""
    status = status or {}
    counters = status.get("counters", {})
    daemon_rows = counter_rows(counters)
    after_frames = next((i + 1 for i, (label, _, _) in enumerate(daemon_rows) if label == "daemon frames"),
                        len(daemon_rows))
    daemon_rows[after_frames:after_frames] = frame_accounting_row(summary, counters)
    rows = run_rows(summary) + camera_command_rows(counters, status.get("mavlink_refusals", [])) + daemon_rows
    print("\n" + format_rows(title, rows))


def print_ending(station: WebStation | None, judged: Verdict) -> int:
    """The web station's address again (the run's first lines have scrolled away), then the VERDICT line, last;
    the exit status: 0 passed, 1 failed."""
    if station is not None:
        print(f"web ground station: {station.url}  (it closes now, with the demo; --duration 600 keeps it up "
              f"for ten minutes)")
    print(judged.line(), flush=True)
    return 0 if judged.passed else 1


def web_station(args: argparse.Namespace, loop: ClosedLoop, daemon_zenoh_port: int) -> contextlib.AbstractContextManager:
    """The web ground station beside the run (unless --no-web: None); prints its address."""
    if args.no_web:
        return contextlib.nullcontext()

    @contextlib.contextmanager
    def announced():
        with web_station_beside(loop, daemon_zenoh_port, args.web_port) as station:
            print(f"web ground station: {station.url}  (open it to watch; click the car to select it, "
                  f"drag a box, Esc stops; it closes when the demo ends)", flush=True)
            yield station
    return announced()


def run_closed_loop(args: argparse.Namespace) -> int:
    video = OUT_DIR / f"demo_closed_loop_{args.flavour}{'_sitl' if args.autopilot == 'sitl' else ''}.avi"
    overrides = {"gimbal": {"coast_s": args.coast_s}} if args.coast_s is not None else {}
    web_zenoh_port = free_port(1)
    overrides = deep_merge(overrides, daemon_listen(web_zenoh_port))
    firmware = args.autopilot == "sitl"
    if firmware and args.pace != "realtime":
        raise SystemExit("--autopilot sitl: the firmware flies in real time; --pace lockstep is for the mock")
    if firmware:
        from sim.sitl_autopilot import firmware_unavailable
        missing = firmware_unavailable(args.flavour)
        if missing:
            raise SystemExit(f"--autopilot sitl: {missing}")
    cfg = ClosedLoopConfig(flavour=args.flavour, autopilot="firmware" if firmware else "mock",
                           speedup=args.sitl_speed, duration_s=args.duration, pace=args.pace,
                           guidance=args.guidance, tracker=args.tracker, scene=SceneConfig(seed=args.seed),
                           video_path=video, daemon_overrides=overrides)
    autopilot = (f"{'ArduCopter SITL' if args.flavour == 'ardupilot' else 'PX4 SIH'} (real firmware; start-up, arming "
                 "and take-off take 10-30 s)") if firmware else f"mock {args.flavour} autopilot"
    print(f"closed loop: {autopilot}, synthetic scene (seed {args.seed}), daemon with "
          f"guidance {args.guidance}, {args.pace} pacing, {args.duration:.0f} s", flush=True)
    with ClosedLoop(cfg) as loop, web_station(args, loop, web_zenoh_port) as station:
        print(f"ground texture: {loop.scene.texture_source}; selecting the car through the mavsdk ground station",
              flush=True)
        result = loop.run(live=True)
        summary = result.summary()
        summary["autopilot_events"] = "; ".join(e for _, e in loop.autopilot.events[-5:]) or "none"
        summary["annotated_video"] = str(video.relative_to(OUT_DIR.parent))
        print_summary("closed loop summary", summary, {"counters": result.counters, "mavlink_refusals": result.refusals})
        return print_ending(station, verdict(result))


def run_replay(args: argparse.Namespace) -> int:
    """Replay a shared sequence as the camera in the closed loop (open loop: the frames do not follow the
    gimbal); the target = the sequence's first ground-truth box."""
    from sim.replay import RecordingWorld, open_recording

    path = Path(args.replay)
    if not path.exists():
        root = os.environ.get("JSAR_DATA_ROOT")
        if not root:
            raise SystemExit(f"--replay {args.replay}: not a path, and JSAR_DATA_ROOT is not set")
        path = Path(root) / args.replay
    recording = open_recording(path)
    if not recording.groundtruth:
        raise SystemExit(f"{path.name} has no groundtruth_rect.txt: nothing to select")
    world = RecordingWorld(recording, loop=args.loop)
    (width, height), count = world.size, len(world.frames)
    # without --loop the run ends with the last frame (frame 0 is the one the target is selected on)
    duration = args.duration if args.loop else min(args.duration, (count - 1) / recording.fps)
    video = OUT_DIR / f"demo_replay_{path.name}.avi"
    # lockstep without the real-time floor: as fast as the daemon consumes (no link drops to keep real)
    web_zenoh_port = free_port(1)
    cfg = ClosedLoopConfig(flavour=args.flavour, duration_s=duration, fps=recording.fps, pace=args.pace,
                           guidance=args.guidance, tracker=args.tracker, camera=CameraConfig(width, height),
                           video_path=video, lockstep_realtime_floor=False,
                           daemon_overrides=daemon_listen(web_zenoh_port))
    print(f"replay {path.name}: {count} frames {width}x{height} at {recording.fps:.0f} fps; selecting the first "
          "ground-truth box via the mavsdk ground station", flush=True)
    with ClosedLoop(cfg, world=world) as loop, web_station(args, loop, web_zenoh_port) as station:
        result = loop.run(live=True)
        summary, errors = result.summary(), result.box_error_px()
        print_summary(f"replay summary ({path.name})", {
            "track_rectangle": result.selection_result, "frames_sent": summary["frames"],
            "frames_processed": summary["answered"], "startup_frames": summary["startup_frames"],
            "wall_s": summary["wall_s"], "send_fps": summary["sent_fps"],
            "processed_fps": summary["processed_fps"], "dropped_frames": summary["dropped_frames"],
            "lost": summary["lost"], "recovered": summary["recovered"],
            "centre_error_px_median": round(float(np.median(errors)), 1) if errors else None,
            "annotated_video": str(video.relative_to(OUT_DIR.parent))},
            {"counters": result.counters, "mavlink_refusals": result.refusals})
        return print_ending(station, replay_verdict(result))


def interrupt_once() -> None:
    """Ctrl-C: KeyboardInterrupt in the main thread once; a second Ctrl-C is ignored, so it cannot cut short the
    clean-up the first one started (stopping the daemon, the mock autopilot, the web station)."""
    def _interrupt(_signum: int, _frame: object) -> None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, _interrupt)


def main(argv: list[str] | None = None) -> int:
    """Exit status: 0 the run passed its bar, 1 it failed (or the daemon exited at start), 130 Ctrl-C, 143 SIGTERM."""
    parser = argparse.ArgumentParser(prog="python -m sim.demo", description=__doc__.splitlines()[0],
                                     epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--flavour", choices=("ardupilot", "px4"), default="ardupilot")
    parser.add_argument("--autopilot", choices=("mock", "sitl"), default="mock",
                        help="mock: the project's mock autopilot (fast, lockstep possible); sitl: the real firmware "
                             "of --flavour, ArduCopter SITL or PX4 SIH from $JSAR_SITL_ROOT (default ../shared/sitl), "
                             "in real time")
    parser.add_argument("--sitl-speed", type=float, default=1.0,
                        help="--autopilot sitl: the firmware's simulation speed over real time during the run (below 1 "
                             "lets a busy machine keep up; frames follow the firmware's clock)")
    parser.add_argument("--duration", type=float, default=30.0, help="seconds (simulated in lockstep)")
    parser.add_argument("--pace", choices=("realtime", "lockstep"), default="realtime")
    parser.add_argument("--guidance", choices=("off", "velocity", "follow_target"), default="velocity")
    parser.add_argument("--tracker", default=None, help="override config.yaml's tracker.name")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--coast-s", type=float, default=None,
                        help="closed loop: override config.yaml's gimbal.coast_s (0 = hold when lost)")
    parser.add_argument("--replay", default=None, help="sequence folder (or name under JSAR_DATA_ROOT) or video")
    parser.add_argument("--loop", action="store_true", help="replay: loop the sequence for the whole duration")
    parser.add_argument("--web-port", type=int, default=8080,
                        help="the web ground station's port on 127.0.0.1 (taken: any free port)")
    parser.add_argument("--no-web", action="store_true", help="run without the web ground station")
    args = parser.parse_args(argv)
    exit_on_sigterm()
    interrupt_once()
    cv2.setNumThreads(1)
    try:
        if args.replay:
            return run_replay(args)
        return run_closed_loop(args)
    except KeyboardInterrupt:  # the with blocks have stopped the daemon, the mock and the web station by now
        print("\ninterrupted (Ctrl-C): the run was stopped, its children too; no summary", flush=True)
        return 130
    except DaemonExited as exc:
        print(f"\n{exc}", flush=True)
        print(f"VERDICT FAIL: the daemon exited (code {exc.code}) before the run: see its log above", flush=True)
        return 1


if __name__ == "__main__":
    raise SystemExit(main())
