"""Reproducibility check of the lockstep closed loop: run one scenario twice, compare frame by frame.

What is compared (everything the daemon and the mock exchanged that should depend on the frames only):
per run frame the daemon's state and box, the car's ground-truth box (a function of the vehicle and
gimbal pose) and the vehicle position; and every message the daemon's component sent the mock on the
service link that controls the vehicle or gimbal (model time, type, fields, outcome), without the
fields stamped on the daemon's wall clock (time_boot_ms / timestamp).

`python -m sim.repro --flavour px4 --duration 12 --link-drop 3 5` prints both runs' summaries and the
first difference (exit 1), or "identical" (exit 0).
"""
from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass
from typing import Any

from sim.closed_loop import SERVICE_COMPONENT, ClosedLoop, ClosedLoopConfig, RunResult
from sim.daemon import exit_on_sigterm
from sim.scene import SceneConfig

WALL_CLOCK_FIELDS = ("time_boot_ms", "timestamp")
# The daemon's control output; its status streams (CAMERA_TRACKING_*_STATUS, for the ground station)
# run on its wall clock and are not part of the loop.
CONTROL_TYPES = ("GIMBAL_MANAGER_SET_PITCHYAW", "GIMBAL_MANAGER_SET_ATTITUDE", "SET_POSITION_TARGET_LOCAL_NED",
                 "FOLLOW_TARGET", "COMMAND_LONG", "COMMAND_INT")


@dataclass(frozen=True)
class RunTrace:
    """A run reduced to what must repeat: per-frame rows and the daemon's commands, in order."""

    frames: tuple[tuple[Any, ...], ...]
    commands: tuple[tuple[Any, ...], ...]
    summary: dict[str, Any]
    gimbal_command_timeouts: int
    frame_gap_holds: int  # the daemon's no-frames holds: wall-clock events, so a run with any may not repeat


def _plain(value: Any) -> Any:
    """Message field -> comparable value (NaN compares equal to NaN as the string 'nan')."""
    if isinstance(value, float) and math.isnan(value):
        return "nan"
    if isinstance(value, (list, tuple)):
        return tuple(_plain(v) for v in value)
    if isinstance(value, bytes):
        return value.hex()
    return value


def trace_of(loop: ClosedLoop, result: RunResult) -> RunTrace:
    """The comparable trace of a finished run (call before the loop is closed)."""
    frames = tuple((r.time_s, r.state, r.box, r.truth.box, r.truth.visible, r.vehicle_ne, r.mode, r.link_down)
                   for r in result.records)
    # In model-time order; the messages of one model time as a set (sorted by their text): the MAVLink thread's
    # requests (a message interval on the autopilot's first heartbeat), the gimbal claim and the loop's guidance can
    # reach the mock in any order within one model time, which is the threads' scheduling, not the loop's.
    commands = tuple(sorted((
        (c.time_s, c.msg_type, c.outcome,
         tuple(sorted((k, _plain(v)) for k, v in c.fields.items() if k not in WALL_CLOCK_FIELDS)))
        for c in loop.autopilot.commands(link="service")
        if c.src_component == SERVICE_COMPONENT and c.msg_type in CONTROL_TYPES),
        key=lambda command: (command[0], repr(command[1:]))))
    return RunTrace(frames, commands, result.summary(), result.gimbal_command_timeouts,
                    int(result.counters.get("frame_gap_holds", 0)))


def first_difference(a: RunTrace, b: RunTrace) -> str | None:
    """Where two traces part (None: identical)."""
    for name, xs, ys in (("frame", a.frames, b.frames), ("command", a.commands, b.commands)):
        for i, (x, y) in enumerate(zip(xs, ys)):
            if x != y:
                return f"{name} {i}:\n  run 1: {x}\n  run 2: {y}"
        if len(xs) != len(ys):
            return f"{name} count differs: {len(xs)} vs {len(ys)}"
    return None


def run_once(cfg: ClosedLoopConfig) -> RunTrace:
    """One lockstep run of cfg with a fresh mock, daemon and Zenoh session."""
    with ClosedLoop(cfg) as loop:
        result = loop.run()
        return trace_of(loop, result)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--flavour", choices=("ardupilot", "px4"), default="ardupilot")
    parser.add_argument("--duration", type=float, default=12.0, help="simulated seconds per run")
    parser.add_argument("--guidance", choices=("off", "velocity", "follow_target"), default="velocity")
    parser.add_argument("--link-drop", type=float, nargs=2, metavar=("START_S", "DURATION_S"))
    parser.add_argument("--occlusion", type=float, action="append", default=[], metavar="TIME_S")
    parser.add_argument("--runs", type=int, default=2)
    args = parser.parse_args(argv)
    exit_on_sigterm()
    if args.runs < 2:
        parser.error("--runs must be >= 2")
    cfg = ClosedLoopConfig(flavour=args.flavour, duration_s=args.duration, guidance=args.guidance,
                           scene=SceneConfig(occlusion_times_s=tuple(args.occlusion)) if args.occlusion else SceneConfig(),
                           link_drops=(tuple(args.link_drop),) if args.link_drop else ())
    traces = []
    for i in range(args.runs):
        trace = run_once(cfg)
        traces.append(trace)
        print(json.dumps({"run": i + 1, "frames": len(trace.frames), "commands": len(trace.commands),
                          "frame_gap_holds": trace.frame_gap_holds, **trace.summary}), flush=True)
    differences = [first_difference(traces[0], t) for t in traces[1:]]
    for i, diff in enumerate(differences, start=2):
        print(f"run 1 vs run {i}: " + ("identical" if diff is None else f"differ at {diff}"), flush=True)
    return 0 if all(d is None for d in differences) else 1


if __name__ == "__main__":
    raise SystemExit(main())
