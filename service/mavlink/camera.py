"""The camera component on the link: receive thread (commands, autopilot state) and send scheduler
(heartbeat 1 Hz, CAMERA_INFORMATION, 275 / 276 at the requested intervals; once a second it asks the
autopilot for the messages the service uses that have stopped arriving, WANTED_STREAMS_HZ).

Command validation is pure (commands.decide); this class only applies decisions and answers.
Tracking intents go to the tracking loop through a one-slot mailbox (a newer selection replaces one
not yet applied).
"""
from __future__ import annotations

import logging
import math
import threading
import time
from typing import Callable

from pymavlink.dialects.v20 import common as mavlink
from pymavlink.dialects.v20.common import (
    MAV_CMD_CAMERA_STOP_TRACKING, MAV_CMD_CAMERA_TRACK_POINT, MAV_CMD_CAMERA_TRACK_RECTANGLE, MAV_CMD_REQUEST_MESSAGE,
    MAV_CMD_SET_MESSAGE_INTERVAL, MAV_RESULT_ACCEPTED, MAV_RESULT_DENIED, MAV_RESULT_FAILED,
    MAV_RESULT_TEMPORARILY_REJECTED, MAV_RESULT_UNSUPPORTED, MAV_SEVERITY_WARNING, MAVLINK_MSG_ID_CAMERA_INFORMATION,
    MAVLINK_MSG_ID_CAMERA_TRACKING_GEO_STATUS, MAVLINK_MSG_ID_CAMERA_TRACKING_IMAGE_STATUS,
    MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION,
)

from service.config import ServiceConfig
from service.domain import TrackSnapshot
from service.mavlink import messages
from service.mavlink.autopilot import WANTED_STREAMS_HZ, AutopilotView, observe, streams_to_request
from service.mavlink.commands import (
    Decision, RequestMessage, SetMessageInterval, StopTracking, TrackPoint, TrackRectangle, command_int_params, decide,
    is_for_us,
)
from service.mavlink.link import MavlinkLink
from service.mavlink.video_stream import (VIDEO_STREAM_MESSAGES, VideoStreamDescription, video_stream_information,
                                          video_stream_status)
from service.sources.base import LatestSlot
from service.threads import service_thread

log = logging.getLogger("service.mavlink")
RESULT_NAMES = {value: entry.name.removeprefix("MAV_RESULT_") for value, entry in mavlink.enums["MAV_RESULT"].items()}
# The operator's commands: a refusal of one is also sent as STATUSTEXT with its reason (not the refusals of
# what a ground station polls for, which would flood the operator's messages).
OPERATOR_COMMANDS = {MAV_CMD_CAMERA_TRACK_POINT: "TRACK_POINT", MAV_CMD_CAMERA_TRACK_RECTANGLE: "TRACK_RECTANGLE",
                     MAV_CMD_CAMERA_STOP_TRACKING: "STOP_TRACKING"}
REJECTED_COUNTERS = {MAV_RESULT_TEMPORARILY_REJECTED: "rejected_temporarily", MAV_RESULT_DENIED: "rejected_denied",
                     MAV_RESULT_UNSUPPORTED: "rejected_unsupported", MAV_RESULT_FAILED: "rejected_failed"}


class RepeatedRefusals:
    """Which refused commands were already logged at WARNING, so a ground station that polls for what this
    camera does not offer (mavsdk's camera plugin re-requests CAMERA_SETTINGS, STORAGE_INFORMATION,
    CAMERA_CAPTURE_STATUS, VIDEO_STREAM_INFORMATION and command 527 every few seconds) logs each kind once,
    not five warnings every few seconds for the whole flight. A repeat is the same command (command,
    requested message id for 511 / 512) from the same source (system, component) refused with the same
    result and reason: another reason is news (an inverted rectangle after a NaN one is warned too)."""

    MAX_KINDS = 64  # counted kinds (result, command, message); a peer sending junk cannot grow it further
    MAX_SEEN = 1024  # remembered repeats; past it every refusal is warned (a junk flood cannot grow memory)

    def __init__(self) -> None:
        self._seen: set[tuple[int, int | None, int, int, int, str]] = set()
        self._counts: dict[tuple[int, int, int | None], list] = {}  # kind -> [count, first reason]

    def first(self, command: int, param1: float, source: tuple[int, int], result: int, reason: str = "") -> bool:
        """True the first time this refusal (command, message, source, result, reason) is seen (log it
        loudly), False for repeats."""
        key = (command, _requested_message(command, param1), source[0], source[1], result, reason)
        if key in self._seen:
            return False
        if len(self._seen) < self.MAX_SEEN:
            self._seen.add(key)
        return True

    def count(self, command: int, param1: float, result: int, reason: str) -> None:
        """Count a refusal by kind (all sources together), keeping the first reason given for it."""
        key = (result, command, _requested_message(command, param1))
        if key in self._counts:
            self._counts[key][0] += 1
        elif len(self._counts) < self.MAX_KINDS:
            self._counts[key] = [1, reason]

    def summary(self) -> list[dict]:
        """Refusals by kind, most frequent first: result name, command, requested message id (511 / 512
        only, else None), count, reason (for the status query and the demo's summary)."""
        rows = [{"result": RESULT_NAMES.get(result, str(result)), "command": command, "message": message,
                 "count": count, "reason": reason}
                for (result, command, message), (count, reason) in self._counts.items()]
        return sorted(rows, key=lambda row: -row["count"])


class TextBudget:
    """A token bucket for the STATUSTEXT that explains a refused operator command: `burst` texts at once, then
    `per_s` a second. An operator's own commands never meet it; a ground station flooding refused commands
    (1,000 a second in issue 42's fault) would otherwise double the camera's traffic with texts nobody can
    read. The ACK, with its result, answers every command regardless."""

    def __init__(self, burst: float = 10.0, per_s: float = 5.0) -> None:
        self.burst, self.per_s = burst, per_s
        self._tokens = burst
        self._at: float | None = None
        self.suppressed = 0

    def take(self, now_s: float) -> bool:
        """True if a text may go out at now_s (time.monotonic() s); counts the suppressed ones."""
        if self._at is not None:
            self._tokens = min(self.burst, self._tokens + (now_s - self._at) * self.per_s)
        self._at = now_s
        if self._tokens >= 1.0:
            self._tokens -= 1.0
            return True
        self.suppressed += 1
        return False


def selection_refusal(source_state: str, has_frame: bool, reason: str) -> Decision | None:
    """Why a valid selection cannot be taken now, or None: TEMPORARILY_REJECTED while the source has not
    delivered its first frame (starting: a ground station that selects as soon as the camera's heartbeat
    arrives may retry), FAILED while it fails or has ended (fixing the camera is not a matter of waiting)."""
    if source_state == "ok" and has_frame:
        return None
    if source_state == "starting":
        return Decision(MAV_RESULT_TEMPORARILY_REJECTED, f"no camera frame yet ({reason}): retry shortly")
    return Decision(MAV_RESULT_FAILED, f"no camera frames: {reason}")


def _requested_message(command: int, param1: float) -> int | None:
    """The message id a MAV_CMD_SET_MESSAGE_INTERVAL (511) / MAV_CMD_REQUEST_MESSAGE (512) is about."""
    asks_for_message = command in (MAV_CMD_SET_MESSAGE_INTERVAL, MAV_CMD_REQUEST_MESSAGE)
    return int(param1) if asks_for_message and math.isfinite(param1) else None


class CameraComponent:
    """MAVLink camera: answers commands, tracks the autopilot, streams status."""

    def __init__(self, config: ServiceConfig, link: MavlinkLink, selections: LatestSlot,
                 frame_size: Callable[[], tuple[int, int] | None], source_ok: Callable[[], bool],
                 source_reason: Callable[[], str],
                 video_stream: Callable[[], VideoStreamDescription | None] | None = None,
                 source_state: Callable[[], str] = lambda: "ok") -> None:
        """video_stream: the RTP stream's description (None until frames arrive); None = no stream.
        source_state: the source's health state (starting / ok / error / ended: SourceHealth.state)."""
        self.config = config
        self.link = link
        self.selections = selections
        self._frame_size = frame_size
        self._source_ok = source_ok
        self._source_reason = source_reason
        self._source_state = source_state
        self._video_stream = video_stream
        self._lock = threading.Lock()
        self._view = AutopilotView()
        self._snapshot = TrackSnapshot()
        # 275 is off until a ground station asks; 276 streams at the guidance rate in follow_target mode
        geo = 1.0 / config.guidance.rate_hz if config.guidance.mode == "follow_target" else None
        self._intervals: dict[int, float | None] = {MAVLINK_MSG_ID_CAMERA_TRACKING_IMAGE_STATUS: None,
                                                    MAVLINK_MSG_ID_CAMERA_TRACKING_GEO_STATUS: geo}
        self._info_requested = threading.Event()
        self._started = time.monotonic()
        self._stop = threading.Event()
        self._autopilot_alive = False
        self._stream_heard_s: dict[int, float] = {}  # wanted autopilot message id -> last arrival (monotonic s)
        self._stream_asked_s: dict[int, float] = {}  # ... -> last SET_MESSAGE_INTERVAL sent for it
        # rejected = the sum of the rejected_* by result (unsupported: this camera does not have what was
        # asked, as when a ground station polls for every camera feature; denied: bad parameters)
        self.counters = {"commands": 0, "accepted": 0, "rejected": 0, "rejected_unsupported": 0, "rejected_denied": 0,
                         "rejected_temporarily": 0, "rejected_failed": 0, "status_sent": 0, "texts_suppressed": 0}
        self._refusals = RepeatedRefusals()
        self._accepted = RepeatedRefusals()  # accepted routine requests: logged at INFO once per kind and source
        self._texts = TextBudget()
        self._text_id = 0  # id of the last chunked STATUSTEXT (1..65535)
        self._threads = [service_thread(self._receive_loop, "mavlink-rx"),
                         service_thread(self._send_loop, "mavlink-tx")]

    # --- shared state -------------------------------------------------------------------------
    def autopilot(self) -> AutopilotView:
        with self._lock:
            return self._view

    def autopilot_alive(self, now_s: float | None = None) -> bool:
        now_s = time.monotonic() if now_s is None else now_s
        return self.autopilot().alive(now_s, self.config.mavlink.heartbeat_timeout_s)

    def publish(self, snapshot: TrackSnapshot) -> None:
        """Latest tracking state from the loop (read by the status scheduler)."""
        with self._lock:
            self._snapshot = snapshot

    def intervals(self) -> dict[int, float | None]:
        with self._lock:
            return dict(self._intervals)

    def time_boot_ms(self) -> int:
        return int((time.monotonic() - self._started) * 1000) & 0xFFFFFFFF

    def refusals(self) -> list[dict]:
        """Refused commands by kind (RepeatedRefusals.summary)."""
        return self._refusals.summary()

    def autopilot_state(self, now_s: float | None = None) -> str:
        """`waiting_for_heartbeat` (never heard), `connected`, or `heartbeat_lost` (for the status query)."""
        view = self.autopilot()
        if view.last_heartbeat_s is None:
            return "waiting_for_heartbeat"
        return "connected" if self.autopilot_alive(now_s) else "heartbeat_lost"

    def start(self) -> None:
        mav = self.config.mavlink
        held = ("gimbal and guidance commands" if not mav.system_id else "guidance commands") + " are held until it arrives"
        log.info('event=waiting_for_autopilot detail="waiting for the autopilot\'s heartbeat on %s (system id %s); '
                 '%s"', mav.url, mav.system_id or "any", held)
        for thread in self._threads:
            thread.start()

    def stop(self, timeout_s: float = 1.0) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout_s)

    # --- receive ------------------------------------------------------------------------------
    def _receive_loop(self) -> None:
        expected = self.config.mavlink.system_id or None
        while not self._stop.is_set():
            msg = self.link.recv(timeout_s=0.2)
            if msg is None:
                continue
            try:
                self._handle(msg, expected)
            except Exception:  # noqa: BLE001 - one bad message must not stop the receiver
                log.exception("event=message_handling_failed type=%s", msg.get_type())

    def _handle(self, msg: object, expected_system: int | None) -> None:
        kind = msg.get_type()  # type: ignore[attr-defined]
        if kind in ("COMMAND_LONG", "COMMAND_INT"):
            self._handle_command(msg, kind)
            return
        now = time.monotonic()
        with self._lock:
            before = self._view
            self._view = observe(before, msg, now, expected_system)
            learned = before.system_id is None and self._view.system_id is not None
            msg_id = msg.get_msgId()  # type: ignore[attr-defined]
            if msg_id in WANTED_STREAMS_HZ and msg.get_srcSystem() == self._view.system_id:  # type: ignore[attr-defined]
                self._stream_heard_s[msg_id] = now
        if learned and self.link.system_id != self._view.system_id:
            log.info("event=system_id_learned system_id=%d", self._view.system_id)
            self.link.set_system_id(self._view.system_id)  # type: ignore[arg-type]
            self._info_requested.set()  # re-announce under the right system id

    def _handle_command(self, msg: object, kind: str) -> None:
        own = self.config.mavlink.component_id
        if kind == "COMMAND_LONG":
            params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)  # type: ignore[attr-defined]
        else:
            params = command_int_params(msg.param1, msg.param2, msg.param3, msg.param4, msg.x, msg.y, msg.z)  # type: ignore[attr-defined]
        if msg.target_system not in (0, self.link.system_id):  # type: ignore[attr-defined]
            return
        if not is_for_us(msg.target_component, msg.command, params, own):  # type: ignore[attr-defined]
            return
        decision = decide(msg.command, params, own)  # type: ignore[attr-defined]
        decision = self._apply(decision)
        self.counters["commands"] += 1
        self.counters["accepted" if decision.result == MAV_RESULT_ACCEPTED else "rejected"] += 1
        source = (msg.get_srcSystem(), msg.get_srcComponent())  # type: ignore[attr-defined]
        if decision.result != MAV_RESULT_ACCEPTED:
            # its own name: `kind` is the message type the log's via= reports
            counter = REJECTED_COUNTERS.get(decision.result, "rejected_failed")
            self.counters[counter] += 1
            self._refusals.count(msg.command, params[0], decision.result, decision.reason)  # type: ignore[attr-defined]
        if decision.result == MAV_RESULT_ACCEPTED:
            # the operator's commands always at INFO; what a ground station polls for (511, 512) once per kind
            routine = msg.command not in OPERATOR_COMMANDS  # type: ignore[attr-defined]
            first = self._accepted.first(msg.command, params[0], source, decision.result)  # type: ignore[attr-defined]
            level, note = (logging.DEBUG, "") if routine and not first else (logging.INFO, "")
        elif self._refusals.first(msg.command, params[0], source, decision.result, decision.reason):  # type: ignore[attr-defined]
            level, note = logging.WARNING, " (repeats of this refusal are logged at DEBUG)"
        else:
            level, note = logging.DEBUG, ""
        log.log(level, 'event=command command=%d via=%s from=%d/%d result=%s reason="%s"%s', msg.command, kind,  # type: ignore[attr-defined]
                source[0], source[1], RESULT_NAMES.get(decision.result, decision.result), decision.reason, note)
        explain = decision.result != MAV_RESULT_ACCEPTED and msg.command in OPERATOR_COMMANDS  # type: ignore[attr-defined]
        if explain and not self._texts.take(time.monotonic()):
            explain = False
            self.counters["texts_suppressed"] += 1
        if explain:
            # the reason, before the ACK, as ground stations show it (QGroundControl's messages, gcs.web)
            self._text_id = self._text_id % 65535 + 1
            text = (f"{OPERATOR_COMMANDS[msg.command]} {RESULT_NAMES.get(decision.result, decision.result)}: "  # type: ignore[attr-defined]
                    f"{decision.reason}")
            for message in messages.status_texts(self.link.mav, MAV_SEVERITY_WARNING, text, self._text_id):
                self.link.send(message)
        self.link.send(self.link.mav.command_ack_encode(  # type: ignore[attr-defined]
            msg.command, decision.result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))  # type: ignore[attr-defined]
        if decision.result == MAV_RESULT_ACCEPTED and isinstance(decision.intent, RequestMessage):
            self._send_requested(decision.intent.message_id)

    def _apply(self, decision: Decision) -> Decision:
        """Carry out an accepted decision; may turn it into FAILED (e.g. no camera frames)."""
        intent = decision.intent
        if decision.result != MAV_RESULT_ACCEPTED or intent is None:
            return decision
        if isinstance(intent, (TrackPoint, TrackRectangle)):
            refusal = selection_refusal(self._source_state(), self._source_ok() and self._frame_size() is not None,
                                        self._source_reason())
            if refusal is not None:
                return refusal
            self.selections.put(intent)
        elif isinstance(intent, RequestMessage) and intent.message_id == MAVLINK_MSG_ID_CAMERA_INFORMATION:
            if self._frame_size() is None:
                # the real frame size is part of the answer: ask again once the camera delivers frames
                return Decision(MAV_RESULT_TEMPORARILY_REJECTED, f"no camera frames yet: {self._source_reason()}")
        elif isinstance(intent, RequestMessage) and intent.message_id in VIDEO_STREAM_MESSAGES:
            if self._video_stream is None:
                return Decision(MAV_RESULT_UNSUPPORTED, "no video stream (video.stream.enabled is false)")
            if self._video_stream() is None:
                return Decision(MAV_RESULT_TEMPORARILY_REJECTED, f"no camera frames yet: {self._source_reason()}")
        elif isinstance(intent, StopTracking):
            self.selections.put(intent)
        elif isinstance(intent, SetMessageInterval):
            interval = intent.interval_s
            if interval == "default":
                interval = self.config.mavlink.default_status_interval_s
            with self._lock:
                self._intervals[intent.message_id] = interval  # type: ignore[assignment]
        return decision

    # --- send ---------------------------------------------------------------------------------
    def _send_requested(self, message_id: int) -> None:
        if message_id == MAVLINK_MSG_ID_CAMERA_INFORMATION:
            self._send_camera_information()
        elif message_id == MAVLINK_MSG_ID_CAMERA_TRACKING_IMAGE_STATUS:
            self._send_image_status()
        elif message_id == MAVLINK_MSG_ID_CAMERA_TRACKING_GEO_STATUS:
            self._send_geo_status()
        elif message_id in VIDEO_STREAM_MESSAGES and self._video_stream is not None:
            stream = self._video_stream()
            if stream is not None:
                build = video_stream_information if message_id == MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION else video_stream_status
                self.link.send(build(self.link.mav, stream))

    def _send_camera_information(self) -> None:
        size = self._frame_size()
        if size is None:
            return  # announced as soon as the first frame gives the real size
        cam = self.config.camera
        self.link.send(messages.camera_information(
            self.link.mav, self.time_boot_ms(), cam.vendor_name, cam.model_name, size,
            geo_status=self.config.guidance.mode == "follow_target", video_stream=self._video_stream is not None))

    def _send_image_status(self) -> None:
        with self._lock:
            status = messages.tracking_status(self._snapshot)
        status = messages.with_source_state(status, self._source_ok())
        self.link.send(messages.tracking_image_status(self.link.mav, status))
        self.counters["status_sent"] += 1

    def _send_geo_status(self) -> None:
        with self._lock:
            snap = self._snapshot
        self.link.send(messages.tracking_geo_status(self.link.mav, messages.tracking_status(snap).status, snap.ground,
                                                    snap.vehicle_alt_amsl_m))

    def _send_loop(self) -> None:
        next_heartbeat = time.monotonic()
        next_due: dict[int, float] = {}
        announced_size: tuple[int, int] | None = None  # once at start (first frame), again on a size change
        senders = {MAVLINK_MSG_ID_CAMERA_TRACKING_IMAGE_STATUS: self._send_image_status,
                   MAVLINK_MSG_ID_CAMERA_TRACKING_GEO_STATUS: self._send_geo_status}
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_heartbeat:
                self.link.send(messages.heartbeat(self.link.mav, self._source_ok()))
                next_heartbeat += 1.0
                if next_heartbeat < now:
                    next_heartbeat = now + 1.0
                if self.autopilot_alive(now):
                    self._request_streams(now)
            # every pass (<= 50 ms apart), not once a second: a lost heartbeat is reported right at its timeout
            self._watch_autopilot(now)
            size = self._frame_size()
            if size is not None and size != announced_size:
                announced_size = size  # first real frame size, or a size change mid-stream
                self._info_requested.set()
            if self._info_requested.is_set() and size is not None:
                self._info_requested.clear()
                self._send_camera_information()
            wake = next_heartbeat
            for message_id, interval in self.intervals().items():
                if interval is None:
                    next_due.pop(message_id, None)
                    continue
                due = next_due.setdefault(message_id, now)
                if now >= due:
                    senders[message_id]()
                    due = due + interval if due + interval > now else now + interval
                    next_due[message_id] = due
                wake = min(wake, due)
            self._stop.wait(max(0.0, min(wake - time.monotonic(), 0.05)))

    def _request_streams(self, now: float) -> None:
        """Ask the autopilot (MAV_CMD_SET_MESSAGE_INTERVAL) for each wanted message it has not sent lately:
        a port it streams nothing on, or a reboot that forgot the request (see WANTED_STREAMS_HZ)."""
        system_id = self.autopilot().system_id
        if system_id is None:
            return
        with self._lock:
            missing = streams_to_request(self._stream_heard_s, self._stream_asked_s, now)
            for msg_id in missing:
                self._stream_asked_s[msg_id] = now
        for msg_id in missing:
            log.debug("event=stream_request message=%d rate_hz=%g", msg_id, WANTED_STREAMS_HZ[msg_id])
            self.link.send(self.link.mav.command_long_encode(  # type: ignore[attr-defined]
                system_id, 1, MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id, 1e6 / WANTED_STREAMS_HZ[msg_id], 0, 0, 0, 0, 0))

    def _watch_autopilot(self, now: float) -> None:
        """Log the autopilot's heartbeat being lost (silent_s: since its last heartbeat) or (re)gained."""
        alive = self.autopilot_alive(now)
        if alive != self._autopilot_alive:
            self._autopilot_alive = alive
            view = self.autopilot()
            if alive:
                log.info("event=autopilot_connected system_id=%s", view.system_id)
            else:
                silent_s = now - view.last_heartbeat_s if view.last_heartbeat_s is not None else float("nan")
                log.warning("event=autopilot_heartbeat_timeout timeout_s=%.1f silent_s=%.2f",
                            self.config.mavlink.heartbeat_timeout_s, silent_s)


