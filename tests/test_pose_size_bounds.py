"""A library caller's frames: too large a frame is refused by name, and what the detector
keeps per input size stays bounded however many sizes come."""

from __future__ import annotations

import numpy as np
import pytest
from test_pose_frame_input import _tiny_pose_like_model

from follow.config import PoseConfig
from follow.pose.detector import PoseDetector
from follow.pose.people_sized_input import MAX_SMALLER_HEIGHTS, PeopleSizedInput
from follow.pose.preprocess import MAX_FRAME_ASPECT, MAX_FRAME_SIDE_PX, check_frame
from follow.pose.runtime import OpenVinoBackend, openvino_installed
from follow.pose.size_cache import FRAME_SIZES_KEPT, SHAPES_KEPT, RecentlyUsed
from follow.types import InvalidInput

PROVIDERS = ["cpu", pytest.param("openvino", marks=pytest.mark.skipif(
    not openvino_installed(), reason="openvino is not installed"))]  # fmt: skip


@pytest.fixture
def tiny_model(tmp_path):
    path = tmp_path / "tiny.onnx"
    _tiny_pose_like_model(path)
    return path


def detector_for(provider: str, model) -> PoseDetector:
    config = PoseConfig(provider=provider, input_height_px=64, input_height_from_people=False,
                        network_stages=2, warmup_runs=0)  # fmt: skip
    return PoseDetector(config, model)


@pytest.mark.parametrize(
    ("height", "width", "message"),
    [
        (MAX_FRAME_SIDE_PX + 8, 640, f"too large \\(640x{MAX_FRAME_SIDE_PX + 8} px; at most 8192"),
        (480, MAX_FRAME_SIDE_PX + 8, f"too large \\({MAX_FRAME_SIDE_PX + 8}x480 px; at most 8192"),
        (16, 16 * MAX_FRAME_ASPECT + 8, "too wide \\(136x16 px; at most 8 times as wide"),
    ],
)
def test_a_frame_beyond_the_bound_is_refused_naming_its_size(tiny_model, height, width, message):
    detector = detector_for("cpu", tiny_model)
    with pytest.raises(InvalidInput, match=message):
        detector.detect(np.zeros((height, width, 3), np.uint8))
    assert len(detector._input_buffers) == 0  # refused before anything was made for it


def test_frames_at_the_bound_are_taken():
    check_frame(np.zeros((MAX_FRAME_SIDE_PX, MAX_FRAME_SIDE_PX // MAX_FRAME_ASPECT, 3), np.uint8))
    check_frame(np.zeros((MAX_FRAME_SIDE_PX // MAX_FRAME_ASPECT, MAX_FRAME_SIDE_PX, 3), np.uint8))
    check_frame(np.zeros((4320, 7680, 3), np.uint8))  # 8K video


@pytest.mark.parametrize("provider", PROVIDERS)
def test_frames_of_ever_new_sizes_keep_the_per_size_caches_at_their_bound(tiny_model, provider):
    detector = detector_for(provider, tiny_model)
    sizes = [(64, 64 + 8 * i) for i in range(SHAPES_KEPT + 4)]  # (height, width): new shapes
    for height, width in sizes:
        detector.detect(np.zeros((height, width, 3), np.uint8))
    assert len(detector._input_buffers) == SHAPES_KEPT
    newest = {(w, h) for h, w in sizes[-SHAPES_KEPT:]}
    assert {key[:2] for key in detector._input_buffers} == newest
    if provider == "openvino":
        assert len(detector.backend._compiled) == SHAPES_KEPT


@pytest.mark.skipif(not openvino_installed(), reason="openvino is not installed")
def test_openvino_keeps_the_recent_shapes_compiled_and_compiles_an_evicted_one_again(tiny_model):
    backend = OpenVinoBackend(tiny_model)
    shapes = [(1, 3, 64, 8 * (i + 1)) for i in range(SHAPES_KEPT + 1)]
    for shape in shapes:
        backend.run(np.zeros(shape, np.float32))
    assert list(backend._compiled) == shapes[1:]
    kept = backend._compiled[shapes[1]]
    backend.run(np.zeros(shapes[1], np.float32))  # a kept shape runs its compiled model
    assert backend._compiled[shapes[1]] is kept
    backend.run(np.zeros(shapes[0], np.float32))  # the evicted one is compiled again
    assert shapes[0] in backend._compiled and shapes[2] not in backend._compiled


def test_one_cameras_input_heights_never_evict_each_other():
    """The people-sized input runs up to 1 + MAX_SMALLER_HEIGHTS heights per frame size;
    evicting one of them would compile it again (OpenVINO) on every switch."""
    for full_px in range(96, 1096, 8):
        heights = PeopleSizedInput(full_px, 74.0, 6).heights_px
        assert len(heights) <= 1 + MAX_SMALLER_HEIGHTS
    assert SHAPES_KEPT >= FRAME_SIZES_KEPT * (1 + MAX_SMALLER_HEIGHTS)


def test_recently_used_drops_the_entry_used_longest_ago():
    cache = RecentlyUsed(3)
    for key in "abc":
        cache[key] = key.upper()
    assert cache["a"] == "A" and cache.get("b") == "B"  # reads count as uses: c is oldest
    cache["d"] = "D"
    assert list(cache) == ["a", "b", "d"]
    assert cache.get("c") is None
    with pytest.raises(ValueError, match="capacity must be >= 1"):
        RecentlyUsed(0)
