"""bench.redetect: lost frames against tracking frames in time, with and without the verifier's thread."""
from __future__ import annotations

import pytest

from bench.redetect import measure
from tests.helpers import real_sequence


@pytest.mark.parametrize("verifier_worker", [False, True])
def test_measure_times_each_tracking_and_lost_frame_once_keeping_its_fastest_run(data_root, verifier_worker):
    """Every hidden frame of the searching tracker is lost (no candidate is taken), every visible one tracked;
    with two rounds each frame is timed twice and counted once; the lattice scored windows on the lost ones."""
    real_sequence(data_root, "OTB_Crossing")
    found = measure(data_root / "OTB_Crossing", 4, None, rounds=2, verifier_worker=verifier_worker)
    assert len(found["tracking"]) == 4 and len(found["lost"]) == 4 == len(found["windows"])
    assert all(ms > 0 for ms in found["tracking"] + found["lost"])
    assert all(windows >= 1 for windows in found["windows"])
