"""Where a frame's instructions go: callgrind's per-function counts by library, by C function and by tracker stage.

    python -m bench.profile DATA_ROOT [--sequences OTB_Crossing] [--frames 5] [--lost-frames 2] [--top 15]
                            [--json out/profile.json] [--keep FOLDER]
    python -m bench.profile DATA_ROOT --report out/profile.json   (print a saved result)
    python -m bench.profile DATA_ROOT --arm64-rootfs ROOTFS [--arm64-cpu cortex-a72]   (the arm64 build, by stage)

The same frame kinds as bench.instructions (jsar, csrt, jsar-re confident, jsar-re lost; fewer frames),
run under `valgrind --tool=callgrind`. Callgrind sees C functions only, so the tracker's Python-level
stages are marked from outside: in this benchmark's process only, the stage functions of STAGES are
replaced by wrappers that dump callgrind's counters (which zeroes them) on entry and on exit. Every dump
is then one segment of a frame, labelled with the stack of stages open while it ran ("locate/features"):
the segments of a frame add up to the frame, each instruction counted once, in the innermost open
stage (exclusive counts; the path makes the nesting explicit). The markers' own cost (a Python call
and a client request per entry and exit) is measured on a no-op stage and reported. The dumps carry
callgrind's per-function costs, summed here by object (`ob=`) into libraries and by function; frame
and stage totals are callgrind's own counter (`summary:`), which the per-function costs match to
within a few 0.1 % (both are printed). With --arm64-rootfs the same markers run in the arm64 build that
deploy/check-arm64.sh installed, under qemu-aarch64 with bench/qemu_insn_marks.c (a mark per dump, as
bench.instructions counts frames): stage totals only, since callgrind does not run under qemu-user.
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # before numpy loads BLAS: one thread, as measured everywhere

import argparse  # noqa: E402
import ctypes  # noqa: E402
import importlib  # noqa: E402
import json  # noqa: E402
import re  # noqa: E402
import tempfile  # noqa: E402
from collections import Counter, defaultdict  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any, Callable, Iterable  # noqa: E402

from bench.instructions import MARK_SYSCALL, count_frame_kinds, run_arm64_marks, run_worker_under_callgrind  # noqa: E402

KINDS = ("jsar", "jsar-re confident", "jsar-re verifier", "jsar-re lost", "csrt")
# (module, attribute path, stage name): the functions the markers wrap. A module-level function is
# wrapped where its callers look it up (module attribute or the defining module's globals).
STAGES: tuple[tuple[str, str, str], ...] = (
    ("jsar.tracking.jsar_tracker", "JsarTracker.locate", "locate"),
    ("jsar.tracking.jsar_tracker", "JsarTracker.commit", "commit"),
    ("jsar.tracking.jsar_tracker", "JsarTracker._update_size", "size filter"),
    ("jsar.features.patches", "sample_patches", "crop"),
    ("jsar.features.translation", "extract_features", "features"),
    ("jsar.features.fhog", "fhog_batch", "fHOG"),
    ("jsar.features._native", "kernels.colour_cells", "colour names"),
    ("jsar.tracking.translation", "TranslationFilter.sample_spectrum", "window + FFT"),
    ("jsar.tracking.translation", "TranslationFilter.response", "response"),
    ("jsar.dcf", "subpixel_peak", "peak"),
    ("jsar.tracking.translation", "TranslationFilter.train", "ADMM"),
    ("jsar.dcf", "_BoxDft.inverse", "box DFT"),
    ("jsar.dcf", "_BoxDft.forward", "box DFT"),
    ("jsar.fourier", "rfft2", "FFT"),
    ("jsar.fourier", "rfft2_channels_last", "FFT"),
    ("jsar.fourier", "irfft2", "FFT"),
    ("jsar.tracking.size_filter", "SizeFilter.sample", "size sample"),
    ("jsar.tracking.size_filter", "SizeFilter.shifted_sample", "size sample"),
    ("jsar.tracking.size_filter", "SizeFilter.spectrum", "size DFT"),
    ("jsar.tracking.size_filter", "SizeFilter.response", "size response"),
    ("jsar.tracking.size_filter", "SizeFilter.train", "size update"),
    ("jsar.redetect.jsar_re", "JsarReTracker._search_lost", "search"),
    ("jsar.redetect.jsar_re", "JsarReTracker._keep_checkpoint", "checkpoint copy"),
    ("jsar.redetect.jsar_re", "JsarReTracker._take", "take"),
    ("jsar.redetect.jsar_re", "JsarReTracker._coast", "coast"),
    ("jsar.redetect.memory", "DecisionFilter.score_sample", "decision: core sample"),
    ("jsar.redetect.memory", "DecisionFilter.score_windows", "decision: windows"),
    ("jsar.redetect.memory", "DecisionFilter.train", "decision: update"),
    ("jsar.redetect.colour_check", "ColourModel.learn", "colour checks"),
    ("jsar.redetect.colour_check", "ColourModel.relative_match", "colour checks"),
    ("jsar.redetect.colour_check", "AnchorColours.share", "colour checks"),
    ("jsar.redetect.appearance", "NetworkEmbedder.embed", "verifier embedding"),
    ("jsar.redetect.appearance", "NetworkEmbedder.gate_peaks", "whole-gate search"),
)
# The rows of the stage tables, (row, stages): a segment counts in the first row whose stages appear in
# its stage path in that order ("locate", "fHOG" matches "locate/features/fHOG"), else in "rest" (the
# Python between the stages). Rows may repeat (two entries, one row).
TRACKED_ROWS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("translation: crop", ("locate", "crop")),
    ("translation: fHOG", ("locate", "fHOG")),
    ("translation: colour names", ("locate", "colour names")),
    ("translation: gray, feature stack", ("locate", "features")),
    ("translation: FFT of the sample, inverse FFT of the response", ("locate", "FFT")),
    ("translation: cosine window", ("locate", "window + FFT")),
    ("translation: response product, peak (Newton)", ("locate", "response")),
    ("translation: response product, peak (Newton)", ("locate", "peak")),
    ("size filter: 169 crops", ("size filter", "crop")),
    ("size filter: 169 fHOG", ("size filter", "fHOG")),
    ("size filter: DFT over the grid (matrix products)", ("size filter", "size DFT")),
    ("size filter: response, update", ("size filter", "size response")),
    ("size filter: response, update", ("size filter", "size update")),
    ("translation update (ADMM): box DFTs (matrix products)", ("commit", "ADMM", "box DFT")),
    ("translation update (ADMM): FFTs", ("commit", "ADMM", "FFT")),
    ("translation update (ADMM): element-wise", ("commit", "ADMM")),
    ("jsar-re: decision filter on the core's sample", ("decision: core sample",)),
    ("jsar-re: decision filter update", ("decision: update",)),
    ("jsar-re: colour checks", ("colour checks",)),
    ("jsar-re: verifier embedding", ("verifier embedding",)),
    ("jsar-re: checkpoint copy", ("checkpoint copy",)),
)
LOST_ROWS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("core: translation detection (locate)", ("locate",)),
    ("decision filter on the core's sample", ("decision: core sample",)),
    ("windows: crops", ("decision: windows", "crop")),
    ("windows: fHOG", ("decision: windows", "fHOG")),
    ("windows: colour names", ("decision: windows", "colour names")),
    ("windows: FFTs", ("decision: windows", "FFT")),
    ("windows: gray, stacking, spectral products, peaks", ("decision: windows",)),
    ("verifier embedding", ("verifier embedding",)),
    ("whole-gate search", ("whole-gate search",)),
    ("colour checks", ("colour checks",)),
    ("core commit (coasting)", ("commit",)),
)
# Library groups of callgrind's objects (ob=), first match of the file name wins; numpy's and libc's
# functions are split further by name (NUMPY_LOOPS, LIBC_COPIES).
LIBRARIES: tuple[tuple[str, str], ...] = (
    (r"libpython|^python3", "interpreter (libpython)"),
    (r"_multiarray_umath", "numpy"),
    (r"pocketfft", "FFT (pocketfft: numpy.fft, scipy.fft)"),
    (r"openblas", "BLAS (OpenBLAS)"),
    (r"^cv2|opencv", "OpenCV (cv2)"),
    (r"^_kernels", "jsar kernels (_kernels)"),
    (r"onnxruntime", "onnxruntime (verifier network)"),
    (r"^libm[.-]", "libm"),
    (r"^libc[.-]", "libc"),
)
# numpy's element-wise work: typed ufunc loops (CFLOAT_multiply_X86_V3), casts and copies between
# layouts, reductions; the rest of numpy is per-call work (dispatch, iterator set-up, indexing, allocation).
NUMPY_LOOPS = r"^[A-Z]+_|^_aligned|^_strided|^_contig|^_cast|sum_of_products|^raw_array_assign"
LIBC_COPIES = r"^__mem(cpy|move|set)"
OTHER = "other"
CLIENT_REQUEST = "desc: Trigger: Client Request: "


@dataclass
class Dump:
    """One callgrind dump: its client-request label ("" for none) and exclusive instructions per (object, function)."""

    label: str
    costs: Counter = field(default_factory=Counter)
    summary: int = 0  # `summary:`, callgrind's instruction counter over the dump's interval
    total: int = 0  # `totals:`, the sum of the per-function costs as callgrind wrote them


def parse_dumps(texts: Iterable[str]) -> list[Dump]:
    """Dumps of one callgrind run, texts in dump (part) order: names compressed as "(id)" are defined
    once per run, not per file, so the files must be read in order and together."""
    names: dict[str, dict[str, str]] = {"ob": {}, "fn": {}}
    dumps = []
    for text in texts:
        dump, ob, fn, skip_next = Dump(""), "", "", False
        for line in text.splitlines():
            if not line:
                continue
            head = line[0]
            if head.isdigit() or head in "+-*":
                if skip_next:  # the inclusive cost of a call (calls= line): not this function's own
                    skip_next = False
                    continue
                parts = line.split()
                if len(parts) > 1:
                    dump.costs[(ob, fn)] += int(parts[1])
                continue
            key, _, value = line.partition("=")
            if key in ("ob", "cob"):
                name = _name(names["ob"], value)
                ob = name if key == "ob" else ob
            elif key in ("fn", "cfn"):
                name = _name(names["fn"], value)
                fn = name if key == "fn" else fn
            elif key == "calls":
                skip_next = True
            elif line.startswith(CLIENT_REQUEST):
                dump.label = line[len(CLIENT_REQUEST):].strip()
            elif line.startswith("summary:"):
                dump.summary = int(line.split()[1])
            elif line.startswith("totals:"):
                dump.total = int(line.split()[1])
        dumps.append(dump)
    return dumps


def _name(table: dict[str, str], value: str) -> str:
    """The name of a compressed "(id) name" / "(id)" reference, recording new ids in `table`."""
    match = re.match(r"\((\d+)\)\s*(.*)$", value)
    if match is None:
        return value.strip()
    ident, name = match.groups()
    if name:
        table[ident] = name
    return table.get(ident, f"({ident})")


def dump_files(folder: Path) -> list[Path]:
    """A run's callgrind.out* files in dump order (their part: number; the end-of-run dump last)."""
    def part(path: Path) -> int:
        with path.open(errors="replace") as handle:
            for line in handle:
                if line.startswith("part:"):
                    return int(line.split()[1])
                if line.startswith("positions:"):
                    break
        return 0
    return sorted(folder.glob("callgrind.out*"), key=part)


def library(object_path: str, function: str) -> str:
    """The library group of a function in a callgrind object (a file path); numpy and libc split by function."""
    base = object_path.rsplit("/", 1)[-1]
    group = next((group for pattern, group in LIBRARIES if re.search(pattern, base)), OTHER)
    if group == "numpy":
        return "numpy: element loops, casts" if re.search(NUMPY_LOOPS, function) else "numpy: per-call work"
    if group == "libc":
        return "libc: memcpy, memset" if re.search(LIBC_COPIES, function) else "libc: malloc, free, rest"
    return group


def by_library(costs: Counter) -> Counter:
    """Instructions per library group from instructions per (object, function)."""
    grouped: Counter = Counter()
    for (ob, fn), count in costs.items():
        grouped[library(ob, fn)] += count
    return grouped


def by_function(costs: Counter) -> Counter:
    """Instructions per (function, object file name) from instructions per (object path, function)."""
    grouped: Counter = Counter()
    for (ob, fn), count in costs.items():
        grouped[(fn, ob.rsplit("/", 1)[-1])] += count
    return grouped


def row_of(path: str, rows: tuple[tuple[str, tuple[str, ...]], ...]) -> str:
    """The table row of a segment with stage path "a/b/c": the first row whose stages appear in it in order,
    else "rest"."""
    stages = path.split("/") if path else []
    for row, pattern in rows:
        remaining = iter(stages)
        if all(any(stage == wanted for stage in remaining) for wanted in pattern):
            return row
    return "rest"


@dataclass
class Profile:
    """Sums over the counted frames of one (sequence, kind): callgrind's per-(object, function) costs; its
    instruction counter per stage path and per frame; segments (dumps)."""

    costs: Counter = field(default_factory=Counter)
    stages: Counter = field(default_factory=Counter)
    frames: Counter = field(default_factory=Counter)
    segments: int = 0


def collect(dumps: list[Dump]) -> dict[tuple[str, str], Profile]:
    """{(sequence, kind): Profile} from dumps labelled "sequence|kind|frame|stage path" (others ignored)."""
    profiles: dict[tuple[str, str], Profile] = defaultdict(Profile)
    for dump in dumps:
        parts = dump.label.split("|")
        if len(parts) != 4:
            continue
        sequence, kind, frame, path = parts
        if sequence == "calibration":
            continue
        profile = profiles[(sequence, kind)]
        profile.costs.update(dump.costs)
        profile.stages[path] += dump.summary
        profile.frames[frame] += dump.summary
        profile.segments += 1
    return dict(profiles)


# ----------------------------------------------------------------------------- under callgrind
class StageMarks:
    """The stage markers: wrap functions so that entering and leaving them dumps the counters, each
    dump labelled `frame label|open stages` (the segment that just ended belongs to the innermost)."""

    def __init__(self, dump: Callable[[str], None]) -> None:
        self.dump = dump
        self.frame = ""
        self.stack: list[str] = []

    def label(self) -> str:
        """The current segment's label."""
        return f"{self.frame}|{'/'.join(self.stack)}"

    def wrap(self, function: Callable[..., Any], stage: str) -> Callable[..., Any]:
        """`function` with a marker on entry and exit."""
        def marked(*args: Any, **kwargs: Any) -> Any:
            if not self.frame:  # outside a counted call (set-up, warm-up): nothing to mark
                return function(*args, **kwargs)
            self.dump(self.label())
            self.stack.append(stage)
            try:
                return function(*args, **kwargs)
            finally:
                self.dump(self.label())
                self.stack.pop()
        return marked

    def frame_call(self, frame: str, call: Callable[[], Any]) -> None:
        """Count one call as the frame `frame` (the caller zeroed the counters)."""
        self.frame, self.stack = frame, []
        try:
            call()
            self.dump(self.label())
        finally:
            self.frame = ""


def install(marks: StageMarks) -> None:
    """Replace every STAGES function by its marked wrapper (this process only)."""
    for module_name, attribute, stage in STAGES:
        owner: Any = importlib.import_module(module_name)
        *outer, name = attribute.split(".")
        for part in outer:
            owner = getattr(owner, part)
        setattr(owner, name, marks.wrap(getattr(owner, name), stage))


def worker(root: Path, sequences: list[str], frames: int, lost_frames: int, helper: Path | None) -> None:
    """Under callgrind (helper: the client-request library) or qemu with the marks plugin (helper None): set each
    sequence's trackers up uncounted, count each measured call by segments."""
    import cv2
    from threadpoolctl import threadpool_limits

    cv2.setNumThreads(1)
    threadpool_limits(limits=1)
    if helper is not None:
        cg = ctypes.CDLL(str(helper))
        cg.cg_dump.argtypes = [ctypes.c_char_p]
        dump: Callable[[str], None] = lambda label: cg.cg_dump(label.encode())
        cg.cg_start()
    else:  # mark i ends the segment labelled i (printed: qemu's plugin records only the count)
        libc = ctypes.CDLL(None, use_errno=True)
        marks_set = [0]

        def dump(label: str) -> None:
            libc.syscall(MARK_SYSCALL, ctypes.c_long(marks_set[0]))
            print(f"DUMP {marks_set[0]} {label}", flush=True)
            marks_set[0] += 1
    marks = StageMarks(dump)

    def counted(frame: str, call: Callable[[], Any]) -> None:
        # A dump, not CALLGRIND_ZERO_STATS: after a zero, callgrind's per-function costs kept part of what ran
        # before it (its counter did not), e.g. 56 M extra in the first frame after the set-up.
        dump("uncounted")
        marks.frame_call(frame, call)

    def noop() -> None:
        return None

    # The markers' cost: 100 calls of a no-op, plain and marked.
    marked_noop = marks.wrap(noop, "noop")
    counted("calibration|plain|0", lambda: [noop() for _ in range(100)])
    counted("calibration|marked|0", lambda: [marked_noop() for _ in range(100)])
    install(marks)
    for sequence in sequences:
        states = count_frame_kinds(root, sequence, frames, lost_frames, counted)
        print(f"{sequence}: counted; hidden frames' states {states}", flush=True)


def run_callgrind(worker_args: list[str], keep: Path | None) -> list[Dump]:
    """Run the worker under callgrind and parse its dumps (kept in `keep` when given)."""
    with tempfile.TemporaryDirectory(prefix="jsar-profile-") as tmp:
        folder = keep if keep is not None else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for old in folder.glob("callgrind.out*"):
            old.unlink()
        run_worker_under_callgrind("bench.profile", [*worker_args, "--worker"], folder, Path(tmp))
        paths = dump_files(folder)
        return parse_dumps(path.read_text(errors="replace") for path in paths)


def run_arm64(worker_args: list[str], rootfs: Path, cpu: str) -> list[Dump]:
    """Run the worker from the arm64 build in `rootfs` under qemu-aarch64 with the marks plugin: dumps with the
    instruction counter of each segment (`summary`) and no per-function costs (no callgrind under qemu-user)."""
    out, counts = run_arm64_marks(rootfs, "bench.profile", [*worker_args, "--worker-marks"], cpu)
    return dumps_from_marks(out, counts)


def dumps_from_marks(out: str, counts: dict[int, int]) -> list[Dump]:
    """The worker's segments from its printed "DUMP i label" lines and the plugin's count at each mark i: the
    segment labelled i ran between marks i - 1 and i (mark 0 only starts the first)."""
    dumps = []
    for line in out.splitlines():
        if line.startswith("DUMP "):
            _, mark, label = line.split(" ", 2)
            index = int(mark)
            if index > 0:
                dumps.append(Dump(label, summary=counts[index] - counts[index - 1]))
    return dumps


# ----------------------------------------------------------------------------- report
def marker_cost(dumps: list[Dump]) -> float:
    """Instructions one marked stage call adds (entry and exit), from the calibration dumps."""
    totals: Counter = Counter()
    for dump in dumps:
        parts = dump.label.split("|")
        if parts[0] == "calibration":
            totals[parts[1]] += dump.summary
    return (totals["marked"] - totals["plain"]) / 100.0


def summary(profiles: dict[tuple[str, str], Profile], per_call: float) -> dict[str, Any]:
    """Per sequence and kind, millions of instructions per frame: total, by library, by stage row, top functions."""
    out: dict[str, Any] = {"marker_instructions_per_stage_call": per_call, "sequences": {}}
    for (sequence, kind), profile in sorted(profiles.items()):
        frames = len(profile.frames)
        total = sum(profile.frames.values())
        rows = TRACKED_ROWS if kind != "jsar-re lost" else LOST_ROWS
        stage_rows: Counter = Counter()
        for path, count in profile.stages.items():
            stage_rows[row_of(path, rows)] += count
        stage_calls = (profile.segments - frames) / 2.0 / frames

        def per_frame(counter: Counter) -> dict[str, float]:
            return {str(key): count / frames / 1e6 for key, count in counter.most_common()}
        out["sequences"].setdefault(sequence, {})[kind] = {
            "frames": frames,
            "total": total / frames / 1e6,  # callgrind's counter
            "frame_totals": [count / 1e6 for _, count in sorted(profile.frames.items(), key=lambda f: int(f[0]))],
            "function_total": sum(profile.costs.values()) / frames / 1e6,  # its per-function costs, summed
            "stage_calls_per_frame": stage_calls,
            "marker_share": stage_calls * per_call * frames / total if total else 0.0,
            "libraries": per_frame(by_library(profile.costs)),
            "stage_paths": per_frame(profile.stages),
            "stages": per_frame(stage_rows),
            "functions": [(fn, ob, count / frames / 1e6) for (fn, ob), count in by_function(profile.costs).most_common()
                          if count >= frames * 1e4],  # >= 0.01 M a frame: the top list and the lookups of report()
        }
    return out


def report(result: dict[str, Any], top: int = 15) -> None:
    """Print the tables: by library, by stage (rows and full paths), top functions."""
    print(f"\nmarkers: {result['marker_instructions_per_stage_call']:.0f} instructions per marked stage call")
    for sequence, kinds in result["sequences"].items():
        shown = [kind for kind in KINDS if kind in kinds]
        print(f"\n{sequence}: millions of instructions per frame (% of the frame)")
        for kind in shown:
            k = kinds[kind]
            functions = f"per-function costs sum to {k['function_total']:.1f} M; " if k["libraries"] else ""
            print(f"  {kind:18s} {k['total']:7.1f} M, mean of {k['frames']} frames "
                  f"({min(k['frame_totals']):.1f}-{max(k['frame_totals']):.1f}); {functions}"
                  f"{k['stage_calls_per_frame']:.0f} stage calls a frame, markers {100 * k['marker_share']:.1f} %")
        per_function = any(kinds[kind]["libraries"] for kind in shown)
        if not per_function:
            print("\n(a), (c): no per-function costs (counted under qemu: totals by stage only)")
        else:
            print("\n(a) by library")
            groups = sorted({g for kind in shown for g in kinds[kind]["libraries"]},
                            key=lambda g: -kinds[shown[0]]["libraries"].get(g, 0.0))
            print(f"  {'library':40s} " + " ".join(f"{kind:>17s}" for kind in shown))
            for group in groups:
                print(f"  {group:40s} " + " ".join(
                    _cell(kinds[kind]["libraries"].get(group, 0.0), kinds[kind]["function_total"]) for kind in shown))
        for title, rows, wanted in (("(b) by stage, tracked frames", TRACKED_ROWS, ("jsar", "jsar-re confident")),
                                    ("(b) by stage, lost frame", LOST_ROWS, ("jsar-re lost",))):
            present = [kind for kind in wanted if kind in kinds]
            if not present:
                continue
            print(f"\n{title}")
            for row in (*dict.fromkeys(row for row, _ in rows), "rest"):
                if any(row in kinds[kind]["stages"] for kind in present):
                    print(f"  {row:56s} " + " ".join(_cell(kinds[kind]["stages"].get(row, 0.0), kinds[kind]["total"])
                                                      for kind in present))
        for kind in shown:
            print(f"\n(b) {kind}: exclusive per stage path")
            for path, count in sorted(kinds[kind]["stage_paths"].items()):
                print(f"  {path or '(top level)':70s} {_cell(count, kinds[kind]['total'])}")
        for kind in shown if per_function else ():
            print(f"\n(c) {kind}: top functions by exclusive instructions, and their instructions in the other kinds")
            costs = {kind: {(fn, ob): count for fn, ob, count in kinds[kind]["functions"]} for kind in shown}
            others = [other for other in shown if other != kind]
            print(f"  {'function':50s} {'object':28s} {kind:>17s} " + " ".join(f"{o:>17s}" for o in others))
            for fn, ob, count in kinds[kind]["functions"][:top]:
                print(f"  {fn[:50]:50s} {ob[:28]:28s} {_cell(count, kinds[kind]['function_total'])} " + " ".join(
                    _cell(costs[o].get((fn, ob), 0.0), kinds[o]["function_total"]) for o in others))


def _cell(millions: float, total: float) -> str:
    return f"{millions:8.2f} ({100 * millions / total:4.1f} %)"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data_root", type=Path)
    parser.add_argument("--sequences", default="OTB_Crossing",
                        help="comma-separated, e.g. OTB_Crossing,DTB70_MountainBike6")
    parser.add_argument("--frames", type=int, default=5, help="tracked frames counted per sequence")
    parser.add_argument("--lost-frames", type=int, default=2, help="lost frames (target hidden) counted per sequence")
    parser.add_argument("--top", type=int, default=15, help="functions listed per frame kind")
    parser.add_argument("--json", type=Path, default=None, help="write the summary here")
    parser.add_argument("--keep", type=Path, default=None, help="keep callgrind's dump files in this folder")
    parser.add_argument("--report", type=Path, default=None, metavar="JSON", help="print an earlier --json result")
    parser.add_argument("--arm64-rootfs", type=Path, default=None,
                        help="profile the arm64 build installed in this root file system (deploy/check-arm64.sh) under "
                             "qemu-aarch64: stage tables only, no per-function costs")
    parser.add_argument("--arm64-cpu", default="cortex-a72", help="qemu CPU model for --arm64-rootfs")
    parser.add_argument("--worker", type=Path, default=None, help=argparse.SUPPRESS)  # the run under callgrind
    parser.add_argument("--worker-marks", action="store_true", help=argparse.SUPPRESS)  # the run under qemu
    args = parser.parse_args(argv)
    if args.report is not None:
        report(json.loads(args.report.read_text()), args.top)
        return 0
    sequences = [s for s in args.sequences.split(",") if s]
    for sequence in sequences:
        if not (args.data_root / sequence / "img").is_dir():
            parser.error(f"{sequence} is not a sequence under {args.data_root}")
    if args.worker is not None or args.worker_marks:
        worker(args.data_root, sequences, args.frames, args.lost_frames, args.worker)
        return 0
    worker_args = [str(args.data_root.resolve()), "--sequences", ",".join(sequences), "--frames", str(args.frames),
                   "--lost-frames", str(args.lost_frames)]
    if args.arm64_rootfs is not None:
        dumps = run_arm64(worker_args, args.arm64_rootfs, args.arm64_cpu)
    else:
        dumps = run_callgrind(worker_args, args.keep)
    result = summary(collect(dumps), marker_cost(dumps))
    report(result, args.top)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
