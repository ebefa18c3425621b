"""The CCF network against a direct reference convolution."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import correlate2d

from follow.ccf.network import CcfExtractor, forward_numpy, quantise
from follow.ccf.weights import CcfWeights, ConvLayer, load_ccf_weights


def reference_forward(weights: CcfWeights, rgb: np.ndarray) -> np.ndarray:
    """conv1 -> ReLU -> 2x2 max-pool -> conv2 for one image (3, H, W), float64, scipy."""

    def conv(x, layer):
        out = np.zeros((layer.out_channels, *x.shape[1:]))
        for o in range(layer.out_channels):
            for c in range(layer.in_channels):
                out[o] += correlate2d(x[c], layer.weights[o, c].astype(np.float64), mode="same")
            out[o] += layer.biases[o]
        return out

    x = np.maximum(conv(rgb.astype(np.float64), weights.conv1), 0.0)
    c, h, w = x.shape
    pooled = np.zeros((c, h // 2, w // 2))
    for i in range(h // 2):
        for j in range(w // 2):
            pooled[:, i, j] = x[:, 2 * i : 2 * i + 2, 2 * j : 2 * j + 2].max(axis=(1, 2))
    return conv(pooled, weights.conv2)


def _random_weights(seed=0) -> CcfWeights:
    rng = np.random.default_rng(seed)
    return CcfWeights(
        ConvLayer(rng.normal(0, 0.3, (4, 3, 5, 5)).astype(np.float32), rng.normal(0, 0.1, 4).astype(np.float32)),
        ConvLayer(rng.normal(0, 0.3, (5, 4, 5, 5)).astype(np.float32), rng.normal(0, 0.1, 5).astype(np.float32)),
    )  # fmt: skip


def _crops(n, h=32, w=16, seed=3):
    return np.random.default_rng(seed).integers(0, 256, size=(n, h, w, 3), dtype=np.uint8)


def _agree(quantised: np.ndarray, raw_reference: np.ndarray) -> None:
    ref = quantise(raw_reference)
    diff = np.abs(quantised.astype(int) - ref.astype(int))
    # float32 vs float64: a value on a rounding boundary may land one step apart
    assert diff.max() <= 1
    assert (diff == 0).mean() > 0.999


def test_numpy_forward_equals_reference_convolution():
    weights = _random_weights()
    crops = _crops(2)
    rgb = crops[..., ::-1].transpose(0, 3, 1, 2) / 256.0
    raw = forward_numpy(weights, rgb)
    for i in range(2):
        np.testing.assert_allclose(raw[i], reference_forward(weights, rgb[i]), atol=1e-4)


@pytest.mark.parametrize("backend", ["numpy", "onnxruntime"])
def test_extractor_equals_reference_on_real_weights(model_path, backend):
    pytest.importorskip("onnx") if backend == "onnxruntime" else None
    weights = load_ccf_weights(model_path("ccf/ccf10"))
    extractor = CcfExtractor(weights, crop_size=(16, 32), backend=backend)
    crops = _crops(3)
    maps = extractor.forward(crops)
    assert maps.shape == (3, 10, 16, 8) and maps.dtype == np.uint8
    for i in range(3):
        rgb = crops[i][..., ::-1].transpose(2, 0, 1) / 256.0  # RGB, pixel / 256
        _agree(maps[i], reference_forward(weights, rgb))
    assert 0 < maps.mean() < 255  # not saturated: the test compares something


def test_channel_order_matters():
    """The network sees RGB: feeding the crop as BGR would give other maps."""
    weights = _random_weights(4)
    extractor = CcfExtractor(weights, crop_size=(16, 32), backend="numpy")
    crop = _crops(1, seed=5)
    rgb = crop[0][..., ::-1].transpose(2, 0, 1) / 256.0
    bgr = crop[0].transpose(2, 0, 1) / 256.0
    maps = extractor.forward(crop)[0]
    _agree(maps, reference_forward(weights, rgb))
    assert np.abs(maps.astype(int) - quantise(reference_forward(weights, bgr))).mean() > 1


def test_feature_maps_are_scaled_integrals_of_the_quantised_maps():
    weights = _random_weights(6)
    extractor = CcfExtractor(weights, crop_size=(16, 32), backend="numpy")
    image = np.random.default_rng(7).integers(0, 256, size=(100, 80, 3), dtype=np.uint8)
    maps = extractor.extract(image, [(10, 5, 26, 69), (40, 20, 60, 90)])
    assert len(maps) == 2
    q = extractor.forward(np.stack([_resized(image, (10, 5, 26, 69))]))[0] / 255.0
    assert maps[0].map_size == (16, 8)
    np.testing.assert_allclose(maps[0].integral[-1, -1], q.sum(axis=(1, 2)), rtol=1e-5)


def _resized(image, roi):
    import cv2

    x0, y0, x1, y1 = roi
    return cv2.resize(image[y0:y1, x0:x1], (16, 32), interpolation=cv2.INTER_AREA)
