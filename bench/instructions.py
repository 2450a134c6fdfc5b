"""Machine-independent cost per frame: instructions executed per tracked frame, counted by callgrind.

    python -m bench.instructions DATA_ROOT [--sequences OTB_Crossing,DTB70_MountainBike6]
                                 [--frames 20] [--redetect-frames 20] [--json out/instructions.json]
                                 [--arm64-rootfs ROOTFS] [--params JSON]
    python -m bench.instructions DATA_ROOT --report out/instructions.json   (print a saved result)

This machine's build: runs itself under `valgrind --tool=callgrind` (instrumentation off until the
trackers are set up; client requests from a tiny helper compiled here zero the counters before and
dump them after each measured call). The arm64 build (`--arm64-rootfs`, the root file system that
deploy/check-arm64.sh made and installed the project into): runs its python under `qemu-aarch64`
with the TCG plugin bench/qemu_insn_marks.c, which reports the guest instructions executed at marks
the worker sets around each measured call (valgrind itself does not run under qemu-user). Either
way each count is the instructions of one call, the Python interpreter, numpy and OpenCV included,
nothing else. Per sequence, on the same decoded frames:
  jsar            `update` on frames 1..N
  csrt            OpenCV's CSRT `update` on frames 1..N
  kcf             OpenCV's KCF `update` on frames 1..N (its default parameters: grey and colour names, no HOG)
  jsar-re         `update` on frames 1..N (confident frames: locate + commit + monitor)
  jsar-re lost    `update` on frames N+1..N+M with the target hidden (bench.redetect.hide_target),
                  after an uncounted run over frames 1..N: what a lost frame costs (the core's locate,
                  the decision filter on its sample, the lattice windows of the per-frame budget, the
                  verifier's looks and the core's coasts; bench.redetect.searching_tracker: warm-up 0, no
                  candidate taken, so every frame of the loss spends its whole budget as the gate grows),
                  on the tracking thread: with a verifier worker (the service's `tracker.verifier_thread`) a
                  coast's commit, part of a lost frame's turned windows' features and half its looks are made on
                  the verifier's thread while this one goes on; here each job runs when its result is asked for
                  (or at the frame's end), counted apart, and the frame's events are replayed on one worker:
  jsar-re lost, verifier thread   the jobs (0 on a frame that gave none)
  jsar-re lost, critical path   the tracking thread's time to the frame's end, its work plus its waits for
                  the jobs, these run one at a time in submit order: a lost frame's time on two cores
                  ("jsar-re lost" is the tracking thread's own work)
--params: jsar-re's jsar.create keywords (JSON) for both jsar-re kinds, to count a variant.
Instruction counts do not depend on the machine's load or clock; they do depend on the instruction
set (x86-64 with AVX2 vs aarch64 NEON) and the libraries' SIMD paths: the arm64 counts are the ones
to size a Pi with. fps projections: fps = clock * IPC / instructions (see docs/results-cost.md).
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # before numpy loads BLAS: one thread, as measured everywhere

import argparse  # noqa: E402
import concurrent.futures  # noqa: E402
import ctypes  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import re  # noqa: E402
import shutil  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any, Callable  # noqa: E402

HELPER_C = r"""
#include <valgrind/callgrind.h>
void cg_start(void) { CALLGRIND_START_INSTRUMENTATION; }
void cg_zero(void) { CALLGRIND_ZERO_STATS; }
void cg_dump(const char *label) { CALLGRIND_DUMP_STATS_AT(label); }
"""
MARK_SYSCALL = 4242  # bench/qemu_insn_marks.c
# Projection assumptions (not measurements): core clock and instructions per cycle on this workload
# (CPython interpreter + numpy / FFT + OpenCV, one thread). Cortex-A72 is 3-wide out-of-order, ~1 IPC
# on such mixed code; Cortex-A76 is 4-wide with ~1.7x the A72's work per clock (Arm's generational
# figures: A73 ~ A72, A75 +22 %, A76 +35 %). fps = clock * IPC / instructions per frame.
CORES = {"Pi 4 (Cortex-A72 1.8 GHz, IPC 1.0)": (1.8e9, 1.0), "Pi 5 (Cortex-A76 2.4 GHz, IPC 1.7)": (2.4e9, 1.7)}
# the last two: kinds of results saved before the search rework (--report still prints them)
KINDS = ("jsar", "csrt", "kcf", "jsar-re confident", "jsar-re verifier", "jsar-re lost", "jsar-re lost, verifier thread",
         "jsar-re lost, critical path", "jsar-re redetect omega 5", "jsar-re redetect omega 12")
# A lost frame's segments with a CountedWorker: the tracking thread's own work, its job events (an empty segment
# each: "... submit K", "... result K") and the jobs ("... job K"), K numbering the frame's jobs from 1.
LOST_EVENT = re.compile(r"jsar-re lost, (submit|result|job) (\d+)$")
Counted = Callable[[str, Callable[[], Any]], Any]  # counted(label, call): call()'s instructions under `label`
DEFAULT_SEQUENCES = "OTB_Crossing,DTB70_MountainBike6"


def build_helper(folder: Path) -> Path:
    """Compile the client-request helper (needs gcc and valgrind's headers); returns the .so path."""
    source, library = folder / "cg_helper.c", folder / "cg_helper.so"
    source.write_text(HELPER_C)
    subprocess.run(["gcc", "-O1", "-shared", "-fPIC", "-o", str(library), str(source)], check=True)
    return library


def parse_dumps(folder: Path) -> list[tuple[str, int]]:
    """(label, instructions) of every callgrind dump triggered by a client request, in dump order."""
    found: list[tuple[int, str, int]] = []
    for path in folder.glob("callgrind.out*"):
        text = path.read_text(errors="replace")
        label = re.search(r"^desc: Trigger: Client Request: (.*)$", text, re.M)
        part = re.search(r"^part: (\d+)$", text, re.M)
        totals = re.search(r"^(?:summary|totals): (\d+)", text, re.M)
        if label and totals:
            found.append((int(part.group(1)) if part else 0, label.group(1).strip(), int(totals.group(1))))
    return [(label, count) for _, label, count in sorted(found)]


def summarise(dumps: list[tuple[str, int]]) -> dict[str, dict[str, dict[str, float]]]:
    """{sequence: {kind: {frames, mean, median, max, counts}}} from labels 'sequence|kind|frame' in the order
    counted (counts: per frame, in frame order: jsar-re's verifier watches every verify.watch_frames-th frame). The
    segments of one label (a call another was counted inside) add up; a lost frame counted with a CountedWorker
    (LOST_EVENT) becomes "jsar-re lost" (the tracking thread's work), "jsar-re lost, verifier thread" (its jobs)
    and "jsar-re lost, critical path" (lost_frame_times)."""
    frames: dict[str, int] = {}
    events: dict[str, list[tuple[str, int]]] = {}  # 'sequence|frame' -> its lost frame's segments in order
    for label, count in dumps:
        sequence, kind, index = label.split("|")
        if kind == "jsar-re lost" or LOST_EVENT.match(kind):
            events.setdefault(f"{sequence}|{index}", []).append((kind, count))
        if not LOST_EVENT.match(kind):
            frames[label] = frames.get(label, 0) + count
    # A sequence counted with a worker: every lost frame gets the three kinds (a frame without a job too).
    shared = {frame.split("|")[0] for frame, segments in events.items()
              if any(LOST_EVENT.match(kind) for kind, _ in segments)}
    for frame, segments in events.items():
        sequence, index = frame.split("|")
        if sequence in shared:
            own, jobs, critical = lost_frame_times(segments)
            frames[f"{sequence}|jsar-re lost|{index}"] = own
            frames[f"{sequence}|jsar-re lost, verifier thread|{index}"] = jobs
            frames[f"{sequence}|jsar-re lost, critical path|{index}"] = critical
    grouped: dict[str, dict[str, list[int]]] = {}
    for label, count in frames.items():
        sequence, kind, _ = label.split("|")
        grouped.setdefault(sequence, {}).setdefault(kind, []).append(count)
    return {seq: {kind: {"frames": len(v), "mean": statistics.fmean(v), "median": statistics.median(v), "max": max(v),
                         "counts": v}
                  for kind, v in kinds.items()} for seq, kinds in grouped.items()}


def lost_frame_times(segments: list[tuple[str, int]]) -> tuple[int, int, int]:
    """(the tracking thread's work, the worker's, the critical path) in instructions of one lost frame from its
    segments in the order counted: "jsar-re lost" the tracking thread's work, "... submit K" / "... result K" its
    job events (their few instructions its own), "... job K" job K's work, wherever it was counted. The worker runs
    the jobs one at a time in submit order, each from its submission or the end of the one before it, whichever is
    later; at a result the tracking thread waits for its job's end. The critical path is the tracking thread's time
    at the frame's end (a job never asked for, such as a deferred watch check, delays only the jobs after it)."""
    matches = [(LOST_EVENT.match(kind), count) for kind, count in segments]
    costs = {int(m.group(2)): count for m, count in matches if m is not None and m.group(1) == "job"}
    clock, queue, submitted, finished = 0, [], {}, {}
    for m, count in matches:
        if m is not None and m.group(1) == "job":
            continue
        clock += count
        if m is None:
            continue
        job = int(m.group(2))
        if m.group(1) == "submit":
            submitted[job] = clock
            queue.append(job)
            continue
        free = 0  # the worker's clock, replayed over the queue up to this job
        for earlier in queue:
            if earlier not in finished:
                finished[earlier] = max(submitted[earlier], free) + costs.get(earlier, 0)
            free = finished[earlier]
            if earlier == job:
                break
        clock = max(clock, finished[job])
    jobs = sum(costs.values())
    return sum(count for _, count in segments) - jobs, jobs, clock


def worker(root: Path, sequences: list[str], frames: int, redetect_frames: int, helper: Path | None,
           overrides: dict[str, Any] | None = None) -> None:
    """Under callgrind (helper: the client-request library) or qemu with the marks plugin (helper None):
    set up each sequence's trackers uncounted, count each measured call."""
    import cv2
    from threadpoolctl import threadpool_limits

    cv2.setNumThreads(1)
    threadpool_limits(limits=1)
    counted = callgrind_counter(helper) if helper is not None else marks_counter()
    for sequence in sequences:
        states = count_frame_kinds(root, sequence, frames, redetect_frames, counted, overrides, share_lost_work=True)
        not_lost = sum(state != "lost" for state in states)
        print(f"{sequence}: counted" + (f" ({not_lost} of {len(states)} hidden frames were not lost frames)"
                                        if not_lost else ""), flush=True)


class NestingCounter:
    """counted(label, call) -> call()'s result (also open(label) ... close()), from two primitives: begin() starts
    counting, boundary(label) ends the segment counted since the last begin or boundary under `label` (and starts
    the next). A span counted inside another is cut out of it: the outer label's segments before and after it add
    up (summarise)."""

    def __init__(self, begin: Callable[[], None], boundary: Callable[[str], None]) -> None:
        self.begin, self.boundary = begin, boundary
        self.labels: list[str] = []

    def open(self, label: str) -> None:
        """Count from here under `label` (the open one's segment so far ends)."""
        if self.labels:
            self.boundary(self.labels[-1])
        else:
            self.begin()
        self.labels.append(label)

    def close(self) -> None:
        """End the innermost open label's segment; the one it was opened in goes on."""
        self.boundary(self.labels.pop())

    def __call__(self, label: str, call: Callable[[], Any]) -> Any:
        self.open(label)
        try:
            return call()
        finally:
            self.close()


def callgrind_counter(helper: Path) -> NestingCounter:
    """Under callgrind: load the client-request helper, start instrumenting, and return counted(label, call)
    (NestingCounter): a zero of the counters begins, a dump named by the label ends a segment (a dump zeroes)."""
    cg = ctypes.CDLL(str(helper))
    cg.cg_dump.argtypes = [ctypes.c_char_p]
    cg.cg_start()
    return NestingCounter(cg.cg_zero, lambda label: cg.cg_dump(label.encode()))


def marks_counter() -> NestingCounter:
    """Under qemu with the marks plugin: counted(label, call) (NestingCounter) sets a mark at every segment's end
    and prints 'SEGMENT first last label' for the count_arm64 side."""
    libc = ctypes.CDLL(None, use_errno=True)
    marks = [-1]

    def mark() -> int:
        marks[0] += 1
        libc.syscall(MARK_SYSCALL, ctypes.c_long(marks[0]))
        return marks[0]

    def boundary(label: str) -> None:
        last = mark()
        print(f"SEGMENT {last - 1} {last} {label}", flush=True)

    def begin() -> None:
        mark()

    return NestingCounter(begin, boundary)


class CountedWorker(concurrent.futures.Executor):
    """A verifier worker for a count, on this thread. submit() marks the event in the caller's count (an empty
    segment 'SEQUENCE|jsar-re lost, submit K|FRAME'); the job runs on its first result() (marked '... result K'), or
    at finish_frame() if nobody asked, counted as 'SEQUENCE|jsar-re lost, job K|FRAME'; a cancelled job never runs.
    `frame` names the lost frame ('SEQUENCE|FRAME'; start_frame). summarise replays the events on one worker
    (lost_frame_times)."""

    def __init__(self, counted: NestingCounter) -> None:
        self.counted = counted
        self.frame = "unlabelled|0"
        self.jobs = 0  # this frame's jobs so far
        self.pending: list[_JobOnResult] = []

    def label(self, part: str) -> str:
        sequence, index = self.frame.split("|")
        return f"{sequence}|{part}|{index}"

    def start_frame(self, frame: str) -> None:
        """Jobs from here on belong to lost frame `frame` ('SEQUENCE|FRAME'), numbered from 1."""
        self.frame, self.jobs = frame, 0

    def submit(self, fn, /, *args, **kwargs):  # type: ignore[no-untyped-def, override]
        self.jobs += 1
        self.counted(self.label(f"jsar-re lost, submit {self.jobs}"), lambda: None)
        job = _JobOnResult(self, self.jobs, self.label(f"jsar-re lost, job {self.jobs}"), lambda: fn(*args, **kwargs))
        self.pending.append(job)
        return job

    def run(self, job: _JobOnResult) -> None:
        """Run `job` now, counted under its label."""
        self.pending.remove(job)
        try:
            job.set_result(self.counted(job.label, job.job))
        except BaseException as exc:  # noqa: BLE001 - the job's error is its future's, as on a real executor
            job.set_exception(exc)

    def finish_frame(self) -> None:
        """Run the frame's jobs nobody asked for (the worker would have): counted, not waited for."""
        for job in list(self.pending):
            if job.cancelled():
                self.pending.remove(job)
            else:
                self.run(job)


class _JobOnResult(concurrent.futures.Future):
    """CountedWorker's future: the job runs on the first result() (or the frame's end)."""

    def __init__(self, worker: CountedWorker, number: int, label: str, job: Callable[[], Any]) -> None:
        super().__init__()
        self.worker, self.number, self.label, self.job = worker, number, label, job

    def result(self, timeout: float | None = None) -> Any:
        if not self.done():
            self.worker.counted(self.worker.label(f"jsar-re lost, result {self.number}"), lambda: None)
            self.worker.run(self)
        return super().result(timeout)


def count_frame_kinds(root: Path, sequence: str, frames: int, lost_frames: int, counted: Counted,
                      overrides: dict[str, Any] | None = None, share_lost_work: bool = False) -> list[str]:
    """Set up the trackers uncounted on `sequence` and hand each measured call to `counted` with its label
    'sequence|kind|frame': jsar, CSRT, KCF and jsar-re on frames 1..frames, then jsar-re's lost frames on the
    next lost_frames with the target hidden; returns the states of those lost frames. `overrides`: jsar.create
    keywords of both jsar-re trackers (--params). share_lost_work: the lost frames have a verifier worker
    (CountedWorker; `counted` a NestingCounter), their jobs and job events counted apart (LOST_EVENT)."""
    import cv2

    import jsar
    from bench.redetect import _load, hide_target, searching_tracker
    from jsar.eval.dataset import load_sequence

    images, box = _load(root / sequence, frames + lost_frames + 1)
    if len(images) < frames + lost_frames + 1:
        raise SystemExit(f"{sequence} has {len(images)} frames, fewer than {frames + lost_frames + 1}")
    groundtruth = load_sequence(root / sequence).groundtruth
    first, tracked = images[0], images[1:frames + 1]
    hidden = [hide_target(image, groundtruth[index])
              for index, image in enumerate(images[frames + 1:], start=frames + 1)]
    csrt, kcf = cv2.TrackerCSRT_create(), cv2.TrackerKCF_create()
    csrt.init(first, tuple(int(round(v)) for v in box))
    kcf.init(first, tuple(int(round(v)) for v in box))
    plain, again = jsar.create("jsar"), jsar.create("jsar-re", **(overrides or {}))
    plain.init(first, box)
    again.init(first, box)
    for index, image in enumerate(tracked, start=1):
        counted(f"{sequence}|jsar|{index}", lambda: plain.update(image))
        counted(f"{sequence}|csrt|{index}", lambda: csrt.update(image))
        counted(f"{sequence}|kcf|{index}", lambda: kcf.update(image))
        counted(f"{sequence}|jsar-re confident|{index}", lambda: again.update(image))
        # the verifier's deferred embeddings, which the service runs on a thread of its own (verify.defer_frames)
        counted(f"{sequence}|jsar-re verifier|{index}", again.run_deferred)
    searching = searching_tracker(overrides=overrides)
    searching.init(first, box)
    for image in tracked:
        searching.update(image)
    searching.run_deferred()  # the tracked frames' deferred work: the verifier thread's, not a lost frame's
    worker = CountedWorker(counted) if share_lost_work else None  # type: ignore[arg-type]
    states: list[str] = []
    searching.set_verifier_worker(worker)
    for index, image in enumerate(hidden, start=frames + 1):
        if worker is not None:
            worker.start_frame(f"{sequence}|{index}")
        counted(f"{sequence}|jsar-re lost|{index}", lambda: states.append(searching.update(image).state))
        if worker is not None:
            worker.finish_frame()
    return states


def count_callgrind(worker_args: list[str]) -> list[tuple[str, int]]:
    """(label, instructions) per measured call of this machine's build, under callgrind."""
    with tempfile.TemporaryDirectory(prefix="jsar-callgrind-") as tmp:
        folder = Path(tmp)
        run_worker_under_callgrind("bench.instructions", [*worker_args, "--worker"], folder, folder)
        return parse_dumps(folder)


def run_worker_under_callgrind(module: str, args: list[str], dumps: Path, scratch: Path) -> None:
    """`python -m module *args HELPER` under callgrind, instrumentation off until the worker starts it; the
    client-request helper is built in `scratch`, callgrind's dumps land in `dumps` (SystemExit without
    valgrind or gcc)."""
    for tool in ("valgrind", "gcc"):
        if shutil.which(tool) is None:
            raise SystemExit(f"{tool} is not installed (apt-get install valgrind gcc)")
    helper = build_helper(scratch)
    command = ["valgrind", "--tool=callgrind", "--instr-atstart=no", "--dump-line=no",
               f"--callgrind-out-file={dumps}/callgrind.out.%p", sys.executable, "-m", module, *args, str(helper)]
    print(f"running: {' '.join(command[:5])} python -m {module} ...", flush=True)
    start = time.monotonic()
    subprocess.run(command, check=True, stderr=subprocess.DEVNULL)
    print(f"callgrind run took {time.monotonic() - start:.0f} s", flush=True)


def count_arm64(rootfs: Path, worker_args: list[str], cpu: str) -> list[tuple[str, int]]:
    """(label, instructions) per measured call of the arm64 build installed in `rootfs` (its venv at
    /opt/jsar/.venv, as deploy/check-arm64.sh leaves it), under qemu-aarch64 emulating `cpu` (numpy,
    OpenBLAS and OpenCV pick their SIMD paths from the CPU's features: cortex-a72 has plain NEON,
    cortex-a76 adds fp16 and dot product, qemu's default "max" more) with the marks plugin."""
    out, counts = run_arm64_marks(rootfs, "bench.instructions", [*worker_args, "--worker-marks"], cpu)
    segments = [line.split(" ", 3)[1:] for line in out.splitlines() if line.startswith("SEGMENT ")]
    return [(label, counts[int(last)] - counts[int(first)]) for first, last, label in segments]


def run_arm64_marks(rootfs: Path, module: str, module_args: list[str], cpu: str) -> tuple[str, dict[int, int]]:
    """(standard output, {mark: guest instructions executed so far}) of `python3 -m module module_args` run from
    the arm64 build installed in `rootfs` under qemu-aarch64 emulating `cpu` with the marks plugin
    (bench/qemu_insn_marks.c: the guest sets a mark with the system call MARK_SYSCALL)."""
    qemu = shutil.which("qemu-aarch64")  # the dynamic build: qemu-aarch64-static cannot load plugins
    if qemu is None or shutil.which("gcc") is None:
        raise SystemExit("needs qemu-aarch64 (apt-get install qemu-user) and gcc")
    python = rootfs / "usr" / "bin" / "python3"
    site = sorted((rootfs / "opt" / "jsar" / ".venv" / "lib").glob("python3*/site-packages"))
    if not python.exists() or not site:
        raise SystemExit(f"{rootfs} has no python3 or no /opt/jsar/.venv: run deploy/check-arm64.sh first")
    # python3 itself, not the venv's python (an absolute link the host would resolve to its own python);
    # the venv's packages on PYTHONPATH; run from / so that no source tree shadows them
    with tempfile.TemporaryDirectory(prefix="jsar-qemu-marks-") as tmp:
        folder = Path(tmp)
        plugin = folder / "qemu_insn_marks.so"
        subprocess.run(["gcc", "-O2", "-shared", "-fPIC", "-o", str(plugin),
                        str(Path(__file__).with_name("qemu_insn_marks.c"))], check=True)
        marks_file = folder / "marks.txt"
        if python.is_symlink():  # Debian's python3 -> python3.11, relative to /usr/bin
            python = python.parent / os.readlink(python)
        command = [qemu, "-L", str(rootfs), "-cpu", cpu, "-plugin", f"{plugin},out={marks_file}", str(python),
                   "-m", module, *module_args]
        env = {**os.environ, "PYTHONPATH": str(site[0]), "PYTHONNOUSERSITE": "1"}
        print(f"running: qemu-aarch64 -cpu {cpu} -plugin qemu_insn_marks.so python3 -m {module} ... (arm64 build)",
              flush=True)
        start = time.monotonic()
        out = subprocess.run(command, check=True, cwd="/", env=env, capture_output=True, text=True).stdout
        print(f"qemu run took {time.monotonic() - start:.0f} s", flush=True)
        counts = {int(mark): int(count) for mark, count in
                  (line.split() for line in marks_file.read_text().splitlines() if not line.startswith("exit"))}
    return out, counts


def host_rate(root: Path, sequence: str, frames: int) -> dict[str, float]:
    """Natively (no valgrind): thread CPU ms per frame of jsar and csrt on the same frames, for the host IPC."""
    import cv2
    from threadpoolctl import threadpool_limits

    import jsar
    from bench.redetect import _load

    cv2.setNumThreads(1)
    threadpool_limits(limits=1)
    images, box = _load(root / sequence, frames + 1)
    plain = jsar.create("jsar")
    plain.init(images[0], box)
    csrt = cv2.TrackerCSRT_create()
    csrt.init(images[0], tuple(int(round(v)) for v in box))
    spent = {"jsar": 0.0, "csrt": 0.0}
    for image in images[1:]:
        start = time.thread_time()
        plain.update(image)
        spent["jsar"] += time.thread_time() - start
        start = time.thread_time()
        csrt.update(image)
        spent["csrt"] += time.thread_time() - start
    return {name: 1e3 * seconds / frames for name, seconds in spent.items()}


def report(machine: str, summary: dict, native: dict[str, float] | None) -> None:
    """Print the counts, the Pi 4 / Pi 5 projections and (x86-64 runs) this host's instruction rate."""
    print(f"\ninstructions per frame ({machine}, millions; mean / median / max over the counted frames):")
    for sequence, kinds in summary.items():
        print(sequence)
        for kind in KINDS:
            if kind in kinds:
                k = kinds[kind]
                print(f"  {kind:26s} {k['mean'] / 1e6:8.1f} {k['median'] / 1e6:8.1f} {k['max'] / 1e6:8.1f}"
                      f"   ({k['frames']} frames)")
    print("\nprojected fps on one core = clock * IPC / mean instructions (assumed clock and IPC in brackets)"
          + ("" if machine.startswith("aarch64") else "; these are x86-64 counts: --arm64-rootfs gives the aarch64 ones"))
    for sequence, kinds in summary.items():
        for core, (clock, ipc) in CORES.items():
            print(f"  {sequence:22s} {core:36s} " + "  ".join(
                f"{kind} {clock * ipc / kinds[kind]['mean']:.1f}" for kind in KINDS if kind in kinds))
    if native:
        sequence = next(iter(summary))
        print(f"\nthis host natively on {sequence} (thread CPU time, one thread): "
              + ", ".join(f"{n} {ms:.2f} ms/frame = {summary[sequence][n]['mean'] / (ms * 1e-3) / 1e9:.2f} G instructions/s"
                          for n, ms in native.items()))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data_root", type=Path)
    parser.add_argument("--sequences", default=DEFAULT_SEQUENCES)
    parser.add_argument("--frames", type=int, default=20, help="tracked frames counted per sequence")
    parser.add_argument("--redetect-frames", type=int, default=20,
                        help="lost frames (target hidden) counted per sequence")
    parser.add_argument("--json", type=Path, default=None, help="write the summary here")
    parser.add_argument("--arm64-rootfs", type=Path, default=None,
                        help="count the arm64 build installed in this root file system under qemu-aarch64")
    parser.add_argument("--arm64-cpu", default="cortex-a72", help="qemu CPU model: cortex-a72 (Pi 4), cortex-a76 (Pi 5)")
    parser.add_argument("--report", type=Path, default=None, metavar="JSON",
                        help="print the counts and projections of an earlier --json result instead of counting")
    parser.add_argument("--params", default="", metavar="JSON",
                        help='jsar-re\'s jsar.create keywords, e.g. \'{"redetect": {"verify": {"lost_looks": 2}}}\'')
    parser.add_argument("--worker", type=Path, default=None, help=argparse.SUPPRESS)  # the run under callgrind
    parser.add_argument("--worker-marks", action="store_true", help=argparse.SUPPRESS)  # the run under qemu
    args = parser.parse_args(argv)
    if args.report is not None:
        saved = json.loads(args.report.read_text())
        report(saved["machine"], saved["instructions"], saved.get("host_cpu_ms_per_frame"))
        return 0
    if not args.data_root.is_dir():
        parser.error(f"{args.data_root} is not a directory")
    sequences = [s for s in args.sequences.split(",") if s]
    for sequence in sequences:
        if not (args.data_root / sequence / "img").is_dir():
            parser.error(f"{sequence} is not a sequence under {args.data_root}")
    try:
        overrides = json.loads(args.params) if args.params else {}
    except json.JSONDecodeError as exc:
        parser.error(f"--params is not JSON: {exc}")
    if not isinstance(overrides, dict):
        parser.error("--params must be a JSON object of jsar-re's keywords")
    if args.worker is not None or args.worker_marks:
        worker(args.data_root, sequences, args.frames, args.redetect_frames, args.worker, overrides)
        return 0
    worker_args = [str(args.data_root.resolve()), "--sequences", ",".join(sequences), "--frames", str(args.frames),
                   "--redetect-frames", str(args.redetect_frames)] + (["--params", args.params] if args.params else [])
    if args.arm64_rootfs is not None:
        machine = f"aarch64 (qemu-aarch64 -cpu {args.arm64_cpu})"
        summary, native = summarise(count_arm64(args.arm64_rootfs, worker_args, args.arm64_cpu)), None
    else:
        machine, summary = platform.machine(), summarise(count_callgrind(worker_args))
        native = host_rate(args.data_root, sequences[0], args.frames)
    report(machine, summary, native)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"machine": machine, "params": overrides,
                                         "frames": args.frames, "redetect_frames": args.redetect_frames,
                                         "instructions": summary, "host_cpu_ms_per_frame": native}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
