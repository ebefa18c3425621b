"""PETS 2009 reader: ground truth parsing, scaling, occlusion, frame access."""

from __future__ import annotations

import numpy as np
import pytest

from follow.eval.pets import (
    VIDEO_SCALE,
    GtBox,
    PetsError,
    PetsSequence,
    evenly_spaced_frames,
    load_ground_truth,
    with_hidden_fractions,
)


def test_hidden_fraction_counts_only_nearer_people():
    far = GtBox(1, xc=100, yc=100, w=20, h=40)  # bottom at 120
    near = GtBox(2, xc=110, yc=110, w=20, h=40)  # bottom at 130, covers half of far
    far_h, near_h = with_hidden_fractions([far, near])
    assert far_h.hidden_fraction == pytest.approx(0.5 * 0.75, abs=0.03)
    assert near_h.hidden_fraction == 0.0


def test_hidden_fraction_uses_the_union_of_occluders():
    back = GtBox(1, xc=50, yc=50, w=20, h=20)
    left = GtBox(2, xc=45, yc=65, w=10, h=50)  # covers the left half
    also_left = GtBox(3, xc=45, yc=66, w=10, h=52)  # the same half again
    out = with_hidden_fractions([back, left, also_left])
    assert out[0].hidden_fraction == pytest.approx(0.5, abs=0.05)


def test_malformed_ground_truth_is_reported(tmp_path):
    bad = tmp_path / "gt.xml"
    bad.write_text('<dataset><frame number="0"><objectlist><object id="1">'
                   '<box h="x" w="1" xc="1" yc="1"/></object></objectlist></frame></dataset>')  # fmt: skip
    with pytest.raises(PetsError, match=r"frame 0, object '1': .*numeric xc, yc, w, h"):
        load_ground_truth(bad)
    with pytest.raises(PetsError, match="not found"):
        PetsSequence(tmp_path)


def test_evenly_spaced_frames():
    assert evenly_spaced_frames(795, 5) == [0, 198, 397, 596, 794]
    assert evenly_spaced_frames(3, 10) == [0, 1, 2]


def test_real_ground_truth_and_video(data_path):
    seq = PetsSequence(data_path("pets2009_s2l1/View_001.avi").parent)
    assert seq.frame_count == 795
    first = {b.person_id: b for b in seq.boxes_gt_px(0)}
    assert set(first) == {9, 15, 19}
    assert first[15].xc == pytest.approx(274.4912) and first[15].h == pytest.approx(88.7021)
    video = {b.person_id: b for b in seq.boxes_video_px(0)}
    assert video[15].xc == pytest.approx(274.4912 * VIDEO_SCALE)
    fractions = [b.hidden_fraction for f in range(0, 795, 5) for b in seq.boxes_gt_px(f)]
    assert 0.0 < np.mean(np.array(fractions) > 0.5) < 0.3  # some, not most, people hidden
    image = seq.read_frame(10)
    assert image.shape == (360, 480, 3) and image.dtype == np.uint8
    # Random access returns the same picture as sequential reading.
    seq.read_frame(3)
    assert np.array_equal(seq.read_frame(10), image)
    again = PetsSequence(seq.root)
    assert np.array_equal(again.read_frame(10), image)
    with pytest.raises(PetsError, match="out of range"):
        seq.read_frame(795)
