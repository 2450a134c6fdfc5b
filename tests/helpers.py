"""Shared test helpers that are not fixtures: skip-or-fail on a missing peer, and the real sequences.

(Loopback ports come from sim.ports; the fixtures and hooks stay in tests/conftest.py.)"""
from __future__ import annotations

import os
from pathlib import Path

import pytest


def require(missing: str | None) -> None:
    """Skip with the reason `missing` (a peer the test needs is absent) outside CI; fail in CI (env CI set)."""
    if missing is None:
        return
    if os.environ.get("CI"):
        pytest.fail(f"CI needs it: {missing}")
    pytest.skip(missing)


def real_sequence(data_root: Path, name: str):
    """Sequence `name` under the data root, read by jsar.eval.dataset.load_sequence (frame paths; ground truth
    (N, 4) 0-based x, y, w, h pixels, NaN rows = target not visible); skip when it is not there."""
    from jsar.eval.dataset import load_sequence

    folder = data_root / name
    if not folder.is_dir():
        pytest.skip(f"sequence {name} is not under JSAR_DATA_ROOT")
    return load_sequence(folder)
