"""The people-sized network input: each frame at the smallest input that keeps the
smallest person seen reliably large, the full input on a schedule and after an empty
frame; and the detector running it on a real person seen large."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from follow.config import PoseConfig
from follow.pose.people_sized_input import (
    MIN_KEYPOINTS_FOR_SIZE,
    PeopleSizedInput,
    person_height_px,
)
from follow.types import NECK, Skeleton

FRAME_HEIGHT_PX = 480


def person(top_px: float, height_px: float, keypoints: int = 14) -> Skeleton:
    """A skeleton whose found keypoints span `height_px` from `top_px` down."""
    points = np.full((18, 2), np.nan)
    ys = np.linspace(top_px, top_px + height_px, keypoints)
    points[:keypoints, 0] = 320.0
    points[:keypoints, 1] = ys
    confidences = np.where(np.isfinite(points[:, 0]), 0.8, 0.0)
    return Skeleton(points, confidences, 1.0)


def schedule(every: int = 6) -> PeopleSizedInput:
    return PeopleSizedInput(full_height_px=368, min_person_input_px=85.0,
                            full_input_every_frames=every)  # fmt: skip


def test_heights_are_few_fixed_steps_up_to_the_full_one():
    assert schedule().heights_px == [256, 288, 320, 352, 368]
    assert PeopleSizedInput(376, 85.0, 6).heights_px == [256, 288, 320, 352, 376]


def test_a_wide_camera_s_full_height_takes_wider_steps_not_more_shapes():
    assert PeopleSizedInput(576, 85.0, 6).heights_px == [256, 336, 416, 496, 576]
    assert PeopleSizedInput(192, 85.0, 6).heights_px == [192]  # under 256: one height


def test_a_fragment_has_no_size_and_a_skeleton_its_keypoints_extent():
    assert person_height_px(person(100, 300)) == pytest.approx(300)
    assert person_height_px(person(100, 300, keypoints=MIN_KEYPOINTS_FOR_SIZE - 1)) is None


def test_the_first_frame_runs_at_the_full_height():
    assert schedule().next_height_px(FRAME_HEIGHT_PX) == 368


def test_large_people_run_the_smallest_input_that_keeps_them_85_px_tall():
    sizing = schedule()
    sizing.observe([person(50, 400), person(100, 300)], 368, FRAME_HEIGHT_PX)
    # 300 px of 480 needs 480 * 85 / 300 = 136 px: the smallest step
    assert sizing.next_height_px(FRAME_HEIGHT_PX) == 256
    sizing.observe([person(50, 400), person(150, 150)], 256, FRAME_HEIGHT_PX)
    # 150 px of 480 needs 272 px: the next step up
    assert sizing.next_height_px(FRAME_HEIGHT_PX) == 288


def test_a_far_person_keeps_the_full_height():
    sizing = schedule()
    sizing.observe([person(50, 400), person(200, 110)], 368, FRAME_HEIGHT_PX)  # needs 371 px
    assert sizing.next_height_px(FRAME_HEIGHT_PX) == 368


def test_a_far_person_seen_at_the_last_full_height_counts_though_missed_since():
    sizing = schedule()
    sizing.observe([person(50, 400), person(200, 150)], 368, FRAME_HEIGHT_PX)
    # the far one missed at the smaller input
    sizing.observe([person(50, 400)], 288, FRAME_HEIGHT_PX)
    assert sizing.next_height_px(FRAME_HEIGHT_PX) == 288  # not 256: it may still be there


def test_a_far_person_missed_by_one_full_height_frame_is_still_looked_for():
    sizing = schedule(every=2)
    # the far one found at the full height, then a full-height frame missed it
    sizing.observe([person(50, 400), person(200, 110)], 368, FRAME_HEIGHT_PX)
    sizing.observe([person(50, 400)], 368, FRAME_HEIGHT_PX)
    assert sizing.next_height_px(FRAME_HEIGHT_PX) == 368
    sizing.observe([person(50, 400)], 368, FRAME_HEIGHT_PX)  # and a second one: it has gone
    assert sizing.next_height_px(FRAME_HEIGHT_PX) == 256


def test_an_empty_frame_and_the_schedule_bring_the_full_height_back():
    sizing = schedule(every=3)
    sizing.observe([person(50, 400)], 368, FRAME_HEIGHT_PX)
    assert sizing.next_height_px(FRAME_HEIGHT_PX) == 256
    sizing.observe([], 256, FRAME_HEIGHT_PX)  # nobody found at the small input: look at full size
    assert sizing.next_height_px(FRAME_HEIGHT_PX) == 368
    sizing.observe([person(50, 400)], 368, FRAME_HEIGHT_PX)
    heights = []
    for _ in range(6):
        height = sizing.next_height_px(FRAME_HEIGHT_PX)
        heights.append(height)
        sizing.observe([person(50, 400)], height, FRAME_HEIGHT_PX)
    assert heights == [256, 256, 368, 256, 256, 368]


def test_sizes_seen_in_frames_of_another_size_are_forgotten():
    sizing = schedule()
    sizing.observe([person(50, 760)], 368, 960)
    assert sizing.next_height_px(960) == 256
    assert sizing.next_height_px(480) == 368  # 760 px of a 960 px frame says nothing here


def test_every_frame_full_with_a_schedule_of_one():
    sizing = schedule(every=1)
    sizing.observe([person(50, 400)], 368, FRAME_HEIGHT_PX)
    assert sizing.next_height_px(FRAME_HEIGHT_PX) == 368


def test_a_schedule_of_zero_is_refused():
    with pytest.raises(ValueError, match="full_input_every_frames"):
        schedule(every=0)


def _person_seen_large(data_path) -> np.ndarray:
    """A 640x480 grey frame holding a real person 380 px tall."""
    crop = cv2.imread(str(data_path("ccf_crops/p01.jpg")))
    crop = cv2.resize(crop, (round(380 * crop.shape[1] / crop.shape[0]), 380))
    frame = np.full((480, 640, 3), 128, np.uint8)
    frame[50:430, 250 : 250 + crop.shape[1]] = crop
    return frame


def test_the_detector_runs_a_person_seen_large_at_a_smaller_input(model_path, data_path):
    """A real person 380 px tall in a 640x480 frame: found at the full 368 px input
    first, then at 256 px, with the neck in the same place (within 2 % of the person's
    height), and at full size again on the schedule."""
    from follow.pose.detector import PoseDetector

    frame = _person_seen_large(data_path)
    config = PoseConfig(provider="cpu", precision="fp32", input_height_px=368,
                        full_input_every_frames=3)  # fmt: skip
    detector = PoseDetector(config, model_path("pose/human-pose-estimation-0001.onnx"))
    heights, necks = [], []
    for _ in range(4):
        skeletons = [s for s in detector.detect(frame) if s.has(NECK)]
        assert len(skeletons) == 1
        heights.append(detector.last_input_height_px)
        necks.append(skeletons[0].keypoints_px[NECK])
    assert heights == [368, 256, 256, 368]
    assert np.linalg.norm(necks[1] - necks[0]) <= 0.02 * 380
    fixed = PoseDetector(dataclasses.replace(config, input_height_from_people=False),
                         model_path("pose/human-pose-estimation-0001.onnx"))  # fmt: skip
    for _ in range(3):
        fixed.detect(frame)
        assert fixed.last_input_height_px == 368


def test_a_frame_of_another_size_runs_at_the_full_height(model_path, data_path):
    """People measured in the pixels of frames of one size do not size the input of a
    frame of another: a person 760 px tall in a 1280x960 frame would ask only 58 px of
    input height of a 480 px frame, whose own people may be far smaller."""
    from follow.pose.detector import PoseDetector

    small = _person_seen_large(data_path)
    large = cv2.resize(small, (1280, 960))
    config = PoseConfig(provider="cpu", precision="fp32", input_height_px=368, warmup_runs=0)
    detector = PoseDetector(config, model_path("pose/human-pose-estimation-0001.onnx"))
    heights = []
    for frame in (large, large, small, small):
        assert len([s for s in detector.detect(frame) if s.has(NECK)]) == 1
        heights.append(detector.last_input_height_px)
    assert heights == [368, 256, 368, 256]


class _NamedAsGpu:
    """The CPU back-end under the CUDA provider's name, recording the input shapes."""

    name = "onnxruntime:CUDAExecutionProvider"

    def __init__(self, backend):
        self.backend, self.frame_input, self.shapes = backend, backend.frame_input, []

    def run(self, tensor):
        self.shapes.append(tensor.shape)
        return self.backend.run(tensor)


def test_on_a_gpu_the_input_keeps_one_height(model_path, data_path, monkeypatch):
    """The person the CPU runs at 256 px runs at the full 368 px where the network is on
    a GPU, warm-up included: a new input shape there costs a convolution-algorithm search
    of a second or more (measured on an H200), which the smaller input does not repay."""
    from follow.pose import detector as detector_module

    real = detector_module.network_and_backend
    monkeypatch.setattr(detector_module, "network_and_backend",
                        lambda *a, **k: (lambda p, b: (p, _NamedAsGpu(b)))(*real(*a, **k)))  # fmt: skip
    frame = _person_seen_large(data_path)
    config = PoseConfig(provider="cpu", precision="fp32", input_height_px=368,
                        full_input_every_frames=3)  # fmt: skip
    detector = detector_module.PoseDetector(
        config, model_path("pose/human-pose-estimation-0001.onnx")
    )
    assert detector.input_sizing is None
    for _ in range(4):
        assert len([s for s in detector.detect(frame) if s.has(NECK)]) == 1
        assert detector.last_input_height_px == 368
    assert {shape[2] for shape in detector.backend.shapes} == {368}  # warm-up too
