"""The uint8 frame input with the conversion in the graph gives the float path's outputs."""

from __future__ import annotations

import numpy as np
import pytest

from follow.onnx_ir import portable_model
from follow.pose.preprocess import prepare_frame, prepare_input
from follow.pose.runtime import OpenVinoBackend, OrtBackend, openvino_installed


def _tiny_pose_like_model(path) -> None:
    """A float NCHW input, one 3x3 convolution to 19 and one to 38 channels at stride 8
    (the two outputs the back-ends sort by channel count)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(0)
    weights = {
        "w_heat": rng.normal(size=(19, 3, 3, 3)).astype(np.float32),
        "w_paf": rng.normal(size=(38, 3, 3, 3)).astype(np.float32),
    }
    nodes = [
        helper.make_node("Conv", ["data", name], [name + "_out"], strides=[8, 8], pads=[1] * 4)
        for name in weights
    ]
    graph = helper.make_graph(
        nodes,
        "tiny",
        [helper.make_tensor_value_info("data", TensorProto.FLOAT, [1, 3, "h", "w"])],
        [helper.make_tensor_value_info(n + "_out", TensorProto.FLOAT, None) for n in weights],
        [numpy_helper.from_array(w, n) for n, w in weights.items()],
    )
    model = portable_model(graph)
    onnx.save(model, str(path))


@pytest.fixture()
def frames():
    rng = np.random.default_rng(1)
    return [rng.integers(0, 256, (h, w, 3), dtype=np.uint8) for h, w in ((480, 640), (360, 480))]


def test_prepare_frame_is_prepare_input_in_another_layout(frames):
    buffers: dict = {}
    for image in frames * 2:  # the second pass reuses the buffers
        frame, plan = prepare_frame(image, 256, buffers)
        tensor, same_plan = prepare_input(image, 256)
        assert plan == same_plan and frame.dtype == np.uint8
        assert frame.shape == (1, plan.input_size[1], plan.input_size[0], 3)
        np.testing.assert_array_equal(frame.transpose(0, 3, 1, 2).astype(np.float32), tensor)
    assert len(buffers) == 2


def test_onnxruntime_frame_input_gives_the_float_outputs(tmp_path, frames):
    path = tmp_path / "tiny.onnx"
    _tiny_pose_like_model(path)
    float_path = OrtBackend(path, ["CPUExecutionProvider"])
    frame_path = OrtBackend(path, ["CPUExecutionProvider"], frame_input=True)
    assert frame_path.session.get_inputs()[0].type == "tensor(uint8)"
    for image in frames:
        want = float_path.run(prepare_input(image, 256)[0])
        got = frame_path.run(prepare_frame(image, 256)[0])
        for w, g in zip(want, got, strict=True):
            assert w.shape[0] in (19, 38)
            np.testing.assert_array_equal(g, w)


@pytest.mark.skipif(not openvino_installed(), reason="openvino is not installed")
def test_openvino_frame_input_gives_the_float_outputs(tmp_path, frames):
    path = tmp_path / "tiny.onnx"
    _tiny_pose_like_model(path)
    float_path = OpenVinoBackend(path)
    frame_path = OpenVinoBackend(path, frame_input=True)
    for image in frames:
        want = float_path.run(prepare_input(image, 256)[0])
        got = frame_path.run(prepare_frame(image, 256)[0])
        for w, g in zip(want, got, strict=True):
            np.testing.assert_allclose(g, w, rtol=1e-5, atol=1e-4)


def test_a_model_without_one_4d_input_is_refused(tmp_path):
    import onnx
    from onnx import TensorProto, helper

    from follow.pose.runtime import with_frame_input

    graph = helper.make_graph(
        [helper.make_node("Relu", ["x"], ["y"])],
        "flat",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 3])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, None)],
    )
    path = tmp_path / "flat.onnx"
    onnx.save(portable_model(graph), str(path))
    with pytest.raises(ValueError, match="flat.onnx: expected one 4-d NCHW input"):
        with_frame_input(path)


SIGNAL_AFTER_DROPPED_BACKENDS = """
import gc, os, signal, sys, time
import numpy as np
from follow.pose.preprocess import prepare_input
from follow.pose.runtime import OpenVinoBackend

def use_two_backends():
    backends = [OpenVinoBackend(sys.argv[1]) for _ in range(2)]
    for backend in backends:
        backend.run(prepare_input(np.zeros((480, 640, 3), np.uint8), 256)[0])

use_two_backends()
gc.collect()

def interrupt(signum, frame):
    raise KeyboardInterrupt

signal.signal(signal.SIGTERM, interrupt)
try:
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(5)
except KeyboardInterrupt:
    print("interrupted")
"""


@pytest.mark.skipif(not openvino_installed(), reason="openvino is not installed")
def test_a_signal_after_openvino_backends_were_dropped_takes_the_python_path(tmp_path):
    """Back-ends made and dropped (a benchmark, a test) must not leave the process
    unable to handle the shutdown signal: each Core used to unload OpenVINO's plugin,
    and the next SIGTERM crashed the process instead of raising in Python."""
    import subprocess
    import sys

    path = tmp_path / "tiny.onnx"
    _tiny_pose_like_model(path)
    done = subprocess.run([sys.executable, "-c", SIGNAL_AFTER_DROPPED_BACKENDS, str(path)],
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "interrupted"
