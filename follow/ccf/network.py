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
MAX_BATCH = 4  # crops per network run: larger batches spill the conv1 output out of cache


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
    """An onnxruntime session of the whole extraction, or None when `onnx` is missing.

    Input: crops (N, H, W, 3) BGR uint8. Output: maps (N, H/2, W/2, C) float32 in [0, 1],
    quantised to 8 bits. The pixel scale and the BGR -> RGB swap are folded into conv1's
    weights, so no preprocessing runs in Python."""
    try:
        import onnxruntime as ort
        from onnx import TensorProto, helper, numpy_helper

        from follow.onnx_ir import portable_model
    except ImportError:
        return None
    k1, k2 = weights.conv1.kernel_size, weights.conv2.kernel_size
    w1_bgr = weights.conv1.weights[:, ::-1] * np.float32(INPUT_SCALE)
    node = helper.make_node
    nodes = [
        node("Cast", ["crops"], ["f"], to=TensorProto.FLOAT),
        node("Transpose", ["f"], ["x"], perm=[0, 3, 1, 2]),
        node("Conv", ["x", "w1", "b1"], ["c1"], kernel_shape=list(k1),
             pads=[k1[0] // 2, k1[1] // 2, k1[0] // 2, k1[1] // 2]),
        node("Relu", ["c1"], ["r1"]),
        node("MaxPool", ["r1"], ["p1"], kernel_shape=[POOL_SIZE] * 2, strides=[POOL_SIZE] * 2),
        node("Conv", ["p1", "w2", "b2"], ["c2"], kernel_shape=list(k2),
             pads=[k2[0] // 2, k2[1] // 2, k2[0] // 2, k2[1] // 2]),
        node("Mul", ["c2", "gain"], ["g"]),
        node("Round", ["g"], ["q"]),
        node("Clip", ["q", "zero", "top"], ["qc"]),
        node("Mul", ["qc", "unit"], ["u"]),
        node("Transpose", ["u"], ["maps"], perm=[0, 2, 3, 1]),
    ]  # fmt: skip
    consts = {
        "w1": w1_bgr, "b1": weights.conv1.biases, "w2": weights.conv2.weights,
        "b2": weights.conv2.biases, "gain": np.float32(OUTPUT_QUANT_GAIN),
        "zero": np.float32(0.0), "top": np.float32(255.0), "unit": np.float32(1.0 / 255.0),
    }  # fmt: skip
    inits = [
        numpy_helper.from_array(np.ascontiguousarray(v, dtype=np.float32), k)
        for k, v in consts.items()
    ]
    graph = helper.make_graph(
        nodes,
        "ccf",
        [helper.make_tensor_value_info("crops", TensorProto.UINT8, ["n", "h", "w", 3])],
        [helper.make_tensor_value_info("maps", TensorProto.FLOAT, None)],
        inits,
    )
    model = portable_model(graph)
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

    def maps(self, crops_bgr: np.ndarray) -> np.ndarray:
        """Maps (N, H/2, W/2, C) float32 in [0, 1] (8-bit quantised) of crops (N, H, W, 3)
        BGR uint8."""
        crops_bgr = np.ascontiguousarray(crops_bgr, dtype=np.uint8)
        if self._session is not None:
            if len(crops_bgr) <= MAX_BATCH:
                return self._session.run(None, {"crops": crops_bgr})[0]
            return np.concatenate(
                [
                    self._session.run(None, {"crops": crops_bgr[i : i + MAX_BATCH]})[0]
                    for i in range(0, len(crops_bgr), MAX_BATCH)
                ]
            )
        rgb = crops_bgr[..., ::-1].transpose(0, 3, 1, 2).astype(np.float32) * INPUT_SCALE
        q = quantise(forward_numpy(self.weights, rgb)).transpose(0, 2, 3, 1)
        return q.astype(np.float32) * np.float32(1.0 / 255.0)

    def forward(self, crops_bgr: np.ndarray) -> np.ndarray:
        """Quantised 8-bit maps (N, C, H/2, W/2) of crops (N, H, W, 3) BGR uint8."""
        return np.rint(self.maps(crops_bgr) * 255.0).astype(np.uint8).transpose(0, 3, 1, 2)

    def _maps(self, crops: np.ndarray) -> list[FeatureMaps]:
        if len(crops) == 0:
            return []
        return [FeatureMaps(ii) for ii in integral_images(self.maps(crops))]

    def extract(self, image_bgr: np.ndarray, rois: Sequence[Roi]) -> list[FeatureMaps]:
        return self._maps(cut_crops(image_bgr, rois, self.crop_size))

    def extract_crops(self, crops_bgr: Sequence[np.ndarray]) -> list[FeatureMaps]:
        return self._maps(resize_crops(crops_bgr, self.crop_size))
