"""Soak run: the closed loop for a long time, checking the daemon's memory stays flat and its latency
does not grow. CI runs a few simulated minutes; the one-hour run is a manual command:

    python -m sim.soak --minutes 60            # lockstep; about 70-80 min of wall time on 2 cores
    python -m sim.soak --minutes 60 --pace realtime

Criteria (the same for both): RSS at the end minus RSS after warm-up (the first 20 % of the run,
at least 10 s) below `max_rss_growth_mib`; median end-to-end latency (daemon telemetry, frame read
to commands sent) over the last quarter of the frames at most `max_latency_ratio` times the median
of the second quarter plus `latency_slack_ms` (ratios, not absolute times: the machine is shared).
"""
from __future__ import annotations

import argparse
import statistics
from dataclasses import dataclass
from pathlib import Path

from sim.closed_loop import ClosedLoop, ClosedLoopConfig, RunResult
from sim.scene import SceneConfig


@dataclass(frozen=True)
class SoakCriteria:
    """Pass / fail thresholds (MiB, ratio, ms)."""

    max_rss_growth_mib: float = 20.0
    max_latency_ratio: float = 1.5
    latency_slack_ms: float = 5.0


@dataclass(frozen=True)
class SoakReport:
    """RSS after warm-up and at the end (KiB), latency medians of the 2nd and 4th quarters (ms)."""

    frames: int
    rss_warm_kib: int
    rss_end_kib: int
    latency_q2_ms: float
    latency_q4_ms: float
    daemon_alive: bool
    summary: dict

    @property
    def rss_growth_mib(self) -> float:
        return (self.rss_end_kib - self.rss_warm_kib) / 1024.0

    def failures(self, criteria: SoakCriteria) -> list[str]:
        """Human-readable reasons the run fails the criteria (empty = pass)."""
        problems = []
        if not self.daemon_alive:
            problems.append("daemon died")
        if self.rss_growth_mib > criteria.max_rss_growth_mib:
            problems.append(f"RSS grew {self.rss_growth_mib:.1f} MiB > {criteria.max_rss_growth_mib} MiB")
        limit = criteria.max_latency_ratio * self.latency_q2_ms + criteria.latency_slack_ms
        if self.latency_q4_ms > limit:
            problems.append(f"latency grew: last quarter {self.latency_q4_ms:.1f} ms > {limit:.1f} ms")
        return problems


def analyse(result: RunResult, duration_s: float) -> SoakReport:
    """Reduce a run to the soak figures (ValueError when it has too little data to judge)."""
    warm_s = max(10.0, 0.2 * duration_s)
    warm = [kib for t, kib in result.rss_kib if t >= warm_s]
    if len(warm) < 2:
        raise ValueError(f"soak needs RSS samples after the {warm_s:.0f} s warm-up; got {result.rss_kib}")
    latencies = [r.latency_ms for r in result.records if r.latency_ms is not None]
    if len(latencies) < 40:
        raise ValueError(f"soak needs latency samples; got {len(latencies)}")
    quarter = len(latencies) // 4
    return SoakReport(len(result.records), warm[0], warm[-1],
                      statistics.median(latencies[quarter:2 * quarter]), statistics.median(latencies[3 * quarter:]),
                      result.daemon_alive, result.summary())


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
    report = soak(args.minutes * 60.0, args.flavour, args.pace, args.seed, rss_every_s=30.0, live=True)
    criteria = SoakCriteria()
    print(f"frames {report.frames}; RSS after warm-up {report.rss_warm_kib / 1024:.1f} MiB, at the end "
          f"{report.rss_end_kib / 1024:.1f} MiB (growth {report.rss_growth_mib:+.1f} MiB); latency median "
          f"2nd quarter {report.latency_q2_ms:.1f} ms, last quarter {report.latency_q4_ms:.1f} ms")
    print(report.summary)
    problems = report.failures(criteria)
    print("PASS" if not problems else "FAIL: " + "; ".join(problems))
    return 0 if not problems else 1


if __name__ == "__main__":
    raise SystemExit(main())
