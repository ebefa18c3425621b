"""Convolutional Channel Features: the first layers of a small re-id network as channels.

RGB crop / 256 -> conv1 (5x5, pad 2) -> ReLU -> 2x2 max-pool -> conv2 (5x5, pad 2); each
output map is quantised to 8 bits as clip(round(128 x), 0, 255), as in the reference
implementation, and scaled to [0, 1] for the classifier. All crops of a frame run as one
batch, through onnxruntime (a graph built in memory from the weights) when the `onnx`
package is importable, else through a numpy im2col implementation.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from follow.ccf.features import FeatureMaps, Roi, cut_crops, integral_images, resize_crops
from follow.ccf.weights import CcfWeights, ConvLayer

log = logging.getLogger(__name__)

INPUT_SCALE = 1.0 / 256.0  # pixel -> network input
OUTPUT_QUANT_GAIN = 128.0  # network output -> 8-bit map
POOL_SIZE = 2


def conv2d_same(x: np.ndarray, layer: ConvLayer) -> np.ndarray:
    """Cross-correlation with zero 'same' padding: (B, Cin, H, W) -> (B, Cout, H, W)."""
    kh, kw = layer.kernel_size
    ph, pw = kh // 2, kw // 2
    xp = np.pad(x, ((0, 0), (0, 0), (ph, ph), (pw, pw)))
    windows = np.lib.stride_tricks.sliding_window_view(xp, (kh, kw), axis=(2, 3))
    out = np.tensordot(windows, layer.weights, axes=([1, 4, 5], [1, 2, 3]))  # B, H, W, Cout
    out += layer.biases
    return np.ascontiguousarray(out.transpose(0, 3, 1, 2))


def max_pool(x: np.ndarray, size: int = POOL_SIZE) -> np.ndarray:
    """Non-overlapping size x size max-pool (trailing odd rows/columns dropped)."""
    b, c, h, w = x.shape
    h2, w2 = h // size, w // size
    return x[:, :, : h2 * size, : w2 * size].reshape(b, c, h2, size, w2, size).max(axis=(3, 5))


def quantise(maps: np.ndarray) -> np.ndarray:
    """Network output -> 8-bit maps, clip(round(128 x), 0, 255)."""
    return np.clip(np.rint(OUTPUT_QUANT_GAIN * maps), 0, 255).astype(np.uint8)


def forward_numpy(weights: CcfWeights, batch_rgb: np.ndarray) -> np.ndarray:
    """Raw conv2 output (B, N2, H/2, W/2) float32 of an input batch (B, 3, H, W) in [0, 1)."""
    x = conv2d_same(batch_rgb.astype(np.float32), weights.conv1)
    np.maximum(x, 0.0, out=x)
    return conv2d_same(max_pool(x), weights.conv2).astype(np.float32)


def _onnx_session(weights: CcfWeights, threads: int):
    """An onnxruntime session of the network, or None when `onnx` is not installed."""
    try:
        import onnxruntime as ort
        from onnx import TensorProto, helper, numpy_helper
    except ImportError:
        return None
    k1, k2 = weights.conv1.kernel_size, weights.conv2.kernel_size
    nodes = [
        helper.make_node(
            "Conv", ["x", "w1", "b1"], ["c1"], kernel_shape=list(k1),
            pads=[k1[0] // 2, k1[1] // 2, k1[0] // 2, k1[1] // 2],
        ),
        helper.make_node("Relu", ["c1"], ["r1"]),
        helper.make_node(
            "MaxPool", ["r1"], ["p1"], kernel_shape=[POOL_SIZE] * 2, strides=[POOL_SIZE] * 2
        ),
        helper.make_node(
            "Conv", ["p1", "w2", "b2"], ["y"], kernel_shape=list(k2),
            pads=[k2[0] // 2, k2[1] // 2, k2[0] // 2, k2[1] // 2],
        ),
    ]  # fmt: skip
    inits = [
        numpy_helper.from_array(np.ascontiguousarray(a, dtype=np.float32), n)
        for a, n in (
            (weights.conv1.weights, "w1"), (weights.conv1.biases, "b1"),
            (weights.conv2.weights, "w2"), (weights.conv2.biases, "b2"),
        )
    ]  # fmt: skip
    graph = helper.make_graph(
        nodes,
        "ccf",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["n", 3, "h", "w"])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, None)],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    options = ort.SessionOptions()
    options.intra_op_num_threads = max(1, int(threads))
    options.inter_op_num_threads = 1
    return ort.InferenceSession(
        model.SerializeToString(), options, providers=["CPUExecutionProvider"]
    )


class CcfExtractor:
    """CCF feature maps of person crops (batched)."""

    def __init__(
        self,
        weights: CcfWeights,
        crop_size: tuple[int, int] = (48, 128),
        backend: str = "auto",
        threads: int = 1,
        name: str | None = None,
    ):
        if backend not in ("auto", "onnxruntime", "numpy"):
            raise ValueError(f"CCF backend must be auto | onnxruntime | numpy, got {backend!r}")
        self.weights = weights
        self.name = name or weights.name
        self.num_channels = weights.num_channels
        self.crop_size = (int(crop_size[0]), int(crop_size[1]))
        if min(self.crop_size) < 2 * POOL_SIZE:
            raise ValueError(f"CCF crop size {self.crop_size} is too small")
        self._session = None if backend == "numpy" else _onnx_session(weights, threads)
        if backend == "onnxruntime" and self._session is None:
            raise ValueError("CCF backend 'onnxruntime' needs the `onnx` package")
        self.backend = "onnxruntime" if self._session is not None else "numpy"

    def forward(self, crops_bgr: np.ndarray) -> np.ndarray:
        """Quantised 8-bit maps (N, C, H/2, W/2) of crops (N, H, W, 3) BGR uint8."""
        batch = crops_bgr[..., ::-1].transpose(0, 3, 1, 2).astype(np.float32) * INPUT_SCALE
        if self._session is not None:
            raw = self._session.run(None, {"x": np.ascontiguousarray(batch)})[0]
        else:
            raw = forward_numpy(self.weights, batch)
        return quantise(raw)

    def _maps(self, crops: np.ndarray) -> list[FeatureMaps]:
        if len(crops) == 0:
            return []
        maps = self.forward(crops).astype(np.float32) * (1.0 / 255.0)
        return [FeatureMaps(ii) for ii in integral_images(maps)]

    def extract(self, image_bgr: np.ndarray, rois: Sequence[Roi]) -> list[FeatureMaps]:
        return self._maps(cut_crops(image_bgr, rois, self.crop_size))

    def extract_crops(self, crops_bgr: Sequence[np.ndarray]) -> list[FeatureMaps]:
        return self._maps(resize_crops(crops_bgr, self.crop_size))
