"""bench.ablation on a tiny synthetic sequence: every variant in the table, each variant's override
reaching the tracker it runs (and only that override), and the lattice budget doing what it should."""
from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import jsar
from bench import ablation
from jsar.config import JsarParams
from jsar.eval import dataset, evaluate
from jsar.eval.synthetic import synthetic_clip, write_otb_sequence
from jsar.redetect.memory import DecisionFilter
from jsar.redetect.params import RedetectParams

REPO = Path(__file__).resolve().parents[1]
N_FRAMES = 60  # room for one 5-frame event after the protocol's first 30 frames and before its 15-frame gap
EVENTS = {"kinds": ("occlusion",), "lengths": (5,)}


@pytest.fixture(scope="module")
def synthetic_root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("otb")
    for seed, name in ((4, "syn"), (5, "syn_b")):
        frames, boxes = synthetic_clip(n_frames=N_FRAMES, size=(120, 160), object_size=(20, 16), seed=seed)
        write_otb_sequence(root / name, frames, boxes)
    return root


@pytest.fixture(scope="module")
def sequences(synthetic_root) -> list[dataset.Sequence]:
    return [dataset.load_sequence(synthetic_root / "syn")]


def test_every_variant_runs_with_its_own_overrides_and_only_those(sequences, monkeypatch):
    """The whole table on one synthetic sequence, watching jsar.create and the decision filter's
    window scoring: every tracker is built from its variant's override (core parameters untouched),
    and windows_per_frame 0 leaves only the pending candidate's window to score while lost."""
    created: list[tuple[dict, object]] = []
    real_create = jsar.create

    def spy_create(name, **overrides):
        tracker = real_create(name, **overrides)
        created.append((overrides, tracker))
        return tracker

    widest: dict[int, int] = {}  # id(decision filter) -> most windows it scored in one call
    real_score_windows = DecisionFilter.score_windows

    def spy_score_windows(self, image, colour_table, centres_xy, target_side_px, angles_deg=None, worker=None,
                          worker_busy=0.0):
        widest[id(self)] = max(widest.get(id(self), 0), len(centres_xy))
        return real_score_windows(self, image, colour_table, centres_xy, target_side_px, angles_deg, worker,
                                  worker_busy)

    monkeypatch.setattr(jsar, "create", spy_create)
    monkeypatch.setattr(DecisionFilter, "score_windows", spy_score_windows)
    result = ablation.run_ablation(sequences, list(ablation.VARIANTS), seeds=[0], **EVENTS)

    assert list(result["variants"]) == [ablation.DEFAULT] + list(ablation.VARIANTS)
    table = ablation.format_table(result)
    for name in result["variants"]:
        assert any(line.startswith(f"| {name} ") for line in table.splitlines()), (name, table)
    for name, row in result["variants"].items():
        assert not row["errors"], (name, row["errors"])
        assert 0.0 <= row["auc"] <= 1.0 and row["longterm_pooled"]["n_events"] == 1, (name, row)
    default = result["variants"][ablation.DEFAULT]["vs_default"]
    assert default["auc"] == 0.0 and default["fps_mean_relative"] == 0.0

    # One tracker per variant and run (one pass, one long-term run), each with exactly its override.
    by_variant: dict[str, list] = {name: [] for name in result["variants"]}
    created_order = []
    for overrides, tracker in created:
        (name,) = [n for n in by_variant if ablation.variant_overrides(n) == overrides["redetect"]]
        by_variant[name].append(tracker)
        created_order.append(name)
        assert tracker.redetect == RedetectParams.from_mapping(overrides["redetect"])
        assert tracker.params == JsarParams.jsar_re()
    assert all(len(trackers) == 2 for trackers in by_variant.values()), {n: len(t) for n, t in by_variant.items()}
    n_variants = len(by_variant)
    # The lockstep order rotates between runs: another variant goes first after each frame's decoding.
    assert created_order[n_variants:] == created_order[1:n_variants] + created_order[:1], created_order

    defaults = RedetectParams()
    for tracker in by_variant["no-budget-lattice"]:
        assert tracker.redetect.search.windows_per_frame == 0 != defaults.search.windows_per_frame
        assert dataclasses.replace(tracker.redetect.search, windows_per_frame=defaults.search.windows_per_frame) \
            == defaults.search
        assert (tracker.redetect.monitor, tracker.redetect.accept) == (defaults.monitor, defaults.accept)

    # The occlusion makes the default search its lattice; without the budget at most the pending window.
    lost_default = [t for t in by_variant[ablation.DEFAULT] if id(t.decision_filter) in widest]
    assert lost_default and max(widest[id(t.decision_filter)] for t in lost_default) > 1, widest
    assert all(widest.get(id(t.decision_filter), 0) <= 1 for t in by_variant["no-budget-lattice"]), widest


def test_no_lattice_windows_change_nothing_before_the_first_reacquisition(sequences):
    """Lattice windows only offer candidates: until one variant re-acquires, both report the same
    boxes and states, lost frames included."""
    factories = ablation.variant_factories(["no-budget-lattice"])
    result = evaluate.evaluate_longterm(sequences, list(factories), list(EVENTS["kinds"]), EVENTS["lengths"], seed=0,
                                        factories=factories)
    (run,) = result["sequences"].values()
    default, no_lattice = run["trackers"][ablation.DEFAULT], run["trackers"]["no-budget-lattice"]
    recovered = [i for i, states in enumerate(zip(default["states"], no_lattice["states"])) if "recovered" in states]
    until = recovered[0] if recovered else N_FRAMES
    assert "lost" in default["states"][:until], default["states"]
    np.testing.assert_array_equal(default["boxes"][:until], no_lattice["boxes"][:until])
    assert default["states"][:until] == no_lattice["states"][:until]


def test_factories_reject_unknown_variants_and_invalid_overrides(monkeypatch):
    with pytest.raises(ValueError, match="unknown variant 'nope'; known: no-relative-drop"):
        ablation.variant_factories(["nope"])
    monkeypatch.setitem(ablation.VARIANTS, "broken", {"search": {"windows_per_frame": -1}})
    with pytest.raises(ValueError, match=r"redetect\.search\.windows_per_frame"):
        ablation.variant_factories(["broken"])


def test_cli_prints_the_table_and_writes_json(synthetic_root, tmp_path):
    out = tmp_path / "ablation.json"
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, "-m", "bench.ablation", str(synthetic_root), "--seeds", "0,1",
                           "--variants", "no-gate,retrain", "--kinds", "occlusion", "--lengths", "5",
                           "--json", str(out), "--no-progress"], cwd=REPO, env=env, capture_output=True, text=True,
                          timeout=180)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    rows = [line for line in proc.stdout.splitlines() if line.startswith("| ")][1:]  # after the header
    assert [row.split("|")[1].strip() for row in rows] == ["default", "no-gate", "retrain"], proc.stdout
    written = json.loads(out.read_text())
    assert list(written["variants"]) == ["default", "no-gate", "retrain"]
    assert written["variants"]["retrain"]["overrides"] == {"accept": {"reacquire": "retrain"}}
    assert sorted(written["variants"]["no-gate"]["longterm_by_seed"]) == ["0", "1"]
    assert written["sequences"] == ["syn", "syn_b"] and written["seeds"] == [0, 1]
    assert sorted(written["variants"]["no-gate"]["auc_by_sequence"]) == ["syn", "syn_b"]

    bad = subprocess.run([sys.executable, "-m", "bench.ablation", str(synthetic_root), "--variants", "nope"],
                         cwd=REPO, env=env, capture_output=True, text=True, timeout=60)
    assert bad.returncode != 0 and "unknown variant 'nope'" in bad.stderr, bad.stderr
