"""The closed loop on the procedural ground: what `make run` gets on a bare machine (no JSAR_DATA_ROOT).

Lockstep (the mock steps only once the daemon's command for the frame has arrived) and without the
real-time floor (no link drops here, so nothing is judged on wall clocks). Each run must keep the car in
view on >= 95 % of frames (the demo's bar, sim.summary.BAR_IN_VIEW), never report "tracking" for 1 s or
more with the box off the car (a false lock: what the drone would follow), and keep the daemon alive. The
demo's centring bar is not asserted here: with the gimbal alone, a car that came back from a canopy turned
can stay lost in view for seconds (centred on 85-88 % of its frames in two of eight gimbal-only seeds,
docs/results-service.md), a known limit of re-detection, not a false lock.

The seeds are the scenes where the track went wrong before the drift check (docs/results-service.md):
- seed 0: the car turns at 22 s; the box, grown tall, slid onto grass and stayed there "tracking";
- seed 7: the loss under the canopy at 8 s ended on the canopy the coasting core had learnt;
- seed 5: the car came back from a canopy at 33 s turned by 90 degrees and was never taken up again.
Gimbal only (guidance off) and velocity guidance, on each flavour; one run a test (xdist spreads them).
"""
from __future__ import annotations

import os

os.environ.setdefault("MAVLINK20", "1")

import pytest

from sim.closed_loop import ClosedLoop, ClosedLoopConfig, RunResult
from sim.scene import SceneConfig
from sim.summary import BAR_IN_VIEW, verdict

pytestmark = pytest.mark.slow

DURATION_S = 40.0
RUNS = (  # (flavour, guidance, seed)
    ("ardupilot", "velocity", 0),
    ("px4", "velocity", 7),
    ("ardupilot", "off", 5),
    ("px4", "off", 0),
)


def run(flavour: str, guidance: str, seed: int) -> RunResult:
    cfg = ClosedLoopConfig(flavour=flavour, duration_s=DURATION_S, guidance=guidance,
                           scene=SceneConfig(seed=seed, texture="procedural"), lockstep_realtime_floor=False)
    with ClosedLoop(cfg) as loop:
        return loop.run()


@pytest.mark.parametrize("key", RUNS, ids=[f"{f}-{g}-seed{s}" for f, g, s in RUNS])
def test_procedural_ground_keeps_the_car_and_never_follows_background(key):
    result = run(*key)
    line = verdict(result).line()
    assert result.daemon_alive, line
    assert not result.false_locks(), line
    assert result.in_view_ratio() >= BAR_IN_VIEW, line
