"""The closed loop on real firmware: the scene rendered from ArduCopter SITL's / PX4 SIH's own vehicle position and
attitude and the mount's reported attitude (sim.sitl_autopilot), the daemon a process on the firmware's companion
link, the selection through the mavsdk ground station routed by the firmware.

One run per firmware, both side by side (each a few % of a core besides the daemon): velocity guidance, so the
firmware flies the vehicle after the car (ArduPilot in GUIDED; PX4 OFFBOARD, engaged by the sim's pilot once the
daemon's setpoints stream), the car passing under a canopy at 8 s. Real time, procedural ground (no data needed).
Each must keep the car in view on >= 95 % of the frames, centred (|dx| <= 0.1 W, |dy| <= 0.1 H) on >= 85 % of
the frames it is visible on, and the vehicle must have followed it. The 60-s figures (>= 90 %) are measured by
`python -m sim.demo --autopilot sitl` runs (docs/sim.md); 85 % here leaves room for a busy machine, where a
real-time loop drops frames and the firmware, unlike the mock, does not wait for them.

Without the firmware (JSAR_SITL_ROOT, else ../shared/sitl) the tests skip with the reason; in CI (env CI set)
they fail instead.
"""
from __future__ import annotations

import math
import os
import time
from concurrent.futures import ThreadPoolExecutor

os.environ.setdefault("MAVLINK20", "1")

import pytest

from sim.closed_loop import ClosedLoop, ClosedLoopConfig, RunResult
from sim.scene import SceneConfig
from sim.summary import BAR_IN_VIEW, verdict

pytestmark = pytest.mark.firmware("arducopter", "px4")

DURATION_S = 20.0
CENTRED_BAR = 0.85
FLAVOURS = ("ardupilot", "px4")


def run(flavour: str) -> tuple[RunResult, list[str], float]:
    """One real-time run on the firmware; (result, the autopilot side's events, wall seconds incl. start-up)."""
    start = time.monotonic()
    cfg = ClosedLoopConfig(flavour=flavour, autopilot="firmware", pace="realtime", duration_s=DURATION_S,
                           guidance="velocity", scene=SceneConfig(seed=0, texture="procedural"))
    with ClosedLoop(cfg) as loop:
        result = loop.run()
        events = [text for _, text in loop.autopilot.events]
    return result, events, time.monotonic() - start


@pytest.fixture(scope="module")
def runs() -> dict[str, tuple[RunResult, list[str], float]]:
    with ThreadPoolExecutor(max_workers=len(FLAVOURS)) as pool:
        futures = {flavour: pool.submit(run, flavour) for flavour in FLAVOURS}
        return {flavour: future.result() for flavour, future in futures.items()}


def trace(result: RunResult) -> str:
    """One line a second, for failure messages."""
    return "\n".join(f"t={r.time_s:5.1f} {r.state or '-':9s} visible={r.truth.visible_fraction:4.2f} "
                     f"dx={r.truth.centre[0] - result.width / 2:7.1f} dy={r.truth.centre[1] - result.height / 2:7.1f} "
                     f"{r.mode:8s} v={r.vehicle_speed:4.1f} d={r.target_distance_m:5.1f}" for r in result.records[::30])


@pytest.mark.parametrize("flavour", FLAVOURS)
def test_firmware_closed_loop_keeps_the_car_centred_and_follows_it(runs, flavour):
    result, events, wall_s = runs[flavour]
    line = verdict(result).line()
    context = f"{flavour} ({wall_s:.0f} s wall): {line}\nevents: {events}\n{trace(result)}"
    assert result.daemon_alive, context
    assert result.selection_result == "SUCCESS", context
    hidden = [r for r in result.records if not r.truth.visible and r.truth.in_view_fraction >= 0.5]
    assert hidden, "the run must take the car under the canopy\n" + context
    assert result.in_view_ratio() >= BAR_IN_VIEW, context
    assert result.centring_ratio() >= CENTRED_BAR, context
    # the firmware flew the vehicle after the car: in the guidance mode, most of the way the car drove
    first, last = result.records[0], result.records[-1]
    moved = math.dist(first.vehicle_ne, last.vehicle_ne)
    car = math.dist((first.truth.target.north, first.truth.target.east), (last.truth.target.north, last.truth.target.east))
    assert moved > 0.5 * car, f"vehicle moved {moved:.1f} m, the car {car:.1f} m\n" + context
    guided = "GUIDED" if flavour == "ardupilot" else "OFFBOARD"
    assert sum(r.mode == guided for r in result.records) > 0.5 * len(result.records), context
