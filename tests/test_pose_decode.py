"""Decoding on synthetic heatmaps and PAFs whose true skeletons are known."""

from __future__ import annotations

import numpy as np

from follow.pose.decode import (
    LIMB_KEYPOINTS,
    LIMB_PAF_CHANNELS,
    DecodedPerson,
    DecodeParams,
    decode,
    find_peaks,
    match_limb,
    suppress_duplicates,
)
from follow.types import Skeleton

H, W = 40, 60


def gaussian(cx: float, cy: float, sigma: float = 1.0) -> np.ndarray:
    y, x = np.mgrid[0:H, 0:W]
    return np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * sigma**2))


def person(x0: float, y0: float, size: float = 1.0) -> np.ndarray:
    """An upright person's 18 keypoints in heatmap cells (NaN for missing face parts)."""
    offsets = {
        0: (0, -2), 1: (0, 0), 2: (-2, 0.2), 3: (-2.5, 3), 4: (-2.7, 6), 5: (2, 0.2),
        6: (2.5, 3), 7: (2.7, 6), 8: (-1.2, 7), 9: (-1.3, 11), 10: (-1.4, 15),
        11: (1.2, 7), 12: (1.3, 11), 13: (1.4, 15),
    }  # fmt: skip
    kps = np.full((18, 2), np.nan)
    for k, (dx, dy) in offsets.items():
        kps[k] = (x0 + dx * size, y0 + dy * size)
    return kps


def render(people: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Heatmaps (19, H, W) and PAFs (38, H, W) as the network is trained to output them."""
    heatmaps = np.zeros((19, H, W), np.float32)
    pafs = np.zeros((38, H, W), np.float32)
    y, x = np.mgrid[0:H, 0:W]
    for kps in people:
        for k in range(18):
            if np.isfinite(kps[k]).all():
                heatmaps[k] = np.maximum(heatmaps[k], gaussian(*kps[k]))
        for (ka, kb), (cx, cy) in zip(LIMB_KEYPOINTS, LIMB_PAF_CHANNELS, strict=True):
            a, b = kps[ka], kps[kb]
            if not (np.isfinite(a).all() and np.isfinite(b).all()):
                continue
            v = b - a
            length = np.linalg.norm(v)
            u = v / length
            rel_x, rel_y = x - a[0], y - a[1]
            along = rel_x * u[0] + rel_y * u[1]
            across = np.abs(-rel_x * u[1] + rel_y * u[0])
            on = (along >= -0.5) & (along <= length + 0.5) & (across <= 0.8)
            pafs[cx][on] = u[0]
            pafs[cy][on] = u[1]
    return heatmaps, pafs


def test_peaks_are_refined_below_one_cell():
    heatmaps = np.zeros((19, H, W), np.float32)
    heatmaps[1] = gaussian(10.3, 7.6, sigma=1.5)
    heatmaps[4] = 0.9 * gaussian(40.8, 30.2, sigma=1.5)
    peaks = find_peaks(heatmaps, 0.1)
    assert len(peaks[1]) == 1 and len(peaks[4]) == 1
    assert np.allclose(peaks[1][0, :2], (10.3, 7.6), atol=0.1)
    assert np.allclose(peaks[4][0, :2], (40.8, 30.2), atol=0.1)
    assert sum(len(p) for p in peaks) == 2


def test_flat_top_gives_a_single_peak():
    heatmaps = np.zeros((19, H, W), np.float32)
    heatmaps[2, 10:12, 20:22] = 0.5
    assert len(find_peaks(heatmaps, 0.1)[2]) == 1


def test_two_people_side_by_side_are_separated():
    truth = [person(15.2, 10.4), person(22.7, 12.1)]
    heatmaps, pafs = render(truth)
    found = decode(heatmaps, pafs, DecodeParams())
    assert len(found) == 2
    found.sort(key=lambda p: p.keypoints_cells[1, 0])
    for p, kps in zip(found, truth, strict=True):
        present = np.isfinite(kps).all(axis=1)
        assert np.array_equal(np.isfinite(p.keypoints_cells).all(axis=1), present)
        assert np.allclose(p.keypoints_cells[present], kps[present], atol=0.15)
        assert np.all(p.confidences[present] > 0.75)
        assert np.all(p.confidences[~present] == 0)


def test_limbs_are_not_joined_across_people_without_paf_support():
    truth = [person(15.0, 10.0), person(40.0, 10.0)]
    heatmaps, pafs = render(truth)
    # Remove the left person's neck->right-hip PAF: its hip chain must not jump across.
    pafs[0:2] = np.where(np.arange(W)[None, None, :] < 28, 0.0, pafs[0:2])
    found = decode(heatmaps, pafs, DecodeParams())
    necks = sorted(p.keypoints_cells[1, 0] for p in found if np.isfinite(p.keypoints_cells[1, 0]))
    assert np.allclose(necks, [15.0, 40.0], atol=0.15)
    for p in found:
        xs = p.keypoints_cells[:, 0][np.isfinite(p.keypoints_cells[:, 0])]
        assert xs.max() - xs.min() < 10, "a person was assembled from parts of both"


def test_persons_with_too_few_parts_are_dropped():
    lone = np.full((18, 2), np.nan)
    lone[1] = (30, 20)
    lone[2] = (28, 20.2)  # neck + one shoulder: 2 parts
    heatmaps, pafs = render([lone])
    assert decode(heatmaps, pafs, DecodeParams(min_keypoints_per_person=3)) == []
    assert len(decode(heatmaps, pafs, DecodeParams(min_keypoints_per_person=2))) == 1


def test_empty_maps_give_no_people():
    assert decode(np.zeros((19, H, W)), np.zeros((38, H, W)), DecodeParams()) == []


def test_greedy_matching_uses_each_candidate_once():
    scores = np.array([[0.9, 0.8], [0.85, -np.inf]])
    assert match_limb(scores) == [(0, 0, 0.9)]
    scores = np.array([[0.5, 0.8], [0.85, -np.inf]])
    assert sorted(match_limb(scores)) == [(0, 1, 0.8), (1, 0, 0.85)]


def test_ten_people_in_two_rows_decode_into_ten_skeletons():
    count = 10
    truth = [person(5 + 5.5 * i, 8 + (i % 2) * 14, size=0.8) for i in range(count)]
    heatmaps, pafs = render(truth)
    found = decode(heatmaps, pafs, DecodeParams())
    assert len(found) == count


def _decoded(kps: np.ndarray, score: float = 5.0) -> DecodedPerson:
    return DecodedPerson(kps, np.where(np.isfinite(kps[:, 0]), 0.5, 0.0), score)


def test_a_second_skeleton_on_the_same_keypoints_is_suppressed():
    whole = person(20, 10, size=2.0)
    upper = np.full((18, 2), np.nan)
    upper[[1, 2, 5]] = whole[[1, 2, 5]] + 0.6  # neck and shoulders a fraction of a cell off
    upper[[3]] = whole[[3]] + (8.0, 0.0)  # an elbow placed elsewhere keeps it out of the box
    kept = suppress_duplicates([_decoded(upper, 9.0), _decoded(whole)], DecodeParams())
    assert len(kept) == 1 and np.isfinite(kept[0].keypoints_cells[10]).all()  # the whole one


def test_a_fragment_inside_a_larger_skeleton_is_suppressed():
    whole = person(20, 10, size=2.0)
    fragment = np.full((18, 2), np.nan)
    fragment[[9, 10]] = whole[[9, 10]] + (1.5, -1.0)  # a second knee-ankle chain on the leg
    kept = suppress_duplicates([_decoded(whole), _decoded(fragment)], DecodeParams())
    assert len(kept) == 1


def test_neighbours_and_overlapping_people_at_other_places_are_kept():
    a, b = person(10, 5), person(16, 5)  # side by side, boxes apart
    c = person(13, 8)  # overlapping both boxes but no keypoint near theirs
    kept = suppress_duplicates([_decoded(a), _decoded(b), _decoded(c)], DecodeParams())
    assert len(kept) == 3


def test_non_finite_network_outputs_count_as_nothing():
    # A back-end fault (an FP16 overflow) can put inf or NaN in the maps: the frame
    # decodes into finite skeletons, rather than into confidences a Skeleton refuses.
    heatmaps, pafs = render([person(15.2, 10.4), person(40.0, 12.0)])
    heatmaps[1, 10, 15] = np.inf
    heatmaps[4, 30, 50] = np.inf
    heatmaps[7, 5, 5] = np.nan
    pafs[12, 10, 14] = np.inf
    pafs[0, 20, 20] = -np.inf
    found = decode(heatmaps, pafs, DecodeParams())
    assert found
    for p in found:
        assert np.isfinite(p.confidences).all() and np.isfinite(p.score)
        Skeleton(p.keypoints_cells, p.confidences, p.score)


def test_joints_beyond_the_frame_edges_are_not_reported_on_its_edge_rows():
    """Feet just below the frame peak on its last heatmap row, a neck just above it on
    the first: that is where they left the view, not where they are."""
    from follow.config import PoseConfig

    low = person(15.0, H - 1 - 13.0)  # ankles two cells below the last row
    high = person(40.0, -0.8)  # neck just above the first row, the rest inside
    heatmaps, pafs = render([low, high])
    kept = sorted(decode(heatmaps, pafs, DecodeParams()), key=lambda p: p.keypoints_cells[1, 0])
    raw = sorted(decode(heatmaps, pafs, DecodeParams(top_edge_margin_cells=0.0,
                                                     bottom_edge_margin_cells=0.0)),
                 key=lambda p: p.keypoints_cells[1, 0])  # fmt: skip
    assert PoseConfig().bottom_edge_margin_cells == DecodeParams().bottom_edge_margin_cells > 0
    assert PoseConfig().top_edge_margin_cells == DecodeParams().top_edge_margin_cells > 0
    ankles = [10, 13]
    assert np.allclose(raw[0].keypoints_cells[ankles, 1], H - 1)  # what the network says
    assert np.isnan(kept[0].keypoints_cells[ankles]).all()
    assert np.all(kept[0].confidences[ankles] == 0)
    knees = [9, 12]
    assert np.allclose(kept[0].keypoints_cells[knees], low[knees], atol=0.15)
    assert np.allclose(raw[1].keypoints_cells[1, 1], 0.0)
    assert np.isnan(kept[1].keypoints_cells[1]).all()
    assert np.allclose(kept[1].keypoints_cells[8], high[8], atol=0.15)  # a hip, inside


def test_a_person_with_every_keypoint_on_the_edge_rows_is_dropped():
    from follow.pose.decode import without_edge_keypoints

    on_edges = np.full((18, 2), np.nan)
    on_edges[1] = (10.0, 0.0)
    on_edges[2] = (12.0, H - 1.0)
    inside = on_edges.copy()
    inside[3] = (12.0, H - 2.6)
    people = [DecodedPerson(k, np.where(np.isfinite(k[:, 0]), 0.8, 0.0), 3.0)
              for k in (on_edges, inside)]  # fmt: skip
    left = without_edge_keypoints(people, H, 0.5, 1.0)
    assert len(left) == 1
    assert np.flatnonzero(np.isfinite(left[0].keypoints_cells[:, 0])).tolist() == [3]
    assert len(without_edge_keypoints(people, H, 0.5, 2.5)) == 0
    assert len(without_edge_keypoints(people, H, 0.0, 1.0)) == 2  # the neck on row 0 kept
