"""Coasting while lost (service.control.coast): synthetic histories, no I/O; and the loop's wiring."""
from __future__ import annotations

import math
import os

os.environ.setdefault("MAVLINK20", "1")

import numpy as np
import pytest

from service.config import ConfigError, GimbalConfig, config_from_mapping
from service.control.coast import (CoastParams, Position, TrackHistory, coast_step, decay, decayed_travel_s,
                                   direction, north_east_m, plan_coast, remember, start_coast)
from service.control.geo import EARTH_RADIUS_M

ORIGIN = (47.0, 8.0)
HEIGHT_M = 30.0
FPS = 30.0
PARAMS = CoastParams.from_config(GimbalConfig(coast_s=3.0, coast_fit_s=1.0))


def position(north: float, east: float, height_m: float = 0.0) -> Position:
    """Inverse of north_east_m around ORIGIN."""
    lat = ORIGIN[0] + math.degrees(north / EARTH_RADIUS_M)
    lon = ORIGIN[1] + math.degrees(east / (EARTH_RADIUS_M * math.cos(math.radians(ORIGIN[0]))))
    return Position(lat, lon, height_m)


def confident_history(target_at, vehicle_at, seconds: float = 1.0, noise_m: float = 0.0, seed: int = 0) -> TrackHistory:
    """Confident frames at FPS with the camera exactly on the target; positions (north, east) m of time s."""
    rng = np.random.default_rng(seed)
    history = TrackHistory()
    for k in range(int(round(seconds * FPS)) + 1):
        t = k / FPS
        target, vehicle = target_at(t), vehicle_at(t)
        camera = direction(target, vehicle, HEIGHT_M)
        seen = (target[0] + rng.normal(0.0, noise_m), target[1] + rng.normal(0.0, noise_m)) if noise_m else target
        history = remember(history, t, position(*vehicle, HEIGHT_M), position(*seen), camera, PARAMS.fit_window_s)
    return history


def true_rates(target_at, vehicle_at, t: float) -> tuple[float, float]:
    """The target direction's (azimuth, elevation) rates rad/s at time t (central difference)."""
    h = 1e-4
    after, before = direction(target_at(t + h), vehicle_at(t + h), HEIGHT_M), direction(target_at(t - h), vehicle_at(t - h), HEIGHT_M)
    return (after[0] - before[0]) / (2 * h), (after[1] - before[1]) / (2 * h)


def fly_coast(history: TrackHistory, target_at, vehicle_at, params: CoastParams = PARAMS):
    """Coast from the end of the history with an ideal rate-following gimbal (vehicle yaw fixed at 0;
    each command acts until the next frame; the tracking controller's last command followed the
    target): yields (time s, rates or None, camera angles, true target direction) per frame."""
    plan = plan_coast(history, params)
    assert plan is not None
    acting = true_rates(target_at, vehicle_at, plan.start_s)
    state = start_coast(plan, acting)
    camera = plan.camera
    t = plan.start_s
    while True:
        t += 1.0 / FPS
        camera = (camera[0] + acting[0] / FPS, camera[1] + acting[1] / FPS)
        state, rates = coast_step(state, t, position(*vehicle_at(t), HEIGHT_M), camera, params)
        yield t, rates, camera, direction(target_at(t), vehicle_at(t), HEIGHT_M)
        if rates is None:
            return
        acting = rates


def east_5_m_s(t: float) -> tuple[float, float]:
    return 30.0, -2.0 + 5.0 * t


def hovering(t: float) -> tuple[float, float]:
    return 0.0, 0.0


def test_constant_velocity_target_coast_rate_matches_its_bearing_rate() -> None:
    history = confident_history(east_5_m_s, hovering)
    plan = plan_coast(history, PARAMS)
    assert plan is not None and plan.velocity_ne == pytest.approx((0.0, 5.0), abs=1e-6)
    assert plan.target_ne == pytest.approx(east_5_m_s(1.0), abs=1e-6)
    for t, rates, camera, truth in fly_coast(history, east_5_m_s, hovering):
        elapsed = t - plan.start_s
        if elapsed >= PARAMS.coast_s:
            assert rates is None  # over: the loop holds the gimbal
        elif elapsed <= PARAMS.coast_s / 2:  # full velocity: the camera stays on the target
            assert rates is not None
            assert abs(camera[0] - truth[0]) < math.radians(0.3) and abs(camera[1] - truth[1]) < math.radians(0.3)
            if elapsed > 0.3:  # past the slew from rest: the azimuth rate is the target's bearing rate
                north, east = east_5_m_s(t)
                bearing_rate = north * 5.0 / (north ** 2 + east ** 2)
                assert rates[0] == pytest.approx(bearing_rate, rel=0.05)


def test_coast_keeps_the_target_when_the_follow_vehicle_brakes() -> None:
    """The case that motivates the ground model: the vehicle followed the car (constant bearing while
    tracking, so an angular-rate estimate would be ~0) and brakes once the track is lost."""
    def car(t: float) -> tuple[float, float]:
        return 40.0 + 4.0 * t, 3.0 * t

    def drone(t: float) -> tuple[float, float]:
        if t <= 1.0:
            return 4.0 * t, 3.0 * t
        braking = min(t - 1.0, 1.25)  # 5 m/s -> 0 at 4 m/s^2
        travelled = 5.0 * braking - 2.0 * braking ** 2
        return 4.0 + 0.8 * travelled, 3.0 + 0.6 * travelled

    history = confident_history(car, drone)
    cameras = [s.camera for s in history.samples]
    assert max(abs(c[0] - cameras[0][0]) for c in cameras) < 1e-9  # bearing constant while following
    worst = 0.0
    for t, rates, camera, truth in fly_coast(history, car, drone):
        if rates is not None and t - 1.0 <= PARAMS.coast_s / 2:
            worst = max(worst, abs(camera[0] - truth[0]), abs(camera[1] - truth[1]))
    assert worst < math.radians(0.5)


def test_coast_keeps_the_offset_the_target_had_from_the_camera_axis() -> None:
    """Lost with the target 2 degrees right of the axis: it stays 2 degrees right (where re-detection
    searches), the camera is not re-centred on a guess."""
    offset = math.radians(2.0)
    history = TrackHistory()
    for k in range(31):
        t = k / FPS
        azimuth, elevation = direction(east_5_m_s(t), (0.0, 0.0), HEIGHT_M)
        history = remember(history, t, position(0.0, 0.0, HEIGHT_M), position(*east_5_m_s(t)),
                           (azimuth - offset, elevation), PARAMS.fit_window_s)
    for t, rates, camera, truth in fly_coast(history, east_5_m_s, hovering):
        if rates is not None and t - 1.0 <= PARAMS.coast_s / 2:
            assert truth[0] - camera[0] == pytest.approx(offset, abs=math.radians(0.3))


def test_noisy_history_gives_bounded_slew_limited_rates() -> None:
    history = confident_history(east_5_m_s, hovering, noise_m=1.0, seed=3)
    plan = plan_coast(history, PARAMS)
    assert plan is not None and math.hypot(plan.velocity_ne[0], plan.velocity_ne[1] - 5.0) < 3.0
    # wild positions (a box jumping between objects): still within the gimbal's limits
    wild = confident_history(lambda t: (30.0 + 200.0 * math.sin(40 * t), 300.0 * math.cos(37 * t)), hovering)
    for history in (history, wild):
        previous = true_rates(east_5_m_s, hovering, 1.0)  # fly_coast's starting command
        for _, rates, _, _ in fly_coast(history, east_5_m_s, hovering):
            if rates is None:
                break
            for rate, before in zip(rates, previous):
                assert abs(rate) <= PARAMS.max_rate + 1e-12
                assert abs(rate - before) <= PARAMS.max_accel / FPS + 1e-9
            previous = rates


def test_decay_profile_and_when_there_is_no_coast() -> None:
    assert [decay(t, 3.0) for t in (0.0, 1.5, 2.25, 3.0, 4.0)] == [1.0, 1.0, 0.5, 0.0, 0.0]
    assert decayed_travel_s(1.0, 3.0) == 1.0 and decayed_travel_s(3.0, 3.0) == pytest.approx(2.25)
    assert decayed_travel_s(10.0, 3.0) == pytest.approx(2.25) and decayed_travel_s(1.0, 0.0) == 0.0
    history = confident_history(east_5_m_s, hovering)
    off = CoastParams.from_config(GimbalConfig(coast_s=0.0))
    assert plan_coast(history, off) is None  # 0 disables: the loop holds at once
    short = TrackHistory(history.origin, history.samples[-4:])  # 4 frames < MIN_SAMPLES
    assert plan_coast(short, PARAMS) is None
    assert plan_coast(TrackHistory(history.origin, history.samples[-8:]), PARAMS) is None  # 0.23 s < 1/3 s span
    plan = plan_coast(history, PARAMS)
    assert plan is not None
    state = start_coast(plan, (0.0, 0.0))
    vehicle = position(0.0, 0.0, HEIGHT_M)
    assert coast_step(state, plan.start_s + 0.1, None, plan.camera, PARAMS)[1] is None  # no pose: hold
    assert coast_step(state, plan.start_s + 0.1, vehicle, None, PARAMS)[1] is None  # no gimbal attitude: hold
    assert coast_step(state, plan.start_s, vehicle, plan.camera, PARAMS)[1] is None  # time not increasing


def test_history_window_restart_and_bad_input() -> None:
    history = confident_history(east_5_m_s, hovering, seconds=3.0)
    times = [s.time_s for s in history.samples]
    assert times[-1] == pytest.approx(3.0) and times[0] >= 2.0 - 1e-9  # only the last fit window is kept
    assert north_east_m(ORIGIN, *[getattr(position(10.0, -20.0), k) for k in ("lat_deg", "lon_deg")]) == \
        pytest.approx((10.0, -20.0), abs=1e-6)
    restarted = remember(history, 0.5, position(0.0, 0.0, HEIGHT_M), position(30.0, 0.0), (0.0, -0.8), 1.0)
    assert len(restarted.samples) == 1  # capture clock went back: a new history
    with pytest.raises(ValueError, match="sighting must be finite"):
        remember(history, 4.0, position(0.0, 0.0, HEIGHT_M), Position(math.nan, 8.0), (0.0, -0.8), 1.0)


def test_coast_config_keys_are_validated_naming_the_key() -> None:
    assert config_from_mapping({"tracker": {"name": "csrt", "range_size_band": 0}}).gimbal.coast_s == 3.0
    for raw, message in [({"coast_s": -1}, "gimbal.coast_s: must be in [0.0, 10.0], got -1"),
                         ({"coast_s": "long"}, "gimbal.coast_s: must be a number"),
                         ({"coast_fit_s": 0}, "gimbal.coast_fit_s: must be in [0.1, 5.0], got 0")]:
        with pytest.raises(ConfigError, match=message.replace("[", r"\[").replace("]", r"\]")):
            config_from_mapping({"tracker": {"name": "csrt", "range_size_band": 0}, "gimbal": raw})


@pytest.mark.parametrize("coast_s", [3.0, 0.0])
def test_loop_coasts_while_lost_then_holds(coast_s: float) -> None:
    """TrackingLoop with a scripted tracker (box drifting right = target moving east), a static vehicle
    and gimbal: lost frames carry coasting=True and the coast's rates, then zero after coast_s;
    coast_s 0 is today's hold."""
    from jsar.api import TrackResult
    from service.control.geo import GimbalAttitude
    from service.domain import ControlCommand
    from service.loop import FrameReport, TrackingLoop
    from service.mavlink import commands as c
    from service.mavlink.autopilot import AutopilotView
    from service.sources.base import Frame, LatestSlot

    config = config_from_mapping({"tracker": {"name": "csrt", "range_size_band": 0}, "camera": {"hfov_deg": 90.0},
                                  "gimbal": {"coast_s": coast_s}})
    view = AutopilotView(system_id=1, position=(47.0, 8.0, 530.0, 30.0), attitude=(0.0, 0.0, 0.0),
                         gimbal=GimbalAttitude(pitch=-math.pi / 4, yaw=0.0, yaw_in_earth_frame=False))
    lost_from = 40

    class Scripted:
        def init(self, image, box):
            self.box, self.frames = box, 0

        def update(self, image):
            self.frames += 1
            if self.frames >= lost_from:
                return TrackResult(self.box, 0.1, "lost")
            x, y, w, h = self.box
            self.box = (x + 0.2, y, w, h)
            return TrackResult(self.box, 1.0, "tracking")

    commands: list[ControlCommand] = []
    reports: list[FrameReport] = []

    class Record:
        def apply(self, now_s: float, command: ControlCommand) -> None:
            commands.append(command)

    selections: LatestSlot = LatestSlot()
    loop = TrackingLoop(config, selections, Scripted, Record(), lambda: view, publish_report=reports.append)
    selections.put(c.TrackRectangle(0.45, 0.45, 0.55, 0.55))
    image = np.zeros((100, 100, 3), np.uint8)
    for k in range(lost_from + int(5.0 * FPS)):
        loop.step(Frame(image, k, k / FPS, 0.0))
    lost = [(cmd, rep) for cmd, rep in zip(commands, reports) if cmd.state == "lost"]
    coasting = [cmd for cmd, _ in lost if cmd.coasting]
    assert all(rep.coasting == cmd.coasting and rep.as_json()["coasting"] == cmd.coasting for cmd, rep in lost)
    if coast_s == 0.0:
        assert not coasting and all(cmd.rates == (0.0, 0.0) for cmd, _ in lost)
        assert loop.counters["coasts"] == 0
        return
    # the last confident frame is frame lost_from - 1; the coast lasts coast_s of capture time after it
    assert len(coasting) == pytest.approx(coast_s * FPS, abs=1.5)
    assert all(cmd.rates is not None and cmd.rates[0] > 0 for cmd in coasting[1:int(FPS)])  # turning east
    assert all(cmd.rates == (0.0, 0.0) and not cmd.coasting for cmd, _ in lost[len(coasting):])
    assert loop.counters["coasts"] == 1 and loop.counters["coast_frames"] == len(coasting)


def test_while_lost_the_search_s_best_candidate_is_logged_once_a_second(monkeypatch, caplog):
    """event=search: the re-detection's best candidate against its bar, from a tracker's `last_step`, at most once per
    SEARCH_LOG_EVERY_S of the service's clock; nothing while tracking."""
    import logging
    from types import SimpleNamespace

    from jsar.api import TrackResult
    from service.control.geo import GimbalAttitude
    from jsar.redetect.jsar_re import SearchStep
    from jsar.redetect.search import Candidate
    from service import loop as loop_module
    from service.loop import SEARCH_LOG_EVERY_S, TrackingLoop
    from service.mavlink import commands as c
    from service.mavlink.autopilot import AutopilotView
    from service.sources.base import Frame, LatestSlot

    view = AutopilotView(system_id=1, position=(47.0, 8.0, 530.0, 30.0), attitude=(0.0, 0.0, 0.0),
                         gimbal=GimbalAttitude(pitch=-math.pi / 4, yaw=0.0, yaw_in_earth_frame=False))
    clock = [100.0]
    monkeypatch.setattr(loop_module, "time", SimpleNamespace(monotonic=lambda: clock[0]))
    lost_from = 5

    class Searching:
        def init(self, image, box):
            self.box, self.frames, self.last_step = box, 0, None

        def update(self, image):
            self.frames += 1
            if self.frames < lost_from:
                return TrackResult(self.box, 1.0, "tracking")
            best = Candidate(40.0 + self.frames, 52.0, 0.21)
            self.last_step = SearchStep(best, 0.35, 6, False, own=Candidate(50.0, 50.0, 0.1))
            return TrackResult(self.box, 0.1, "lost")

    config = config_from_mapping({"tracker": {"name": "csrt", "range_size_band": 0}})
    selections: LatestSlot = LatestSlot()
    loop = TrackingLoop(config, selections, Searching, SimpleNamespace(apply=lambda now_s, command: None),
                        lambda: view)
    selections.put(c.TrackRectangle(0.45, 0.45, 0.55, 0.55))
    image = np.zeros((100, 100, 3), np.uint8)
    caplog.set_level(logging.INFO, logger="service.loop")
    for k in range(20):  # 20 frames within one instant of the service's clock: one line
        loop.step(Frame(image, k, k / FPS, 0.0))
    lines = [r.getMessage() for r in caplog.records if "event=search" in r.getMessage()]
    assert lines == ["event=search best_score=0.210 bar=0.350 best_centre_px=45,52 windows=6 taken=False core_coasting=False"]
    clock[0] += SEARCH_LOG_EVERY_S
    loop.step(Frame(image, 20, 20 / FPS, 0.0))
    lines = [r.getMessage() for r in caplog.records if "event=search" in r.getMessage()]
    assert len(lines) == 2 and "best_centre_px=60,52" in lines[1]  # the selection frame is init, not an update


@pytest.mark.parametrize("back_frames, back_moves, cause, resumed",
                         [(3, False, "peak", True), (20, False, "peak", True), (20, True, "peak", False),
                          (40, False, "peak", False), (40, False, "appearance", True), (40, False, "drift", True),
                          (40, True, "appearance", False)])
def test_a_loss_soon_after_a_short_reacquisition_resumes_the_interrupted_coast(back_frames: int, back_moves: bool,
                                                                              cause: str, resumed: bool) -> None:
    """A re-acquisition lost again resumes the coast it interrupted, until that coast's coast_s is over, when it was
    too short to fit a new velocity on (3 frames), or shorter than coast_fit_s (20 frames, 0.67 s) and its fit
    contradicts the interrupted coast (a place that does not move, where the target moved at about 4 m/s). One
    that moves on with the target (20 frames), or that lasted longer than coast_fit_s (40 frames), starts a coast
    of its own, unless the tracker refuted it (cause "appearance" or "drift"): then a contradicting fit resumes the
    interrupted coast at any length."""
    from jsar.api import TrackResult
    from service.control.geo import GimbalAttitude
    from service.domain import ControlCommand
    from service.loop import TrackingLoop
    from service.mavlink import commands as c
    from service.mavlink.autopilot import AutopilotView
    from service.sources.base import Frame, LatestSlot

    config = config_from_mapping({"tracker": {"name": "csrt", "range_size_band": 0}, "camera": {"hfov_deg": 90.0},
                                  "gimbal": {"coast_s": 3.0, "coast_fit_s": 1.0, "coast_resume_change_m_s": 2.0}})
    view = AutopilotView(system_id=1, position=(47.0, 8.0, 530.0, 30.0), attitude=(0.0, 0.0, 0.0),
                         gimbal=GimbalAttitude(pitch=-math.pi / 4, yaw=0.0, yaw_in_earth_frame=False))
    # frames: tracked to 39 (the target moving right), lost 40-79 (1.3 s: longer than the fit window), tracked
    # back_frames frames from 80 (on a place that does not move, or on the target moving on), lost after
    back = set(range(80, 80 + back_frames))
    tracked = set(range(40)) | back

    class Scripted:
        def init(self, image, box):
            self.box, self.frames = box, 0
            self.loss_cause: str | None = None

        def update(self, image):
            self.frames += 1
            self.loss_cause = cause if self.frames >= 80 else "peak"  # why each loss began (JSAR-Re's attribute)
            if self.frames < 40 or (back_moves and self.frames in back):
                x, y, w, h = self.box
                self.box = (x + 0.2, y, w, h)
            return TrackResult(self.box, 1.0, "tracking") if self.frames in tracked else TrackResult(self.box, 0.1, "lost")

    commands: list[ControlCommand] = []

    class Record:
        def apply(self, now_s: float, command: ControlCommand) -> None:
            commands.append(command)

    selections: LatestSlot = LatestSlot()
    loop = TrackingLoop(config, selections, Scripted, Record(), lambda: view)
    selections.put(c.TrackRectangle(0.45, 0.45, 0.55, 0.55))
    image = np.zeros((100, 100, 3), np.uint8)
    for k in range(260):
        loop.step(Frame(image, k, k / FPS, 0.0))
    # commands[k] is frame k's (frame 0 selects); the first coast started at frame 39's capture time
    lost_again = 80 + back_frames
    assert all(commands[k].coasting for k in range(40, 80))
    assert not any(commands[k].coasting for k in back)
    if resumed:
        coast_end = 39 + int(3.0 * FPS)
        assert all(commands[k].coasting for k in range(lost_again, coast_end - 1)), \
            [commands[k].coasting for k in range(lost_again, coast_end + 2)]
        assert not any(commands[k].coasting for k in range(coast_end + 1, 260))
        assert loop.counters["coasts"] == 1 and loop.counters["coasts_resumed"] == 1
    else:
        assert loop.counters["coasts"] == 2 and loop.counters["coasts_resumed"] == 0
        assert commands[lost_again].coasting
