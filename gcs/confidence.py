"""The track's confidence for an operator, from the daemon's public track samples (`<prefix>/track`).

A sample's `score` is the tracker's raw peak (about 0.01-0.06 for JSAR / JSAR-Re, 1 or 0 for CSRT / KCF): no
operator can read that scale and no fixed threshold suits every target, so the station shows it as a
percentage of the best score of the current lock, and below LOW_CONFIDENCE the page marks the track "low
confidence" (a drifting or false lock shows before the tracker declares the target lost).

A lock begins when the samples go from idle / lost (or nothing) to tracking / recovered, and when this
station's own track command is accepted; a selection made by another ground station while tracking is not
seen (the reference carries over).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

LOW_CONFIDENCE = 0.7  # below this fraction of the lock's best score: "low confidence"
LOCKED_STATES = ("tracking", "recovered")


@dataclass
class ConfidenceGauge:
    """One drone's gauge: feed it every track sample in order (update); it keeps the best score of the lock."""

    reference: float | None = None  # the best score of the current lock (None: no lock yet)
    previous_state: str | None = None

    def new_lock(self) -> None:
        """A new selection: the next sample's score starts the reference again."""
        self.reference = None

    def update(self, sample: dict[str, Any]) -> dict[str, Any] | None:
        """The sample's confidence: {"percent": 0-100 of the lock's best score (rounded down), "low": below
        LOW_CONFIDENCE, "low_below": LOW_CONFIDENCE, "reference": that best score}; None while idle or without a
        usable score (missing, not finite, or no positive score in the lock yet)."""
        state = sample.get("state")
        score = sample.get("score")
        if state in LOCKED_STATES and self.previous_state not in LOCKED_STATES:
            self.new_lock()
        self.previous_state = state
        if state not in (*LOCKED_STATES, "lost"):
            return None
        if isinstance(score, bool) or not isinstance(score, (int, float)) or not math.isfinite(score):
            return None
        if state in LOCKED_STATES:
            self.reference = score if self.reference is None else max(self.reference, score)
        if self.reference is None or self.reference <= 0:
            return None
        ratio = min(1.0, max(0.0, score / self.reference))
        return {"percent": math.floor(100 * ratio + 1e-9), "low": ratio < LOW_CONFIDENCE, "low_below": LOW_CONFIDENCE,
                "reference": self.reference}
