"""python -m jsar.eval DATA_ROOT --trackers jsar,strcf,csrt,kcf [--json F] [--plots D] [--published D]
[--sequences a,b] [--longterm [--kinds ...] [--lengths 5,15,40] [--seed 0]] [--max-frames N] [--params JSON]
[--starts exact|sre|sre:I,J,...] [--jobs N]

The options: --help; the protocol (one pass, long-term, SRE starts) and its outputs: docs/evaluation.md.
With several --starts the tables and the JSON's "sequences" / "summary" stay the exact start's; the JSON's
"sre" holds the spread over the starts and every start's per-sequence figures and boxes.
One thread, so speeds compare: the BLAS / OpenMP env vars are set to 1, cv2.setNumThreads(1), and
threadpoolctl caps the pools already loaded (`import jsar` loads numpy's OpenBLAS before this module runs);
the pool sizes are printed and stored in the JSON ("threads").
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from jsar.eval.runner import cap_loaded_pools, describe_pools, limit_threads_env

limit_threads_env()  # before the trackers' modules (scipy, ...) are imported below

from tqdm import tqdm  # noqa: E402

from jsar.eval import dataset, evaluate, longterm, report, sre  # noqa: E402

tqdm.monitor_interval = 0  # no tqdm monitor thread: --jobs forks worker processes from this one


def _csv(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m jsar.eval", description=__doc__.split("\n\n")[0])
    parser.add_argument("data_root", type=Path, help="folder of OTB-layout sequences (or one sequence)")
    parser.add_argument("--trackers", default="jsar,strcf,csrt,kcf", help="comma-separated jsar.create names")
    parser.add_argument("--sequences", default="", help="comma-separated sequence folder names (default all)")
    parser.add_argument("--published", type=Path, help="DIR/<tracker>/<seq>.txt results to score as extra rows")
    parser.add_argument("--json", type=Path, help="write every number and per-frame boxes here")
    parser.add_argument("--plots", type=Path, help="write precision / success PNG plots into this folder")
    parser.add_argument("--max-frames", type=int, help="only the first N frames of each sequence (quick runs)")
    parser.add_argument("--longterm", action="store_true", help="long-term protocol with injected events")
    parser.add_argument("--kinds", default=",".join(longterm.EVENT_KINDS), help="event kinds (--longterm)")
    parser.add_argument("--lengths", default=",".join(map(str, longterm.DEFAULT_LENGTHS)),
                        help="event lengths in frames (--longterm)")
    parser.add_argument("--seed", type=int, default=0, help="event placement seed (--longterm)")
    parser.add_argument("--starts", default="exact",
                        help=f"initial boxes per sequence (OTB's SRE): {sre.STARTS_SYNTAX}, e.g. sre:0,2,5,9; "
                             "the starts: " + ", ".join(f"{s.index} {s.name}" for s in sre.SRE_STARTS)
                             + " (shift2 = 2 px, shift10 = 10 %% of w / h, scale about the centre; clipped to the "
                             "frame); scored against the unperturbed ground truth (default exact)")
    parser.add_argument("--jobs", type=int, default=1,
                        help="(sequence, start) runs in this many single-threaded worker processes (default 1); "
                             "same results, speeds measured with the runs sharing the machine")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--params", default="",
                        help='JSON {tracker: {jsar.create keyword: value}}, e.g. '
                             '\'{"jsar-re": {"redetect": {"search": {"windows_per_frame": 4}}}}\'')
    return parser.parse_args(argv)


def parse_params(text: str, trackers: list[str]) -> dict[str, dict]:
    """--params: a JSON object {tracker name: {jsar.create keyword: value}} naming only --trackers
    ({} when empty); ValueError saying what is wrong."""
    if not text.strip():
        return {}
    try:
        params = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"--params is not JSON: {exc}") from exc
    if not isinstance(params, dict) or not all(isinstance(v, dict) for v in params.values()):
        raise ValueError("--params must be a JSON object {tracker: {keyword: value}}")
    unknown = [name for name in params if name not in trackers]
    if unknown:
        raise ValueError(f"--params names {', '.join(unknown)}, not in --trackers ({', '.join(trackers)})")
    return params


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    trackers = _csv(args.trackers)
    if not trackers:
        raise SystemExit("--trackers: give at least one tracker name")
    if args.longterm and args.published:
        raise SystemExit("--published does not apply to --longterm (published boxes are for the original frames)")
    try:
        folders = dataset.select_sequences(dataset.discover_sequences(args.data_root), _csv(args.sequences))
        sequences = [dataset.load_sequence(f) for f in folders]
        if args.max_frames is not None and args.max_frames < 2:
            raise ValueError(f"--max-frames must be >= 2, got {args.max_frames}")
        params = parse_params(args.params, trackers)
        starts = sre.parse_starts(args.starts)
        if args.jobs < 1:
            raise ValueError(f"--jobs must be >= 1, got {args.jobs}")
        factories = evaluate.tracker_factories(trackers, params)
    except ValueError as exc:
        raise SystemExit(f"error: {exc}") from exc
    for name, factory in factories.items():
        try:
            factory()  # import every tracker's modules now, so the thread cap below covers their libraries
        except (ValueError, TypeError) as exc:  # a bad --params value or keyword, named by the tracker
            raise SystemExit(f"error: --params {name}: {exc}") from exc
    threads = cap_loaded_pools()
    print(describe_pools(threads), file=sys.stderr)
    if params:
        print(f"params: {json.dumps(params, sort_keys=True)}", file=sys.stderr)
    kinds = _csv(args.kinds)
    lengths = tuple(int(v) for v in _csv(args.lengths))
    total = (sum(min(len(s), args.max_frames or len(s)) for s in sequences) * (len(kinds) if args.longterm else 1)
             * len(starts))
    with tqdm(total=total, unit="frame", disable=args.no_progress, file=sys.stderr) as bar:
        try:
            if args.longterm:
                result = evaluate.evaluate_longterm(sequences, trackers, kinds, lengths, args.seed,
                                                    progress=bar.update, max_frames=args.max_frames,
                                                    factories=factories, starts=starts, jobs=args.jobs)
            else:
                result = evaluate.evaluate(sequences, trackers, args.published, progress=bar.update,
                                           max_frames=args.max_frames, factories=factories, starts=starts,
                                           jobs=args.jobs)
        except ValueError as exc:
            raise SystemExit(f"error: {exc}") from exc
    result["threads"] = threads
    result["data_root"] = str(args.data_root)
    result["max_frames"] = args.max_frames
    result["params"] = params
    result["starts"] = args.starts
    result["jobs"] = args.jobs
    if args.longterm:
        print(report.format_longterm_table(result))
    else:
        print(report.format_sequence_table(result))
        print()
        print(report.format_summary_table(result))
    if "sre" in result:
        print()
        print(report.format_sre_tables(result))
    if args.json:
        report.write_json(result, args.json)
        print(f"json: {args.json}")
    if args.plots:
        paths = report.save_plots(result, args.plots, "injected events" if args.longterm else "shared UAV sequences")
        if args.longterm:
            paths.append(report.save_longterm_timeline(result, args.plots / "longterm_timeline.png"))
        print(f"plots: {len(paths)} PNG in {args.plots}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
