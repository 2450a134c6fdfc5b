"""The demo writes a readable annotated MJPG video and a per-frame CSV log."""
import csv

import cv2

from jsar.demo import run_demo


def test_demo_on_the_synthetic_clip_writes_video_and_log(tmp_path):
    summary = run_demo("kcf", tmp_path, sequence=None, data_root=None, max_frames=8)
    assert summary["sequence"] == "synthetic" and summary["frames"] == 8 and summary["fps"] > 0
    rows = list(csv.DictReader(summary["log"].open()))
    assert [int(r["frame"]) for r in rows] == list(range(8))
    assert set(rows[0]) == {"frame", "x", "y", "w", "h", "score", "state", "ms"}
    assert all(r["state"] in ("tracking", "lost", "recovered") for r in rows)
    capture = cv2.VideoCapture(str(summary["video"]))
    assert capture.isOpened()
    count = 0
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        assert frame.shape == (360, 480, 3)
        count += 1
    assert count == 8
