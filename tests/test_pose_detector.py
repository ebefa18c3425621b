"""PoseDetector on real PETS 2009 frames, provider fallback, bad frames."""

from __future__ import annotations

import logging

import cv2
import numpy as np
import pytest

from follow.config import PoseConfig
from follow.eval.pets import PetsSequence
from follow.pose.detector import PoseDetector
from follow.types import NECK, InvalidInput

ONNX = "pose/human-pose-estimation-0001.onnx"
FRAMES = (0, 200, 400)
_DETECTORS: dict[tuple, PoseDetector] = {}
_SEQUENCES: dict[str, PetsSequence] = {}


@pytest.fixture
def detector(model_path):
    key = ("cpu", 480)
    if key not in _DETECTORS:
        # every frame at 480 px: these tests compare frames at one input size
        config = PoseConfig(provider="cpu", input_height_px=480, input_height_from_people=False)
        _DETECTORS[key] = PoseDetector(config, model_path(ONNX))
    return _DETECTORS[key]


@pytest.fixture
def pets(data_path):
    root = str(data_path("pets2009_s2l1/View_001.avi").parent)
    if root not in _SEQUENCES:
        _SEQUENCES[root] = PetsSequence(root)
    return _SEQUENCES[root]


@pytest.mark.parametrize("index", FRAMES)
def test_necks_fall_in_ground_truth_boxes(detector, pets, index):
    skeletons = detector.detect(pets.read_frame(index))
    boxes = pets.boxes_video_px(index)
    visible = [b for b in boxes if b.hidden_fraction <= 0.5]
    necks = [s.keypoints_px[NECK] for s in skeletons if s.has(NECK)]
    # Count: about one skeleton with a neck (what the tracker uses) per visible person;
    # neckless fragments (a lone limb of a half-hidden person) are ignored downstream.
    assert len(visible) - 2 <= len(necks) <= len(boxes) + 1
    found = 0
    for box in visible:
        inside = [n for n in necks if box.contains(*n)]
        if inside:
            found += 1
            # The neck sits in the upper part of the box, near its middle column.
            rel_y = (inside[0][1] - box.top) / box.h
            assert 0.0 <= rel_y <= 0.35, f"neck at {rel_y:.2f} of the box height"
            assert abs(inside[0][0] - box.xc) <= 0.5 * box.w
    assert found >= 0.6 * len(visible)
    strays = [n for n in necks if not any(b.contains(*n) for b in boxes)]
    assert len(strays) <= 1


def test_keypoints_are_mapped_back_to_original_pixels_exactly(detector, pets):
    """A frame at the network size and the same frame doubled (each pixel repeated
    2x2) give the network the very same input, so every keypoint of the doubled frame
    must be x2 = (x1 + 0.5) * 2 - 0.5 (pixel-centre convention) to float precision."""
    base = cv2.resize(pets.read_frame(200), (640, 480), interpolation=cv2.INTER_LINEAR)
    doubled = cv2.resize(base, (1280, 960), interpolation=cv2.INTER_NEAREST)
    a = detector.detect(base)
    b = detector.detect(doubled)
    assert len(a) >= 3 and len(a) == len(b)
    order_a = np.argsort([s.score for s in a])
    order_b = np.argsort([s.score for s in b])
    for i, j in zip(order_a, order_b, strict=True):
        expected = (a[i].keypoints_px + 0.5) * 2 - 0.5
        np.testing.assert_allclose(b[j].keypoints_px, expected, atol=1e-4)
        np.testing.assert_allclose(b[j].confidences, a[i].confidences, atol=1e-5)


def test_timings_are_split(detector, pets):
    detector.detect(pets.read_frame(0))
    timing = detector.last_timing_ms
    assert set(timing) >= {"preprocess", "inference", "decode", "total"}
    assert timing["total"] >= timing["inference"] + timing["decode"]


@pytest.mark.parametrize("provider", ["cuda", "tensorrt"])
def test_missing_gpu_provider_falls_back_to_cpu_with_a_message(
    model_path, provider, caplog, monkeypatch
):
    import onnxruntime

    if "CUDAExecutionProvider" in onnxruntime.get_available_providers():
        pytest.skip("this onnxruntime has CUDA; the fallback cannot be exercised")
    config = PoseConfig(provider=provider, input_height_px=128, warmup_runs=1)
    with caplog.at_level(logging.WARNING, logger="follow.pose"):
        det = PoseDetector(config, model_path(ONNX))
    assert det.backend_name == "onnxruntime:CPUExecutionProvider"
    assert any(
        provider in r.getMessage() and "falling back" in r.getMessage() for r in caplog.records
    )


def test_openvino_request_without_openvino_falls_back(model_path, caplog, monkeypatch):
    import follow.pose.runtime as runtime

    monkeypatch.setattr(runtime, "openvino_installed", lambda: False)
    with caplog.at_level(logging.WARNING, logger="follow.pose"):
        det = PoseDetector(PoseConfig(provider="openvino", input_height_px=128),
                           model_path(ONNX))  # fmt: skip
    assert det.backend_name.startswith("onnxruntime:")
    assert any("openvino package is not installed" in r.getMessage() for r in caplog.records)


def test_input_height_must_be_a_multiple_of_eight(model_path):
    with pytest.raises(ValueError, match="multiple of 8, got 250"):
        PoseDetector(PoseConfig(input_height_px=250, warmup_runs=0), model_path(ONNX))


def test_unknown_provider_is_an_error(model_path):
    with pytest.raises(ValueError, match="provider 'gpu' unknown"):
        PoseDetector(PoseConfig(provider="gpu"), model_path(ONNX))


@pytest.mark.parametrize(
    "frame, message",
    [
        (None, "None"),
        (np.zeros((0, 480, 3), np.uint8), "empty"),
        (np.zeros((360, 480, 4), np.uint8), "HxWx3"),
    ],
)
def test_corrupt_or_empty_frame_raises_invalid_input(detector, frame, message):
    with pytest.raises(InvalidInput, match=message):
        detector.detect(frame)


def test_undecodable_image_file_gives_a_clear_error(detector, tmp_path):
    bad = tmp_path / "frame.jpg"
    bad.write_bytes(b"\xff\xd8\xff\xe0 truncated")
    with pytest.raises(InvalidInput, match="None"):
        detector.detect(cv2.imread(str(bad)))


def test_tensorrt_gets_an_engine_cache_in_the_user_cache(tmp_path, monkeypatch):
    from follow.pose.runtime import provider_entries

    monkeypatch.setenv("FOLLOW_CACHE_DIR", str(tmp_path))
    entries = provider_entries(
        ["TensorrtExecutionProvider", "CUDAExecutionProvider", "CPUExecutionProvider"]
    )
    name, options = entries[0]
    assert name == "TensorrtExecutionProvider"
    assert options["trt_engine_cache_enable"] is True
    assert options["trt_engine_cache_path"] == str(tmp_path / "tensorrt")
    assert (tmp_path / "tensorrt").is_dir()
    assert entries[1:] == ["CUDAExecutionProvider", "CPUExecutionProvider"]


def test_the_median_filter_setting_reaches_the_network(model_path, pets):
    """`[pose] median_filter_radius_px` filters the frame the network sees: the same
    heatmaps as the unfiltered detector on a frame filtered beforehand, other ones than
    on the raw frame."""
    from follow.pose.preprocess import median_filtered

    config = PoseConfig(provider="cpu", input_height_px=256)
    plain = PoseDetector(config, model_path(ONNX))
    filtering = PoseDetector(PoseConfig(provider="cpu", input_height_px=256,
                                        median_filter_radius_px=1), model_path(ONNX))  # fmt: skip
    frame = pets.read_frame(200)
    filtered_heatmaps = filtering.infer(frame)[0]
    np.testing.assert_allclose(filtered_heatmaps, plain.infer(median_filtered(frame, 1))[0],
                               atol=1e-6)  # fmt: skip
    assert np.abs(filtered_heatmaps - plain.infer(frame)[0]).max() > 1e-3


def test_the_unsharp_mask_setting_reaches_the_network(model_path, pets):
    """`[pose] unsharp_amount` sharpens the frame the network sees, after the median."""
    from follow.pose.preprocess import FrameFilter

    pets_filter = FrameFilter(median_radius_px=1, unsharp_amount=0.5)
    plain = PoseDetector(PoseConfig(provider="cpu", input_height_px=256), model_path(ONNX))
    config = PoseConfig(provider="cpu", input_height_px=256, median_filter_radius_px=1,
                        unsharp_amount=0.5)  # fmt: skip
    sharpening = PoseDetector(config, model_path(ONNX))
    frame = pets.read_frame(200)
    heatmaps = sharpening.infer(frame)[0]
    np.testing.assert_allclose(heatmaps, plain.infer(pets_filter(frame))[0], atol=1e-6)
    median_only = FrameFilter(median_radius_px=1)
    assert np.abs(heatmaps - plain.infer(median_only(frame))[0]).max() > 1e-3


def test_a_keypoint_in_the_last_heatmap_column_stays_inside_the_frame():
    """640x480 at 368 px is 491 px wide, padded to 496: the last heatmap column's centre
    (491.5) lies in the padding, past the frame's last pixel. A person at the right edge
    found there is at the edge, not beyond it."""
    from follow.pose.decode import DecodedPerson
    from follow.pose.detector import to_skeleton
    from follow.pose.preprocess import plan_letterbox

    plan = plan_letterbox((640, 480), 368)
    assert plan.input_size[0] - plan.resized_size[0] == 5
    last_column, last_row = plan.input_size[0] // 8 - 1, plan.input_size[1] // 8 - 1
    cells = np.full((18, 2), np.nan)
    cells[NECK] = (last_column, last_row)
    confidences = np.where(np.isfinite(cells[:, 0]), 0.9, 0.0)
    skeleton = to_skeleton(DecodedPerson(cells, confidences, 1.0), plan)
    x, y = skeleton.keypoints_px[NECK]
    assert -0.5 <= x <= 639.5 and -0.5 <= y <= 479.5
    assert x == pytest.approx(639.5)
    assert np.isnan(skeleton.keypoints_px[0]).all()  # missing keypoints stay missing
