"""JSAR-Re's additions beyond the paper, one at a time, one thread:

    python -m bench.ablation DATA_ROOT [--seeds 0,1,2,3] [--variants a,b] [--json F] [--max-frames N]
        [--sequences a,b] [--kinds occlusion,out-of-view,real] [--lengths 5,15,40]

A variant is JSAR-Re's defaults with one addition switched off (or the paper's own choice restored),
written as a `redetect` override (jsar.create("jsar-re", redetect=...), params.RedetectParams); the
table of variants is VARIANTS below. Every chosen variant and "default" run in lockstep on the same
decoded frames (jsar.eval.runner), so they share the machine's load and their speeds compare: one
pass over DATA_ROOT (jsar.eval.evaluate.evaluate) and the long-term protocol for each seed
(evaluate_longterm: injected occlusion / out-of-view events plus the sequences' own absent runs).
The lockstep order rotates from one sequence run to the next: the first tracker after a frame's
decoding runs a few per cent slower, a bias that would otherwise fall on one variant.

Per variant: mean AUC and mean fps of the one pass, the worst per-sequence p99 / p50 update time of
the one pass and of the long-term runs, the long-term fps (frame-weighted), and the re-acquisition
and false re-initialisation rates per seed and pooled over seeds; each with its difference to
"default" (fps as a relative change). A markdown table on stdout, every number with --json.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any, Callable, Mapping

from jsar.eval.runner import cap_loaded_pools, describe_pools, limit_threads_env

limit_threads_env()  # before the trackers' modules (scipy, ...) are imported below

from tqdm import tqdm  # noqa: E402

from jsar.api import Tracker  # noqa: E402
from jsar.eval import dataset, evaluate, longterm, report  # noqa: E402
from jsar.redetect.params import RedetectParams  # noqa: E402

TRACKER = "jsar-re"
DEFAULT = "default"
# The one place the ablation's variants are defined: name -> redetect override {group: {key: value}}.
VARIANTS: dict[str, dict[str, dict[str, Any]]] = {
    # Loss = the paper's absolute zeta_e alone, no drop relative to the target's own peak level.
    "no-relative-drop": {"monitor": {"relative_drop": 0.0}},
    # The paper's eta_d: an absolute 0.02 decaying by 1.005 per failed frame, nothing relative.
    "absolute-eta-d": {"accept": {"fraction": 0.0, "floor": 0.0, "peak": 0.02}},
    # No lattice windows: the decision filter scores the core's own detection sample only.
    "no-budget-lattice": {"search": {"windows_per_frame": 0}},
    # The search stays on the last confident centre instead of following the target's velocity.
    "no-motion": {"search": {"predict_max_frames": 0}},
    # No turned windows: the decision filter scores upright windows only.
    "no-turned": {"search": {"turned_angles_deg": []}},
    # No coasting: while lost the core waits at the predicted centre instead of following its detection.
    "no-coast": {"search": {"coast_radius_sides": 0.0}},
    # No motion gate: a candidate may be taken anywhere (the value must be finite; 1e9 sides is nowhere).
    "no-gate": {"accept": {"gate_base_sides": 1e9}},
    # A candidate is taken on the first frame it passes the bar.
    "no-confirm": {"accept": {"confirm_frames": 0}},
    # Candidates may be taken from the first lost frame on.
    "no-holdoff": {"accept": {"holdoff_frames": 0}},
    # No colour check: a candidate above the bar (the core confident again included) is taken on its score.
    "no-colour": {"colour": {"min_match": 0.0, "core_min_match": 0.0}},
    # A take lets the core's size filter (of the target's look before the loss) estimate the size at once.
    "no-size-hold": {"accept": {"size_hold_fraction": 0.0}},
    # A re-acquisition lost again within a few frames stands: no refutation, no return to the search it ended.
    "no-probation": {"accept": {"probation_frames": 0}},
    # The core confident again on a single lost frame ends the loss (no second frame asked).
    "core-confirm-1": {"accept": {"core_confirm_frames": 1}},
    # The paper's re-initialisation: the core's filters retrained from the re-acquired frame.
    "retrain": {"accept": {"reacquire": "retrain"}},
    # The paper's omega grows without bound; 1000 sides is beyond any frame of up to 2000 px for a lost
    # target of 4 px and more (monitor.min_area_px2 16), and keeps the lattice (O(omega^2) offsets) in memory.
    "paper-omega": {"search": {"area_max_sides": 1000.0}},
    # The learnt uses (issue 45): the default is the verifier alone. No learnt model at all:
    "no-verifier": {"verify": {"enabled": False}},
    # The verifier and the whole-gate search (one network pass over the motion gate per lost frame):
    "verifier-and-gate-map": {"verify": {"gate_map": True}},
    # The whole-gate search alone: the network runs, but its verdicts never reach a decision (no cosine is
    # "target" at 1.0, none "other" under -1, no watch while tracking).
    "gate-map-alone": {"verify": {"gate_map": True, "min_similarity": 1.0, "reject_similarity": -1.0,
                                  "watch_frames": 0}},
}


def variant_overrides(name: str) -> dict[str, dict[str, Any]]:
    """The redetect override of variant `name` ({} for "default"); ValueError naming the known ones."""
    if name == DEFAULT:
        return {}
    if name not in VARIANTS:
        raise ValueError(f"unknown variant {name!r}; known: {', '.join(VARIANTS)}")
    return VARIANTS[name]


def variant_factories(names: list[str]) -> dict[str, Callable[[], Tracker]]:
    """Variant name -> zero-argument jsar-re factory with its overrides ("default" first, always);
    ValueError now on an unknown variant or an override params.RedetectParams rejects."""
    factories: dict[str, Callable[[], Tracker]] = {}
    for name in [DEFAULT] + [n for n in names if n != DEFAULT]:
        overrides = variant_overrides(name)
        RedetectParams.from_mapping(overrides)  # fail before an hour of tracking, naming the key
        factories[name] = evaluate.tracker_factories([TRACKER], {TRACKER: {"redetect": overrides}})[TRACKER]
    return factories


def describe(overrides: Mapping[str, Mapping[str, Any]]) -> str:
    """`group.key=value, ...` of an override ('-' when empty)."""
    return ", ".join(f"{group}.{key}={value:g}" if isinstance(value, float) else f"{group}.{key}={value}"
                     for group, values in overrides.items() for key, value in values.items()) or "-"


def _worst_ratio(entries: list[dict[str, Any]]) -> float | None:
    """The largest p99 / p50 update time over run entries (None if none is finite)."""
    ratios = [float(e["frame_ms_p99_over_p50"]) for e in entries]
    finite = [r for r in ratios if math.isfinite(r)]
    return max(finite) if finite else None


def _entries(result: Mapping[str, Any], name: str) -> list[dict[str, Any]]:
    """Every per-sequence run entry of tracker `name` in an evaluate / evaluate_longterm result."""
    return [seq["trackers"][name] for seq in result["sequences"].values() if name in seq["trackers"]]


def variant_row(name: str, one_pass: Mapping[str, Any], longterm_by_seed: Mapping[int, Mapping[str, Any]]
                ) -> dict[str, Any]:
    """One variant's numbers from a one-pass result and long-term results by seed (rates in [0, 1], fps)."""
    summary = one_pass["summary"][name]
    runs = {seed: _entries(result, name) for seed, result in longterm_by_seed.items()}
    by_seed = {seed: longterm.summarise_longterm([e["longterm"] for e in entries]) for seed, entries in runs.items()}
    pooled_runs = [e for entries in runs.values() for e in entries]
    frames = sum(int(e["frames_timed"]) for e in pooled_runs)
    seconds = sum(float(e["seconds"]) for e in pooled_runs)
    errors = list(summary["errors"]) + [f"seed {seed}: {msg}" for seed, result in longterm_by_seed.items()
                                        for msg in result["summary"][name]["errors"]]
    return {
        "overrides": variant_overrides(name),
        "sequences": summary["sequences"],
        "auc": summary["auc"],
        "precision": summary["precision"],
        "fps_mean": summary["fps_mean"],
        "fps_frame_weighted": summary["fps_frame_weighted"],
        "frame_ms_p99_over_p50_worst": summary["frame_ms_p99_over_p50_worst"],
        "auc_by_sequence": {seq: run["trackers"][name]["auc"] for seq, run in one_pass["sequences"].items()},
        "longterm_fps_frame_weighted": frames / seconds if seconds > 0 else None,
        "longterm_frame_ms_p99_over_p50_worst": _worst_ratio(pooled_runs),
        "longterm_by_seed": by_seed,
        "longterm_pooled": longterm.summarise_longterm([e["longterm"] for e in pooled_runs]),
        "errors": errors,
    }


def _difference(value: float | None, reference: float | None) -> float | None:
    return None if value is None or reference is None else value - reference


def with_differences(rows: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Rows with "vs_default": AUC and pooled rates as differences, fps as a relative change."""
    base = rows[DEFAULT]
    out = {}
    for name, row in rows.items():
        pooled, base_pooled = row["longterm_pooled"], base["longterm_pooled"]
        fps, base_fps = row["fps_mean"], base["fps_mean"]
        out[name] = {**row, "vs_default": {
            "auc": _difference(row["auc"], base["auc"]),
            "fps_mean_relative": fps / base_fps - 1.0 if base_fps else None,
            "reacquisition_rate": _difference(pooled["reacquisition_rate"], base_pooled["reacquisition_rate"]),
            "false_reinit_rate": _difference(pooled["false_reinit_rate"], base_pooled["false_reinit_rate"]),
        }}
    return out


def run_ablation(sequences: list[dataset.Sequence], names: list[str], seeds: list[int],
                 kinds: tuple[str, ...] = longterm.EVENT_KINDS, lengths: tuple[int, ...] = longterm.DEFAULT_LENGTHS,
                 max_frames: int | None = None, progress: Callable[[int], None] | None = None) -> dict[str, Any]:
    """Every variant (and "default") of `names` on `sequences`: one pass, then the long-term protocol
    per seed; {"variants": {name: row with vs_default}, "seeds", "kinds", "lengths", "max_frames"}."""
    factories = variant_factories(names)

    def one_pass_run(seqs: list[dataset.Sequence], facs: dict[str, Callable[[], Tracker]]) -> dict[str, Any]:
        return evaluate.evaluate(seqs, list(facs), progress=progress, max_frames=max_frames, factories=facs)

    def longterm_run(seed: int) -> Callable[..., dict[str, Any]]:
        return lambda seqs, facs: evaluate.evaluate_longterm(seqs, list(facs), list(kinds), lengths, seed,
                                                             progress=progress, max_frames=max_frames, factories=facs)

    one_pass = _rotating(sequences, factories, 0, one_pass_run)
    # Each seed's rotation starts where the previous run's ended, so the first place keeps cycling.
    by_seed = {seed: _rotating(sequences, factories, (1 + k) * len(sequences), longterm_run(seed))
               for k, seed in enumerate(seeds)}
    rows = {name: variant_row(name, one_pass, by_seed) for name in factories}
    return {"tracker": TRACKER, "variants": with_differences(rows), "seeds": seeds, "kinds": list(kinds),
            "lengths": list(lengths), "max_frames": max_frames, "criteria": longterm.LongTermCriteria().__dict__}


def rotated(factories: dict[str, Callable[[], Tracker]], shift: int) -> dict[str, Callable[[], Tracker]]:
    """`factories` in lockstep order rotated left by `shift` (mod their number)."""
    names = list(factories)
    k = shift % len(names)
    return {name: factories[name] for name in names[k:] + names[:k]}


def _rotating(sequences: list[dataset.Sequence], factories: dict[str, Callable[[], Tracker]], start: int,
              run: Callable[[list[dataset.Sequence], dict[str, Callable[[], Tracker]]], Mapping[str, Any]]
              ) -> dict[str, Any]:
    """`run` (an evaluate / evaluate_longterm call) on each sequence alone, the lockstep order rotated by
    one more per sequence from `start`: the tracker right after a frame's decoding runs measurably slower
    (~3% here), so every variant takes that place in turn. {"sequences": merged, "summary": evaluate.summarise}."""
    merged: dict[str, Any] = {}
    for k, sequence in enumerate(sequences):
        merged.update(run([sequence], rotated(factories, start + k))["sequences"])
    return {"sequences": merged, "summary": evaluate.summarise(merged)}


def _signed(value: float | None, spec: str) -> str:
    return report._fmt(value, "+" + spec)  # the evaluation's own number format ('-' for None / NaN)


def _per_seed(row: Mapping[str, Any], key: str) -> str:
    return " / ".join(report._fmt(lt[key], ".2f") for lt in row["longterm_by_seed"].values())


def format_table(result: Mapping[str, Any]) -> str:
    """The markdown table: one row per variant, "default" first, differences to it beside each number."""
    fmt = report._fmt
    rows = []
    for name, row in result["variants"].items():
        diff, pooled = row["vs_default"], row["longterm_pooled"]
        rows.append([name, describe(row["overrides"]), fmt(row["auc"]), _signed(diff["auc"], ".3f"),
                     fmt(row["fps_mean"], ".1f"), _signed(None if diff["fps_mean_relative"] is None
                                                          else 100 * diff["fps_mean_relative"], ".0f") + "%",
                     fmt(row["frame_ms_p99_over_p50_worst"], ".2f"), fmt(row["longterm_fps_frame_weighted"], ".1f"),
                     fmt(row["longterm_frame_ms_p99_over_p50_worst"], ".2f"),
                     f"{fmt(pooled['reacquisition_rate'], '.3f')} of {pooled['n_events']}",
                     _signed(diff["reacquisition_rate"], ".3f"), _per_seed(row, "reacquisition_rate"),
                     fmt(pooled["false_reinit_rate"], ".4f"), _signed(diff["false_reinit_rate"], ".4f"),
                     _per_seed(row, "false_reinit_rate")])
    header = ["variant", "overrides", "AUC", "dAUC", "fps", "dfps", "p99/p50", "lt fps", "lt p99/p50",
              "re-acq (pooled)", "d re-acq", "re-acq by seed", "false re-init", "d false", "false by seed"]
    seeds = ", ".join(map(str, result["seeds"])) or "none"
    note = (f"{TRACKER}; AUC, fps, p99/p50: one pass (mean over sequences; p99/p50 = worst sequence's update-time "
            f"ratio); lt: long-term runs (kinds {', '.join(result['kinds'])}, lengths "
            f"{', '.join(map(str, result['lengths']))}), seeds {seeds}; d = variant - default (fps: relative)")
    errors = [f"  {name}: {msg}" for name, row in result["variants"].items() for msg in row["errors"]]
    text = report._table(header, rows) + "\n" + note
    return text + ("\nTRACKER ERRORS (boxes after the failure count as misses):\n" + "\n".join(errors)
                   if errors else "")


def _csv(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m bench.ablation", description=__doc__.split("\n\n")[0])
    parser.add_argument("data_root", type=Path, help="folder of OTB-layout sequences (or one sequence)")
    parser.add_argument("--seeds", default="0,1,2,3", help="long-term event placement seeds")
    parser.add_argument("--variants", default=",".join(VARIANTS),
                        help=f"comma-separated, of: {', '.join(VARIANTS)} (\"default\" always runs)")
    parser.add_argument("--sequences", default="", help="comma-separated sequence folder names (default all)")
    parser.add_argument("--kinds", default=",".join(longterm.EVENT_KINDS), help="long-term event kinds")
    parser.add_argument("--lengths", default=",".join(map(str, longterm.DEFAULT_LENGTHS)),
                        help="injected event lengths in frames")
    parser.add_argument("--max-frames", type=int, help="only the first N frames of each sequence (quick runs)")
    parser.add_argument("--json", type=Path, help="write every number here")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser.parse_args(argv)


def _frames_to_run(sequences: list[dataset.Sequence], kinds: tuple[str, ...], seeds: list[int],
                   max_frames: int | None) -> int:
    """Frames the lockstep loop will step through (the progress bar's total)."""
    cut = [evaluate.truncated(s, max_frames) for s in sequences]
    per_seed = sum(len(s) for s in cut for kind in kinds
                   if kind != "real" or longterm.inject_events(s, "real").events)
    return sum(len(s) for s in cut) + len(seeds) * per_seed


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        seeds = [int(v) for v in _csv(args.seeds)]
        names = _csv(args.variants)
        kinds = tuple(_csv(args.kinds))
        lengths = tuple(int(v) for v in _csv(args.lengths))
        if args.max_frames is not None and args.max_frames < 2:
            raise ValueError(f"--max-frames must be >= 2, got {args.max_frames}")
        folders = dataset.select_sequences(dataset.discover_sequences(args.data_root), _csv(args.sequences))
        sequences = [dataset.load_sequence(f) for f in folders]
        factories = variant_factories(names)
    except ValueError as exc:
        raise SystemExit(f"error: {exc}") from exc
    factories[DEFAULT]()  # import the tracker's modules now, so the thread cap below covers their libraries
    threads = cap_loaded_pools()
    print(describe_pools(threads), file=sys.stderr)
    total = _frames_to_run(sequences, kinds, seeds, args.max_frames)
    with tqdm(total=total, unit="frame", disable=args.no_progress, file=sys.stderr) as bar:
        try:
            result = run_ablation(sequences, names, seeds, kinds, lengths, args.max_frames, progress=bar.update)
        except ValueError as exc:
            raise SystemExit(f"error: {exc}") from exc
    result.update({"threads": threads, "data_root": str(args.data_root),
                   "sequences": [s.name for s in sequences]})
    print(format_table(result))
    if args.json:
        report.write_json(result, args.json)
        print(f"json: {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
