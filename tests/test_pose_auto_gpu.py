"""`provider = "auto"` where onnxruntime lists a GPU provider that does not start.

An onnxruntime-gpu install without its CUDA libraries (or with a driver of another CUDA)
still lists CUDAExecutionProvider; a session asked for it runs on the CPU provider, FP32,
or fails. `auto` must then run what it runs on a machine without a GPU (OpenVINO, INT8
where made), not onnxruntime's CPU provider on the GPU's FP32 model.
"""

from __future__ import annotations

import logging

import pytest
from test_pose_frame_input import _tiny_pose_like_model

from follow.config import PoseConfig
from follow.model_manifest import write_manifest
from follow.pose import runtime
from follow.pose.detector import PoseDetector, network_and_backend
from follow.pose.quantize import default_int8_path
from follow.pose.runtime import auto_provider, create_backend, runs_on_gpu

CUDA_LISTED = ["CUDAExecutionProvider", "CPUExecutionProvider"]
DRIVER_ERROR = "CUDA failure 35: CUDA driver version is insufficient for CUDA runtime version"


@pytest.fixture(autouse=True)
def no_gpu_failures_yet(monkeypatch):
    """Each test starts in a process that has not yet found a GPU provider not starting."""
    monkeypatch.setattr(runtime, "GPU_FAILURES", {})


def list_providers(monkeypatch, providers: list[str]) -> None:
    import onnxruntime

    monkeypatch.setattr(onnxruntime, "get_available_providers", lambda: list(providers))


def break_cuda(monkeypatch, how: str) -> list[list[str]]:
    """onnxruntime lists CUDA; a session asked for it runs on the CPU provider alone
    (`how` "cpu_only") or fails ("raises"). Returns the providers each session asked for."""
    import onnxruntime

    list_providers(monkeypatch, CUDA_LISTED)
    asked: list[list[str]] = []
    real_session = onnxruntime.InferenceSession

    class BrokenCudaSession(real_session):
        def __init__(self, model, options=None, providers=None, **kwargs):
            names = [p if isinstance(p, str) else p[0] for p in providers or []]
            asked.append(names)
            if how == "raises" and "CUDAExecutionProvider" in names:
                raise RuntimeError(DRIVER_ERROR)
            super().__init__(model, options, providers=["CPUExecutionProvider"], **kwargs)

    monkeypatch.setattr(onnxruntime, "InferenceSession", BrokenCudaSession)
    return asked


def cpu_choice(monkeypatch, make):
    """What `make()` gives on this machine with no GPU provider listed."""
    list_providers(monkeypatch, ["CPUExecutionProvider"])
    return make()


@pytest.mark.parametrize("openvino_here", [True, False])
@pytest.mark.parametrize("how", ["cpu_only", "raises"])
def test_auto_runs_the_cpu_choice_where_a_listed_cuda_does_not_start(
    tmp_path, monkeypatch, caplog, how, openvino_here
):
    if openvino_here and not runtime.openvino_installed():
        pytest.skip("openvino is not installed")
    monkeypatch.setattr(runtime, "openvino_installed", lambda: openvino_here)
    path = tmp_path / "tiny.onnx"
    _tiny_pose_like_model(path)
    asked = break_cuda(monkeypatch, how)
    assert auto_provider(path) == "cuda" and runs_on_gpu("auto")  # listed: chosen
    with caplog.at_level(logging.WARNING, logger="follow.pose"):
        backend = create_backend("auto", path)
    assert asked[0] == ["CUDAExecutionProvider", "CPUExecutionProvider"]  # it was tried
    warnings = [r.getMessage() for r in caplog.records if "does not start" in r.getMessage()]
    assert len(warnings) == 1 and "CUDAExecutionProvider" in warnings[0]
    assert ("CPUExecutionProvider only" if how == "cpu_only" else DRIVER_ERROR) in warnings[0]
    assert not runs_on_gpu("auto")  # the INT8 model is right again
    # exactly what `auto` runs on a machine without a GPU
    expected = cpu_choice(monkeypatch, lambda: create_backend("auto", path))
    assert type(backend) is type(expected)
    assert (backend.name, backend.frame_input) == (expected.name, expected.frame_input)
    assert backend.name == ("openvino:CPU" if openvino_here else "onnxruntime:CPUExecutionProvider")
    assert auto_provider(path) == ("openvino" if openvino_here else "cpu")


def test_a_listed_tensorrt_that_does_not_start_is_not_retried_as_cuda(tmp_path, monkeypatch):
    """A TensorRT session on the CPU alone started CUDA neither: CUDA is not tried next."""
    path = tmp_path / "tiny.onnx"
    _tiny_pose_like_model(path)
    asked = break_cuda(monkeypatch, "cpu_only")
    list_providers(monkeypatch, ["TensorrtExecutionProvider", *CUDA_LISTED])
    monkeypatch.setattr(runtime, "openvino_installed", lambda: False)
    backend = create_backend("auto", path)
    assert backend.name == "onnxruntime:CPUExecutionProvider"
    assert [names[0] for names in asked] == ["TensorrtExecutionProvider", "CPUExecutionProvider"]
    assert set(runtime.GPU_FAILURES) == {"tensorrt", "cuda"}


def test_a_cuda_that_starts_is_kept(tmp_path, monkeypatch):
    """The check passes a session that runs on the GPU provider it was asked for."""
    import onnxruntime

    path = tmp_path / "tiny.onnx"
    _tiny_pose_like_model(path)
    list_providers(monkeypatch, CUDA_LISTED)
    real_session = onnxruntime.InferenceSession

    class WorkingCudaSession(real_session):
        def __init__(self, model, options=None, providers=None, **kwargs):
            super().__init__(model, options, providers=["CPUExecutionProvider"], **kwargs)

        def get_providers(self):
            return list(CUDA_LISTED)

    monkeypatch.setattr(onnxruntime, "InferenceSession", WorkingCudaSession)
    backend = create_backend("auto", path)
    assert backend.name == "onnxruntime:CUDAExecutionProvider"
    assert runtime.GPU_FAILURES == {} and runs_on_gpu("auto")


def test_the_detector_runs_the_int8_model_where_auto_found_cuda_not_starting(
    tmp_path, monkeypatch, model_path
):
    """The FP32 model was chosen for the GPU; once the GPU is found not to start, the file
    is what `precision = "auto"` runs on a CPU: the INT8 model, where made."""
    from follow.pose import cpu_features

    fp32 = model_path("pose/human-pose-estimation-0001.onnx")
    monkeypatch.setattr(cpu_features, "cpu_flags", lambda: frozenset({"avx2", "avx512_vnni"}))
    monkeypatch.setenv("FOLLOW_CACHE_DIR", str(tmp_path / "cache"))
    int8 = default_int8_path()
    int8.parent.mkdir(parents=True)
    _tiny_pose_like_model(int8)  # stands in for the made INT8 model: it runs fast
    write_manifest(int8, fp32)
    config = PoseConfig(provider="auto", precision="auto", network_stages=2,
                        input_height_px=128, input_height_from_people=False, warmup_runs=1)  # fmt: skip
    break_cuda(monkeypatch, "cpu_only")
    detector = PoseDetector(config)
    expected_path, expected = cpu_choice(monkeypatch, lambda: network_and_backend(config))
    assert detector.model_path == expected_path == int8
    assert detector.backend_name == expected.name
    assert type(detector.backend) is type(expected)


def test_a_model_file_that_no_provider_loads_is_no_gpu_failure(tmp_path, monkeypatch):
    """A file cut short fails a GPU session as it fails the CPU's: it is the model's
    error, named as such, and the GPU stays trusted for the next (good) file."""
    from follow.models import ModelError

    break_cuda(monkeypatch, "cpu_only")  # a CUDA session that is made: the file decides
    cut = tmp_path / "cut.onnx"
    _tiny_pose_like_model(cut)
    cut.write_bytes(cut.read_bytes()[:40])
    with pytest.raises((ModelError, ValueError)):
        create_backend("auto", cut)
    assert runtime.GPU_FAILURES == {}
