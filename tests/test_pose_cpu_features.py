"""Reading the CPU's 8-bit dot-product support: `precision = "auto"` runs the INT8 pose
model only where the CPU has it, and the advice given when INT8 is asked for without it."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from follow.config import PoseConfig
from follow.pose import cpu_features, detector
from follow.pose.cpu_features import cpu_flags, has_int8_dot_product
from follow.pose.input_size import (
    RELIABLE_PERSON_INPUT_PX,
    input_height_for_camera,
    reliable_person_input_px,
)

X86_AVX2 = "processor\t: 0\nmodel name\t: Some CPU\nflags\t\t: fpu sse4_2 avx avx2 fma\n\n"
X86_VNNI = "processor\t: 0\nflags\t\t: fpu avx avx2 avx512f avx512_vnni\n"
ARM_DOT = "processor\t: 0\nFeatures\t: fp asimd evtstrm aes crc32 asimddp\n"


def test_flags_are_read_from_cpuinfo_on_x86_and_arm(tmp_path):
    for text, expected in ((X86_AVX2, False), (X86_VNNI, True), (ARM_DOT, True)):
        path = tmp_path / "cpuinfo"
        path.write_text(text)
        assert has_int8_dot_product(cpu_flags(path)) is expected, text


def test_unknown_flags_say_nothing(tmp_path):
    assert cpu_flags(tmp_path / "missing") is None
    assert has_int8_dot_product(None) is None
    (tmp_path / "empty").write_text("processor\t: 0\n")
    assert cpu_flags(tmp_path / "empty") is None


def test_int8_on_a_cpu_without_dot_products_is_advised_against(monkeypatch, caplog):
    monkeypatch.setattr(cpu_features, "cpu_flags", lambda: frozenset({"avx2"}))
    int8 = Path("human-pose-estimation-0001-int8-abc.onnx")
    with caplog.at_level(logging.WARNING, logger="follow.pose.detector"):
        detector._advise_on_int8_without_dot_product(int8, "onnxruntime:CPUExecutionProvider")
        assert 'precision = "fp32"' in caplog.text
        caplog.clear()
        detector._advise_on_int8_without_dot_product(int8, "onnxruntime:CUDAExecutionProvider")
        detector._advise_on_int8_without_dot_product(Path("pose-fp32.onnx"), "openvino:CPU")
        monkeypatch.setattr(cpu_features, "cpu_flags", lambda: frozenset({"avx512_vnni"}))
        detector._advise_on_int8_without_dot_product(int8, "openvino:CPU")
    assert caplog.text == ""


@pytest.fixture
def int8_in_cache(tmp_path, monkeypatch):
    """A recorded INT8 model in an empty model cache, as `follow models prepare` leaves it."""
    from follow import model_manifest
    from follow.pose.quantize import default_int8_path

    monkeypatch.setenv("FOLLOW_CACHE_DIR", str(tmp_path / "models"))
    int8 = default_int8_path()
    int8.parent.mkdir(parents=True)
    int8.write_bytes(b"an INT8 network")
    model_manifest.write_manifest(int8, int8, {"calibration": "test"})
    return int8


def test_auto_precision_runs_int8_only_where_the_cpu_has_dot_products(monkeypatch, int8_in_cache):
    fp32 = Path("/models/human-pose-estimation-0001.onnx")
    monkeypatch.setattr(detector.models, "resolve", lambda name: fp32)
    auto = PoseConfig(provider="cpu")  # on a GPU "auto" would take FP32 whatever the CPU
    for flags, expected in ((frozenset({"avx2"}), "fp32"),
                            (frozenset({"avx2", "avx512_vnni"}), "int8"),
                            (None, "int8")):  # fmt: skip
        monkeypatch.setattr(cpu_features, "cpu_flags", lambda flags=flags: flags)
        assert detector.resolved_precision(auto) == expected, flags
        source = detector._source_model_file(auto)
        assert source == (int8_in_cache if expected == "int8" else fp32), flags
    # asked for by name, INT8 runs on any CPU (the advice above says what it costs)
    monkeypatch.setattr(cpu_features, "cpu_flags", lambda: frozenset({"avx2"}))
    assert detector.resolved_precision(PoseConfig(precision="int8")) == "int8"
    assert detector._source_model_file(PoseConfig(precision="int8")) == int8_in_cache


def test_auto_precision_without_the_int8_model_or_on_a_gpu_is_fp32(monkeypatch, tmp_path):
    monkeypatch.setenv("FOLLOW_CACHE_DIR", str(tmp_path / "empty"))
    monkeypatch.setattr(cpu_features, "cpu_flags", lambda: frozenset({"avx512_vnni"}))
    assert detector.resolved_precision(PoseConfig()) == "fp32"
    assert detector.resolved_precision(PoseConfig(provider="cuda")) == "fp32"
    named = PoseConfig(model_file="/models/human-pose-estimation-0001-int8-abc.onnx")
    assert detector.resolved_precision(named) == "int8"
    assert detector.resolved_precision(PoseConfig(model_file="/models/pose.onnx")) == "fp32"


def test_the_reliable_person_size_follows_the_precision_that_runs(monkeypatch, int8_in_cache):
    """FP32 finds a far person from 74 px in the input where INT8 needs 85 (docs/pose.md):
    on a CPU without dot products "auto" runs FP32 and so a smaller input for the same
    camera; a number in the config is kept whatever runs."""
    camera_fy_px, image_height_px = 554.0, 480  # 640x480, 60 degrees wide
    on_cpu = PoseConfig(provider="cpu")  # on a GPU "auto" runs FP32 whatever the CPU
    heights = {}
    for flags in (frozenset({"avx512_vnni"}), frozenset({"avx2"})):
        monkeypatch.setattr(cpu_features, "cpu_flags", lambda flags=flags: flags)
        precision = detector.resolved_precision(on_cpu)
        assert reliable_person_input_px(on_cpu) == RELIABLE_PERSON_INPUT_PX[precision]
        assert reliable_person_input_px(PoseConfig(min_person_input_px=90.0)) == 90.0
        heights[precision] = input_height_for_camera(camera_fy_px, image_height_px, on_cpu)
    assert RELIABLE_PERSON_INPUT_PX == {"int8": 85.0, "fp32": 74.0}
    assert heights == {"int8": 376, "fp32": 328}
