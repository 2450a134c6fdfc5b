"""Soak run: the closed loop for a long time, checking the daemon's memory stays flat and its latency
does not grow. CI runs a few simulated minutes; the one-hour run is a manual command:

    python -m sim.soak --minutes 60            # lockstep; about 70-80 min of wall time on 2 cores
    python -m sim.soak --minutes 60 --pace realtime

Criteria (the same for both):

- Memory: the daemon's RSS is sampled every `rss_every_s`. Samples in the warm-up (the first 20 % of
  the run, at least 10 s) are ignored; the rest are split in two halves. Growth = RSS at the end
  minus the MAXIMUM RSS of the first half, and must stay below `max_rss_growth_mib`. A leak keeps
  growing past what was once reached; a one-off step (the first re-detection under the first
  occlusion: EdgeBoxes, FFT plans, allocator arenas) lands in the first half and then stays flat, so
  it does not count. The least-squares slope of the second half (MiB/h) is reported for information
  only: over a short run a 1 MiB allocator wobble is a large slope.
- Track integrity: the car is in the image (at least half of it, occluded or not) on at least
  `min_in_view_ratio` of all frames. Memory and latency alone pass a run whose tracker re-initialised
  onto background and steered the gimbal, and the vehicle, after it for the rest of the hour.
- Latency: median end-to-end latency (daemon telemetry, frame read to commands sent) over the last
  quarter of the frames at most `max_latency_ratio` times the median of the second quarter plus
  `latency_slack_ms` (ratios, not absolute times: the machine is shared).
"""
from __future__ import annotations

import argparse
import statistics
from dataclasses import dataclass
from pathlib import Path

from sim.closed_loop import ClosedLoop, ClosedLoopConfig, RunResult
from sim.daemon import exit_on_sigterm
from sim.scene import SceneConfig

MIN_RSS_SAMPLES = 4  # after the warm-up: two per half
MIN_LATENCY_SAMPLES = 40


@dataclass(frozen=True)
class SoakCriteria:
    """Pass / fail thresholds (MiB, ratio, ms)."""

    max_rss_growth_mib: float = 20.0
    max_latency_ratio: float = 1.5
    latency_slack_ms: float = 5.0
    min_in_view_ratio: float = 0.9


@dataclass(frozen=True)
class RssTrend:
    """Post-warm-up RSS: max of the first half and the last sample (KiB), second-half slope (MiB/h)."""

    samples: int
    reference_kib: int
    end_kib: int
    slope_mib_h: float

    @property
    def growth_mib(self) -> float:
        return (self.end_kib - self.reference_kib) / 1024.0


def warm_up_s(duration_s: float) -> float:
    """Seconds of a run whose RSS samples are ignored: 20 % of the run, at least 10 s."""
    return max(10.0, 0.2 * duration_s)


def rss_trend(rss_kib: list[tuple[float, int]], warm_s: float) -> RssTrend:
    """(time s, RSS KiB) samples -> trend after warm_s (ValueError with fewer than MIN_RSS_SAMPLES)."""
    after = [(t, kib) for t, kib in rss_kib if t >= warm_s]
    if len(after) < MIN_RSS_SAMPLES:
        raise ValueError(f"soak needs >= {MIN_RSS_SAMPLES} RSS samples after the {warm_s:.0f} s warm-up; "
                         f"got {len(after)} of {rss_kib}")
    half = len(after) // 2
    return RssTrend(len(after), max(kib for _, kib in after[:half]), after[-1][1],
                    slope_per_hour_mib(after[half:]))


def slope_per_hour_mib(samples: list[tuple[float, int]]) -> float:
    """Least-squares slope of (time s, RSS KiB) samples in MiB per hour (needs >= 2 distinct times)."""
    times = [t for t, _ in samples]
    if len(set(times)) < 2:
        raise ValueError(f"slope needs samples at >= 2 distinct times, got {samples}")
    slope_kib_s = statistics.linear_regression(times, [kib for _, kib in samples]).slope
    return slope_kib_s * 3600.0 / 1024.0


@dataclass(frozen=True)
class SoakReport:
    """Memory trend, latency medians of the 2nd and 4th quarters (ms), liveness, the run summary and the
    fraction of frames with the car in view."""

    frames: int
    rss: RssTrend
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
        if self.rss.growth_mib > criteria.max_rss_growth_mib:
            problems.append(f"RSS grew {self.rss.growth_mib:.1f} MiB past the first-half maximum "
                            f"> {criteria.max_rss_growth_mib} MiB")
        limit = criteria.max_latency_ratio * self.latency_q2_ms + criteria.latency_slack_ms
        if self.latency_q4_ms > limit:
            problems.append(f"latency grew: last quarter {self.latency_q4_ms:.1f} ms > {limit:.1f} ms")
        if self.in_view_ratio < criteria.min_in_view_ratio:
            problems.append(f"car in view on {100 * self.in_view_ratio:.1f} % of the frames < "
                            f"{100 * criteria.min_in_view_ratio:.0f} %: the track left the car")
        return problems

    def describe(self) -> str:
        """One paragraph for the console."""
        return (f"frames {self.frames}; RSS after warm-up ({self.rss.samples} samples): first-half max "
                f"{self.rss.reference_kib / 1024:.1f} MiB, end {self.rss.end_kib / 1024:.1f} MiB (growth "
                f"{self.rss.growth_mib:+.1f} MiB; second-half slope {self.rss.slope_mib_h:+.1f} MiB/h, for "
                f"information); latency median 2nd quarter {self.latency_q2_ms:.1f} ms, last quarter "
                f"{self.latency_q4_ms:.1f} ms; car in view on {100 * self.in_view_ratio:.1f} % of the frames")


def latency_quarters(latencies: list[float]) -> tuple[float, float]:
    """Medians (ms) of the 2nd and last quarter of the latencies, in frame order."""
    if len(latencies) < MIN_LATENCY_SAMPLES:
        raise ValueError(f"soak needs >= {MIN_LATENCY_SAMPLES} latency samples; got {len(latencies)}")
    quarter = len(latencies) // 4
    return statistics.median(latencies[quarter:2 * quarter]), statistics.median(latencies[3 * quarter:])


def analyse(result: RunResult, duration_s: float) -> SoakReport:
    """Reduce a run to the soak figures (ValueError when it has too little data to judge)."""
    trend = rss_trend(result.rss_kib, warm_up_s(duration_s))
    q2, q4 = latency_quarters([r.latency_ms for r in result.records if r.latency_ms is not None])
    return SoakReport(len(result.records), trend, q2, q4, result.daemon_alive, result.summary(),
                      result.in_view_ratio())


def soak(duration_s: float, flavour: str = "ardupilot", pace: str = "lockstep", seed: int = 0,
         rss_every_s: float = 5.0, video: Path | None = None, live: bool = False) -> SoakReport:
    """Run the closed loop for duration_s simulated seconds and analyse it."""
    cfg = ClosedLoopConfig(flavour=flavour, duration_s=duration_s, pace=pace, guidance="velocity",
                           scene=SceneConfig(seed=seed), rss_every_s=rss_every_s, video_path=video)
    with ClosedLoop(cfg) as loop:
        result = loop.run(live=live)
    return analyse(result, duration_s)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="closed-loop soak: flat daemon memory, no latency growth")
    parser.add_argument("--minutes", type=float, default=60.0)
    parser.add_argument("--flavour", choices=("ardupilot", "px4"), default="ardupilot")
    parser.add_argument("--pace", choices=("lockstep", "realtime"), default="lockstep")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    exit_on_sigterm()
    duration_s = args.minutes * 60.0
    # every 30 s for the hour; at least 20 samples in a short run (the trend needs >= 4 after warm-up)
    report = soak(duration_s, args.flavour, args.pace, args.seed, rss_every_s=min(30.0, duration_s / 20.0), live=True)
    criteria = SoakCriteria()
    print(report.describe())
    print(report.summary)
    problems = report.failures(criteria)
    print("PASS" if not problems else "FAIL: " + "; ".join(problems))
    return 0 if not problems else 1


if __name__ == "__main__":
    raise SystemExit(main())
