"""What the service's video work costs per 640x480 frame: libx264 settings (the stream's own and slower ones), the
stream's colour conversion, the JPEG preview and the capture's MJPG decode.

    python -m bench.encoders DATA_ROOT [--sequence UAVDT_S1301] [--frames 150] [--callgrind]
                             [--arm64-rootfs ROOTFS [--arm64-cpu cortex-a72]]

Frames: the shared sequence resized to 640x480 (as bench.service plays it), written as an MJPG file for the
decode. Every call goes through the service's own code where it has one (service.video.rtp_stream.yuv420 and
x264_options, service.video.zenoh_preview.preview_payload) on one thread. H.264 through PyAV as the stream
encodes it: its x264_options with the preset / tune of the row, 2000 kbit/s at 30 fps, timestamps on the
90 kHz clock; quality = PSNR of the decoded luma against the source's, bit rate = the bytes that came out.

Natively: thread CPU ms per frame (time.thread_time). --callgrind: the same calls counted under valgrind's
callgrind (a client request zeroes the counters before and dumps them after each call: bench.instructions'
helper), giving instructions per frame and, against the native times, this host's instruction rate for each
kind of work. --arm64-rootfs: the same calls in the arm64 build that deploy/check-arm64.sh installed, counted
under qemu-aarch64 with bench.instructions' marks plugin (the libraries' NEON paths: what a Pi runs). A setting
without zerolatency holds frames back (lookahead): its total over the run, the final flush included, is divided by
the frames.
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import fractions  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Callable  # noqa: E402

import numpy as np  # noqa: E402

WIDTH, HEIGHT, FPS, BITRATE_KBPS = 640, 480, 30.0, 2000
RTP_CLOCK_HZ = 90_000
STREAM_SETTING = "ultrafast + zerolatency (the stream's)"
# x264 settings compared: overrides of the stream's x264_options (None removes the option)
X264_SETTINGS: dict[str, dict[str, str | None]] = {
    STREAM_SETTING: {},
    "ultrafast": {"tune": None},
    "superfast + zerolatency": {"preset": "superfast"},
    "veryfast + zerolatency": {"preset": "veryfast"},
    "medium + zerolatency": {"preset": "medium"},
    "medium, no tune (x264's default)": {"preset": "medium", "tune": None, "bf": None},
}
OTHER_WORK = ("mjpg decode (capture)", "bgr -> i420 (stream)", "jpeg q70 + header (preview)")


def setting_options(overrides: dict[str, str | None]) -> dict[str, str]:
    """The stream's libx264 options at 2000 kbit/s, 30 fps, with `overrides` applied (None drops an option)."""
    from service.config import StreamConfig
    from service.video.rtp_stream import x264_options

    options = x264_options(StreamConfig(fps=FPS, bitrate_kbps=BITRATE_KBPS))
    for key, value in overrides.items():
        if value is None:
            options.pop(key, None)
        else:
            options[key] = value
    return options


def psnr_db(reference: np.ndarray, decoded: np.ndarray) -> float:
    """PSNR (dB) of two uint8 images of the same shape; inf when identical."""
    mse = float(np.mean((reference.astype(np.float64) - decoded.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(255.0 ** 2 / mse)


def load_frames(sequence: Path, count: int) -> list[np.ndarray]:
    """The first `count` frames of a shared sequence, resized to 640x480 (BGR)."""
    import cv2

    paths = sorted((sequence / "img").glob("*.jpg"))[:count]
    if len(paths) < count:
        raise SystemExit(f"{sequence} has {len(paths)} frames, fewer than {count}")
    return [cv2.resize(cv2.imread(str(p)), (WIDTH, HEIGHT), interpolation=cv2.INTER_AREA) for p in paths]


def write_mjpg(frames: list[np.ndarray], path: Path) -> None:
    import cv2

    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), FPS, (WIDTH, HEIGHT))
    for frame in frames:
        writer.write(frame)
    writer.release()


def run_work(frames: list[np.ndarray], clip: Path, measure: Callable[[str, Callable[[], object]], object]) -> dict:
    """Every kind of work on every frame, each call through measure(label, call); returns quality per setting."""
    import av
    import cv2

    from service.config import PreviewConfig
    from service.sources.base import Frame
    from service.video.rtp_stream import yuv420
    from service.video.zenoh_preview import preview_payload

    cv2.setNumThreads(1)
    capture = cv2.VideoCapture(str(clip), cv2.CAP_FFMPEG)
    for index in range(len(frames)):
        measure(f"{OTHER_WORK[0]}|{index}", capture.read)
    capture.release()
    planes = []
    for index, image in enumerate(frames):
        planes.append(measure(f"{OTHER_WORK[1]}|{index}", lambda image=image: yuv420(image, (WIDTH, HEIGHT))))
    preview = PreviewConfig()
    for index, image in enumerate(frames):
        frame = Frame(image, index, 1000.0 + index / FPS, index / FPS)
        measure(f"{OTHER_WORK[2]}|{index}", lambda frame=frame: preview_payload(frame, preview))
    quality = {}
    for name, overrides in X264_SETTINGS.items():
        encoder = av.CodecContext.create("libx264", "w")
        encoder.width, encoder.height, encoder.pix_fmt = WIDTH, HEIGHT, "yuv420p"
        encoder.bit_rate = BITRATE_KBPS * 1000
        encoder.framerate = fractions.Fraction(int(FPS))
        encoder.time_base = fractions.Fraction(1, RTP_CLOCK_HZ)
        encoder.options = setting_options(overrides)
        packets: list = []
        for index, plane in enumerate(planes):
            video_frame = av.VideoFrame.from_ndarray(plane, format="yuv420p")
            video_frame.pts = round(index * RTP_CLOCK_HZ / FPS)
            video_frame.time_base = fractions.Fraction(1, RTP_CLOCK_HZ)
            packets.extend(measure(f"{name}|{index}", lambda f=video_frame: encoder.encode(f)))
        packets.extend(measure(f"{name}|flush", lambda: encoder.encode(None)))
        decoder = av.CodecContext.create("h264", "r")
        decoded = [f.to_ndarray(format="yuv420p")[:HEIGHT] for p in packets for f in decoder.decode(p)]
        decoded += [f.to_ndarray(format="yuv420p")[:HEIGHT] for f in decoder.decode(None)]
        luma = [plane[:HEIGHT] for plane in planes]
        quality[name] = {"frames_decoded": len(decoded),
                         "psnr_y_db": float(np.mean([psnr_db(a, b) for a, b in zip(luma, decoded)])),
                         "kbit_s": sum(p.size for p in packets) * 8 / 1000 / (len(planes) / FPS)}
    return quality


def native(frames: list[np.ndarray], clip: Path) -> tuple[dict[str, float], dict]:
    """(thread CPU ms per frame by kind of work, quality per x264 setting), measured in this process."""
    spent: dict[str, float] = {}

    def measure(label: str, call: Callable[[], object]) -> object:
        started = time.thread_time()
        result = call()
        kind = label.split("|")[0]
        spent[kind] = spent.get(kind, 0.0) + time.thread_time() - started
        return result

    quality = run_work(frames, clip, measure)
    return {kind: 1e3 * seconds / len(frames) for kind, seconds in spent.items()}, quality


def worker(sequence: Path, count: int, clip: Path, helper: Path) -> None:
    """Under callgrind: every call between a zero and a labelled dump of the counters."""
    from bench.instructions import callgrind_counter

    frames = load_frames(sequence, count)
    write_mjpg(frames, clip)
    run_work(frames, clip, callgrind_counter(helper))


def worker_marks(sequence: Path, count: int, clip: Path) -> None:
    """Under qemu with the marks plugin: every call between two marks (bench.instructions.marks_counter)."""
    from bench.instructions import marks_counter

    frames = load_frames(sequence, count)
    write_mjpg(frames, clip)
    run_work(frames, clip, marks_counter())


def count_arm64(rootfs: Path, sequence: Path, count: int, cpu: str) -> dict[str, float]:
    """Instructions per frame by kind of work of the arm64 build in `rootfs`, under qemu-aarch64 emulating `cpu`."""
    from bench.instructions import run_arm64_marks

    with tempfile.TemporaryDirectory(prefix="jsar-encoders-") as tmp:
        out, marks = run_arm64_marks(rootfs, "bench.encoders", [
            str(sequence.parent.resolve()), "--sequence", sequence.name, "--frames", str(count), "--clip",
            str(Path(tmp) / "clip.avi"), "--worker-marks"], cpu)
    totals: dict[str, int] = {}
    for line in out.splitlines():
        if line.startswith("SEGMENT "):
            first, last, label = line.split(" ", 3)[1:]
            kind = label.split("|")[0]
            totals[kind] = totals.get(kind, 0) + marks[int(last)] - marks[int(first)]
    return {kind: total / count for kind, total in totals.items()}


def count_callgrind(sequence: Path, count: int) -> dict[str, float]:
    """Instructions per frame by kind of work, under callgrind (this machine's build)."""
    from bench.instructions import parse_dumps, run_worker_under_callgrind

    with tempfile.TemporaryDirectory(prefix="jsar-encoders-") as tmp:
        folder = Path(tmp)
        run_worker_under_callgrind("bench.encoders", [str(sequence.parent), "--sequence", sequence.name, "--frames",
                                                      str(count), "--clip", str(folder / "clip.avi"), "--worker"],
                                   folder, folder)
        totals: dict[str, int] = {}
        for label, instructions in parse_dumps(folder):
            kind = label.split("|")[0]
            totals[kind] = totals.get(kind, 0) + instructions
    return {kind: total / count for kind, total in totals.items()}


def report(ms: dict[str, float], quality: dict, instructions: dict[str, float] | None, native_counts: bool = True) -> str:
    """Markdown table: per kind of work, CPU ms per frame, instructions and this host's rate (when counted here:
    native_counts; an arm64 count has no rate), quality."""
    lines = ["| work (640x480, one thread) | CPU ms per frame | M instructions per frame | G instructions/s "
             "| PSNR Y dB | kbit/s at 30 fps |", "|---|---|---|---|---|---|"]
    for kind in (*OTHER_WORK, *X264_SETTINGS):
        count = instructions.get(kind) if instructions else None
        rate = f"{count / (ms[kind] * 1e-3) / 1e9:.1f}" if count and native_counts else "-"
        counted = f"{count / 1e6:.1f} | {rate}" if count else "- | -"
        q = quality.get(kind)
        shown = f"{q['psnr_y_db']:.2f} | {q['kbit_s']:.0f}" if q else "- | -"
        lines.append(f"| {kind} | {ms[kind]:.2f} | {counted} | {shown} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.encoders", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("data_root", type=Path, help="the shared data folder (JSAR_DATA_ROOT)")
    parser.add_argument("--sequence", default="UAVDT_S1301")
    parser.add_argument("--frames", type=int, default=150, help="frames of the sequence (5 s at 30 fps)")
    parser.add_argument("--callgrind", action="store_true", help="also count instructions under callgrind")
    parser.add_argument("--json", type=Path, default=None, help="write the numbers here")
    parser.add_argument("--arm64-rootfs", type=Path, default=None,
                        help="count the arm64 build installed in this root file system under qemu-aarch64 instead")
    parser.add_argument("--arm64-cpu", default="cortex-a72", help="qemu CPU model: cortex-a72 (Pi 4), cortex-a76 (Pi 5)")
    parser.add_argument("--worker", type=Path, default=None, help=argparse.SUPPRESS)  # the run under callgrind
    parser.add_argument("--worker-marks", action="store_true", help=argparse.SUPPRESS)  # the run under qemu
    parser.add_argument("--clip", type=Path, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    sequence = args.data_root / args.sequence
    if args.worker is not None:
        worker(sequence, args.frames, args.clip, args.worker)
        return 0
    if args.worker_marks:
        worker_marks(sequence, args.frames, args.clip)
        return 0
    frames = load_frames(sequence, args.frames)
    with tempfile.TemporaryDirectory(prefix="jsar-encoders-") as tmp:
        clip = Path(tmp) / "clip.avi"
        write_mjpg(frames, clip)
        ms, quality = native(frames, clip)
    if args.arm64_rootfs is not None:
        instructions = count_arm64(args.arm64_rootfs, sequence, args.frames, args.arm64_cpu)
    else:
        instructions = count_callgrind(sequence, args.frames) if args.callgrind else None
    machine = f"aarch64 (qemu-aarch64 -cpu {args.arm64_cpu}) instructions, " if args.arm64_rootfs else ""
    print(f"{args.sequence}, {args.frames} frames at {WIDTH}x{HEIGHT}; H.264 at {BITRATE_KBPS} kbit/s, {FPS:.0f} fps; "
          f"{machine}this host's CPU ms")
    print(report(ms, quality, instructions, native_counts=args.arm64_rootfs is None))
    if args.json is not None:
        args.json.write_text(json.dumps({"ms": ms, "quality": quality, "instructions": instructions,
                                         "instructions_machine": machine or "this host"}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
