"""JSAR-Re: JSAR with failure monitoring, re-detection by the decision filter, and re-acquisition.

Each frame the core tracker (JSAR) localises around its current centre, changing nothing; the failure
monitor (monitor.py) judges its peak; then the phase (Phase, TRANSITIONS) says what the frame does:
commit the detection, start a loss, or search (search.py, the decision filter of memory.py scoring). Each
step's rule is in its docstring; the reasons and the measured effect of each addition beyond the paper are
in docs/method.md ("JSAR-Re") and the ablation (`python -m bench.ablation`).
"""
from __future__ import annotations

import collections
import concurrent.futures
import copy
import dataclasses
import enum
import math
from dataclasses import dataclass
from typing import Any, Literal, Mapping

import numpy as np

from jsar.api import Box, TrackResult, validate_frame
from jsar.config import JsarParams
from jsar.redetect.appearance import (AppearanceMemory, DeferredEmbeddings, Embedder, Look, Verdict as Appearance,
                                     ring_boxes, shared_embedder)
from jsar.redetect.colour_check import AnchorColours, ColourModel
from jsar.redetect.memory import COAST_COMMIT_COST, DecisionFilter
from jsar.redetect.monitor import FailureMonitor, Verdict
from jsar.redetect.params import RedetectParams
from jsar.redetect.search import (Candidate, LossSearch, decayed_bar, gate_reach, predicted_centre, track_speed,
                                  track_velocity)
from jsar.tracking.jsar_tracker import JsarTracker, Localisation
from jsar.tracking.size_filter import bound_side


DeferredKind = Literal["learn", "watch"]  # the verifier's deferred work: a reliable frame learnt, or a watch check


class Phase(enum.Enum):
    """Where the tracker is in a loss's lifecycle; it moves only by TRANSITIONS."""

    TRACKING = "tracking"  # committing the core's detections
    LOST = "lost"  # searching (JsarReTracker.loss holds the search)
    PROBATION = "probation"  # tracking after a re-acquisition that a loss within accept.probation_frames refutes


# (phase, event) -> next phase: every change of JsarReTracker.phase is one of these (JsarReTracker._go).
TRANSITIONS: dict[tuple[Phase, str], Phase] = {
    (Phase.TRACKING, "tracked"): Phase.TRACKING,  # confident, or no loss may be declared: commit as plain JSAR
    (Phase.TRACKING, "lost"): Phase.LOST,  # a loss (peak, drift or appearance): search
    (Phase.PROBATION, "tracked"): Phase.PROBATION,  # committed within accept.probation_frames of the take
    (Phase.PROBATION, "held"): Phase.TRACKING,  # accept.probation_frames committed: the take holds
    (Phase.PROBATION, "refuted"): Phase.LOST,  # lost again on probation: the search the take ended resumes
    (Phase.PROBATION, "lost"): Phase.LOST,  # lost again on probation, the take verified throughout: a new loss
    (Phase.LOST, "searched"): Phase.LOST,  # nothing taken: the core coasts or waits
    (Phase.LOST, "core recovered"): Phase.TRACKING,  # the core confident again where the decision filter agrees
    (Phase.LOST, "confirmed at core"): Phase.TRACKING,  # a candidate confirmed where the coasting core is
    (Phase.LOST, "reacquired"): Phase.PROBATION,  # a candidate taken elsewhere: the core moves there
    (Phase.LOST, "reacquired unguarded"): Phase.TRACKING,  # the same with accept.probation_frames 0
}


@dataclass(frozen=True)
class SearchStep:
    """What one searching frame did (diagnostics): the best candidate, the bar, windows scored, taken."""

    best: Candidate | None
    bar: float
    windows: int  # candidates left to the decision, the core's own aside (while it coasts: those beating it)
    taken: bool
    own: Candidate  # the decision filter on the core's own detection sample
    coasting: bool = False  # the core followed its own detection on the last lost frame


@dataclass
class Probation:
    """What a refuted re-acquisition restores: the search it ended and the core, monitor and motion as they were."""

    loss: LossSearch
    core: JsarTracker
    monitor: FailureMonitor
    recent_centres: list[tuple[int, float, float]]
    taken: Candidate  # the refuted place: a candidate there must beat it (accept.refute_margin)
    frames_left: int  # committed frames until the take holds
    core_at_loss: JsarTracker | None
    verified: bool = False  # the verifier called the take and every check since the target (verify.hold_verified)


class JsarReTracker:
    """Long-term JSAR: `init(frame, box)`, `update(frame) -> TrackResult` (state tracking / lost / recovered)."""

    def __init__(self, params: JsarParams | None = None, redetect: RedetectParams | None = None,
                 embedder: Embedder | None = None) -> None:
        self.params = params if params is not None else JsarParams.jsar_re()
        self.params.validate()
        self.redetect = redetect if redetect is not None else RedetectParams()
        self.redetect.validate()
        # The verifier's network (jsar.learnt; loaded on the first init() when verify.enabled and none given).
        self.embedder = embedder
        self.appearance: AppearanceMemory | None = None  # the verifier's memories (appearance.py)
        self.reliable_frames = 0  # reliable committed frames since init (the verifier learns one in learn_frames)
        self.away_checks = 0  # the verifier's checks in a row that called the tracked box another object
        self.watched_now = False  # a deferred watch check was judged at the start of this frame
        # (due frame index, "learn" or "watch", embeddings): the verifier's deferred work (verify.defer_frames)
        self.deferred: collections.deque[tuple[int, DeferredKind, DeferredEmbeddings]] = collections.deque()
        self.worker: concurrent.futures.Executor | None = None  # where deferred embeddings run (None: when due)
        self.gate_template: tuple[np.ndarray, float] | None = None  # the whole-gate search's (template, scale)
        self.core = JsarTracker(self.params, use_size_filter=True)
        self.monitor = FailureMonitor(self.redetect.monitor)
        self.decision_filter: DecisionFilter | None = None
        self.colour = self._new_colour_model()
        self.anchor: AnchorColours | None = None  # the target's colours at selection (the drift check)
        self.drift_frames = 0  # tracked frames in a row whose box holds too few of them
        self.share = math.inf  # the last tracked frame's share of them (AnchorColours.share)
        # (frame index, core, decision filter, colour model) on the last checkpoint: a tracked frame whose
        # box clearly held the target's colours. A drift loss rolls back to it (what slid learnt the background).
        self.checkpoint: tuple[int, JsarTracker, DecisionFilter, ColourModel] | None = None
        self.loss_cause: str | None = None  # why the current loss began: "peak", "drift" or "appearance"
        self.phase = Phase.TRACKING
        self.loss: LossSearch | None = None  # the search of the current loss (phase LOST only)
        self.probation: Probation | None = None  # what a refutation restores (phase PROBATION only)
        self.core_at_loss: JsarTracker | None = None  # the core as it was when the loss began
        self.frame_index = -1
        self.reacquisitions = 0
        self.last_step: SearchStep | None = None
        self.last_event: str | None = None  # the TRANSITIONS event of the last update (diagnostics: how a loss ended)
        # (frame index, centre x px, centre y px) of the last committed frames: the motion model.
        self.recent_centres: collections.deque[tuple[int, float, float]] = collections.deque(
            maxlen=self.redetect.search.motion_frames)

    # ----------------------------------------------------------------- public API
    def init(self, frame: np.ndarray, box: Box) -> None:
        """Start tracking `box` (x, y, w, h px) in `frame`; trains the core and the decision filter."""
        self.core.init(frame, box)
        monitor = self.redetect.monitor  # the decision filter's reference follows its peaks at the monitor's rates
        self.decision_filter = DecisionFilter(self.params, self.core, monitor.reference_rate, monitor.reference_fall_rate)
        self.colour = self._new_colour_model()
        self.colour.learn(frame, self.core.box)
        colour = self.redetect.colour
        self.anchor = AnchorColours(frame, self.core.box, colour.surround_scale, colour.anchor_inner,
                                    colour.anchor_min_share)
        self.drift_frames = 0
        self.share = math.inf
        self.checkpoint = None
        self.loss_cause = None
        self.reliable_frames = 0
        self.away_checks = 0
        self.deferred.clear()
        self.appearance = None
        self.gate_template = None
        if self.redetect.verify.enabled:
            self.appearance = self._learn_appearance(frame, self.core.box)
            if self.redetect.verify.gate_map:
                self.gate_template = self.embedder.template(frame, self.core.box, self.redetect.verify.gate_map_cells)
        self.monitor = FailureMonitor(self.redetect.monitor)
        self.phase = Phase.TRACKING
        self.loss = None
        self.probation = None
        self.core_at_loss = None
        self.frame_index = 0
        self.reacquisitions = 0
        self.last_step = None
        self.recent_centres.clear()
        self._remember_position()

    def load_models(self) -> None:
        """Load now what init() would load on first use: the verifier's network (about 1 s; one per process)."""
        if self.redetect.verify.enabled and self.embedder is None:
            self.embedder = shared_embedder()

    def set_verifier_worker(self, worker: concurrent.futures.Executor | None) -> None:
        """Run the verifier's deferred embeddings (verify.defer_frames) on `worker`, a one-thread executor on
        another core, while the tracker goes on, and share a lost frame's work with it (part of the turned windows'
        features, half of its looks); None: all on the tracking thread. The same boxes either way."""
        self.worker = worker

    def run_deferred(self) -> None:
        """Compute the deferred embeddings now (a benchmark's way to count them apart from update())."""
        for _, _, job in self.deferred:
            job.rows()

    def set_side_bounds(self, side_bounds_px: tuple[float, float] | None) -> None:
        """Bound the box side sqrt(w*h) to (lo, hi) px (None: unbounded), for the core's size estimate
        and for re-acquired boxes; see JsarTracker.set_side_bounds. init() clears it."""
        self.core.set_side_bounds(side_bounds_px)

    @property
    def box(self) -> Box:
        """The current box (x, y, w, h) px: the core's (while lost, where it coasts or waits)."""
        return self.core.box

    def update(self, frame: np.ndarray) -> TrackResult:
        """Track one frame: localise, then track, start a loss or search it; the phase moves by TRANSITIONS."""
        if self.decision_filter is None:
            raise RuntimeError("tracker used before init(frame, box)")
        frame = validate_frame(frame)
        self.frame_index += 1
        self.last_step = None
        self._apply_due()
        loc, verdict = self._localise(frame)
        if self.phase is not Phase.LOST:
            cause = self._loss_cause(frame, loc, verdict)
            if cause is None:
                self._go(self._track_frame(frame, loc, verdict))
                return TrackResult(box=self.core.box, score=loc.peak, state="tracking")
            self.loss_cause = cause
            if self.phase is Phase.PROBATION and not self._verified_take():
                self._refute()
                self._go("refuted")
                loc, verdict = self._localise(frame)  # the restored core localises afresh
            else:
                self.probation = None  # a verified take lost again: nothing to restore, a loss of its own
                loc, verdict = self._start_loss(frame, loc, verdict)
                self._go("lost")
        event, score = self._search_lost(frame, loc, verdict)
        self._go(event)
        return TrackResult(box=self.core.box, score=score, state="lost" if self.phase is Phase.LOST else "recovered")

    def _go(self, event: str) -> None:
        """Move the phase by TRANSITIONS (KeyError: no such transition); leaving LOST ends the loss."""
        left, self.phase = self.phase, TRANSITIONS[(self.phase, event)]
        self.last_event = event
        if self.phase is Phase.LOST and left is not Phase.LOST:  # a watch check of the track that ended is moot
            self.deferred = collections.deque(job for job in self.deferred if job[1] != "watch")
        if left is Phase.LOST and self.phase is not Phase.LOST:
            self.loss, self.drift_frames, self.away_checks, self.loss_cause = None, 0, 0, None
        assert (self.phase is Phase.LOST) == (self.loss is not None)
        assert (self.phase is Phase.PROBATION) == (self.probation is not None)

    def _localise(self, frame: np.ndarray) -> tuple[Localisation, Verdict]:
        """The core's detection around its centre (nothing updated) and the monitor's verdict on its peak."""
        loc = self.core.locate(frame)
        return loc, self.monitor.assess(loc.peak, self.core.box, (frame.shape[1], frame.shape[0]), self.frame_index)

    def _loss_cause(self, frame: np.ndarray, loc: Localisation, verdict: Verdict) -> str | None:
        """Why this tracked frame is a loss: "peak" (the monitor), "drift" or "appearance"; None: it is not."""
        # Not the monitor's size limits: a box that grew onto background past max_area is what this catches.
        warm = self.frame_index >= self.redetect.monitor.warmup_frames
        drifted = self._drifted(frame, loc) and warm
        away = not drifted and self._looks_away(frame, loc) and warm
        return "peak" if verdict.lost else "drift" if drifted else "appearance" if away else None

    def _track_frame(self, frame: np.ndarray, loc: Localisation, verdict: Verdict) -> str:
        """Commit the detection as plain JSAR; the event: "held" on probation's last frame, else "tracked"."""
        # The decision filter's score on the core's sample is needed only where the filter learns the frame.
        self._commit(frame, loc, verdict.reliable, self._score_core_sample(loc) if verdict.reliable else None)
        self._keep_checkpoint()
        if self.probation is None:
            return "tracked"
        self.probation.frames_left -= 1
        if self.probation.frames_left > 0:
            return "tracked"
        self.probation = None
        return "held"

    def _start_loss(self, frame: np.ndarray, loc: Localisation, verdict: Verdict) -> tuple[Localisation, Verdict]:
        """A new loss: a drift or appearance loss rolls back to the checkpoint; the search starts at the core."""
        if self.loss_cause in ("drift", "appearance") and self.checkpoint is not None:
            loc, verdict = self._roll_back(frame, loc)
        self.loss = self._new_loss()
        self.core_at_loss = copy.deepcopy(self.core)
        return loc, verdict

    def _drifted(self, frame: np.ndarray, loc: Localisation) -> bool:
        """Whether the box at the core's detection has held too few of the target's colours at selection
        (colour.drift_share) on colour.drift_frames tracked frames in a row: the track slid off the target
        onto background while its peak stayed confident (the core learnt the background as it slid)."""
        assert self.anchor is not None
        minimum = self.redetect.colour.drift_share
        if minimum <= 0 or not self.anchor.usable:
            return False
        self.share = self.anchor.share(frame, self._detection_box(loc))
        self.drift_frames = self.drift_frames + 1 if self.share < minimum else 0
        return self.drift_frames >= self.redetect.colour.drift_frames

    def _looks_away(self, frame: np.ndarray, loc: Localisation) -> bool:
        """Whether the verifier called the box at the core's detection another object on verify.watch_count
        checks in a row, one check per verify.watch_frames tracked frames: a confident slide onto a look-alike
        or the background that kept the target's colours."""
        verify = self.redetect.verify
        if self.appearance is None or self.embedder is None or verify.watch_frames == 0:
            return False
        # Deferred, except on probation (its checks decide verify.hold_verified within its frames)
        if verify.defer_frames > 0 and self.probation is None:
            if self.frame_index % verify.watch_frames == 0:
                self._defer("watch", frame, np.array([self._detection_box(loc)]))
            return self.watched_now and self.away_checks >= verify.watch_count  # a check judged by _apply_due
        if self.frame_index % verify.watch_frames:
            return False
        look = self.appearance.judge(self.embedder.embed(frame, np.array([self._detection_box(loc)])))[0]
        if self.probation is not None and look.verdict is not Appearance.TARGET:
            self.probation.verified = False
        self.away_checks = self.away_checks + 1 if self._away(look) else 0
        return self.away_checks >= verify.watch_count

    def _away(self, look: Look) -> bool:
        """Whether the look at the core's box (a watch check, the core's own way out of a loss) is another object:
        "other", or under verify.selection_floor to the selection's look (the target memory learns along a slow
        slide; the selection's look does not)."""
        return look.verdict is Appearance.OTHER or look.selection < self.redetect.verify.selection_floor

    def _detection_box(self, loc: Localisation) -> Box:
        """The box (x, y, w, h px) at the core's detection `loc`, at the core's size."""
        w, h = self.core.size_wh
        return (loc.centre_xy[0] - w / 2.0, loc.centre_xy[1] - h / 2.0, w, h)

    def _keep_checkpoint(self) -> None:
        """After a committed tracked frame: the core, decision filter and colour model become the checkpoint
        when the box clearly held the target's colours at selection (colour.clear_share) and the last
        checkpoint is colour.checkpoint_frames old (one copy, so the filters they share stay shared)."""
        colour = self.redetect.colour
        if self.anchor is None or not self.anchor.usable or colour.drift_share <= 0 or self.share < colour.clear_share:
            return  # no drift check, nothing to roll back for; or the box did not clearly hold the colours
        if self.checkpoint is not None and self.frame_index - self.checkpoint[0] < colour.checkpoint_frames:
            return
        assert self.decision_filter is not None
        core, decision_filter, model = copy.deepcopy((self.core, self.decision_filter, self.colour))
        self.checkpoint = (self.frame_index, core, decision_filter, model)

    def _roll_back(self, frame: np.ndarray, loc: Localisation) -> tuple[Localisation, Verdict]:
        """A drift loss: the core, decision filter and colour model as at the checkpoint (their size and
        look before the slide), the core moved to where the drifted one found its detection; its own
        detection there, judged against the monitor's reference (nothing is updated)."""
        assert self.checkpoint is not None
        _, core, decision_filter, model = copy.deepcopy(self.checkpoint)
        self.core, self.decision_filter, self.colour = core, decision_filter, model
        self.core.relocate(loc.centre_xy)
        loc = self.core.locate(frame)
        confident, reliable = self.monitor.judge(loc.peak)
        last = self.recent_centres[-1]
        self.recent_centres.clear()  # the drifted track's motion is the background's: keep its last place only
        self.recent_centres.append(last)
        return loc, Verdict(confident, reliable, True, self.monitor.reference)

    def _score_core_sample(self, loc: Localisation) -> Candidate:
        """The decision filter on the core's detection sample (before the core moves): peak px and score."""
        assert self.decision_filter is not None
        return self.decision_filter.score_detection(loc, self.core)

    @staticmethod
    def _within_a_side(found: Candidate, loc: Localisation, loss: LossSearch) -> bool:
        """Whether the decision filter's peak lies within one target side of the core's detection (their
        boxes overlap): only then may the loss end at the core's box. A coasting core can sit on the
        occluder next to the target while the decision filter's peak, in the same window, is on the target."""
        return found.distance_sides(loc.centre_xy, loss.side_px) < 1.0

    def _predicted_centre(self) -> tuple[float, float]:
        return predicted_centre(list(self.recent_centres), self.frame_index, self.redetect.search.predict_max_frames)

    def _verified_take(self) -> bool:
        """Whether the take on probation stands although lost again (verify.hold_verified): the verifier called it
        the target when taken and on every check since. Its loss is then a new loss from the track, not a return to
        the search the take ended with the take's place barred: a target taken back at an occluder's edge and lost
        again as it went further under comes out near that place (bench.occlusions), and a fast target has moved on
        from where the old search waited."""
        return self.redetect.verify.hold_verified and self.probation is not None and self.probation.verified

    def _refute(self) -> None:
        """Restore the search a refuted re-acquisition ended; its place joins the refuted ones."""
        assert self.probation is not None
        kept, self.probation = self.probation, None
        self.core, self.monitor, self.core_at_loss = kept.core, kept.monitor, kept.core_at_loss
        self.recent_centres.clear()
        self.recent_centres.extend(kept.recent_centres)
        self.loss = kept.loss
        # The counts towards a way out start afresh: what passed before the take proved nothing.
        self.loss.pending, self.loss.confirmations, self.loss.core_agreements = None, 0, 0
        self.loss.refuted.append(kept.taken)

    # ----------------------------------------------------------------- steps
    def _commit(self, frame: np.ndarray, loc: Localisation, reliable: bool, own: Candidate | None) -> None:
        """Commit the core's detection; the decision filter learns it when reliable (own: its score there,
        needed then)."""
        assert self.decision_filter is not None
        self.core.commit(frame, loc)
        self._remember_position()
        if reliable:
            assert own is not None
            self.decision_filter.train(self.core, own.score)
            self.colour.learn(frame, self.core.box)
            self.reliable_frames += 1
            if self.appearance is not None and self.reliable_frames % self.redetect.verify.learn_frames == 0:
                if self.redetect.verify.defer_frames > 0:
                    self._defer("learn", frame, self._appearance_boxes(frame, self.core.box))
                else:
                    self._learn_appearance(frame, self.core.box)
        else:
            self.decision_filter.skip()

    def _new_loss(self) -> LossSearch:
        """A search around the core's box (centre px, side sqrt(w*h) px), starting now."""
        x, y, w, h = self.core.box
        return LossSearch((x + w / 2.0, y + h / 2.0), math.sqrt(w * h), self.redetect.search, self.redetect.accept)

    def _may_coast(self, loc: Localisation, loss: LossSearch) -> bool:
        """Whether the core's detection `loc` may coast on this lost frame if nothing is taken (_coast), the
        verifier's search.coast_unless_other aside: known once the search is aimed (_aim), before any window."""
        radius = self.redetect.search.coast_radius_sides * loss.side_px
        near = math.hypot(loc.centre_xy[0] - loss.anchor_xy[0], loc.centre_xy[1] - loss.anchor_xy[1]) <= radius
        # The motion model follows a coasting core: on still ground that the verifier calls another object the
        # prediction would stay on the core, and every lattice window would have to beat it (_beating_the_core).
        # A drift or appearance loss began because the core's place was judged not the target: a coast there
        # relearns it, and the prediction, following the coast, holds the search on it.
        refused = self.loss_cause in ("drift", "appearance") and not self.redetect.search.coast_after_drift
        # A coast the decision filter never confirms may be on still ground (the closed loop's camera coasting past
        # it): bounded, the search is no longer held on it (_beating_the_core) nor the prediction with it.
        limit = self.redetect.search.coast_max_frames
        spent = limit > 0 and loss.coasted_frames >= limit
        return near and not refused and not spent

    def _speculate_coast(self, frame: np.ndarray, loc: Localisation,
                         loss: LossSearch) -> concurrent.futures.Future[JsarTracker] | None:
        """With a verifier worker, a copy of the core committing `loc` as a coast would, made there while this
        thread scores the windows (a coasting commit on top of a full window budget passed 2x a tracked frame's
        instructions; docs/results-cost.md); None without a worker, where the frame cannot coast, or where the
        verifier's verdict decides it (search.coast_unless_other). _coast uses it when the frame coasts: the same
        core as committing there, since the copy and the core are the same state."""
        if self.worker is None or self.redetect.search.coast_unless_other or not self._may_coast(loc, loss):
            return None
        return self.worker.submit(_committed, copy.deepcopy(self.core), frame, loc,
                                  self.redetect.search.coast_learns_size)

    def _coast(self, frame: np.ndarray, loc: Localisation, loss: LossSearch,
               speculation: concurrent.futures.Future[JsarTracker] | None = None) -> None:
        """A lost frame with nothing taken: the core commits its detection as plain JSAR when it lies
        within coast_radius_sides of where the target was going (a target still there whose look
        changed moves on as predicted; an absent one's background does not), the loss's cause is the
        monitor's (unless search.coast_after_drift), the loss has not coasted search.coast_max_frames yet and,
        with search.coast_unless_other, the verifier does not call it another object; else the core waits at the
        prediction, learning nothing. The decision filter learns nothing either way. `speculation`: that commit
        made already (_speculate_coast)."""
        if self._may_coast(loc, loss) and not (self.redetect.search.coast_unless_other
                                               and self._looks_other(frame, loc.centre_xy)):
            if speculation is not None:
                self.core = speculation.result()
            else:
                self.core.commit(frame, loc, learn_size=self.redetect.search.coast_learns_size)
            self.decision_filter.skip()
            self._remember_position()  # the motion model follows a coasting target
            loss.coasting = True
            loss.coasted_frames += 1
        else:
            self.core.relocate(loss.anchor_xy)
            loss.coasting = False

    def _candidates(self, frame: np.ndarray, loss: LossSearch, own: Candidate,
                    worker_busy: float = 0.0) -> list[Candidate]:
        """The core sample's candidate, this frame's lattice windows (upright and turned), and a
        window on the pending candidate, or else on the last frame's best (at its angle; moved on by the
        track's velocity with search.focus_follows_motion); worker_busy: the verifier worker's queued work, in
        upright windows (DecisionFilter.score_windows)."""
        assert self.decision_filter is not None
        image = self.core.prepare(frame)
        centres, angles = loss.windows((frame.shape[1], frame.shape[0]))
        peaks = self._gate_peaks(frame, loss)
        if peaks:
            centres = np.vstack([centres, peaks])
            angles = np.append(angles, np.zeros(len(peaks)))
        focus = loss.pending if loss.pending is not None else loss.lead
        if focus is not None:
            # found on the last frame: a target that moves on is one frame's motion further now
            follows = self.redetect.search.focus_follows_motion
            vx, vy = track_velocity(list(self.recent_centres)) if follows else (0.0, 0.0)
            centres = np.vstack([centres, [[focus.x + vx, focus.y + vy]]])
            angles = np.append(angles, focus.angle_deg)
        side = loss.side_px  # the last confident size (a coasting core's may have drifted)
        found = self.decision_filter.score_windows(image, self.core.feature_colour_table, centres, side, angles,
                                                   self.worker, worker_busy)
        factor = self.redetect.search.turned_score_factor
        return [own] + [c if c.angle_deg == 0 else dataclasses.replace(c, score=c.score * factor) for c in found]

    def _search_lost(self, frame: np.ndarray, loc: Localisation, verdict: Verdict) -> tuple[str, float]:
        """One lost frame: the core's own way out, else a candidate taken, else the core coasts; (event, score)."""
        assert self.loss is not None
        loss = self.loss
        own = self._score_core_sample(loc)
        loss.lost_frames += 1
        bar, core_bar = self._bars(loss.lost_frames)
        if self._core_recovered(frame, loc, verdict, own, core_bar):
            self._commit(frame, loc, verdict.reliable, own)
            return "core recovered", loc.peak
        self._aim(loss)
        speculation = self._speculate_coast(frame, loc, loss)
        candidates = self._candidates(frame, loss, own, COAST_COMMIT_COST if speculation is not None else 0.0)
        if loss.coasting:
            candidates = self._beating_the_core(candidates, own, loss)
        taken, verified = self._take(frame, loss, candidates, bar, own)
        if taken is None:
            self._coast(frame, loc, loss, speculation)
            return "searched", loc.peak
        if speculation is not None:
            speculation.cancel()  # not coasting: the copy is dropped (if it already runs, it finishes unused)
        if loss.coasting and self._within_a_side(taken, loc, loss):
            # The decision filter confirms the target where the coasting core already is: keep the core's
            # own detection (its box follows the target; the filter's peak is coarser) and end the loss.
            self._commit(frame, loc, verdict.reliable, own)
            # The core's peak was judged against the level from before the loss; the target confirmed here may
            # look otherwise now (turned, shaded): that level would call the next frame lost again, a take
            # elsewhere restarts it too (_reacquire).
            self.monitor.restart()
            return "confirmed at core", taken.score
        return self._reacquire_on_probation(frame, loss, taken, verified), taken.score

    def _bars(self, lost_frames: int) -> tuple[float, float]:
        """The acceptance bars (raw peak) on this lost frame: a candidate's, and the core's own detection's."""
        assert self.decision_filter is not None
        # Never below zeta_s: a candidate must score as a frame the decision filter would learn from
        # (ending a loss on a weaker one took background, e.g. with a target whose own level is low).
        accept, zeta_s = self.redetect.accept, self.redetect.monitor.reliable_peak
        bar = decayed_bar(self.decision_filter.reference, lost_frames - 1, accept, zeta_s)
        # The core confident again where the decision filter peaks passes two tests: a lower start suffices.
        return bar, decayed_bar(self.decision_filter.reference, lost_frames - 1, accept, zeta_s, accept.core_fraction)

    def _core_recovered(self, frame: np.ndarray, loc: Localisation, verdict: Verdict, own: Candidate,
                        core_bar: float) -> bool:
        """Whether the core, confident where the decision filter peaks above core_bar, in the target's colours and
        not another object, has been so on accept.core_confirm_frames lost frames in a row."""
        assert self.loss is not None
        if (verdict.confident and own.score >= core_bar and self._within_a_side(own, loc, self.loss)
                and self._colour_passes(frame, loc.centre_xy, self.redetect.colour.core_min_match)
                and not self._looks_other(frame, loc.centre_xy)):
            self.loss.core_agreements += 1
            return self.loss.core_agreements >= self.redetect.accept.core_confirm_frames
        self.loss.core_agreements = 0
        return False

    def _aim(self, loss: LossSearch) -> None:
        """Centre the search where the target was going and open its motion gate for this lost frame."""
        loss.anchor_xy = self._predicted_centre()
        loss.reach_sides = gate_reach(track_speed(list(self.recent_centres), loss.side_px), loss.lost_frames,
                                      self.redetect.accept)

    def _beating_the_core(self, candidates: list[Candidate], own: Candidate, loss: LossSearch) -> list[Candidate]:
        """While the core coasts, the candidates at it or scoring accept.switch_margin x its own score."""
        # The core follows a target moving as predicted: a place elsewhere must clearly beat it.
        margin = self.redetect.accept.switch_margin * own.score
        return [c for c in candidates if c.score >= margin
                or c.distance_sides((own.x, own.y), loss.side_px) <= self.redetect.accept.confirm_radius_sides]

    def _take(self, frame: np.ndarray, loss: LossSearch, candidates: list[Candidate], bar: float,
              own: Candidate) -> tuple[Candidate | None, bool]:
        """The candidate taken on this lost frame (LossSearch.decide with the colour and verifier tests), or None;
        whether the verifier called it the target."""
        minimum, over_match = self.redetect.colour.min_match, self.redetect.verify.over_colour_match
        looks, unlooked = self._looks(frame, loss, candidates, bar)
        # The verifier's "target" stands in for the colour model's match (the embedding sees the colours too,
        # and the match refused targets whose box held other colours: a wakeboarder in spray), never for the
        # selection's colours (the drift check's: what slid onto grass must not come back through it).
        taken = loss.decide(candidates, bar, lambda c: self._colour_passes(
                                frame, (c.x, c.y), 0.0 if self._verified(looks, c) and over_match else minimum),
                            lambda c: math.inf if id(c) in unlooked else
                            self._candidate_bar(frame, c, bar, looks[id(c)][0] if id(c) in looks else None))
        self._learn_refused(candidates, bar, looks)
        best = max(candidates, key=lambda c: c.score)
        self.last_step = SearchStep(best, bar, len(candidates) - 1, taken is not None, own=own,
                                    coasting=loss.coasting)
        return taken, taken is not None and self._verified(looks, taken)

    def _reacquire_on_probation(self, frame: np.ndarray, loss: LossSearch, taken: Candidate, verified: bool) -> str:
        """Move the track to `taken` (`verified`: the verifier called it the target), keeping what a refutation
        restores (accept.probation_frames > 0); the event."""
        frames = self.redetect.accept.probation_frames
        kept = (Probation(loss, copy.deepcopy(self.core), copy.deepcopy(self.monitor), list(self.recent_centres),
                          taken, frames, self.core_at_loss, verified) if frames > 0 else None)
        self._reacquire(frame, taken)
        self.probation = kept
        return "reacquired" if kept is not None else "reacquired unguarded"

    def _candidate_bar(self, frame: np.ndarray, candidate: Candidate, bar: float, look: Look | None) -> float:
        """The bar a candidate must pass: none (inf) where the verifier calls it another object, or, in a loss the
        watch began, where its look is under verify.selection_floor to the selection's;
        verify.bar_fraction x `bar` where it calls it the target; colour.clear_bar_fraction x `bar` where its
        box clearly holds the target's colours at selection (colour.clear_share; a car that came back turned
        scores low on the decision filter's gradients but keeps its colours); else `bar`."""
        assert self.anchor is not None
        if look is not None and look.verdict is Appearance.OTHER:
            return math.inf
        floor = self.redetect.verify.selection_floor
        if look is not None and self.loss_cause == "appearance" and look.selection < floor:
            return math.inf  # the watch found the track off the selection's look: a take must be nearer it than that
        if look is not None and look.verdict is Appearance.TARGET:
            return min(self.redetect.verify.bar_fraction, self.redetect.colour.clear_bar_fraction) * bar
        colour = self.redetect.colour
        lower = colour.clear_bar_fraction * bar
        if not lower <= candidate.score < bar or not self.anchor.usable:
            return bar  # only a candidate between the two bars needs its colours looked at
        w, h = (self.core_at_loss if self.core_at_loss is not None else self.core).size_wh
        box = (candidate.x - w / 2.0, candidate.y - h / 2.0, w, h)
        return lower if self.anchor.share(frame, box) >= colour.clear_share else bar

    def _loss_box(self, centre_xy: tuple[float, float]) -> Box:
        """A box (x, y, w, h px) of the target's size at the loss centred on centre_xy px."""
        w, h = (self.core_at_loss if self.core_at_loss is not None else self.core).size_wh
        return (centre_xy[0] - w / 2.0, centre_xy[1] - h / 2.0, w, h)

    def _appearance_boxes(self, frame: np.ndarray, box: Box) -> np.ndarray:
        """(1 + ring_count, 4) boxes a reliable frame teaches the verifier: `box` (x, y, w, h px), then the
        look-alike windows on a ring around it."""
        verify = self.redetect.verify
        ring = ring_boxes(box, verify.ring_sides, verify.ring_count, (frame.shape[1], frame.shape[0]))
        return np.vstack([np.asarray(box, float)[None], ring])

    def _defer(self, kind: DeferredKind, frame: np.ndarray, boxes: np.ndarray) -> None:
        """Start the embeddings of `boxes` for `kind` ("learn" or "watch"), used verify.defer_frames from now."""
        assert self.embedder is not None
        job = DeferredEmbeddings(self.embedder, frame, boxes, self.worker)
        self.deferred.append((self.frame_index + self.redetect.verify.defer_frames, kind, job))

    def _apply_due(self) -> None:
        """The deferred work due at this frame: a learnt frame joins the memories; a watch check is judged
        (its track goes on: a loss drops them) and counts towards verify.watch_count."""
        self.watched_now = False
        while self.deferred and self.deferred[0][0] <= self.frame_index:
            _, kind, job = self.deferred.popleft()
            assert self.appearance is not None
            if kind == "learn":
                self._learn_rows(job.rows())
                continue
            look = self.appearance.judge(job.rows())[0]
            self.away_checks = self.away_checks + 1 if self._away(look) else 0
            self.watched_now = True

    def _learn_appearance(self, frame: np.ndarray, box: Box) -> AppearanceMemory:
        """The verifier learns a reliable frame at once: the target's embedding at `box` (x, y, w, h px) and the
        look-alikes' on a ring around it (one batch); on init the memories are made."""
        if self.embedder is None:
            self.embedder = shared_embedder()  # the network loads only where the verifier is used
        return self._learn_rows(self.embedder.embed(frame, self._appearance_boxes(frame, box)))

    def _learn_rows(self, rows: np.ndarray) -> AppearanceMemory:
        """The verifier's memories learn the embeddings of `_appearance_boxes`: rows[0] the target's, the rest the
        look-alikes'; the first frame makes the memories."""
        if self.appearance is None:
            self.appearance = AppearanceMemory(self.redetect.verify, rows[0])
        else:
            self.appearance.learn_target(rows[0])
        self.appearance.learn_others(rows[1:])
        return self.appearance

    def _looks(self, frame: np.ndarray, loss: LossSearch, candidates: list[Candidate],
               bar: float) -> tuple[dict[int, tuple[Look, np.ndarray]], set[int]]:
        """The verifier's Look at each candidate whose look is used, with its embedding (keyed by id; one batch):
        over the bar (a refused one is learnt: _learn_refused), or over the lowest bar a look can give and one the
        search may take (LossSearch.may_take). Embedding the others would change nothing: a window's peak outside
        the motion gate is never taken (early in a loss most of the lattice's are). With verify.lost_looks, at
        most that many, those near the pending candidate first (its confirmation), then the best; also the ids
        of the candidates that needed a look and got none (not to be taken on this frame)."""
        if self.appearance is None or self.embedder is None:
            return {}, set()
        lowest = min(self.redetect.verify.bar_fraction, self.redetect.colour.clear_bar_fraction) * bar
        near = [c for c in candidates if c.score >= bar or (c.score >= lowest and loss.may_take(c))]
        limit = self.redetect.verify.lost_looks
        skipped: list[Candidate] = []
        if 0 < limit < len(near):
            pending = loss.pending
            radius = self.redetect.accept.confirm_radius_sides

            def order(c: Candidate) -> tuple[bool, float]:
                at_pending = pending is not None and c.distance_sides((pending.x, pending.y), loss.side_px) <= radius
                return not at_pending, -c.score
            near = sorted(near, key=order)
            near, skipped = near[:limit], near[limit:]
        if not near:
            return {}, set()
        rows = self._embed_lost(frame, np.array([self._loss_box((c.x, c.y)) for c in near]))
        looks = {id(c): (look, row) for c, look, row in zip(near, self.appearance.judge(rows), rows)}
        return looks, {id(c) for c in skipped}

    def _embed_lost(self, frame: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        """(N, D) embeddings of a lost frame's boxes (N, 4) x, y, w, h px: with a verifier worker, the first half
        on this thread while the rest are made there (the same rows: a box's embedding does not depend on its
        batch)."""
        assert self.embedder is not None
        if self.worker is None or len(boxes) < 2:
            return self.embedder.embed(frame, boxes)
        half = (len(boxes) + 1) // 2
        others = self.worker.submit(self.embedder.embed, frame, boxes[half:])
        return np.vstack([self.embedder.embed(frame, boxes[:half]), others.result()])

    @staticmethod
    def _verified(looks: dict[int, tuple[Look, np.ndarray]], candidate: Candidate) -> bool:
        """Whether the verifier called `candidate` the target."""
        return id(candidate) in looks and looks[id(candidate)][0].verdict is Appearance.TARGET

    def _looks_other(self, frame: np.ndarray, centre_xy: tuple[float, float]) -> bool:
        """Whether the target-sized box centred on centre_xy px, where the core is, is another object (_away)."""
        if self.appearance is None or self.embedder is None:
            return False
        rows = self.embedder.embed(frame, np.array([self._loss_box(centre_xy)]))
        return self._away(self.appearance.judge(rows)[0])

    def _gate_peaks(self, frame: np.ndarray, loss: LossSearch) -> list[tuple[float, float]]:
        """The whole-gate search on this lost frame (verify.gate_map): the centres (px) where the target's
        template matches best over the motion gate, within the lattice's square and verify.gate_map_max_px."""
        verify = self.redetect.verify
        if self.gate_template is None or self.embedder is None or loss.lost_frames % verify.gate_map_frames:
            return []
        template, scale = self.gate_template
        radius = (min(loss.reach_sides, loss.area_sides() / 2.0) + 0.5) * loss.side_px
        radius = min(radius, verify.gate_map_max_px / (2.0 * scale))
        height, width = frame.shape[:2]
        x0, y0 = max(loss.anchor_xy[0] - radius, 0.0), max(loss.anchor_xy[1] - radius, 0.0)
        x1, y1 = min(loss.anchor_xy[0] + radius, float(width)), min(loss.anchor_xy[1] + radius, float(height))
        if x1 - x0 < 1 or y1 - y0 < 1:
            return []
        peaks = self.embedder.gate_peaks(frame, (x0, y0, x1 - x0, y1 - y0), scale, template,
                                         verify.gate_map_peaks, verify.gate_map_min_cosine)
        return [(x, y) for x, y, _ in peaks]

    def _learn_refused(self, candidates: list[Candidate], bar: float,
                       looks: dict[int, tuple[Look, np.ndarray]]) -> None:
        """Candidates over the bar that the verifier called other objects join the look-alikes (they would
        have been taken without it: the hardest negatives there are)."""
        refused = [looks[id(c)][1] for c in candidates if c.score >= bar and id(c) in looks
                   and looks[id(c)][0].verdict is Appearance.OTHER]
        if refused and self.appearance is not None:
            self.appearance.learn_others(np.vstack(refused))

    def _new_colour_model(self) -> ColourModel:
        colour = self.redetect.colour
        return ColourModel(colour.bins, colour.rate, colour.reference_rate, colour.surround_scale)

    def _colour_passes(self, frame: np.ndarray, centre_xy: tuple[float, float], minimum: float) -> bool:
        """Whether a box of the target's size at the loss, centred on centre_xy px, matches the target's
        colours at least `minimum` x as well as the tracked target did (colour_check.py; 0: always), and
        holds at least colour.drift_share x the share of the target's colours at selection (the drift
        check's test: a place the track would slide off again at once is no way out)."""
        assert self.anchor is not None
        w, h = (self.core_at_loss if self.core_at_loss is not None else self.core).size_wh
        box = (centre_xy[0] - w / 2.0, centre_xy[1] - h / 2.0, w, h)
        if self.anchor.share(frame, box) < self.redetect.colour.drift_share:
            return False
        return minimum <= 0 or self.colour.relative_match(frame, box) >= minimum

    def _reacquire(self, frame: np.ndarray, at: Candidate) -> None:
        """Move the track to `at`: the core (as before the loss, or as it coasted) that responds more
        strongly there, relocated, learns this frame (its size kept until its size filter recognises
        the target: params.AcceptParams.size_hold_fraction); if neither responds above zeta_e (a target that
        turned while hidden), or params.AcceptParams.reacquire is "retrain", the pre-loss core is
        retrained there from this frame (the paper's re-initialisation)."""
        assert self.decision_filter is not None
        height, width = frame.shape[:2]
        centre = (min(max(at.x, 0.0), float(width - 1)), min(max(at.y, 0.0), float(height - 1)))
        options = [self.core_at_loss] if self.core_at_loss is not None else []
        options.append(self.core)
        best: tuple[JsarTracker, Localisation] | None = None
        if self.redetect.accept.reacquire == "relocate":
            side = math.sqrt(options[0].size_wh[0] * options[0].size_wh[1])
            for option in options:
                moved = copy.deepcopy(option)
                moved.relocate(centre)
                loc = moved.locate(frame)
                # A core whose detection leaves the taken place follows what it learnt elsewhere (a coasting
                # core, the occluder it coasted on): moving it there would end the loss off the target.
                stays = math.hypot(loc.centre_xy[0] - centre[0], loc.centre_xy[1] - centre[1]) <= side
                if stays and loc.peak > self.redetect.monitor.confident_peak and (best is None or loc.peak > best[1].peak):
                    best = (moved, loc)
        if best is not None:
            self.core = best[0]
            if self.redetect.accept.size_hold_fraction > 0:
                # The size model knew the target as it was: keep the size until it recognises it again.
                self.core.hold_size_until_recognised(self.redetect.accept.size_hold_fraction)
            self.core.commit(frame, best[1])
        else:
            self.core = copy.deepcopy(options[0])
            w, h = bound_side(self.core.size_wh, self.core.side_bounds)
            self.core.reinitialise(frame, (centre[0] - w / 2.0, centre[1] - h / 2.0, w, h))
        self.decision_filter.skip()
        self.recent_centres.clear()  # a new track: no velocity across the jump
        self._remember_position()
        # The peak level of the re-acquired target starts a new reference (it may look otherwise now);
        # the decision filter's reference (the long-term one) is kept.
        self.monitor.restart()
        self.reacquisitions += 1

    def _remember_position(self) -> None:
        """Add the core's centre (px) on this frame to the motion model."""
        cx, cy = self.core.centre_xy
        self.recent_centres.append((self.frame_index, cx, cy))


def _committed(core: JsarTracker, frame: np.ndarray, loc: Localisation, learn_size: bool) -> JsarTracker:
    """`core` after committing `loc` on `frame` (a coast's commit, made on a verifier worker)."""
    core.commit(frame, loc, learn_size=learn_size)
    return core


def make_jsar_re(redetect: Mapping[str, Any] | None = None, **overrides: Any) -> JsarReTracker:
    """Registry factory for "jsar-re": JsarParams.jsar_re() with `overrides` and JSAR-Re's own
    parameters as nested groups, e.g. redetect={"search": {"windows_per_frame": 2}} (ValueError
    naming the key on an unknown key or an invalid value)."""
    return JsarReTracker(JsarParams.jsar_re(**overrides), RedetectParams.from_mapping(redetect))
