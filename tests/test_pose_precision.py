import pytest

from follow.config import PoseConfig
from follow.model_manifest import write_manifest
from follow.models import ModelError
from follow.pose.detector import model_file_for
from follow.pose.quantize import default_int8_path


@pytest.fixture(autouse=True)
def cpu_with_dot_products(monkeypatch):
    """These tests are of a CPU that runs INT8 fast (VNNI), whatever CPU runs them; a CPU
    without 8-bit dot products is tests/test_pose_cpu_features.py's."""
    from follow.pose import cpu_features

    monkeypatch.setattr(cpu_features, "cpu_flags", lambda: frozenset({"avx2", "avx512_vnni"}))


def test_auto_precision_uses_the_int8_model_once_it_is_made(tmp_path, monkeypatch, model_path):
    model_path("pose/human-pose-estimation-0001.onnx")
    monkeypatch.setenv("FOLLOW_CACHE_DIR", str(tmp_path / "cache"))
    config = PoseConfig(precision="auto", provider="cpu", network_stages=2)  # the file as it is
    assert model_file_for(config).name == "human-pose-estimation-0001.onnx"
    with pytest.raises(ModelError, match="follow models prepare"):
        model_file_for(PoseConfig(precision="int8", network_stages=2))
    int8 = default_int8_path()
    int8.parent.mkdir(parents=True)
    int8.write_bytes(b"onnx")
    write_manifest(int8, model_path("pose/human-pose-estimation-0001.onnx"))
    assert model_file_for(config) == int8
    with pytest.raises(ValueError, match="choose auto, fp32, int8 or int8_if_made"):
        model_file_for(PoseConfig(precision="int4", network_stages=2))


def test_the_pose_model_name_is_checked_whatever_the_precision(tmp_path, monkeypatch):
    """The INT8 model in the cache used to stand in for any [pose] model name."""
    monkeypatch.setenv("FOLLOW_CACHE_DIR", str(tmp_path / "cache"))
    int8 = default_int8_path()
    int8.parent.mkdir(parents=True)
    int8.write_bytes(b"onnx")
    for precision in ("auto", "int8", "fp32"):
        with pytest.raises(ModelError, match="unknown model 'nosuchmodel'"):
            model_file_for(PoseConfig(model="nosuchmodel", precision=precision))
    with pytest.raises(ModelError, match="INT8 model is made from human-pose-estimation-0001"):
        model_file_for(PoseConfig(model="human-pose-estimation-0001-ir", precision="int8"))


@pytest.mark.parametrize(
    ("provider", "offered", "expected"),
    [
        ("cuda", ["CUDAExecutionProvider", "CPUExecutionProvider"], "fp32"),
        ("tensorrt", ["TensorrtExecutionProvider", "CUDAExecutionProvider"], "fp32"),
        ("tensorrt", ["CUDAExecutionProvider", "CPUExecutionProvider"], "fp32"),  # on CUDA
        ("auto", ["CUDAExecutionProvider", "CPUExecutionProvider"], "fp32"),
        ("cuda", ["CPUExecutionProvider"], "int8"),  # falls back to the CPU: INT8 is right
        ("auto", ["CPUExecutionProvider"], "int8"),
        ("cpu", ["CUDAExecutionProvider", "CPUExecutionProvider"], "int8"),
    ],
)
def test_auto_precision_runs_fp32_where_the_network_goes_to_a_gpu(
    tmp_path, monkeypatch, model_path, provider, offered, expected
):
    """On CUDA the INT8 model ran 1.3-2.3x slower than FP32 (docs/pose.md); `auto` takes it
    only where the network runs on the CPU."""
    fp32 = model_path("pose/human-pose-estimation-0001.onnx")
    monkeypatch.setenv("FOLLOW_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr("follow.pose.runtime.ort_available_providers", lambda: offered)
    int8 = default_int8_path()
    int8.parent.mkdir(parents=True)
    int8.write_bytes(b"onnx")
    write_manifest(int8, fp32)
    chosen = model_file_for(PoseConfig(precision="auto", provider=provider, network_stages=2))
    assert chosen == (fp32 if expected == "fp32" else int8)


def test_int8_if_made_runs_the_made_int8_model_on_a_cpu_without_dot_products(
    tmp_path, monkeypatch, model_path
):
    # PETS's settings were chosen with the INT8 model; "auto" runs FP32 on a CPU without
    # VNNI, where the same frames then gave other figures (docs/pose.md). int8_if_made
    # keeps the INT8 model wherever it has been made, and runs FP32 where it has not
    # (the tests' own cache: nothing is made there).
    from follow.pose import cpu_features
    from follow.pose.detector import resolved_precision

    monkeypatch.setattr(cpu_features, "cpu_flags", lambda: frozenset({"avx2"}))
    source = model_path("pose/human-pose-estimation-0001.onnx")
    monkeypatch.setenv("FOLLOW_CACHE_DIR", str(tmp_path / "cache"))
    config = PoseConfig(precision="int8_if_made", provider="cpu", network_stages=2)
    assert resolved_precision(config) == "fp32"
    assert model_file_for(config).name == "human-pose-estimation-0001.onnx"
    int8 = default_int8_path()
    int8.parent.mkdir(parents=True)
    int8.write_bytes(b"onnx")
    write_manifest(int8, source)
    assert resolved_precision(config) == "int8" and model_file_for(config) == int8
    auto = PoseConfig(precision="auto", provider="cpu", network_stages=2)
    assert resolved_precision(auto) == "fp32"  # "auto" on this CPU: FP32, made or not
    assert model_file_for(auto).name == "human-pose-estimation-0001.onnx"
