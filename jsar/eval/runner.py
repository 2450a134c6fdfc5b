"""Run trackers one-pass over a sequence, in lockstep on the same decoded frames, timing only them.

Every frame is decoded once (outside the timed region) and handed to every tracker in turn, so all
trackers see identical pixels and decoding never counts toward anyone's speed. A tracker's time is
its init on frame 0 plus its updates, measured with time.perf_counter around each call. Independent runs
(sequences, initial boxes) can go to forked single-threaded worker processes (run_indexed).
"""
from __future__ import annotations

import multiprocessing
import os
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from typing import Callable, Iterable, TypeVar

import cv2
import numpy as np

from jsar.api import Tracker

R = TypeVar("R")
THREAD_ENV_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                   "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")


@dataclass
class TrackerRun:
    """One tracker on one sequence: per-frame boxes (N, 4) 0-based x,y,w,h, scores, states, time (s)."""

    tracker: str
    sequence: str
    boxes: np.ndarray
    scores: np.ndarray
    states: list[str]
    frame_seconds: np.ndarray  # (N,) time of init (frame 0) or update (later frames), seconds
    error: str | None = None  # the exception text if the tracker raised; boxes after it are NaN
    failed_at: int | None = None

    @property
    def seconds(self) -> float:
        """Tracker time: init + all updates, seconds."""
        return float(np.nansum(self.frame_seconds))

    @property
    def frames_timed(self) -> int:
        """Frames the tracker processed (init frame included)."""
        return int(np.count_nonzero(~np.isnan(self.frame_seconds)))

    @property
    def fps(self) -> float:
        """Frames per second of tracker time (init + updates)."""
        return self.frames_timed / self.seconds if self.seconds > 0 else float("nan")


@dataclass
class _Live:
    """A tracker in the middle of a run (imperative shell's private state)."""

    tracker: Tracker | None
    run: TrackerRun = field(repr=False)


def limit_threads_env() -> None:
    """Set one-thread env vars for BLAS / OpenMP libraries loaded from now on (already-loaded ones
    are limited by threadpoolctl in the CLI), and OpenCV's own pool to one thread."""
    for name in THREAD_ENV_VARS:
        os.environ[name] = "1"
    cv2.setNumThreads(1)


def cap_loaded_pools() -> dict[str, object]:
    """Cap the thread pools of BLAS / OpenMP libraries already loaded to one (threadpoolctl), and
    OpenCV's to one; return what is in force: {"cv2": n, "pools": [{library, prefix, threads,
    architecture}]}. architecture is the CPU kernel set OpenBLAS chose (e.g. Haswell, SkylakeX; None for
    other libraries): JSAR-Re's loss decisions are thresholds on sums whose rounding depends on it, so a
    long-term result is reproduced bit for bit only on the same kernels (OPENBLAS_CORETYPE sets them).

    The cap is process-wide and deliberately not undone: this is for the evaluation / demo processes.
    """
    from threadpoolctl import threadpool_info, threadpool_limits

    cv2.setNumThreads(1)
    threadpool_limits(limits=1)
    return {"cv2": cv2.getNumThreads(),
            "pools": [{"library": p["internal_api"], "prefix": p["prefix"], "threads": p["num_threads"],
                       "architecture": p.get("architecture")} for p in threadpool_info()]}


def describe_pools(threads: dict[str, object]) -> str:
    """One line for a run's log: what cap_loaded_pools() put in force, e.g.
    "threads: cv2 1, libscipy_openblas 1 (SkylakeX)"."""
    pools = threads["pools"]
    assert isinstance(pools, list)
    return f"threads: cv2 {threads['cv2']}, " + ", ".join(
        f"{p['prefix']} {p['threads']}" + (f" ({p['architecture']})" if p["architecture"] else "") for p in pools)


def track_lockstep(frames: Iterable[np.ndarray], n_frames: int, init_box: np.ndarray,
                   trackers: dict[str, Callable[[], Tracker]], sequence: str,
                   on_frame: Callable[[], None] | None = None) -> dict[str, TrackerRun]:
    """Run every tracker over `frames` (init on frame 0 with `init_box`, 0-based x,y,w,h).

    `trackers` maps a name to a factory. A tracker that raises is recorded with its error and the
    frame it failed at (its remaining boxes are NaN, so they count as misses), the others go on.
    """
    box0 = np.asarray(init_box, dtype=np.float64)
    if box0.shape != (4,) or np.any(np.isnan(box0)):
        raise ValueError(f"{sequence}: the first frame's ground truth must be a box, got {init_box}")
    live: dict[str, _Live] = {}
    for name, factory in trackers.items():
        run = TrackerRun(name, sequence, np.full((n_frames, 4), np.nan), np.full(n_frames, np.nan),
                         ["absent"] * n_frames, np.full(n_frames, np.nan))
        live[name] = _Live(factory(), run)
    index = -1
    for index, frame in enumerate(frames):
        if index >= n_frames:
            raise ValueError(f"{sequence}: more frames than the {n_frames} announced")
        for name, item in live.items():
            if item.tracker is None:
                continue
            run = item.run
            try:
                if index == 0:
                    start = time.perf_counter()
                    item.tracker.init(frame, tuple(float(v) for v in box0))
                    run.frame_seconds[0] = time.perf_counter() - start
                    run.boxes[0] = box0
                    run.scores[0] = 1.0
                    run.states[0] = "tracking"
                else:
                    start = time.perf_counter()
                    result = item.tracker.update(frame)
                    run.frame_seconds[index] = time.perf_counter() - start
                    run.boxes[index] = result.box
                    run.scores[index] = result.score
                    run.states[index] = result.state
            except Exception as exc:  # noqa: BLE001 - recorded and reported, never swallowed
                run.error = f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=3)}"
                run.failed_at = index
                item.tracker = None
        if on_frame is not None:
            on_frame()
    if index + 1 != n_frames:
        raise ValueError(f"{sequence}: got {index + 1} frames, expected {n_frames}")
    return {name: item.run for name, item in live.items()}


# The task of the pool in progress: forked workers inherit it, so tasks that close over tracker factories
# (lambdas, bench.ablation's variants) need no pickling; only the task index and its result cross processes.
_POOL_TASK: Callable[[int, Callable[[], None] | None], object] | None = None


def _pool_worker_init() -> None:
    """Each worker single-threaded, as the parent: the caps are inherited through fork, set again to be sure."""
    limit_threads_env()
    cap_loaded_pools()


def _pool_call(index: int) -> object:
    assert _POOL_TASK is not None
    return _POOL_TASK(index, None)


def run_indexed(task: Callable[[int, Callable[[], None] | None], R], sizes: list[int], jobs: int = 1,
                progress: Callable[[int], None] | None = None) -> list[R]:
    """[task(i, on_frame) for i in range(len(sizes))], in this process (jobs 1: on_frame reports each frame
    to `progress`) or in `jobs` forked single-threaded worker processes (on_frame None; `progress` gets
    sizes[i] frames when task i ends). Results in index order; a task's exception is raised here."""
    if jobs < 1:
        raise ValueError(f"jobs must be >= 1, got {jobs}")
    if jobs == 1 or len(sizes) <= 1:
        on_frame = (lambda: progress(1)) if progress else None
        return [task(i, on_frame) for i in range(len(sizes))]
    if "fork" not in multiprocessing.get_all_start_methods():
        raise ValueError("jobs > 1 needs the fork start method (Linux)")
    global _POOL_TASK
    _POOL_TASK = task  # type: ignore[assignment]
    results: list[R | None] = [None] * len(sizes)
    pool = ProcessPoolExecutor(max_workers=min(jobs, len(sizes)), mp_context=multiprocessing.get_context("fork"),
                               initializer=_pool_worker_init)
    try:
        futures = {pool.submit(_pool_call, i): i for i in range(len(sizes))}
        for future in as_completed(futures):
            index = futures[future]
            results[index] = future.result()  # type: ignore[assignment]
            if progress:
                progress(sizes[index])
    except BaseException:
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    finally:
        pool.shutdown(wait=True)
        _POOL_TASK = None
    return results  # type: ignore[return-value]
