"""Soak run: the closed loop for a long time, checking the daemon's memory stays flat and its per-frame
work (hence its latency) does not grow. CI runs a few simulated minutes; the one-hour run is a manual command:

    python -m sim.soak --minutes 60            # lockstep; about 70-80 min of wall time on 2 cores
    python -m sim.soak --minutes 60 --pace realtime

Criteria (the same for both):

- Memory: the daemon's RSS is sampled every `rss_every_s`. Samples in the warm-up (the first 20 % of
  the run, at least 10 s) are ignored; of the rest, the second half must have a slope (MiB/h) of at
  most `max_rss_slope_mib_h`. A leak is a slope; a one-off allocation is a step, and the slope must
  not see it: the largest rise between two consecutive samples is taken out as a step (the samples
  after it are lowered by it), then the Theil-Sen slope (median of all pairwise slopes; robust to
  outliers and to a further step away from the window's middle) of what remains is the figure. The
  step the 45-s CI soak shows (about +24 MiB when the second occlusion's re-detection runs, flat
  after) is glibc's malloc, not the tracker: the first re-detection frees its ~12 MiB scoring arrays
  (mmapped), glibc then raises its mmap threshold to that size and its heap trim threshold to twice
  it, so the next, larger re-detection's arrays come from the heap and up to ~24 MiB of freed heap
  stays resident. With MALLOC_MMAP_THRESHOLD_=131072 (the threshold fixed) the same run is flat.
  The bound, 100 MiB/h, is a leak of about 1 KiB per frame at 30 fps.
- Track integrity: the car is in the image (at least half of it, occluded or not) on at least
  `min_in_view_ratio` of all frames. Memory and latency alone pass a run whose tracker re-initialised
  onto background and steered the gimbal, and the vehicle, after it for the rest of the hour.
- Per-frame work: the daemon's CPU time (all its threads, from /proc, sampled with the RSS) per
  simulated second, as ms per frame: the median over the run's last quarter at most
  `max_cpu_ratio` times the median over its second quarter plus `cpu_slack_ms`. CPU time, not wall
  latency: on a shared machine another process's burst doubles a quarter's wall latency (seen: 10.9
  -> 22.3 ms at load 12 on 2 cores, the daemon's CPU unchanged), while work the daemon itself adds
  (a growing search, a list scanned every frame) shows in its CPU time. The median end-to-end
  latency (daemon telemetry, frame read to commands sent) of both quarters is reported for
  information.
"""
from __future__ import annotations

import argparse
import statistics
from dataclasses import dataclass
from pathlib import Path

from sim.closed_loop import ClosedLoop, ClosedLoopConfig, RunResult
from sim.daemon import exit_on_sigterm
from sim.scene import SceneConfig
from sim.summary import BAR_IN_VIEW

MIN_RSS_SAMPLES = 4  # after the warm-up: two per half
MIN_LATENCY_SAMPLES = 40
MIN_CPU_RATES = 3  # CPU-rate intervals per judged quarter


@dataclass(frozen=True)
class SoakCriteria:
    """Pass / fail thresholds (MiB/h, ratio, ms)."""

    max_rss_slope_mib_h: float = 100.0
    max_cpu_ratio: float = 1.5
    cpu_slack_ms: float = 2.0  # ms of CPU per frame
    min_in_view_ratio: float = BAR_IN_VIEW  # the demo's bar, issue 42's: the car in view on 95 % of frames


@dataclass(frozen=True)
class RssTrend:
    """Post-warm-up RSS (KiB): its second half's slope without its largest step (MiB/h), that step (MiB,
    with the simulated time it ended at, s), and the first and last sample after the warm-up."""

    samples: int
    slope_mib_h: float
    step_mib: float
    step_at_s: float
    start_kib: int
    end_kib: int

    @property
    def growth_mib(self) -> float:
        """RSS at the end minus RSS at the end of the warm-up (information only)."""
        return (self.end_kib - self.start_kib) / 1024.0


def warm_up_s(duration_s: float) -> float:
    """Seconds of a run whose RSS samples are ignored: 20 % of the run, at least 10 s."""
    return max(10.0, 0.2 * duration_s)


def rss_trend(rss_kib: list[tuple[float, int]], warm_s: float) -> RssTrend:
    """(time s, RSS KiB) samples -> trend after warm_s (ValueError with fewer than MIN_RSS_SAMPLES)."""
    after = [(t, kib) for t, kib in rss_kib if t >= warm_s]
    if len(after) < MIN_RSS_SAMPLES:
        raise ValueError(f"soak needs >= {MIN_RSS_SAMPLES} RSS samples after the {warm_s:.0f} s warm-up; "
                         f"got {len(after)} of {rss_kib}")
    second_half = after[len(after) // 2:]
    stepless, step_kib, step_at_s = without_largest_step(second_half)
    return RssTrend(len(after), theil_sen_slope(stepless) * 3600.0 / 1024.0, step_kib / 1024.0, step_at_s,
                    after[0][1], after[-1][1])


def without_largest_step(samples: list[tuple[float, float]]) -> tuple[list[tuple[float, float]], float, float]:
    """(time s, value) samples in time order -> (the samples with their largest rise between two
    consecutive samples subtracted from every sample after it, that rise (>= 0), the time it ended at)."""
    if len(samples) < 2:
        return list(samples), 0.0, samples[0][0] if samples else 0.0
    rises = [b[1] - a[1] for a, b in zip(samples, samples[1:])]
    k = max(range(len(rises)), key=rises.__getitem__)
    step = max(rises[k], 0.0)
    return [(t, v - step if i > k else v) for i, (t, v) in enumerate(samples)], step, samples[k + 1][0]


def theil_sen_slope(samples: list[tuple[float, float]]) -> float:
    """Theil-Sen slope (median of the slopes of all sample pairs) of (time, value) samples, in value
    units per time unit (ValueError without two distinct times)."""
    slopes = [(b[1] - a[1]) / (b[0] - a[0]) for i, a in enumerate(samples) for b in samples[i + 1:] if b[0] != a[0]]
    if not slopes:
        raise ValueError(f"slope needs samples at >= 2 distinct times, got {samples}")
    return statistics.median(slopes)


def rss_leak_problem(trend: RssTrend, criteria: SoakCriteria) -> str | None:
    """Why the RSS trend is a leak by the criteria, or None."""
    if trend.slope_mib_h > criteria.max_rss_slope_mib_h:
        return (f"RSS keeps growing: {trend.slope_mib_h:.0f} MiB/h over the second half after the warm-up "
                f"> {criteria.max_rss_slope_mib_h:.0f} MiB/h (largest step {trend.step_mib:+.1f} MiB at "
                f"{trend.step_at_s:.1f} s left out)")
    return None


@dataclass(frozen=True)
class SoakReport:
    """Memory trend, CPU ms per frame and latency medians (ms) of the 2nd and 4th quarters, liveness, the
    run summary and the fraction of frames with the car in view."""

    frames: int
    rss: RssTrend
    cpu_q2_ms: float
    cpu_q4_ms: float
    latency_q2_ms: float
    latency_q4_ms: float
    daemon_alive: bool
    summary: dict
    in_view_ratio: float = 1.0

    def failures(self, criteria: SoakCriteria) -> list[str]:
        """Human-readable reasons the run fails the criteria (empty = pass)."""
        problems = []
        if not self.daemon_alive:
            problems.append("daemon died")
        leak = rss_leak_problem(self.rss, criteria)
        if leak is not None:
            problems.append(leak)
        limit = criteria.max_cpu_ratio * self.cpu_q2_ms + criteria.cpu_slack_ms
        if self.cpu_q4_ms > limit:
            problems.append(f"per-frame work grew: last quarter {self.cpu_q4_ms:.1f} ms of CPU a frame > "
                            f"{limit:.1f} ms ({criteria.max_cpu_ratio} x the second quarter's "
                            f"{self.cpu_q2_ms:.1f} ms + {criteria.cpu_slack_ms} ms)")
        if self.in_view_ratio < criteria.min_in_view_ratio:
            problems.append(f"car in view on {100 * self.in_view_ratio:.1f} % of the frames < "
                            f"{100 * criteria.min_in_view_ratio:.0f} %: the track left the car")
        return problems

    def describe(self) -> str:
        """One paragraph for the console."""
        return (f"frames {self.frames}; RSS after warm-up ({self.rss.samples} samples): "
                f"{self.rss.start_kib / 1024:.1f} -> {self.rss.end_kib / 1024:.1f} MiB; second half: slope "
                f"{self.rss.slope_mib_h:+.1f} MiB/h without its largest step ({self.rss.step_mib:+.1f} MiB at "
                f"{self.rss.step_at_s:.1f} s); CPU a frame, median, 2nd quarter {self.cpu_q2_ms:.1f} ms, last "
                f"quarter {self.cpu_q4_ms:.1f} ms; latency median 2nd quarter {self.latency_q2_ms:.1f} ms, last "
                f"quarter {self.latency_q4_ms:.1f} ms (information); car in view on {100 * self.in_view_ratio:.1f} % "
                f"of the frames")


def latency_quarters(latencies: list[float]) -> tuple[float, float]:
    """Medians (ms) of the 2nd and last quarter of the latencies, in frame order."""
    if len(latencies) < MIN_LATENCY_SAMPLES:
        raise ValueError(f"soak needs >= {MIN_LATENCY_SAMPLES} latency samples; got {len(latencies)}")
    quarter = len(latencies) // 4
    return statistics.median(latencies[quarter:2 * quarter]), statistics.median(latencies[3 * quarter:])


def cpu_quarters(cpu_s: list[tuple[float, float]], duration_s: float, fps: float) -> tuple[float, float]:
    """(time s, daemon CPU s) samples -> medians of CPU ms per frame (rate between consecutive samples /
    fps) over the intervals whose midpoints lie in the 2nd and in the last quarter of the run
    (ValueError with fewer than MIN_CPU_RATES intervals in either)."""
    rates = [((t0 + t1) / 2.0, (c1 - c0) / (t1 - t0) * 1e3 / fps)
             for (t0, c0), (t1, c1) in zip(cpu_s, cpu_s[1:]) if t1 > t0]
    q2 = [r for t, r in rates if 0.25 * duration_s <= t < 0.5 * duration_s]
    q4 = [r for t, r in rates if t >= 0.75 * duration_s]
    if len(q2) < MIN_CPU_RATES or len(q4) < MIN_CPU_RATES:
        raise ValueError(f"soak needs >= {MIN_CPU_RATES} CPU samples' intervals in the 2nd and in the last quarter; "
                         f"got {len(q2)} and {len(q4)} of {cpu_s}")
    return statistics.median(q2), statistics.median(q4)


def analyse(result: RunResult, duration_s: float, fps: float = 30.0) -> SoakReport:
    """Reduce a run to the soak figures (ValueError when it has too little data to judge)."""
    trend = rss_trend(result.rss_kib, warm_up_s(duration_s))
    cpu_q2, cpu_q4 = cpu_quarters(result.cpu_s, duration_s, fps)
    q2, q4 = latency_quarters([r.latency_ms for r in result.records if r.latency_ms is not None])
    return SoakReport(len(result.records), trend, cpu_q2, cpu_q4, q2, q4, result.daemon_alive, result.summary(),
                      result.in_view_ratio())


def soak(duration_s: float, flavour: str = "ardupilot", pace: str = "lockstep", seed: int = 0,
         rss_every_s: float = 5.0, video: Path | None = None, live: bool = False,
         workdir: Path | None = None) -> SoakReport:
    """Run the closed loop for duration_s simulated seconds and analyse it; workdir (kept) holds the daemon's
    config and log (None: a temporary directory)."""
    cfg = ClosedLoopConfig(flavour=flavour, duration_s=duration_s, pace=pace, guidance="velocity",
                           scene=SceneConfig(seed=seed), rss_every_s=rss_every_s, video_path=video)
    with ClosedLoop(cfg, workdir=workdir) as loop:
        result = loop.run(live=live)
    return analyse(result, duration_s, cfg.fps)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="closed-loop soak: flat daemon memory, no latency growth")
    parser.add_argument("--minutes", type=float, default=60.0)
    parser.add_argument("--flavour", choices=("ardupilot", "px4"), default="ardupilot")
    parser.add_argument("--pace", choices=("lockstep", "realtime"), default="lockstep")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workdir", type=Path,
                        help="keep the daemon's config and log (service.log: its event=search lines while lost) here")
    args = parser.parse_args(argv)
    exit_on_sigterm()
    duration_s = args.minutes * 60.0
    # every 30 s for the hour; at least 20 samples in a short run (the trend needs >= 4 after warm-up)
    if args.workdir is not None:
        args.workdir.mkdir(parents=True, exist_ok=True)
    report = soak(duration_s, args.flavour, args.pace, args.seed, rss_every_s=min(30.0, duration_s / 20.0), live=True,
                  workdir=args.workdir)
    criteria = SoakCriteria()
    print(report.describe())
    print(report.summary)
    problems = report.failures(criteria)
    print("PASS" if not problems else "FAIL: " + "; ".join(problems))
    return 0 if not problems else 1


if __name__ == "__main__":
    raise SystemExit(main())
