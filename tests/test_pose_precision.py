import pytest

from follow.config import PoseConfig
from follow.model_manifest import write_manifest
from follow.models import ModelError
from follow.pose.detector import model_file_for
from follow.pose.quantize import default_int8_path


def test_auto_precision_uses_the_int8_model_once_it_is_made(tmp_path, monkeypatch, model_path):
    model_path("pose/human-pose-estimation-0001.onnx")
    monkeypatch.setenv("FOLLOW_CACHE_DIR", str(tmp_path / "cache"))
    config = PoseConfig(precision="auto", network_stages=2)  # the file as it is
    assert model_file_for(config).name == "human-pose-estimation-0001.onnx"
    with pytest.raises(ModelError, match="follow models prepare"):
        model_file_for(PoseConfig(precision="int8", network_stages=2))
    int8 = default_int8_path()
    int8.parent.mkdir(parents=True)
    int8.write_bytes(b"onnx")
    write_manifest(int8, model_path("pose/human-pose-estimation-0001.onnx"))
    assert model_file_for(config) == int8
    with pytest.raises(ValueError, match="choose auto, fp32 or int8"):
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
