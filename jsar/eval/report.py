"""Output of an evaluation: text tables, precision / success plots (PNG), JSON with every number."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from jsar.eval import metrics


def _fmt(value: object, spec: str = ".3f") -> str:
    """A number formatted with `spec`, '-' for None / NaN."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return format(value, spec)


def _table(header: list[str], rows: list[list[str]]) -> str:
    """Left-aligned first column, right-aligned others, markdown-style pipes."""
    widths = [max(len(r[i]) for r in [header] + rows) for i in range(len(header))]
    def line(cells: list[str]) -> str:
        parts = [c.ljust(widths[0]) if i == 0 else c.rjust(widths[i]) for i, c in enumerate(cells)]
        return "| " + " | ".join(parts) + " |"
    sep = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
    return "\n".join([line(header), sep] + [line(r) for r in rows])


def _order(summary: dict[str, dict[str, object]]) -> list[str]:
    """Run trackers first (in run order), then published ones by decreasing AUC."""
    run = [n for n, r in summary.items() if not r["published"]]
    published = sorted((n for n, r in summary.items() if r["published"]),
                       key=lambda n: -float(summary[n]["auc"]))  # type: ignore[arg-type]
    return run + published


def format_sequence_table(result: dict[str, object]) -> str:
    """Per sequence and tracker: precision@20px, AUC, fps, fps / CSRT, and the per-frame time
    distribution of its update() calls: median, 99th percentile and maximum (ms), p99 / median."""
    summary = result["summary"]
    rows = []
    for seq_name, seq in result["sequences"].items():  # type: ignore[union-attr]
        for name in _order(summary):  # type: ignore[arg-type]
            entry = seq["trackers"].get(name)
            if entry is None:
                continue
            rows.append([seq_name, name + (" (published)" if entry["published"] else ""),
                         _fmt(entry["precision"]), _fmt(entry["auc"]),
                         _fmt(entry.get("fps"), ".1f"), _fmt(entry.get("fps_ratio_vs_csrt"), ".2f"),
                         _fmt(entry.get("frame_ms_p50"), ".1f"), _fmt(entry.get("frame_ms_p99"), ".1f"),
                         _fmt(entry.get("frame_ms_max"), ".1f"), _fmt(entry.get("frame_ms_p99_over_p50"), ".2f")])
    return _table(["sequence", "tracker", "prec@20", "AUC", "fps", "fps/CSRT", "ms p50", "ms p99", "ms max",
                   "p99/p50"], rows)


def format_summary_table(result: dict[str, object]) -> str:
    """Per tracker: mean precision / AUC over its sequences, mean and frame-weighted fps, ratio vs CSRT."""
    summary = result["summary"]
    rows = []
    for name in _order(summary):  # type: ignore[arg-type]
        row = summary[name]  # type: ignore[index]
        rows.append([name + (" (published)" if row["published"] else ""), str(row["sequences"]),
                     _fmt(row["precision"]), _fmt(row["auc"]), _fmt(row.get("fps_mean"), ".1f"),
                     _fmt(row.get("fps_frame_weighted"), ".1f"), _fmt(row.get("fps_ratio_vs_csrt"), ".2f"),
                     _fmt(row.get("frame_ms_p99_over_p50_worst"), ".2f")])
    text = _table(["tracker", "seqs", "mean prec@20", "mean AUC", "mean fps", "fps (frame-weighted)",
                   "fps/CSRT", "worst p99/p50"], rows)
    return text + _errors(summary)  # type: ignore[arg-type]


def format_longterm_table(result: dict[str, object]) -> str:
    """Per tracker: re-acquisition rate, frames to recover, false re-inits, precision / AUC, fps."""
    summary = result["summary"]
    rows = []
    for name, row in summary.items():  # type: ignore[union-attr]
        lt = row["longterm"]
        by_length = ", ".join(f"{k}:{v['rate']:.2f}/{v['events']}"
                              for k, v in row["reacquisition_by_length"].items())
        by_kind = ", ".join(f"{k}:{v['rate']:.2f}/{v['events']}" for k, v in row["reacquisition_by_kind"].items())
        rows.append([name, f"{_fmt(lt['reacquisition_rate'], '.2f')} of {lt['n_events']}",
                     f"{_fmt(lt['reacquisition_rate_on_target_before'], '.2f')} of "
                     f"{lt['n_events_on_target_before']}", by_length, by_kind,
                     _fmt(lt["mean_frames_to_recover"], ".1f"), _fmt(lt["median_frames_to_recover"], ".1f"),
                     f"{_fmt(lt['false_reinit_rate'], '.3f')} ({lt['false_reinit_absent']}+"
                     f"{lt['false_reinit_wrong_object']}/{lt['absent_frames']})",
                     _fmt(lt["absent_reported_lost_rate"], ".2f"),
                     _fmt(row["precision"]), _fmt(row["auc"]), _fmt(row["fps_frame_weighted"], ".1f"),
                     _fmt(row.get("fps_ratio_vs_csrt"), ".2f")])
    criteria = result["criteria"]
    note = (f"re-acquired: on target (IoU > {criteria['min_iou']} or centre error <= "
            f"{criteria['max_centre_error_px']} px) within {criteria['window']} frames of reappearance; "
            f"false re-init: 'recovered' state or box jump while absent + 'recovered' onto IoU 0, "
            f"per absent frame; began on target = the events whose previous frame the box was on target; by length / kind = rate/events (kind real = the ground truth's own absent runs); absent: lost = share of absent frames reported lost; seed {result['seed']}")
    text = _table(["tracker", "re-acquired", "began on target: re-acquired", "by length", "by kind", "mean frames", "median frames",
                   "false re-init (abs+wrong/absent)", "absent: lost", "prec@20", "AUC", "fps", "fps/CSRT"], rows) + "\n" + note
    return text + _errors(summary)  # type: ignore[arg-type]


SRE_COLUMNS = {"auc": ("AUC", ".3f"), "precision": ("prec@20", ".3f"),
               "reacquisition_rate": ("re-acquired", ".2f"), "false_reinit_rate": ("false re-init", ".3f"),
               "absent_reported_lost_rate": ("absent: lost", ".2f")}


def _spread_cell(figure: dict[str, object], spec: str) -> str:
    """"mean ±std [min, max] exact" of one figure over the starts, e.g. "0.550 ±0.020 [0.510, 0.570] 0.560"."""
    return (f"{_fmt(figure['mean'], spec)} ±{_fmt(figure['std'], spec)} "
            f"[{_fmt(figure['min'], spec)}, {_fmt(figure['max'], spec)}] {_fmt(figure['exact'], spec)}")


def format_sre_tables(result: dict[str, object]) -> str:
    """The spatial robustness part (jsar.eval.sre): per sequence (run) and tracker, then per tracker over the
    set, each figure as mean ±std [min, max] over the starts and the exact start's value; then each start's
    set figures; '' without it."""
    section = result.get("sre")
    if not section:
        return ""
    metrics_ = section["metrics"]  # type: ignore[index]
    header = [f"{SRE_COLUMNS[m][0]}: mean ±sd [min, max] exact" for m in metrics_]
    rows = [[run, name] + [_spread_cell(figures[m], SRE_COLUMNS[m][1]) for m in metrics_]
            for run, seq in section["sequences"].items()  # type: ignore[index]
            for name, figures in seq["trackers"].items()]
    set_rows = [[name] + [_spread_cell(figures[m], SRE_COLUMNS[m][1]) for m in metrics_]
                for name, figures in section["summary"].items()]  # type: ignore[index]
    per_start_rows = [[name, start] + [_fmt(row[m], SRE_COLUMNS[m][1]) for m in metrics_]
                      for name, figures in section["summary"].items()  # type: ignore[index]
                      for start, row in figures["per_start"].items()]
    starts = ", ".join(f"{s['index']} {s['name']}" for s in section["starts"])  # type: ignore[index]
    return (f"Spatial robustness: {len(section['starts'])} initial boxes ({starts}); "  # type: ignore[arg-type]
            f"scored against the unperturbed ground truth; sd = population standard deviation over the starts\n\n"
            + _table(["sequence", "tracker"] + header, rows) + "\n\n"
            + _table(["tracker (set)"] + header, set_rows) + "\n\n"
            + _table(["tracker (set)", "start"] + [SRE_COLUMNS[m][0] for m in metrics_], per_start_rows))


def _errors(summary: dict[str, dict[str, object]]) -> str:
    """Trackers that raised, one line each ('' if none)."""
    errors = [f"  {name}: {msg}" for name, row in summary.items() for msg in row.get("errors", [])]  # type: ignore[attr-defined]
    return "\nTRACKER ERRORS (boxes after the failure count as misses):\n" + "\n".join(errors) if errors else ""


def save_plots(result: dict[str, object], directory: Path | str, title: str = "shared UAV sequences") -> list[Path]:
    """Precision and success plots (overall mean, and per sequence) as PNG; returns the paths."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []

    def draw(curves: dict[str, tuple[np.ndarray, np.ndarray, bool, int]], label: str, stem: str) -> None:
        for kind in ("precision", "success"):
            fig, ax = plt.subplots(figsize=(8.5, 4.8), dpi=100)
            key = 0 if kind == "precision" else 1
            thresholds = metrics.PRECISION_THRESHOLDS_PX if kind == "precision" else metrics.SUCCESS_THRESHOLDS
            def value(name: str) -> float:
                curve = curves[name][key]
                return float(np.interp(metrics.PRECISION_AT_PX, thresholds, curve)) if kind == "precision" \
                    else metrics.auc(curve)
            palette = plt.get_cmap("tab20").colors  # 20 distinct colours: up to 20 trackers per plot
            for rank, name in enumerate(sorted(curves, key=lambda n: -value(n))):
                prec, succ, published, n_seq = curves[name]
                extra = f", {n_seq} seq" if n_seq and published else ""
                ax.plot(thresholds, curves[name][key], linestyle="--" if published else "-",
                        color=palette[(2 * rank + rank // 10) % len(palette)],
                        linewidth=1.2 if published else 2.2, label=f"{name} [{value(name):.3f}{extra}]")
            if kind == "precision":
                ax.set(xlabel="Location error threshold (px)", ylabel="Precision", xlim=(0, 50))
                ax.set_title(f"Precision plots of OPE on {label}")
            else:
                ax.set(xlabel="Overlap threshold", ylabel="Success rate", xlim=(0, 1))
                ax.set_title(f"Success plots of OPE on {label}")
            ax.set_ylim(0, 1)
            ax.grid(True, alpha=0.3)
            ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
            fig.tight_layout()
            path = directory / f"{stem}_{kind}.png"
            fig.savefig(path)
            plt.close(fig)
            written.append(path)

    summary = result["summary"]
    draw({n: (r["precision_curve"], r["success_curve"], r["published"], r["sequences"])  # type: ignore
          for n, r in summary.items()}, title, "overall")  # type: ignore[union-attr]
    for seq_name, seq in result["sequences"].items():  # type: ignore[union-attr]
        draw({n: (e["precision_curve"], e["success_curve"], e["published"], 0)
              for n, e in seq["trackers"].items()}, seq_name, seq_name)
    return written


TIMELINE_COLOURS = {"absent": (0.80, 0.80, 0.80), "on": (0.20, 0.65, 0.30), "off": (0.85, 0.25, 0.20),
                    "lost": (0.55, 0.75, 0.95), "recovered": (0.0, 0.0, 0.0)}


def timeline_codes(states: list[str], on_target: np.ndarray, visible: np.ndarray) -> list[str]:
    """Per frame, what the long-term timeline draws: "recovered", "lost" (the tracker said so), else
    "absent" (target not in the ground truth), "on" / "off" (box on the target or not)."""
    codes = []
    for state, hit, seen in zip(states, on_target, visible):
        if state in ("recovered", "lost"):
            codes.append(state)
        elif not seen:
            codes.append("absent")
        else:
            codes.append("on" if hit else "off")
    return codes


def save_longterm_timeline(result: dict[str, object], path: Path | str) -> Path:
    """One PNG: per (sequence + event kind) and tracker a strip over the frames, coloured by
    timeline_codes, the ground truth's absent frames marked above each group."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    from jsar.eval import longterm

    runs = list(result["sequences"].items())  # type: ignore[union-attr]
    trackers = list(result["summary"])  # type: ignore[arg-type]
    rows = len(runs) * (len(trackers) + 1)
    fig, ax = plt.subplots(figsize=(9.0, 0.16 * rows + 1.0), dpi=80)
    labels, ticks, row = [], [], 0
    for name, seq in runs:
        gt = np.asarray(seq["groundtruth"], dtype=np.float64)
        visible = metrics.visible_mask(gt)
        absent = [(i, 1) for i in np.flatnonzero(~visible)]
        ax.broken_barh(absent, (row, 0.8), color=TIMELINE_COLOURS["absent"])
        labels.append(name)
        ticks.append(row + 0.4)
        row += 1
        for tracker in trackers:
            entry = seq["trackers"][tracker]
            hit = longterm.on_target(np.asarray(entry["boxes"], dtype=np.float64), gt, longterm.LongTermCriteria())
            codes = timeline_codes(entry["states"], hit, visible)
            for code, colour in TIMELINE_COLOURS.items():
                frames = [(i, 1) for i, c in enumerate(codes) if c == code]
                if frames:
                    ax.broken_barh(frames, (row, 0.8), color=colour)
            labels.append(f"  {tracker}")
            ticks.append(row + 0.4)
            row += 1
    ax.set_yticks(ticks)
    ax.set_yticklabels(labels, fontsize=6)
    ax.invert_yaxis()
    ax.set_xlabel("frame")
    ax.legend(handles=[Patch(color=c, label=k) for k, c in TIMELINE_COLOURS.items()], fontsize=6, ncol=5,
              loc="upper center", bbox_to_anchor=(0.5, 1.0 + 1.2 / rows), frameon=False)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


def boxes_from_json(rows: list) -> np.ndarray:
    """(N, 4) float64 boxes from write_json's lists: a null value (NaN or inf written) or a null row -> NaN."""
    return np.array([[np.nan] * 4 if row is None else [np.nan if v is None else v for v in row] for row in rows],
                    dtype=np.float64).reshape(-1, 4)


def _jsonable(value: object) -> object:
    """numpy arrays / scalars -> lists / floats, NaN and inf -> None (strict JSON)."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def write_json(result: dict[str, object], path: Path | str) -> None:
    """Every number and the per-frame boxes (0-based x,y,w,h pixels) as strict JSON (NaN -> null)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(_jsonable(result), indent=1))
