"""End-to-end benchmark of the daemon: latency from frame read to gimbal command, and CPU use.

    python -m bench.service [--sequence UAVDT_S1301] [--trackers jsar-re,csrt] [--seconds 15] [--video off,on] [--rounds 1]
                            [--threads-report] [--callgrind [--callgrind-fps 0.25]] [--verifier-thread]

A real shared sequence (JSAR_DATA_ROOT) is resized to 640x480 and written as an MJPG video at 30 fps
(under out/bench/, git-ignored). For each tracker the daemon runs as a subprocess on that file
(paced at 30 fps like a camera, one OpenCV / BLAS thread), talking MAVLink to a benchmark peer that
plays the autopilot (heartbeats, records GIMBAL_MANAGER_SET_PITCHYAW) and selects the target with
TRACK_RECTANGLE at the ground-truth box. Latency comes from the daemon's per-frame telemetry on
Zenoh (`latency_ms.total`: frame read by the capture thread -> gimbal command handed to the
socket). CPU use is the daemon's user+system CPU time over the tracking window divided by its wall
time (1.0 = one core busy). OpenCV's CSRT runs in the same session as the reference.

Video (docs/video.md): `off` runs with the Zenoh preview and the RTP stream switched off; `on` with
both on at config.yaml's settings (preview 640x480 JPEG, the stream at 640x480, 30 fps) and a
viewer for each (a Zenoh subscriber to the preview, a UDP socket on the stream's port), so that
their cost (encoding on the video threads, competing with tracking for the cores) shows in the
tracking latency and the CPU use of the same tracker.

--threads-report: CPU time of every daemon thread over the window (utime + stime of /proc/PID/task/*/stat at
its start and end; the service names its threads for the OS, service/threads.py), per processed frame and
per camera frame (each frame-driven thread divided by its own frames: see per_camera_frame). --callgrind:
the daemon runs under valgrind's callgrind, one count per thread (zeroed at the window's start, dumped at
its end with callgrind_control; vgdb maps valgrind's threads to the OS's), the file paced slowly enough
that the daemon keeps up; instructions per camera frame by thread and the Pi cores they would take.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import yaml

os.environ.setdefault("MAVLINK20", "1")

from pymavlink.dialects.v20 import common as dialect  # noqa: E402

import jsar  # noqa: E402
from jsar.api import SideBoundedTracker  # noqa: E402
from sim.ports import free_port  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
WIDTH, HEIGHT, FPS = 640, 480, 30.0
IDLE_S = 3.0  # measured before the selection: decoding, telemetry and MAVLink without tracking
ONE_THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "MAVLINK20": "1"}


def prepare_video(sequence: Path, out: Path, max_frames: int, fps: float = FPS) -> tuple[Path, np.ndarray]:
    """Write the sequence at 640x480 as MJPG at fps; returns (video path, ground truth scaled, 0-based)."""
    images = sorted((sequence / "img").glob("*.jpg"))[:max_frames]
    if not images:
        raise SystemExit(f"no frames in {sequence / 'img'}")
    rows = [[float(v) for v in line.replace("\t", ",").split(",")]
            for line in (sequence / "groundtruth_rect.txt").read_text().splitlines() if line.strip()]
    gt = np.array(rows[:len(images)], dtype=float)
    first = cv2.imread(str(images[0]))
    sx, sy = WIDTH / first.shape[1], HEIGHT / first.shape[0]
    gt[:, 0] = (gt[:, 0] - 1) * sx
    gt[:, 1] = (gt[:, 1] - 1) * sy
    gt[:, 2] *= sx
    gt[:, 3] *= sy
    out.mkdir(parents=True, exist_ok=True)
    video = out / (f"{sequence.name}_640x480.avi" if fps == FPS else f"{sequence.name}_640x480_{fps:g}fps.avi")
    if not video.exists():
        writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), fps, (WIDTH, HEIGHT))
        for path in images:
            writer.write(cv2.resize(cv2.imread(str(path)), (WIDTH, HEIGHT), interpolation=cv2.INTER_AREA))
        writer.release()
    return video, gt


class AutopilotStub:
    """UDP peer at the service's mavlink port: heartbeats as ArduCopter system 1, records gimbal rates."""

    def __init__(self, port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.1)
        self.mav = dialect.MAVLink(self, srcSystem=1, srcComponent=1)
        self.gcs = dialect.MAVLink(self, srcSystem=255, srcComponent=190)  # the operator's commands
        self.parser = dialect.MAVLink(None)
        self.parser.robust_parsing = True
        self.peer: tuple[str, int] | None = None
        self.gimbal_commands = 0
        self.acks: list[int] = []
        self.heard = threading.Event()
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._rx, daemon=True), threading.Thread(target=self._beat, daemon=True)]
        for thread in self._threads:
            thread.start()

    def write(self, data: bytes) -> None:
        if self.peer is not None:
            self.sock.sendto(data, self.peer)

    def _rx(self) -> None:
        while not self._stop.is_set():
            try:
                data, self.peer = self.sock.recvfrom(65536)
            except socket.timeout:
                continue
            for msg in self.parser.parse_buffer(data) or []:
                kind = msg.get_type()
                if kind == "HEARTBEAT" and msg.get_srcComponent() == 100:
                    self.heard.set()
                elif kind == "GIMBAL_MANAGER_SET_PITCHYAW":
                    self.gimbal_commands += 1
                elif kind == "COMMAND_ACK":
                    self.acks.append(msg.result)

    def _beat(self) -> None:
        while not self._stop.wait(0.5):
            self.mav.send(self.mav.heartbeat_encode(2, 3, 1, 4, 4))

    def track(self, box: np.ndarray) -> None:
        x, y, w, h = box
        self.gcs.send(self.gcs.command_long_encode(1, 100, 2005, 0, x / WIDTH, y / HEIGHT, (x + w) / WIDTH,
                                                   (y + h) / HEIGHT, 0, 0, 0))

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(1.0)
        self.sock.close()


def stat_ticks(pid: int) -> int:
    """utime + stime of a process from /proc, its ended threads included (clock ticks)."""
    return parse_stat(Path(f"/proc/{pid}/stat").read_text())[1]


def cpu_seconds(pid: int) -> float:
    """utime + stime of a process from /proc (seconds)."""
    return stat_ticks(pid) / os.sysconf("SC_CLK_TCK")


def parse_stat(line: str) -> tuple[str, int]:
    """(comm, utime + stime in clock ticks) of one /proc/PID[/task/TID]/stat line.

    comm is field 2 in parentheses and may itself hold spaces and parentheses: it runs from the first "("
    to the last ")"; utime and stime are fields 14 and 15 (proc(5)).
    """
    head, tail = line.rsplit(")", 1)
    fields = tail.split()
    return head.split("(", 1)[1], int(fields[11]) + int(fields[12])


def thread_times(pid: int) -> dict[int, tuple[str, int]]:
    """Each live thread of process pid: tid -> (comm, utime + stime in clock ticks); threads that end while
    being read are left out."""
    found: dict[int, tuple[str, int]] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            found[int(task.name)] = parse_stat((task / "stat").read_text())
        except (FileNotFoundError, ProcessLookupError):
            continue
    return found


SERVICE_THREADS = ("tracking-loop", "verifier", "capture", "mavlink-rx", "mavlink-tx", "video-preview", "video-stream")
ZENOH_RUNTIMES = ("app", "acc", "net", "rx", "tx")  # zenoh-runtime's pools, threads named <pool>-<n>
ZENOH_WATCHDOGS = ("Watchdog Confirmator", "Watchdog Validator")  # zenoh's shared-memory threads, cut to 15 bytes
THREAD_GROUPS = (*SERVICE_THREADS, "main", "zenoh runtime", "other native", "ended threads")
# the threads whose work comes per frame, and the window count of their frames: the rest wake on timers and messages.
# Zenoh's pools carry a telemetry sample per tracked frame (and the previews); their timers (keep-alives) are small.
FRAME_DRIVEN = {"capture": "source", "tracking-loop": "loop", "verifier": "loop", "video-preview": "preview_sent",
                "video-stream": "stream_sent", "zenoh runtime": "loop"}
END_MARGIN_FRAMES = 15  # the window ends this many frames before the file does: the capture thread is still alive


def thread_group(comm: str, tid: int, pid: int) -> str:
    """The report row of a daemon thread: its service name (service.threads sets them), "main" (the process's
    first thread, which waits for signals), "zenoh runtime" (Zenoh's Rust pools) or "other native"."""
    if tid == pid:
        return "main"
    if comm.startswith("capture-"):  # capture-<reader name>, cut to 15 bytes by the kernel
        return "capture"
    if comm in SERVICE_THREADS:
        return comm
    pool, _, number = comm.rpartition("-")
    if (pool in ZENOH_RUNTIMES and number.isdigit()) or any(name[:15] == comm for name in ZENOH_WATCHDOGS):
        return "zenoh runtime"
    return "other native"


def cpu_ms_by_group(start: dict[int, tuple[str, int]], end: dict[int, tuple[str, int]], pid: int,
                    ticks_per_s: float, process_ticks: int = 0) -> dict[str, float]:
    """CPU ms of each thread group between two thread_times samples (every group of THREAD_GROUPS, 0 where no
    thread of it ran); a thread born in between counts from 0. process_ticks, the process's own utime + stime
    over the same span (it keeps the time of threads that ended), puts what the live threads do not account
    for under "ended threads"."""
    ticks = dict.fromkeys(THREAD_GROUPS, 0)
    for tid, (comm, end_ticks) in end.items():
        ticks[thread_group(comm, tid, pid)] += end_ticks - start.get(tid, (comm, 0))[1]
    ticks["ended threads"] = max(0, process_ticks - sum(ticks.values()))
    return {group: count / ticks_per_s * 1e3 for group, count in ticks.items()}


def per_frame(cpu_ms: dict[str, float], frames: int) -> dict[str, float]:
    """Each group's CPU ms divided by frames (> 0)."""
    if frames <= 0:
        raise ValueError(f"frames must be > 0, got {frames}")
    return {group: ms / frames for group, ms in cpu_ms.items()}


def per_camera_frame(cpu_ms: dict[str, float], counts: dict[str, int], wall_s: float, fps: float,
                     shares: dict[str, float]) -> dict[str, float]:
    """CPU ms (or instructions) of each group per camera frame at fps with every frame read and tracked: a
    frame-driven thread's CPU per frame of its own (FRAME_DRIVEN: the capture per frame read, the loop and Zenoh
    per frame tracked, each encoder per frame it sent) times its share of the camera frames (shares, 1 where
    absent), the other threads' CPU per second / fps. Removes what a slow machine changes: frames dropped
    before tracking or encoding."""
    out = {}
    for group, ms in cpu_ms.items():
        unit = FRAME_DRIVEN.get(group)
        if unit is None:
            out[group] = ms / wall_s / fps
        else:
            out[group] = ms / counts[unit] * shares.get(group, 1.0) if counts.get(unit) else 0.0
    return out


CALLGRIND_PATIENCE = 40.0  # how much longer than natively the daemon may take for anything under callgrind


def callgrind_command(folder: Path) -> list[str]:
    """The valgrind prefix of the daemon: callgrind, one count per thread, controllable (vgdb), dumps in folder."""
    return ["valgrind", "--tool=callgrind", "--separate-threads=yes", "--vgdb=yes",
            f"--callgrind-out-file={folder}/callgrind.out.%p"]


def callgrind_control(pid: int, *args: str) -> str:
    """Run callgrind_control on the daemon (--zero: counts from now on; --dump: write them); its output."""
    return subprocess.run(["callgrind_control", *args, str(pid)], capture_output=True, text=True, check=True,
                          timeout=600).stdout


def vgdb_threads(scheduler: str) -> dict[int, int]:
    """valgrind thread number -> OS thread id (lwpid), from vgdb's `v.info scheduler` output."""
    found = {}
    for line in scheduler.splitlines():
        match = re.match(r"Thread (\d+): status = .*\(lwpid (\d+)\)", line.strip())
        if match:
            found[int(match.group(1))] = int(match.group(2))
    return found


def callgrind_dump_totals(text: str) -> tuple[int, int]:
    """(valgrind thread number, instructions) of one callgrind dump file (`thread:` and `summary:` lines)."""
    thread = re.search(r"^thread: (\d+)$", text, re.MULTILINE)
    summary = re.search(r"^summary: (\d+)$", text, re.MULTILINE)
    if thread is None or summary is None:
        raise ValueError("not a per-thread callgrind dump (no thread: or summary: line)")
    return int(thread.group(1)), int(summary.group(1))


def callgrind_window(pid: int, folder: Path) -> dict[int, int]:
    """OS thread id -> instructions since the last --zero, for every thread of the daemon under callgrind (a
    thread that ended since is under -1 with the rest valgrind could not map)."""
    scheduler = subprocess.run(["vgdb", f"--pid={pid}", "v.info", "scheduler"], capture_output=True, text=True,
                               timeout=600).stdout
    lwpids = vgdb_threads(scheduler)
    before = set(folder.glob(f"callgrind.out.{pid}.*"))
    callgrind_control(pid, "--dump")
    counts: dict[int, int] = {}
    for path in sorted(set(folder.glob(f"callgrind.out.{pid}.*")) - before):
        thread, instructions = callgrind_dump_totals(path.read_text(errors="replace"))
        lwpid = lwpids.get(thread, -1)
        counts[lwpid] = counts.get(lwpid, 0) + instructions
    return counts


def callgrind_folder(out: Path, tracker: str, mode: str) -> Path:
    """The folder (made) for the callgrind dumps of one run."""
    folder = out / "callgrind" / f"{tracker}_video_{mode}"
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def instructions_report(counts: dict[int, int], threads: dict[int, tuple[str, int]], pid: int,
                        frames: dict[str, int], wall_s: float, shares: dict[str, float]) -> dict:
    """Instructions of the window by thread group (threads: comm by OS thread id) and per camera frame at FPS."""
    by_group = dict.fromkeys(THREAD_GROUPS, 0.0)
    for tid, instructions in counts.items():
        group = thread_group(threads[tid][0], tid, pid) if tid in threads else "ended threads"
        by_group[group] += instructions
    return {"thread_instructions": by_group,
            "thread_instructions_per_camera_frame": per_camera_frame(by_group, frames, wall_s, FPS, shares)}


class UdpSink:
    """A viewer of the RTP stream: a UDP socket on the stream's port counting datagrams and bytes."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.1)
        self.port = self.sock.getsockname()[1]
        self.datagrams = 0
        self.bytes = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._rx, daemon=True)
        self._thread.start()

    def _rx(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.sock.recv(65536)
            except socket.timeout:
                continue
            self.datagrams += 1
            self.bytes += len(data)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(1.0)
        self.sock.close()


def status_counters(session: object, timeout_s: float = 5.0) -> dict:
    """The counters of the daemon's status, with the frames the source read as source_frames ({} without an
    answer)."""
    answers = session.get("bench/status", timeout=timeout_s)  # type: ignore[attr-defined]
    replies = [r.ok for r in answers if r.ok is not None]
    if not replies:
        return {}
    status = json.loads(replies[0].payload.to_string())
    return {**status["counters"], "source_frames": status["source"]["frames"]}


def video_counters(counters: dict) -> dict:
    """The preview_* / stream_* counters among the daemon's status counters."""
    return {k: v for k, v in counters.items() if k.startswith(("preview_", "stream_"))}


def run_one(tracker: str, video: Path, gt: np.ndarray, seconds: float, out: Path, video_out: bool = False,
            video_fps: float = FPS, callgrind: Path | None = None, verifier_thread: bool = False) -> dict:
    """Run the daemon with `tracker` on the video, paced at video_fps (video_out: preview and RTP stream on); the
    measured numbers. callgrind: run the daemon under callgrind, its per-thread dumps of the window in this folder.
    verifier_thread: config's tracker.verifier_thread (jsar-re's deferred verifier work on a thread of its own)."""
    import zenoh

    patience = 1.0 if callgrind is None else CALLGRIND_PATIENCE  # every wait for the daemon is this much longer

    mav_port, zenoh_port = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_STREAM)
    config = yaml.safe_load((REPO / "config.yaml").read_text())
    sink = UdpSink() if video_out else None
    config["video"]["preview"]["enabled"] = video_out
    config["video"]["stream"].update({"enabled": video_out, "host": "127.0.0.1", "port": sink.port if sink else 5600,
                                      "max_width_px": WIDTH, "max_height_px": HEIGHT, "fps": FPS})
    config["tracker"].update({"name": tracker, "threads": 1, "verifier_thread": verifier_thread})
    if not isinstance(jsar.create(tracker), SideBoundedTracker):
        config["tracker"]["range_size_band"] = 0  # OpenCV's trackers take no side bounds (the service refuses them)
    config["source"].update({"kind": "file", "path": str(video), "realtime": True, "loop": False})
    config["mavlink"]["url"] = f"udpout:127.0.0.1:{mav_port}"
    config["zenoh"].update({"enabled": True, "listen": [f"tcp/127.0.0.1:{zenoh_port}"], "prefix": "bench"})
    config["logging"]["level"] = "WARNING"
    config_file = out / f"config_{tracker}_video_{'on' if video_out else 'off'}.yaml"
    config_file.write_text(yaml.safe_dump(config))
    autopilot = AutopilotStub(mav_port)
    prefix = [] if callgrind is None else callgrind_command(callgrind)
    proc = subprocess.Popen([*prefix, sys.executable, "-m", "service", "--config", str(config_file)], cwd=REPO,
                            env={**os.environ, **ONE_THREAD_ENV}, stderr=subprocess.PIPE, text=True)
    zc = zenoh.Config()
    zc.insert_json5("mode", '"peer"')
    zc.insert_json5("scouting/multicast/enabled", "false")
    zc.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{zenoh_port}"]))
    reports: list[dict] = []
    lock = threading.Condition()

    def on_sample(sample: object) -> None:
        with lock:
            reports.append(json.loads(sample.payload.to_string()))  # type: ignore[attr-defined]
            lock.notify_all()

    previews = [0]

    def on_preview(sample: object) -> None:
        previews[0] += 1

    session = None
    counters_end: dict = {}
    try:
        if not autopilot.heard.wait(60.0 * patience):
            raise SystemExit(f"{tracker}: no heartbeat from the daemon: {proc.stderr.read() if proc.poll() else ''}")
        session = zenoh.open(zc)
        subscriber = session.declare_subscriber("bench/track", on_sample)
        preview_subscriber = session.declare_subscriber("bench/camera/preview", on_preview)
        with lock:
            if not lock.wait_for(lambda: len(reports) > 0, 30.0 * patience):
                raise SystemExit(f"{tracker}: no telemetry from the daemon")
            # idle: frames decoded and reported, nothing tracked (IDLE_S of the file)
            idle_wall, idle_cpu = time.monotonic(), cpu_seconds(proc.pid)
            first_idle = reports[-1]["frame_id"]
            lock.wait_for(lambda: reports[-1]["frame_id"] >= first_idle + max(1, int(IDLE_S * video_fps)),
                          (IDLE_S + 10) * patience)
            idle_cores = (cpu_seconds(proc.pid) - idle_cpu) / (time.monotonic() - idle_wall)
            current = reports[-1]["frame_id"]
        autopilot.track(gt[min(current + 1, len(gt) - 1)])
        with lock:
            lock.wait_for(lambda: any(r["state"] != "idle" for r in reports), 30.0 * patience)
        counters_start = status_counters(session, 5.0 * patience)
        if callgrind is not None:
            callgrind_control(proc.pid, "--zero")
        threads_start, process_start = thread_times(proc.pid), stat_ticks(proc.pid)
        start_wall, start_cpu = time.monotonic(), cpu_seconds(proc.pid)
        stream_bytes_before = sink.bytes if sink else 0
        start_index = len(reports)
        with lock:
            lock.wait_for(lambda: proc.poll() is not None
                          or (reports and reports[-1]["frame_id"] >= len(gt) - 2 - END_MARGIN_FRAMES)
                          or time.monotonic() - start_wall > seconds, seconds + 5)
        wall, cpu = time.monotonic() - start_wall, cpu_seconds(proc.pid) - start_cpu
        threads_end, process_end = thread_times(proc.pid), stat_ticks(proc.pid)
        instructions = callgrind_window(proc.pid, callgrind) if callgrind is not None else None
        stream_kbit_s = (sink.bytes - stream_bytes_before) * 8 / 1000 / wall if sink else 0.0
        counters_end = status_counters(session, 5.0 * patience)
        subscriber.undeclare()
        preview_subscriber.undeclare()
    finally:
        if session is not None:
            session.close()
        if proc.poll() is None:
            proc.terminate()
            proc.wait(10 * patience)
        autopilot.close()
        if sink is not None:
            sink.close()
    window = [r for r in reports[start_index:] if r["state"] != "idle"]
    if not window:
        raise SystemExit(f"{tracker}: nothing tracked")
    total = np.array([r["latency_ms"]["total"] for r in window])
    track = np.array([r["latency_ms"]["track"] for r in window])
    queue = np.array([r["latency_ms"]["queue"] for r in window])
    frames_seen = window[-1]["frame_id"] - window[0]["frame_id"] + 1
    # the loop's own count over the exact window of the thread samples (the telemetry's may miss a sample)
    loop_frames = counters_end.get("frames", 0) - counters_start.get("frames", 0)
    threads_ms = cpu_ms_by_group(threads_start, threads_end, proc.pid, os.sysconf("SC_CLK_TCK"),
                                 process_end - process_start)
    counts = {"loop": loop_frames or len(window),
              **{key: counters_end.get(key, 0) - counters_start.get(key, 0)
                 for key in ("source_frames", "preview_sent", "stream_sent")}}
    counts["source"] = counts.pop("source_frames")
    shares = {"video-preview": min(1.0, config["video"]["preview"]["max_fps"] / FPS),
              "video-stream": min(1.0, config["video"]["stream"]["fps"] / FPS)}
    centre_err = [np.hypot(r["box_px"][0] + r["box_px"][2] / 2 - g[0] - g[2] / 2,
                           r["box_px"][1] + r["box_px"][3] / 2 - g[1] - g[3] / 2)
                  for r in window for g in [gt[r["frame_id"]]] if np.all(np.isfinite(g))]
    return {"tracker": tracker, "video": "on" if video_out else "off", "frames_processed": len(window), "frames_offered": frames_seen,
            "processed_fps": len(window) / wall, "latency_p50_ms": float(np.percentile(total, 50)),
            "latency_p99_ms": float(np.percentile(total, 99)), "track_p50_ms": float(np.percentile(track, 50)),
            "queue_p50_ms": float(np.percentile(queue, 50)),
            "control_send_p50_ms": float(np.percentile(total - queue - track, 50)),
            "cpu_cores": cpu / wall, "idle_cpu_cores": idle_cores, "dropped_frames": window[-1]["dropped_frames"] - window[0]["dropped_frames"],
            "gimbal_commands": autopilot.gimbal_commands, "previews_received": previews[0],
            "stream_datagrams_received": sink.datagrams if sink else 0,
            "stream_kbit_s": stream_kbit_s,
            "video_counters": video_counters(counters_end),
            "window_frames": counts, "window_s": wall, "thread_cpu_ms": threads_ms,
            "thread_cpu_ms_per_frame": per_frame(threads_ms, counts["loop"]),
            "thread_cpu_ms_per_camera_frame": per_camera_frame(threads_ms, counts, wall, FPS, shares),
            "threads_seen": sorted({comm for comm, _ in threads_end.values()}),
            **({} if instructions is None else instructions_report(instructions, threads_end, proc.pid, counts, wall,
                                                                   shares)),
            # CPU time of each encoder's thread over the tracking window, in cores (contention does not inflate it)
            "preview_encoder_cores": (counters_end.get("preview_cpu_ms", 0) - counters_start.get("preview_cpu_ms", 0)) / 1e3 / wall,
            "stream_encoder_cores": (counters_end.get("stream_cpu_ms", 0) - counters_start.get("stream_cpu_ms", 0)) / 1e3 / wall,
            "centre_error_median_px": float(np.median(centre_err)) if centre_err else float("nan")}


def threads_table(results: list[dict], key: str = "thread_cpu_ms_per_frame") -> str:
    """Markdown: CPU ms per frame by thread group (rows) for each run (columns), with the whole process; key
    picks the normalisation (thread_cpu_ms_per_frame: per processed frame; thread_cpu_ms_per_camera_frame)."""
    rounds = any(r.get("round", 1) > 1 for r in results)
    runs = [f"{r['tracker']} video {r['video']}" + (f" r{r['round']}" if rounds else "") for r in results]
    lines = ["| thread | " + " | ".join(runs) + " |", "|---|" + "---|" * len(runs)]
    for group in THREAD_GROUPS:
        lines.append(f"| {group} | " + " | ".join(f"{r[key][group]:.2f}" for r in results) + " |")
    lines.append("| **whole process** | " + " | ".join(f"**{sum(r[key].values()):.2f}**" for r in results) + " |")
    lines.append("| frames: tracked / read / preview / stream | " + " | ".join(
        "{loop} / {source} / {preview_sent} / {stream_sent}".format(**r["window_frames"]) for r in results) + " |")
    return "\n".join(lines)


def instructions_table(results: list[dict]) -> str:
    """Markdown: millions of instructions per camera frame by thread group for each run under callgrind, the
    whole process, and the cores it would keep busy at FPS on each board of bench.instructions.CORES."""
    from bench.instructions import CORES

    runs = [r for r in results if "thread_instructions_per_camera_frame" in r]
    lines = ["| thread | " + " | ".join(f"{r['tracker']} video {r['video']}" for r in runs) + " |",
             "|---|" + "---|" * len(runs)]
    for group in THREAD_GROUPS:
        lines.append(f"| {group} | " + " | ".join(f"{r['thread_instructions_per_camera_frame'][group] / 1e6:.2f}"
                                                 for r in runs) + " |")
    totals = [sum(r["thread_instructions_per_camera_frame"].values()) for r in runs]
    lines.append("| **whole process** | " + " | ".join(f"**{total / 1e6:.1f}**" for total in totals) + " |")
    for board, (clock_hz, ipc) in CORES.items():
        lines.append(f"| cores at {FPS:.0f} fps, {board} | " + " | ".join(
            f"{total * FPS / (clock_hz * ipc):.2f}" for total in totals) + " |")
    lines.append("| frames: tracked / read / preview / stream | " + " | ".join(
        "{loop} / {source} / {preview_sent} / {stream_sent}".format(**r["window_frames"]) for r in runs) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.service", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sequence", default="UAVDT_S1301", help="folder under JSAR_DATA_ROOT")
    parser.add_argument("--trackers", default="jsar-re,csrt", help="comma-separated tracker names")
    parser.add_argument("--seconds", type=float, default=15.0, help="tracking window per tracker")
    parser.add_argument("--video", default="off,on",
                        help="comma-separated: off (preview and stream off), on (both on, each with a viewer)")
    parser.add_argument("--rounds", type=int, default=1,
                        help="repeat every tracker x video run this many times, interleaved (noisy shared machines)")
    parser.add_argument("--threads-report", action="store_true",
                        help="also print CPU ms per processed frame by daemon thread (from /proc/PID/task/*/stat)")
    parser.add_argument("--callgrind", action="store_true",
                        help="run the daemon under valgrind's callgrind (x86-64) and count the window's instructions "
                             "by thread; the file is then paced at --callgrind-fps (latencies mean nothing there)")
    parser.add_argument("--callgrind-fps", type=float, default=0.25,
                        help="frame rate of the file under callgrind: slow enough that every frame is tracked")
    parser.add_argument("--verifier-thread", action="store_true",
                        help="tracker.verifier_thread on: jsar-re's deferred verifier work on the daemon's `verifier` "
                             "thread (the configuration for a board with a spare core)")
    parser.add_argument("--out", default=str(REPO / "out" / "bench"))
    args = parser.parse_args(argv)
    root = os.environ.get("JSAR_DATA_ROOT")
    if not root:
        print("JSAR_DATA_ROOT is not set: the benchmark plays a real shared sequence", file=sys.stderr)
        return 2
    out = Path(args.out)
    video_fps = args.callgrind_fps if args.callgrind else FPS
    video, gt = prepare_video(Path(root) / args.sequence, out, max_frames=int(FPS * (args.seconds + IDLE_S + 5)),
                              fps=video_fps)
    modes = args.video.split(",")
    if not modes or any(mode not in ("off", "on") for mode in modes):
        parser.error(f"--video: a comma-separated list of off / on, got {args.video!r}")
    if args.rounds < 1:
        parser.error(f"--rounds: must be >= 1, got {args.rounds}")
    results = [{**run_one(name, video, gt, args.seconds, out, video_out=mode == "on", video_fps=video_fps,
                          callgrind=callgrind_folder(out, name, mode) if args.callgrind else None,
                          verifier_thread=args.verifier_thread),
                "round": index + 1}
               for index in range(args.rounds) for name in args.trackers.split(",") for mode in modes]
    print(f"640x480 @ {FPS:.0f} fps, {args.sequence}, one thread; latency = frame read -> gimbal command")
    print("| tracker | video | round | frames | fps | latency p50 ms | latency p99 ms | wait p50 ms | track p50 ms "
          "| control+send p50 ms | CPU (cores) | idle CPU | dropped | centre error px |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in results:
        print(f"| {r['tracker']} | {r['video']} | {r['round']} | {r['frames_processed']} | {r['processed_fps']:.1f} | {r['latency_p50_ms']:.1f} "
              f"| {r['latency_p99_ms']:.1f} | {r['queue_p50_ms']:.1f} | {r['track_p50_ms']:.1f} "
              f"| {r['control_send_p50_ms']:.2f} | {r['cpu_cores']:.2f} | {r['idle_cpu_cores']:.2f} | {r['dropped_frames']} "
              f"| {r['centre_error_median_px']:.1f} |")
    video_on = [r for r in results if r["video"] == "on"]
    if video_on:
        print("\nvideo outputs: frames sent, dropped by a slow encoder, thinned by rate, received by the viewers over "
              "the whole run (idle + tracking); bit rate and encoder threads' CPU over the tracking window")
        print("| tracker | round | preview sent | preview dropped | preview rate-skipped | previews received "
              "| stream sent | stream dropped | RTP datagrams received | stream kbit/s "
              "| preview encoder CPU (cores) | stream encoder CPU (cores) |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|")
        for r in video_on:
            c = r["video_counters"]
            print(f"| {r['tracker']} | {r['round']} | {c.get('preview_sent')} | {c.get('preview_dropped')} | "
                  f"{c.get('preview_rate_skipped')} | {r['previews_received']} | {c.get('stream_sent')} | "
                  f"{c.get('stream_dropped')} | {r['stream_datagrams_received']} | {r['stream_kbit_s']:.0f} "
                  f"| {r['preview_encoder_cores']:.3f} | {r['stream_encoder_cores']:.3f} |")
    if args.threads_report:
        print("\nCPU ms per processed frame by daemon thread over the tracking window (utime + stime of "
              "/proc/PID/task/*/stat at its start and end; frames = the loop's count)")
        print(threads_table(results))
        print(f"\nthe same per camera frame at {FPS:.0f} fps with every frame tracked: capture per frame read, loop "
              "per frame tracked, encoders per frame sent x their share of the frames, other threads per second / fps")
        print(threads_table(results, "thread_cpu_ms_per_camera_frame"))
    if args.callgrind:
        print(f"\nmillions of instructions per camera frame at {FPS:.0f} fps by daemon thread, counted by callgrind "
              f"over the window (file paced at {video_fps:g} fps; normalised as the CPU table above)")
        print(instructions_table(results))
    (out / "results.json").write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
