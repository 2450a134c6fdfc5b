"""The imperative shell: build the adapters from config, run the tracking loop, shut down cleanly."""
from __future__ import annotations

import concurrent.futures
import logging
import os
import signal
import threading
import time
from typing import Any

import cv2
from threadpoolctl import threadpool_limits

import jsar
from jsar.api import DeferringTracker, SideBoundedTracker
from service.config import VERIFIER_THREAD_MIN_CPUS, ConfigError, ServiceConfig, as_plain
from service.domain import ControlCommand, LoopState
from service.loop import FrameReport, TrackingLoop
from service.mavlink.camera import CameraComponent
from service.mavlink.link import MavlinkLink
from service.mavlink.outputs import MavlinkOutputs
from service.run_marker import PreviousRun, mark_running, mark_stopped, read_previous, runtime_directory
from service.sources import CaptureWorker, LatestSlot, check_source, make_reader
from service.sources.base import Frame
from service.systemd import sd_notify, watchdog_interval_s
from service.telemetry import Telemetry, open_session
from service.threads import name_os_thread, service_thread
from service.video.rtp_stream import RtpH264Stream, check_destination
from service.video.zenoh_preview import ZenohPreview

SIGNAL_POLL_S = 0.1  # s: how often the main thread looks for a stop signal or a stop request

log = logging.getLogger("service")


def verifier_thread_wanted(setting: bool | str, cpus: int) -> bool:
    """tracker.verifier_thread: true or false as set; "auto" on where the service may run on `cpus` >=
    VERIFIER_THREAD_MIN_CPUS CPUs (its affinity mask: a unit's CPUAffinity= counts, not the board's cores)."""
    if setting == "auto":
        return cpus >= VERIFIER_THREAD_MIN_CPUS
    return bool(setting)


class Service:
    """All parts of the daemon; `run(stop)` blocks until `stop` is set."""

    def __init__(self, config: ServiceConfig) -> None:
        self.config = config
        self.started_s = time.monotonic()
        tracker_cfg = config.tracker
        # The tracker's small matrix products slow down tens of times when a multi-threaded BLAS
        # competes for the cores (measured: 0.9 ms -> 42 ms per frame), so BLAS / OpenMP pools get the
        # same thread count as OpenCV, even when the environment (systemd unit, Dockerfile) did not set it.
        cv2.setNumThreads(tracker_cfg.threads)
        threadpool_limits(limits=tracker_cfg.threads)
        try:
            probe = jsar.create(tracker_cfg.name, **tracker_cfg.params)  # fail at start on bad tracker params
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"tracker.params: {exc}") from exc
        load_models = getattr(probe, "load_models", None)
        if load_models is not None:  # at start, not on the operator's first selection (frames would queue behind it)
            began = time.monotonic()
            load_models()
            log.info("event=tracker_prepared tracker=%s load_s=%.2f", tracker_cfg.name, time.monotonic() - began)
        # One thread, named for the OS, for the tracker's deferred work (jsar-re's verifier): another core's time
        # instead of the tracking thread's, the same boxes.
        cpus = len(os.sched_getaffinity(0))
        self.verifier_worker = (
            concurrent.futures.ThreadPoolExecutor(max_workers=1, initializer=name_os_thread, initargs=("verifier",))
            if verifier_thread_wanted(tracker_cfg.verifier_thread, cpus) and isinstance(probe, DeferringTracker)
            else None)
        log.info("event=verifier_thread tracker=%s enabled=%s setting=%s cpus=%d", tracker_cfg.name,
                 str(self.verifier_worker is not None).lower(), str(tracker_cfg.verifier_thread).lower(), cpus)
        if tracker_cfg.range_size_band != 0 and not isinstance(probe, SideBoundedTracker):
            raise ConfigError(f"tracker.range_size_band: tracker {tracker_cfg.name!r} cannot bound its box size; "
                              "set 0 to run it without the range size bound")
        if config.video.stream.enabled:
            check_destination(config.video.stream)
        check_source(config.source)
        self._session = open_session(config.zenoh) if config.zenoh.enabled else None
        try:
            self.mailbox: LatestSlot[Frame] = LatestSlot()
            reader = make_reader(config.source, self._session, config.zenoh.prefix)
            self.worker = CaptureWorker(reader, self.mailbox, config.source.retry_initial_s, config.source.retry_max_s)
            self.selections: LatestSlot = LatestSlot()
            self.link = MavlinkLink(config.mavlink, config.mavlink.system_id or config.mavlink.provisional_system_id)
            health = self.worker.health
            self.stream = RtpH264Stream(config.video.stream, config.camera.hfov_deg) if config.video.stream.enabled else None
            stream = self.stream
            self.camera = CameraComponent(
                config, self.link, self.selections,
                frame_size=lambda: health.last_frame_size,
                source_ok=lambda: health.state == "ok",
                source_reason=lambda: f"source {health.state}: {health.reason}" if health.reason else f"source {health.state}",
                source_state=lambda: health.state,
                video_stream=(lambda: stream.describe(health.last_frame_size)) if stream is not None else None)
            self.outputs = MavlinkOutputs(config, self.link, self.camera.autopilot, self.camera.time_boot_ms)
            self.telemetry = (Telemetry(self._session, config.zenoh.prefix, self.status, config.zenoh)
                              if self._session else None)
            self.preview = (ZenohPreview(self._session, config.zenoh.prefix, config.video.preview)
                            if self._session is not None and config.video.preview.enabled else None)
            if config.video.preview.enabled and self._session is None:
                log.info("event=preview_off reason=zenoh_disabled")
            self.video_outputs = [output for output in (self.preview, self.stream) if output is not None]
            self.loop = TrackingLoop(
                config, self.selections, self._new_tracker,
                self.outputs, self.camera.autopilot, publish_snapshot=self.camera.publish,
                publish_report=self._publish_report, dropped=lambda: self.worker.dropped,
                publish_frame=self._publish_frame)
        except BaseException:
            if self._session is not None:
                self._session.close()
            raise
        self._last_report: FrameReport | None = None
        self.telemetry_errors = 0
        self._runtime_dir = runtime_directory(os.environ)
        self.previous_run: PreviousRun = read_previous(self._runtime_dir)
        self.outputs.stop_gimbal_first = self.previous_run.exit == "unclean"

    def _publish_report(self, report: FrameReport) -> None:
        self._last_report = report
        if self.telemetry is not None:
            try:
                self.telemetry.publish(report.as_json())
            except Exception as exc:  # noqa: BLE001 - losing a telemetry sample must not stop tracking
                self.telemetry_errors += 1
                log.warning('event=telemetry_failed error="%s"', exc)

    def _publish_frame(self, frame: Frame) -> None:
        """Tracking thread: hand the tracked frame to each video output (never waits for an encoder)."""
        for output in self.video_outputs:
            output.offer(frame)

    def status(self) -> dict[str, Any]:
        """Status, counters and effective configuration (answer of the <prefix>/status queryable)."""
        health = self.worker.health.snapshot()
        view = self.camera.autopilot()
        report = self._last_report
        return {
            "status": "ok" if health["state"] == "ok" else "error" if health["state"] in ("error", "ended") else "starting",
            "uptime_s": round(time.monotonic() - self.started_s, 3),
            "source": health,
            "track": {"state": self.loop.state, "box_px": list(self.loop.box) if self.loop.box else None,
                      "last_frame_id": report.frame_id if report else None},
            "counters": {"dropped_frames": self.worker.dropped, **self.loop.counters,
                         **{f"mavlink_{k}": v for k, v in self.camera.counters.items()},
                         **{f"out_{k}": v for k, v in self.outputs.counters.items()},
                         "mavlink_sent": self.link.sent, "mavlink_send_errors": self.link.send_errors,
                         "mavlink_bad_packets": self.link.bad_packets, "telemetry_errors": self.telemetry_errors,
                         "mavlink_signing_refused_unsigned": self.link.signing.refused_unsigned,
                         "mavlink_signing_refused_bad_signature": self.link.signing.refused_bad_signature,
                         **{f"{output.worker.name}_{k}": v for output in self.video_outputs
                            for k, v in output.worker.counters().items()}},
            "video": {"preview": self.preview.status() if self.preview is not None else None,
                      "stream": self.stream.status() if self.stream is not None else None},
            "autopilot": {"system_id": view.system_id, "alive": self.camera.autopilot_alive(),
                          "state": self.camera.autopilot_state(), "custom_mode": view.custom_mode,
                          # a gimbal device reported its attitude (GIMBAL_DEVICE_ATTITUDE_STATUS) since start
                          "gimbal_attitude_heard": view.gimbal is not None},
            "mavlink_refusals": self.camera.refusals(),
            "mavlink_signing": self.link.signing_status(),
            "mavlink_system_id": self.link.system_id,
            # how the previous run ended (service.run_marker): "unclean" after a kill, with systemd's restart
            "run": self.previous_run.as_json(),
            "config": as_plain(self.config),
        }

    def run(self, stop: threading.Event, signals: frozenset[int] = frozenset()) -> None:
        """Start the threads, notify systemd, run the loop until `stop` or one of `signals`, then shut down (< 2 s).

        `signals` (SIGTERM, SIGINT) must be blocked in every thread (service.__main__ blocks them before any
        thread starts): the main thread takes them synchronously, so no handler ever interrupts it.

        RuntimeError if the tracking loop itself crashed (the process then exits non-zero and systemd
        restarts it); per-frame errors are handled inside the loop.
        """
        self.worker.start()
        for output in self.video_outputs:
            output.start()
        self.camera.start()
        watchdog_s = watchdog_interval_s()
        last_ping = [0.0]

        def ping() -> None:
            now = time.monotonic()
            if watchdog_s is not None and now - last_ping[0] >= watchdog_s:
                sd_notify("WATCHDOG=1")
                last_ping[0] = now

        self._mark_running()
        sd_notify("READY=1")
        log.info("event=started source=%s tracker=%s mavlink=%s gimbal=%s guidance=%s watchdog_s=%s track=%s "
                 "previous_exit=%s", self.worker.reader.name, self.config.tracker.name, self.config.mavlink.url,
                 self.config.gimbal.backend, self.config.guidance.mode, watchdog_s, self.loop.state,
                 self.previous_run.exit)
        # The loop runs on its own thread so that a slow tracker step (a re-detection can take a while)
        # never delays the stop: the main thread waits for the stop request and bounds the join.
        loop_failed: list[BaseException] = []

        def run_loop() -> None:
            try:
                self.loop.run(self.mailbox, stop.is_set, on_iteration=ping)
            except BaseException as exc:  # noqa: BLE001 - reported by the main thread
                loop_failed.append(exc)
                log.exception("event=loop_crashed")
                stop.set()

        runner = service_thread(run_loop, "tracking-loop")
        runner.start()
        try:
            # Signals are taken here with sigtimedwait, not by a handler: a handler runs on the main thread
            # between two bytecodes, and its stop.set() deadlocked when it landed inside stop.wait() on the
            # same event, whose internal lock the main thread then held (one CI failure: `event=signal` in
            # the log, the loop and the capture thread still running 5 s later).
            while not stop.is_set():
                received = signal.sigtimedwait(signals, SIGNAL_POLL_S) if signals else None
                if received is not None:
                    log.info("event=signal signal=%s", signal.Signals(received.si_signo).name)
                    stop.set()
                elif not signals:
                    stop.wait(SIGNAL_POLL_S)
        finally:
            runner.join(timeout=0.8)
            if runner.is_alive():
                log.warning("event=loop_still_busy detail=abandoning_the_current_frame")
            self.shutdown()
        if loop_failed:  # the marker stays: the next run reports this one as unclean
            raise RuntimeError("tracking loop crashed") from loop_failed[0]
        try:
            mark_stopped(self._runtime_dir)
        except OSError as exc:
            log.warning('event=run_marker_failed dir=%s error="%s"', self._runtime_dir, exc)

    def _mark_running(self) -> None:
        """Report an unclean end of the previous run (its marker left behind), then mark this one running."""
        previous = self.previous_run
        if previous.exit == "unclean":
            log.warning('event=restarted_after_unclean_exit previous_pid=%s previous_started_unix_s=%s track=%s '
                        'detail="the previous run was killed or crashed; this one starts idle: the target must be '
                        'selected again"', previous.pid, previous.started_unix_s, self.loop.state)
        try:
            mark_running(self._runtime_dir, os.getpid(), time.time())
        except OSError as exc:  # a read-only or missing directory costs the report, not the service
            log.warning('event=run_marker_failed dir=%s error="%s"', self._runtime_dir, exc)

    def _new_tracker(self) -> Any:
        """A tracker for a new selection, its deferred work on the verifier thread when there is one."""
        tracker = jsar.create(self.config.tracker.name, **self.config.tracker.params)
        if self.verifier_worker is not None:
            tracker.set_verifier_worker(self.verifier_worker)
        return tracker

    def shutdown(self) -> None:
        """Zero the gimbal if tracking, stop threads, close links."""
        sd_notify("STOPPING=1")
        if self.loop.tracker is not None:
            self.outputs.apply(time.monotonic(), ControlCommand(state=LoopState.IDLE, stopped=True, rates=(0.0, 0.0)))
        self.camera.stop(timeout_s=0.5)
        self.worker.stop(timeout_s=0.5)
        for output in self.video_outputs:
            output.stop(timeout_s=0.3)
        if self.telemetry is not None:
            self.telemetry.close()
        self.link.close()
        if self.verifier_worker is not None:
            self.verifier_worker.shutdown(wait=False, cancel_futures=True)
        if self._session is not None:
            self._session.close()
        log.info("event=stopped frames=%d dropped=%d", self.loop.counters["frames"], self.worker.dropped)
