"""Letterbox planning, exact coordinate mapping, frame validation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from follow.pose.preprocess import (
    FrameFilter,
    heatmap_to_network_px,
    median_filtered,
    plan_letterbox,
    prepare_frame,
    prepare_input,
    unsharp_masked,
)
from follow.types import InvalidInput


def test_width_follows_aspect_ratio_and_is_padded_to_stride():
    plan = plan_letterbox((480, 360), 256)
    assert plan.resized_size == (341, 256)
    assert plan.input_size == (344, 256)
    plan = plan_letterbox((1280, 720), 368)
    assert plan.resized_size == (654, 368) and plan.input_size == (656, 368)


def test_input_height_must_be_a_multiple_of_the_stride():
    with pytest.raises(ValueError, match="multiple of 8"):
        plan_letterbox((480, 360), 250)


@given(
    st.integers(16, 2000), st.integers(16, 2000), st.sampled_from([128, 256, 368, 480]),
    st.floats(-0.5, 1999.5), st.floats(-0.5, 1999.5),
)  # fmt: skip
def test_mapping_to_network_and_back_is_exact(width, height, input_h, x, y):
    plan = plan_letterbox((width, height), input_h)
    pt = np.array([x, y])
    assert np.allclose(plan.to_original(plan.to_network(pt)), pt, atol=1e-9)


def test_pixel_centres_and_edges_map_consistently():
    plan = plan_letterbox((480, 360), 240)  # exactly two thirds of the frame
    assert plan.resized_size == (320, 240)
    # Original pixel edges -0.5 and 479.5 are the network image's edges -0.5 and 319.5.
    assert np.allclose(plan.to_network(np.array([[-0.5, -0.5], [479.5, 359.5]])),
                       [[-0.5, -0.5], [319.5, 239.5]])  # fmt: skip
    # A heatmap cell's centre is the centre of its 8x8 block of input pixels.
    assert np.allclose(heatmap_to_network_px(np.array([0.0, 2.0])), [3.5, 19.5])


def test_tensor_is_raw_bgr_with_neutral_padding():
    image = np.zeros((360, 480, 3), np.uint8)
    image[..., 0] = 200  # blue
    tensor, plan = prepare_input(image, 256)
    assert tensor.shape == (1, 3, 256, 344) and tensor.dtype == np.float32
    assert np.all(tensor[0, 0, :, : plan.resized_size[0]] == 200)
    assert np.all(tensor[0, 1:, :, : plan.resized_size[0]] == 0)
    assert np.all(tensor[0, :, :, plan.resized_size[0] :] == 128)


@pytest.mark.parametrize(
    "frame, message",
    [
        (None, "None"),
        (np.zeros((0, 0, 3), np.uint8), "empty"),
        (np.zeros((360, 480), np.uint8), "HxWx3"),
        (np.zeros((360, 480, 3), np.float32), "uint8"),
        (np.zeros((4, 4, 3), np.uint8), "too small"),
        (b"\xff\xd8 corrupt jpeg", "numpy array"),
    ],
)
def test_bad_frames_are_rejected_with_a_clear_message(frame, message):
    with pytest.raises(InvalidInput, match=message):
        prepare_input(frame, 256)


def test_the_median_filter_removes_specks_and_keeps_edges():
    """Isolated noise pixels go; a person's outline (a step edge) stays where it was,
    to the pixel, which a blur of the same size would smear."""
    image = np.zeros((40, 60, 3), np.uint8)
    image[:, 30:] = 200  # a vertical edge
    specks = image.copy()
    specks[10, 10] = 255
    specks[20, 45] = 0
    assert median_filtered(specks, 0) is specks
    filtered = median_filtered(specks, 1)
    np.testing.assert_array_equal(filtered, image)


def test_the_network_input_is_made_from_the_filtered_frame():
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    frame_filter = FrameFilter(median_radius_px=2, unsharp_amount=0.5)
    smooth = unsharp_masked(median_filtered(image, 2), 0.5, 1.0)
    assert not np.array_equal(smooth, image)
    for prepare in (prepare_input, prepare_frame):
        want, _ = prepare(smooth, 32)
        got, _ = prepare(image, 32, None, frame_filter)
        np.testing.assert_array_equal(got, want)
        assert not np.array_equal(prepare(image, 32)[0], want)


def test_the_unsharp_mask_steepens_a_soft_edge_and_leaves_flat_areas():
    """A step blurred by the lens gets back a steeper slope across the edge; far from
    it, flat grey stays as it was."""
    import cv2

    step = np.zeros((20, 60, 3), np.uint8)
    step[:, 30:] = 160
    soft = cv2.GaussianBlur(step, (0, 0), 1.5)
    assert unsharp_masked(soft, 0.0, 1.0) is soft
    sharp = unsharp_masked(soft, 0.5, 1.0)
    slope = np.abs(np.diff(soft[10, :, 0].astype(int))).max()
    assert np.abs(np.diff(sharp[10, :, 0].astype(int))).max() > slope
    np.testing.assert_array_equal(sharp[:, :20], soft[:, :20])
    np.testing.assert_array_equal(sharp[:, 45:], soft[:, 45:])


@pytest.mark.parametrize(("frame_size", "input_height_px", "interpolation"), [
    ((640, 480), 368, "INTER_LINEAR"),  # a robot camera's frame to the robot input: 0.77x
    ((640, 480), 256, "INTER_LINEAR"),  # the smallest people-sized input: 0.53x
    ((1920, 1080), 368, "INTER_AREA"),  # a 1080p frame: 0.34x, bilinear would skip pixels
    ((320, 240), 368, "INTER_LINEAR"),  # enlarged
])  # fmt: skip
def test_a_frame_is_shrunk_bilinearly_down_to_half_size_and_area_averaged_below(
    frame_size, input_height_px, interpolation
):
    import cv2

    width, height = frame_size
    rng = np.random.default_rng(0)
    frame = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)  # every pixel its own
    tensor, plan = prepare_frame(frame, input_height_px)
    expected = cv2.resize(frame, plan.resized_size, interpolation=getattr(cv2, interpolation))
    np.testing.assert_array_equal(tensor[0, :, : plan.resized_size[0]], expected)
