"""Frame sources and the tracking loop's fault handling: corrupt frames, end of file, camera absent,
latest-frame-wins, frame size change, tracker failure, lost / stop behaviour."""
from __future__ import annotations

import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from pymavlink.dialects.v20.common import CAMERA_TRACKING_MODE_NONE as MODE_NONE
from pymavlink.dialects.v20.common import CAMERA_TRACKING_MODE_POINT as MODE_POINT
from pymavlink.dialects.v20.common import CAMERA_TRACKING_MODE_RECTANGLE as MODE_RECTANGLE
from pymavlink.dialects.v20.common import CAMERA_TRACKING_STATUS_FLAGS_ACTIVE as ACTIVE
from pymavlink.dialects.v20.common import CAMERA_TRACKING_STATUS_FLAGS_COASTING as COASTING
from pymavlink.dialects.v20.common import CAMERA_TRACKING_STATUS_FLAGS_ERROR as ERROR
from pymavlink.dialects.v20.common import CAMERA_TRACKING_STATUS_FLAGS_IDLE as IDLE

from bench.fuzz import scene  # the synthetic test frame (other tests import it from here)
from jsar.api import TrackResult
from service.config import config_from_mapping
from service.domain import ControlCommand
from service.loop import TrackingLoop
from service.mavlink.autopilot import AutopilotView
from service.mavlink.commands import StopTracking, TrackRectangle
from service.sources.base import CaptureWorker, EndOfStream, Frame, LatestSlot, SourceError, backoff_delays
from service.sources.file import FileReader
from service.sources.v4l2 import V4L2Reader
from service.sources.zenoh_wire import encode_frame
from sim.ports import free_tcp_port


def frame(image: np.ndarray, frame_id: int, t: float) -> Frame:
    return Frame(image, frame_id, t, t)


# --- mailbox, backoff ----------------------------------------------------------------------------------
def test_latest_frame_wins_and_drops_are_counted() -> None:
    slot: LatestSlot[int] = LatestSlot()
    for i in range(5):
        slot.put(i)
    assert slot.take(0.0) == 4 and slot.dropped == 4
    assert slot.take(0.0) is None  # nothing queued behind it


def test_backoff_doubles_up_to_the_cap() -> None:
    delays = backoff_delays(0.5, 3.0)
    assert [next(delays) for _ in range(5)] == [0.5, 1.0, 2.0, 3.0, 3.0]


# --- file source -------------------------------------------------------------------------------------
def test_image_folder_skips_corrupt_frames_and_ends(tmp_path: Path) -> None:
    for i in range(4):
        cv2.imwrite(str(tmp_path / f"{i:04d}.png"), scene((64, 48), (32, 24), 16))
    (tmp_path / "0002.jpg").write_bytes(b"\xff\xd8 this is not a jpeg")  # sorts between 0002.png and 0003.png
    reader = FileReader(str(tmp_path), realtime=False)
    mailbox: LatestSlot[Frame] = LatestSlot()
    worker = CaptureWorker(reader, mailbox, 0.05, 0.1)
    worker.start()
    assert worker.health.wait_for(lambda h: h.state == "ended", 10.0)
    health = worker.health.snapshot()
    assert (health["frames"], health["corrupt"]) == (4, 1)
    assert "end of file" in str(health["reason"])
    worker.stop()


def test_video_file_round_trip_loop_and_pacing(tmp_path: Path) -> None:
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 25.0, (64, 48))
    images = [scene((64, 48), (20 + 3 * i, 24), 16) for i in range(6)]
    for image in images:
        writer.write(image)
    writer.release()
    reader = FileReader(str(path), realtime=True, loop=True)
    reader.open()
    assert reader.frame_interval_s() == pytest.approx(1 / 25.0)  # paced at the file's own rate
    got = [reader.read(0.1) for _ in range(6)]
    assert all(np.array_equal(f.image, im) for f, im in zip(got, images))  # FFV1 is lossless
    assert reader.read(0.1) is None  # end: rewinds (loop)
    again = reader.read(0.1)
    assert again is not None and again.frame_id == 6 and np.array_equal(again.image, images[0])
    reader.close()
    once = FileReader(str(path), realtime=False, loop=False)
    once.open()
    for _ in range(6):
        once.read(0.1)
    with pytest.raises(EndOfStream):
        once.read(0.1)
    once.close()


def test_missing_file_is_a_source_error(tmp_path: Path) -> None:
    with pytest.raises(SourceError, match="does not exist"):
        FileReader(str(tmp_path / "none.avi")).open()
    (tmp_path / "junk.avi").write_bytes(b"not a video")
    with pytest.raises(SourceError, match="cannot open video"):
        FileReader(str(tmp_path / "junk.avi")).open()


# --- v4l2 ----------------------------------------------------------------------------------------------
def test_absent_camera_reports_error_and_retries_with_backoff() -> None:
    reader = V4L2Reader("/dev/video97", 640, 480, 30.0, "MJPG")
    with pytest.raises(SourceError, match="absent"):
        reader.open()
    worker = CaptureWorker(reader, LatestSlot(), 0.01, 0.04)
    worker.start()
    assert worker.health.wait_for(lambda h: h.failures >= 4, 10.0)
    snap = worker.health.snapshot()
    assert snap["state"] == "error" and "absent" in str(snap["reason"]) and "retry in 0.0" in str(snap["reason"])
    worker.stop()
    assert not worker._thread.is_alive()


class FailingReader:
    """Delivers two frames, then fails like an unplugged camera, then works again."""

    name = "flaky"

    def __init__(self) -> None:
        self.opens = 0
        self.count = 0

    def open(self) -> None:
        self.opens += 1

    def frame_interval_s(self) -> None:
        return None

    def read(self, timeout_s: float) -> Frame | None:
        self.count += 1
        if self.count == 3:
            raise SourceError("device vanished")
        return frame(np.zeros((8, 8, 3), np.uint8), self.count, 0.0)

    def close(self) -> None:
        pass


def test_source_failure_mid_stream_reopens() -> None:
    reader = FailingReader()
    worker = CaptureWorker(reader, LatestSlot(), 0.01, 0.02)
    worker.start()
    assert worker.health.wait_for(lambda h: h.frames >= 5, 10.0)
    worker.stop()
    assert reader.opens >= 2 and worker.health.failures >= 1


# --- the tracking loop ----------------------------------------------------------------------------------
class RecordingOutputs:
    """loop.Outputs that records commands and lets a test wait for one."""

    def __init__(self) -> None:
        self.commands: list[ControlCommand] = []
        self._cond = threading.Condition()

    def apply(self, now_s: float, command: ControlCommand) -> None:
        with self._cond:
            self.commands.append(command)
            self._cond.notify_all()

    def wait_for(self, predicate, timeout_s: float) -> bool:
        with self._cond:
            return self._cond.wait_for(predicate, timeout=timeout_s)


def make_loop(make_tracker=None) -> tuple[TrackingLoop, LatestSlot, RecordingOutputs]:
    import jsar
    config = config_from_mapping({"tracker": {"name": "csrt", "range_size_band": 0}, "camera": {"hfov_deg": 60.0}})
    selections: LatestSlot = LatestSlot()
    outputs = RecordingOutputs()
    # An autopilot heard on every frame: the gimbal loop is closed, so its controller integrates.
    loop = TrackingLoop(config, selections, make_tracker or (lambda: jsar.create("csrt")), outputs,
                        lambda: AutopilotView(system_id=1, last_heartbeat_s=time.monotonic()))
    return loop, selections, outputs


def test_frame_size_change_mid_stream_rescales_and_keeps_tracking() -> None:
    loop, selections, outputs = make_loop()
    selections.put(TrackRectangle(400 / 640, 300 / 480, 440 / 640, 340 / 480))
    t = 0.0
    for i in range(5):
        t += 1 / 30
        report = loop.step(frame(scene((640, 480), (420 + i, 320)), i, t))
    assert report.state == "tracking"
    for i in range(5, 10):
        t += 1 / 30
        report = loop.step(frame(scene((320, 240), (212 + i / 2, 160), side=20), i, t))
    assert loop.counters["resized"] == 1 and report.image_size == (320, 240)
    assert report.state == "tracking"
    x, y, w, h = report.box
    assert abs(x + w / 2 - 214) < 6 and abs(y + h / 2 - 160) < 6
    yaw_rate, pitch_rate = outputs.commands[-1].rates
    assert yaw_rate > 0 and pitch_rate < 0  # right of and below the centre


class ScriptedTracker:
    """Returns scripted states; raises on 'boom'."""

    def __init__(self, states: list[str]) -> None:
        self.states = states

    def init(self, image: np.ndarray, box: tuple) -> None:
        self.box = box

    def update(self, image: np.ndarray) -> TrackResult:
        state = self.states.pop(0)
        if state == "boom":
            raise RuntimeError("tracker bug")
        return TrackResult(self.box, 0.5, state)  # type: ignore[arg-type]


def test_lost_gives_zero_rates_and_resets_the_integrator_then_stop_ends_commands() -> None:
    tracker = ScriptedTracker(["tracking", "tracking", "lost", "boom", "recovered", "tracking"])
    loop, selections, outputs = make_loop(lambda: tracker)
    image = scene((160, 120), (120, 30), 20)
    selections.put(TrackRectangle(110 / 160, 20 / 120, 130 / 160, 40 / 120))
    states = [loop.step(frame(image, i, i / 30)).state for i in range(7)]
    # frame 0 initialises (its box is the selection); the tracker's script starts with frame 1
    assert states == ["tracking", "tracking", "tracking", "lost", "lost", "recovered", "tracking"]
    rates = [cmd.rates for cmd in outputs.commands]
    assert rates[3] == (0.0, 0.0) and rates[4] == (0.0, 0.0)
    assert loop.counters["tracker_errors"] == 1 and loop.counters["recovered"] == 1
    # after recovery the integrator restarted from zero: the first rate equals the first rate after init
    assert rates[5] == pytest.approx(rates[0]) and rates[6] != pytest.approx(rates[0])
    selections.put(StopTracking())
    stopped = loop.step(frame(image, 7, 8 / 30))
    after = loop.step(frame(image, 8, 9 / 30))
    assert stopped.state == "idle" and outputs.commands[-2].stopped and outputs.commands[-2].rates == (0.0, 0.0)
    assert after.state == "idle" and outputs.commands[-1].rates is None  # no more gimbal commands


def _steady_track(captures: list[tuple[int, float, float]], size: tuple[int, int] = (160, 120),
                  between=lambda loop, i: None) -> tuple[TrackingLoop, list[tuple[float, float]]]:
    """Track a still, off-centre target over frames (frame_id, capture time s, service read time s);
    between(loop, i) runs before frame i. Returns the loop and the gimbal rates of every frame."""
    loop, selections, outputs = make_loop(lambda: ScriptedTracker(["tracking"] * len(captures)))
    selections.put(TrackRectangle(110 / 160, 20 / 120, 130 / 160, 40 / 120))
    image = np.zeros((size[1], size[0], 3), np.uint8)
    for i, (frame_id, capture_s, read_s) in enumerate(captures):
        between(loop, i)
        loop.step(Frame(image, frame_id, capture_s, read_s))
    return loop, [cmd.rates for cmd in outputs.commands]


def test_gimbal_rates_follow_the_capture_clock_not_the_processing_time() -> None:
    from service.control.gimbal import GimbalState, PidGains, angular_error, gimbal_step
    from service.selection import rectangle_box
    captures = [1000.0 + i / 30 for i in range(12)]  # 30 fps on the source's clock
    even = [(i, t, 5.0 + i / 30) for i, t in enumerate(captures)]
    # the same frames, the service stalling 0.3 s before every 3rd one (slow tracker, loaded machine)
    stalled = [(i, t, 5.0 + i / 30 + 0.3 * (i // 3)) for i, t in enumerate(captures)]
    loop, rates_even = _steady_track(even)
    _, rates_stalled = _steady_track(stalled)
    assert rates_even == rates_stalled
    # and they are the controller's response to a steady error sampled every 1/30 s of capture time
    box = rectangle_box(TrackRectangle(110 / 160, 20 / 120, 130 / 160, 40 / 120), (160, 120))
    yaw_err, pitch_err = angular_error(box, (160, 120), loop.hfov)
    state, expected = GimbalState(), []
    for _ in captures:
        state, yaw_rate, pitch_rate = gimbal_step(state, yaw_err, pitch_err, 1 / 30, PidGains.from_config(loop.config.gimbal))
        expected.append((yaw_rate, pitch_rate))
    assert [r for pair in rates_even for r in pair] == pytest.approx([r for pair in expected for r in pair], abs=1e-12)
    assert len(set(rates_even)) == len(rates_even)  # slew limit and integrator at work: dt matters


def test_unusable_capture_intervals_reset_the_controller_instead_of_a_spike() -> None:
    from service.control.gimbal import gimbal_step
    frames = [(i, 1000.0 + i / 30, 0.0) for i in range(3)]
    frames += [(3, 1000.0 + 2 / 30, 0.0)]  # 3: same capture time as frame 2 (repeated stamp)
    frames += [(4, 1000.0 + 3 / 30, 0.0)]  # 4: normal step after the reset
    frames += [(5, 1005.0, 0.0)]  # 5: a 4.9 s gap (stalled stream)
    frames += [(0, 20.0, 0.0)]  # 6: publisher restarted: frame ids and its clock start again
    frames += [(1, 20.8, 0.0)]  # 7: 0.8 s: usable, integrated as the 0.5 s maximum step
    before_clamped: list = []
    loop, rates = _steady_track(frames, between=lambda loop, i: before_clamped.append(loop.gimbal) if i == 7 else None)
    from_rest = rates[0]
    assert rates[1] != pytest.approx(from_rest)
    assert rates[3] == from_rest and rates[5] == from_rest and rates[6] == from_rest
    assert rates[4] == rates[1]  # the clock restarted cleanly at frame 3
    assert loop.counters["clock_resets"] == 3
    from service.control.gimbal import angular_error
    yaw_err, pitch_err = angular_error(loop.box, (160, 120), loop.hfov)
    _, *clamped = gimbal_step(before_clamped[0], yaw_err, pitch_err, 0.5, loop.gains)
    assert rates[7] == pytest.approx(tuple(clamped), abs=1e-12)


def test_frame_size_change_restarts_the_controller() -> None:
    loop, selections, outputs = make_loop(lambda: ScriptedTracker(["tracking"] * 5))
    selections.put(TrackRectangle(110 / 160, 20 / 120, 130 / 160, 40 / 120))
    for i, size in enumerate([(160, 120)] * 3 + [(320, 240)]):  # same view, twice the resolution
        loop.step(Frame(np.zeros((size[1], size[0], 3), np.uint8), i, 1000.0 + i / 30, 0.0))
    rates = [cmd.rates for cmd in outputs.commands]
    assert loop.counters["resized"] == 1
    assert rates[3] == pytest.approx(rates[0], abs=1e-12) and rates[2] != pytest.approx(rates[0])


def test_bad_selection_box_is_refused_without_crash() -> None:
    def refuse() -> ScriptedTracker:
        raise ValueError("box does not overlap")
    loop, selections, outputs = make_loop(refuse)
    selections.put(TrackRectangle(0.1, 0.1, 0.2, 0.2))
    assert loop.step(frame(np.zeros((40, 40, 3), np.uint8), 0, 0.0)).state == "idle"


def test_run_stops_promptly_and_stop_applies_without_frames() -> None:
    loop, selections, outputs = make_loop(lambda: ScriptedTracker(["tracking"] * 10))
    mailbox: LatestSlot[Frame] = LatestSlot()
    selections.put(TrackRectangle(0.1, 0.1, 0.5, 0.5))
    mailbox.put(frame(np.zeros((40, 40, 3), np.uint8), 0, 0.0))
    stop = threading.Event()
    runner = threading.Thread(target=loop.run, args=(mailbox, stop.is_set))
    runner.start()
    assert outputs.wait_for(lambda: len(outputs.commands) >= 1, 5.0)  # the one frame was tracked
    # the camera goes silent; a stop request must still reach the loop
    selections.put(StopTracking())
    assert outputs.wait_for(lambda: any(c.stopped for c in outputs.commands), 5.0)
    assert loop.state == "idle" and loop.counters["frames"] == 1
    stop.set()
    runner.join(2.0)
    assert not runner.is_alive()
    assert outputs.commands[-1].stopped


# --- zenoh source ------------------------------------------------------------------------------------
def test_zenoh_source_decodes_frames_and_counts_corrupt_ones() -> None:
    from service.config import ZenohConfig
    from service.sources.zenoh import ZenohReader, frame_key
    from service.telemetry import open_session

    port = free_tcp_port()
    service_side = open_session(ZenohConfig(listen=(f"tcp/127.0.0.1:{port}",)))
    publisher_side = open_session(ZenohConfig(connect=(f"tcp/127.0.0.1:{port}",)))
    try:
        reader = ZenohReader(service_side, "test")
        mailbox: LatestSlot[Frame] = LatestSlot()
        worker = CaptureWorker(reader, mailbox, 0.05, 0.1)
        worker.start()
        pub = publisher_side.declare_publisher(frame_key("test"))
        image = scene((64, 48), (30, 20), 16)
        # publish until the subscription is matched and a frame arrives (no fixed sleeps)
        arrived = None
        for i in range(200):
            pub.put(encode_frame(image, i, 123.0 + i))
            arrived = mailbox.take(0.05)
            if arrived is not None:
                break
        assert arrived is not None and np.array_equal(arrived.image, image)
        assert arrived.capture_time_s == 123.0 + arrived.frame_id
        pub.put(b"JFR1garbage")
        assert worker.health.wait_for(lambda h: h.corrupt >= 1, 5.0)
        pub.put(encode_frame(image, 999, float("nan")))  # the controllers integrate over capture times
        assert worker.health.wait_for(lambda h: h.corrupt >= 2, 5.0)
        assert mailbox.take(0.0) is None
        worker.stop()
    finally:
        publisher_side.close()
        service_side.close()


def test_frames_stop_while_tracking_holds_gimbal_and_vehicle_once() -> None:
    loop, selections, outputs = make_loop(lambda: ScriptedTracker(["tracking"] * 10))
    mailbox: LatestSlot[Frame] = LatestSlot()
    selections.put(TrackRectangle(0.6, 0.1, 0.9, 0.4))
    mailbox.put(frame(np.zeros((40, 40, 3), np.uint8), 0, 0.0))
    stop = threading.Event()
    iterations = [0]
    ticked = threading.Condition()

    def count_iteration() -> None:
        with ticked:
            iterations[0] += 1
            ticked.notify_all()

    runner = threading.Thread(target=loop.run, args=(mailbox, stop.is_set, count_iteration))
    runner.start()
    try:
        assert outputs.wait_for(lambda: len(outputs.commands) >= 2, 5.0)  # the frame, then the hold
        assert outputs.commands[0].rates[0] > 0  # tracked: turning right towards the target
        hold = outputs.commands[1]
        assert hold.state == "lost" and hold.rates == (0.0, 0.0) and hold.bearing is None
        assert loop.tracker is not None  # the track is kept for when frames come back
        at_hold = iterations[0]
        with ticked:
            assert ticked.wait_for(lambda: iterations[0] >= at_hold + 4, 10.0)
        assert len(outputs.commands) == 2  # several more empty waits: held once per gap, not every timeout
        mailbox.put(frame(np.zeros((40, 40, 3), np.uint8), 1, 1.0))
        assert outputs.wait_for(lambda: len(outputs.commands) >= 3, 5.0)
        assert outputs.commands[2].state == "tracking"
    finally:
        stop.set()
        runner.join(2.0)


def test_status_reports_error_when_the_camera_fails_while_tracking() -> None:
    from service.mavlink import messages as m
    active = m.TrackingStatus(ACTIVE, MODE_RECTANGLE, (0.1, 0.1, 0.2, 0.2))
    assert m.with_source_state(active, False) == m.TrackingStatus(ERROR, MODE_RECTANGLE, (0.1, 0.1, 0.2, 0.2))
    assert m.with_source_state(active, True) == active
    assert m.with_source_state(m.TrackingStatus(), False) == m.TrackingStatus()


def test_the_loop_state_maps_to_tracking_status_and_mode() -> None:
    from service.domain import LoopState, SelectionKind, TrackSnapshot
    from service.mavlink import messages as m
    box = (0.1, 0.1, 0.2, 0.2)
    statuses = {LoopState.TRACKING: ACTIVE, LoopState.RECOVERED: ACTIVE, LoopState.LOST: COASTING}
    for state, status in statuses.items():
        for kind, mode in ((SelectionKind.POINT, MODE_POINT), (SelectionKind.RECTANGLE, MODE_RECTANGLE)):
            snapshot = TrackSnapshot(state=state, selection=kind, box_normalised=box)
            assert m.tracking_status(snapshot) == m.TrackingStatus(status, mode, box)
    assert m.tracking_status(TrackSnapshot()) == m.TrackingStatus(IDLE, MODE_NONE, None)


def test_backoff_restarts_after_the_source_worked_again() -> None:
    class Flaky:
        """Fails to open three times, then delivers one frame and fails, and so on."""

        name = "flaky-open"

        def __init__(self) -> None:
            self.opens = 0

        def open(self) -> None:
            self.opens += 1
            if self.opens % 4 != 0:
                raise SourceError("not yet")

        def frame_interval_s(self) -> None:
            return None

        def read(self, timeout_s: float) -> Frame | None:
            if getattr(self, "served", 0) < self.opens:
                self.served = self.opens
                return frame(np.zeros((4, 4, 3), np.uint8), self.opens, 0.0)
            raise SourceError("gone again")

        def close(self) -> None:
            pass

    worker = CaptureWorker(Flaky(), LatestSlot(), 0.01, 0.08)
    reasons: list[str] = []
    worker.start()
    assert worker.health.wait_for(lambda h: (reasons.append(h.reason) or True) and h.frames >= 2, 10.0)
    worker.stop()
    delays = [r.rsplit("retry in ", 1)[1] for r in reasons if "retry in" in r]
    # 0.01, 0.02, 0.04, then a frame, then "gone again" retries from 0.01 instead of continuing at 0.08
    assert "0.0 s" in delays[0] and any("gone again" in r and "retry in 0.0 s" in r for r in reasons)
