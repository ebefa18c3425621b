"""INT8 quantisation of the pose model: written where asked, close to FP32 on real frames."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import onnx
import pytest

from follow import models
from follow.config import PoseConfig
from follow.eval.pets import PetsSequence
from follow.pose.decode import find_peaks
from follow.pose.detector import PoseDetector
from follow.pose.preprocess import prepare_input
from follow.pose.quantize import quantize_pose_model
from follow.pose.runtime import OrtBackend

HEIGHT = 256
ROOT = Path(__file__).resolve().parents[1]


_MADE: dict[str, Path] = {}


@pytest.fixture
def int8_model(model_path, data_path, tmp_path_factory):
    """An INT8 model quantised once per test session (calibrated on two PETS frames)."""
    if "model" not in _MADE:
        fp32 = model_path("pose/human-pose-estimation-0001.onnx")
        pets = PetsSequence(data_path("pets2009_s2l1/View_001.avi").parent)
        target = tmp_path_factory.mktemp("int8") / "int8.onnx"
        out = quantize_pose_model(fp32, [pets.read_frame(5), pets.read_frame(405)], HEIGHT, target)
        assert out == target
        _MADE["model"] = out
    return _MADE["model"]


def test_int8_model_is_quantised_and_close_to_fp32(int8_model, model_path, data_path):
    fp32 = model_path("pose/human-pose-estimation-0001.onnx")
    pets = PetsSequence(data_path("pets2009_s2l1/View_001.avi").parent)
    out = int8_model
    assert out.stat().st_size < fp32.stat().st_size / 2
    ops = {n.op_type for n in onnx.load(str(out)).graph.node}
    assert {"QuantizeLinear", "DequantizeLinear"} <= ops
    tensor, _ = prepare_input(pets.read_frame(200), HEIGHT)
    ref_h, ref_p = OrtBackend(fp32, ["CPUExecutionProvider"]).run(tensor)
    q_h, q_p = OrtBackend(out, ["CPUExecutionProvider"]).run(tensor)
    assert np.abs(q_h - ref_h).mean() < 0.01 and np.abs(q_p - ref_p).mean() < 0.01
    # Clear FP32 keypoint peaks are still peaks, within a cell; the PAFs (mostly near
    # zero, where 8-bit steps weigh most) still correlate well with FP32.
    ref_peaks, q_peaks = find_peaks(ref_h, 0.2), find_peaks(q_h, 0.05)
    found = total = 0
    for ref_k, q_k in zip(ref_peaks, q_peaks, strict=True):
        for peak in ref_k:
            total += 1
            found += bool(len(q_k)) and np.hypot(*(q_k[:, :2] - peak[:2]).T).min() <= 1.0
    assert total >= 8 and found >= 0.8 * total
    assert np.corrcoef(q_p.ravel(), ref_p.ravel())[0, 1] > 0.75


def test_int8_precision_without_the_model_explains_how_to_make_it(tmp_path, monkeypatch):
    monkeypatch.setenv("FOLLOW_CACHE_DIR", str(tmp_path))
    with pytest.raises(models.ModelError, match="follow models prepare"):
        PoseDetector(PoseConfig(precision="int8"))


def test_unknown_precision(tmp_path, monkeypatch):
    with pytest.raises(ValueError, match="precision 'int4' unknown"):
        PoseDetector(PoseConfig(precision="int4"))


def test_tool_help_runs():
    result = subprocess.run([sys.executable, str(ROOT / "tools/quantize_pose.py"), "--help"],
                            capture_output=True, text=True, timeout=60)  # fmt: skip
    assert result.returncode == 0 and "--height" in result.stdout


def test_bench_pose_reports_every_runtime(int8_model, capsys):
    import json

    from follow import cli

    args = ["bench", "pose", "--frames", "2", "--height", str(HEIGHT), "--int8-model",
            str(int8_model), "--json"]  # fmt: skip
    assert cli.main(args) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    for key in ("ort_fp32_ms", "fast_path_ms", "ort_int8_ms", "ort_int8_frame_input_ms",
                "prepare_input_ms", "prepare_frame_ms", "prepare_input_median1_ms",
                "prepare_input_median1_unsharp_ms",
                "decode_ms"):  # fmt: skip
        assert result[key] > 0, key
    if result["reference_openvino_int8_ms"] is None:
        assert result["notes"]
    else:
        ratio = result["fast_path_ms"] / result["reference_openvino_int8_ms"]
        assert result["fast_path_over_reference"] == pytest.approx(ratio)
    assert result["decode_crowd_people"] >= result["decode_max_people"] >= 1
