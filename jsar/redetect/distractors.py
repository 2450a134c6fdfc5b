"""Look-alikes seen while the target was tracked (pure parts): where they are, and the bar they set.

The decision filter scores a look-alike in the target's colours (another car, another member of a group)
as highly as the target, and the colour check cannot refuse it: most of JSAR-Re's wrong takes are of such a
place. But a look-alike is usually there while the target is still tracked elsewhere, and a place that
scored high while the target was somewhere else is not the target. So every `survey_every_frames` reliable
frames the decision filter also scores the lattice's first ring of windows around the tracked target; each
peak at least `min_distance_sides` from the target scoring `min_fraction` x the filter's reference or more is
a distractor. While lost, a candidate within `radius_sides` of a distractor must score `margin` x the
distractor's score to count (as near a refuted re-acquisition), and a candidate there that does not is taken
for the distractor itself: the distractor moves to it and keeps the higher score (a look-alike walking along is
followed as long as the search sees it).

Conventions: positions are full-frame pixels (x right, y down) of response peaks, distances in target sides
sqrt(w*h) at the last confident size, scores raw decision-filter peaks (MATLAB FFT convention, as eta_d).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from jsar.redetect.search import Candidate, lattice_offsets


def survey_centres(target_xy: tuple[float, float], side_px: float, stride_sides: float) -> np.ndarray:
    """(8, 2) px: the centres of the lattice's first ring (stride stride_sides) around target_xy px."""
    ring = lattice_offsets(stride_sides, stride_sides)  # area = stride: exactly the first ring
    return np.asarray(target_xy, dtype=np.float64) + ring * side_px


def surveyed(candidates: list[Candidate], target_xy: tuple[float, float], side_px: float, reference: float,
             min_fraction: float, min_distance_sides: float) -> list[Candidate]:
    """The distractors among a survey's candidates: peaks at least min_distance_sides from target_xy px scoring
    min_fraction x reference or more, the best first; two within min_distance_sides of each other count once."""
    found: list[Candidate] = []
    for c in sorted(candidates, key=lambda c: -c.score):
        if c.score < min_fraction * reference or c.distance_sides(target_xy, side_px) < min_distance_sides:
            continue
        if all(c.distance_sides((d.x, d.y), side_px) >= min_distance_sides for d in found):
            found.append(c)
    return found


def distractor_bar(candidate: Candidate, distractors: list[Candidate], side_px: float, radius_sides: float,
                   margin: float) -> float:
    """margin x the best score of the distractors within radius_sides of `candidate` (0: none)."""
    near = [d.score for d in distractors if candidate.distance_sides((d.x, d.y), side_px) <= radius_sides]
    return margin * max(near) if near else 0.0


def followed(distractors: list[Candidate], candidates: list[Candidate], side_px: float, radius_sides: float,
             margin: float) -> list[Candidate]:
    """The distractors after a lost frame's candidates: each moves to the best candidate within radius_sides of it
    that stays under its bar (margin x its score), its score the higher of the two (a survey window seldom
    centres a look-alike, and scores it lower the farther off); a candidate that beats the bar could be the
    target, and leaves the distractor where it was."""
    moved = []
    for d in distractors:
        near = [c for c in candidates if c.distance_sides((d.x, d.y), side_px) <= radius_sides
                and c.score < margin * d.score]
        if near:
            best = max(near, key=lambda c: c.score)
            d = dataclasses.replace(d, x=best.x, y=best.y, score=max(d.score, best.score))
        moved.append(d)
    return moved
