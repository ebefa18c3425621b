"""Heatmaps full of peaks (a faulty back-end) are decoded from the strongest candidates
of each keypoint only: every pair of candidates of a limb is scored, and 700 peaks a
heatmap took seconds and gigabytes a frame."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from test_pose_decode import person, render

import follow.pose.decode as decode_module
from follow.pose.decode import DecodeParams, decode, find_peaks

# The network's maps of a 640x480 frame at the default 368 px input.
ROWS, COLUMNS = 46, 62


def peak_every_other_cell() -> np.ndarray:
    """Heatmaps with a local maximum at every other cell of every other row."""
    grid = (np.arange(ROWS)[:, None] % 2 == 0) & (np.arange(COLUMNS)[None] % 2 == 0)
    return np.broadcast_to(grid.astype(np.float32) * 0.5, (19, ROWS, COLUMNS)).copy()


@pytest.fixture
def scored_peaks(monkeypatch) -> list:
    """The candidates per keypoint that each decode hands to limb scoring."""
    seen = []
    score_limbs = decode_module.score_limbs

    def recording(pafs, peaks, params):
        seen.append([len(p) for p in peaks])
        return score_limbs(pafs, peaks, params)

    monkeypatch.setattr(decode_module, "score_limbs", recording)
    return seen


def test_a_heatmap_full_of_peaks_pairs_only_its_strongest_candidates(scored_peaks):
    heatmaps = peak_every_other_cell()
    assert max(len(p) for p in find_peaks(heatmaps, 0.1)) > 700
    decode(heatmaps, np.zeros((38, ROWS, COLUMNS), np.float32), DecodeParams())
    assert max(scored_peaks[0]) == 64  # MAX_PEAKS_PER_KEYPOINT


def test_the_strongest_candidates_are_kept_in_their_order():
    heatmaps = peak_every_other_cell()
    heatmaps[3, 10, 20], heatmaps[3, 40, 4] = 0.8, 0.9
    kept, dropped = decode_module.strongest_peaks(find_peaks(heatmaps, 0.1), 2)
    np.testing.assert_allclose(kept[3], [[20, 10, 0.8], [4, 40, 0.9]], rtol=1e-6)
    assert all(len(p) == 2 for p in kept)
    assert dropped == sum(len(p) for p in find_peaks(heatmaps, 0.1)) - 2 * len(kept)


def test_dropping_candidates_is_warned_of_once_in_a_while(monkeypatch, caplog):
    monkeypatch.setattr(decode_module, "_peaks_dropped_warned_s", None)
    maps = peak_every_other_cell(), np.zeros((38, ROWS, COLUMNS), np.float32)
    with caplog.at_level(logging.WARNING, logger="follow.pose.decode"):
        decode(*maps, DecodeParams())
        decode(*maps, DecodeParams())
    assert len(caplog.records) == 1
    assert "beyond the 64 strongest of a heatmap" in caplog.text


def test_people_within_the_limit_decode_as_without_it(monkeypatch, caplog):
    crowd = [person(4 + 7 * i, 3 + 20 * row) for i in range(8) for row in range(2)]
    heatmaps, pafs = render(crowd)
    with caplog.at_level(logging.WARNING, logger="follow.pose.decode"):
        limited = decode(heatmaps, pafs, DecodeParams())
    monkeypatch.setattr(decode_module, "MAX_PEAKS_PER_KEYPOINT", 10**9)
    unlimited = decode(heatmaps, pafs, DecodeParams())
    assert len(limited) == len(crowd) and not caplog.records
    for a, b in zip(limited, unlimited, strict=True):
        np.testing.assert_array_equal(a.keypoints_cells, b.keypoints_cells)
        np.testing.assert_array_equal(a.confidences, b.confidences)
        assert a.score == b.score
