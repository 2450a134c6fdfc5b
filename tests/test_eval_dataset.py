"""Sequence loading, discovery and published-result parsing, with their errors."""
from pathlib import Path

import numpy as np
import pytest

from jsar.eval import dataset
from jsar.eval.synthetic import synthetic_clip, write_otb_sequence


def _tiny_sequence(folder: Path, n: int = 3, lines: list[str] | None = None) -> Path:
    (folder / "img").mkdir(parents=True)
    for i in range(1, n + 1):
        (folder / "img" / f"{i}.jpg").write_bytes(b"")
    text = "\n".join(lines if lines is not None else [f"{i},{i},5,6" for i in range(1, n + 1)])
    (folder / "groundtruth_rect.txt").write_text(text + "\n")
    return folder


def test_parse_boxes_accepts_commas_tabs_spaces_and_nan():
    boxes = dataset.parse_boxes("1,2,3,4\n5\t6\t7\t8\n\n9 10  11 12\nNaN,NaN,NaN,NaN\n", "t")
    assert boxes.shape == (4, 4)
    np.testing.assert_array_equal(boxes[2], [9, 10, 11, 12])
    assert np.all(np.isnan(boxes[3]))


@pytest.mark.parametrize("text, message", [
    ("1,2,3\n", "expected 4 values"),
    ("1,2,a,4\n", "not a number"),
    ("1,2,NaN,4\n", "partly NaN"),
    ("1,2,3,4\n1,2,inf,4\n", r"t:2: infinite"),
])
def test_parse_boxes_rejects_malformed_lines(text, message):
    with pytest.raises(ValueError, match=message):
        dataset.parse_boxes(text, "t")


def test_load_sequence_converts_to_zero_based_and_sorts_naturally(tmp_path):
    folder = _tiny_sequence(tmp_path / "seq", n=11)
    seq = dataset.load_sequence(folder)
    assert seq.name == "seq" and len(seq) == 11
    assert [p.name for p in seq.frame_paths[:3]] == ["1.jpg", "2.jpg", "3.jpg"]
    assert seq.frame_paths[-1].name == "11.jpg"
    np.testing.assert_array_equal(seq.groundtruth[0], [0, 0, 5, 6])  # file 1,1 -> 0,0
    assert seq.groundtruth.dtype == np.float64


def test_load_sequence_errors(tmp_path):
    with pytest.raises(ValueError, match="missing img/"):
        (tmp_path / "a").mkdir()
        (tmp_path / "a" / "groundtruth_rect.txt").write_text("1,1,2,2\n")
        dataset.load_sequence(tmp_path / "a")
    with pytest.raises(ValueError, match="3 frames in img/ but 2 boxes"):
        dataset.load_sequence(_tiny_sequence(tmp_path / "b", n=3, lines=["1,1,2,2", "1,1,2,2"]))
    with pytest.raises(ValueError, match="groundtruth_rect.txt:2: expected 4 values"):
        dataset.load_sequence(_tiny_sequence(tmp_path / "c", n=2, lines=["1,1,2,2", "1,1,2"]))
    with pytest.raises(ValueError, match=":2: non-positive box size"):
        dataset.load_sequence(_tiny_sequence(tmp_path / "d", n=2, lines=["1,1,2,2", "1,1,0,2"]))


def test_discovery_lists_sequences_and_rejects_incomplete_ones(tmp_path):
    _tiny_sequence(tmp_path / "b_seq")
    _tiny_sequence(tmp_path / "a_seq")
    (tmp_path / "notes").mkdir()  # unrelated folder: ignored
    assert [p.name for p in dataset.discover_sequences(tmp_path)] == ["a_seq", "b_seq"]
    assert dataset.discover_sequences(tmp_path / "a_seq") == [tmp_path / "a_seq"]
    assert [p.name for p in dataset.select_sequences(dataset.discover_sequences(tmp_path), ["b_seq"])] == ["b_seq"]
    with pytest.raises(ValueError, match="unknown sequence"):
        dataset.select_sequences(dataset.discover_sequences(tmp_path), ["zzz"])
    (tmp_path / "c_seq" / "img").mkdir(parents=True)
    with pytest.raises(ValueError, match="c_seq: incomplete, missing groundtruth_rect.txt"):
        dataset.discover_sequences(tmp_path)
    with pytest.raises(ValueError, match="no sequence folders"):
        dataset.discover_sequences(tmp_path / "notes")


def test_load_published(tmp_path):
    (tmp_path / "T").mkdir()
    (tmp_path / "T" / "s.txt").write_text("11\t21\t5\t6\n12,22,5,6\n")
    boxes = dataset.load_published(tmp_path, "T", "s", 2)
    np.testing.assert_array_equal(boxes, [[10, 20, 5, 6], [11, 21, 5, 6]])
    assert dataset.load_published(tmp_path, "T", "other", 2) is None
    with pytest.raises(ValueError, match="2 rows but the sequence has 3 frames"):
        dataset.load_published(tmp_path, "T", "s", 3)
    assert dataset.published_trackers(tmp_path) == ["T"]


def test_synthetic_sequence_round_trips_through_the_loader(tmp_path):
    frames, boxes = synthetic_clip(n_frames=4, size=(60, 80), object_size=(12, 10))
    seq = dataset.load_sequence(write_otb_sequence(tmp_path / "syn", frames, boxes, separator="\t"))
    np.testing.assert_array_equal(seq.groundtruth, boxes)
    assert seq.read_frame(0).shape == (60, 80, 3)
