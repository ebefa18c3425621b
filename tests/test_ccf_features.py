"""Integral images give the same rectangle means as a direct mean; LUV/gradient channels."""

from __future__ import annotations

import numpy as np

from follow.ccf.channels import ChannelFeatureExtractor
from follow.ccf.features import FeatureMaps, RectIndex


def test_rect_means_equal_direct_means():
    rng = np.random.default_rng(0)
    maps = rng.random((20, 10, 3))
    fm = FeatureMaps.from_maps(maps)
    rects = np.array([[0.0, 0.0, 1.0, 1.0], [0.2, 0.25, 0.5, 0.75], [0.9, 0.9, 0.95, 0.95]])
    channels = np.array([0, 2, 1])
    got = fm.rect_means(channels, rects)
    idx = RectIndex.build(rects, (20, 10))
    for k in range(3):
        r0, r1, c0, c1 = idx.r0[k], idx.r1[k], idx.c0[k], idx.c1[k]
        assert r1 > r0 and c1 > c0  # never empty, even for a sliver
        assert np.isclose(got[k], maps[r0:r1, c0:c1, channels[k]].mean())
    assert np.isclose(got[0], maps[..., 0].mean())
    assert (idx.r0[1], idx.r1[1], idx.c0[1], idx.c1[1]) == (5, 15, 2, 5)


def test_channel_features_respond_to_colour_and_edges():
    extractor = ChannelFeatureExtractor(crop_size=(16, 32))
    flat_red = np.zeros((64, 32, 3), np.uint8)
    flat_red[..., 2] = 200
    striped = np.zeros((64, 32, 3), np.uint8)
    striped[:, ::8] = 255
    striped[:, 1::8] = 255
    a, b = extractor.extract_crops([flat_red, striped])
    assert a.num_channels == 10 and a.map_size == (16, 8)
    whole = np.array([[0.0, 0.0, 1.0, 1.0]] * 10)
    mean_a = a.rect_means(np.arange(10), whole)
    mean_b = b.rect_means(np.arange(10), whole)
    assert mean_a[3] < 0.01 < mean_b[3]  # gradient magnitude: flat vs stripes
    assert mean_b[4] > 0.5 * mean_b[3]  # vertical stripes: horizontal gradients, bin 0
    assert abs(mean_a[1] - mean_b[1]) > 0.05  # u differs between red and gray
    assert np.all((mean_a >= 0) & (mean_a <= 1)) and np.all((mean_b >= 0) & (mean_b <= 1))
