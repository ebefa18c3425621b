"""Reading the CPU's 8-bit dot-product support, and the advice given when the INT8 pose
model runs on a CPU without it."""

from __future__ import annotations

import logging
from pathlib import Path

from follow.pose import cpu_features, detector
from follow.pose.cpu_features import cpu_flags, has_int8_dot_product

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
