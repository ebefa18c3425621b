"""tools/ir_to_onnx.py: the official IR converted here matches the reference ONNX."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import onnx
import pytest

from follow.eval.pets import PetsSequence
from follow.pose.preprocess import prepare_input
from follow.pose.runtime import OrtBackend

TOOL = Path(__file__).resolve().parents[1] / "tools" / "ir_to_onnx.py"


def load_tool():
    spec = importlib.util.spec_from_file_location("ir_to_onnx", TOOL)
    module = importlib.util.module_from_spec(spec)
    sys.modules["ir_to_onnx"] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def tool():
    return load_tool()


@pytest.fixture
def frames(data_path):
    pets = PetsSequence(data_path("pets2009_s2l1/View_001.avi").parent)
    return [prepare_input(pets.read_frame(i), 256)[0] for i in (100, 600)]


def test_converted_ir_matches_the_reference_onnx_on_real_frames(tool, model_path, frames, tmp_path):
    xml = model_path("pose/human-pose-estimation-0001.xml")
    reference = OrtBackend(model_path("pose/human-pose-estimation-0001.onnx"),
                           ["CPUExecutionProvider"])  # fmt: skip
    out = tool.convert_ir(xml, tmp_path / "pose.onnx")
    model = onnx.load(str(out))
    assert model.graph.input[0].name == "data"
    assert {o.name for o in model.graph.output} == {"Mconv7_stage2_L1", "Mconv7_stage2_L2"}
    assert all(i.data_type == onnx.TensorProto.FLOAT for i in model.graph.initializer
               if len(i.dims) == 4)  # fmt: skip
    converted = OrtBackend(out, ["CPUExecutionProvider"])
    for tensor in frames:
        ref_h, ref_p = reference.run(tensor)
        got_h, got_p = converted.run(tensor)
        assert ref_h.max() > 0.5  # real people in view
        np.testing.assert_allclose(got_h, ref_h, atol=1e-4)
        np.testing.assert_allclose(got_p, ref_p, atol=1e-4)


def test_emulated_fake_quantize_stays_close(tool, model_path, frames, tmp_path):
    out = tool.convert_ir(model_path("pose/human-pose-estimation-0001.xml"),
                          tmp_path / "fq.onnx", fake_quantize_mode="emulate")  # fmt: skip
    ops = [n.op_type for n in onnx.load(str(out)).graph.node]
    assert ops.count("Round") == 63  # one per activation FakeQuantize of the INT8 IR
    reference = OrtBackend(model_path("pose/human-pose-estimation-0001.onnx"),
                           ["CPUExecutionProvider"])  # fmt: skip
    ref_h, _ = reference.run(frames[0])
    got_h, _ = OrtBackend(out, ["CPUExecutionProvider"]).run(frames[0])
    assert np.abs(got_h - ref_h).mean() < 1e-3
    assert np.abs(got_h - ref_h).max() < 0.1


def test_fake_quantize_reference_formula(tool):
    x = np.array([-1.0, 0.0, 0.3, 0.5, 2.0])
    y = tool.fake_quantize(x, 0.0, 1.0, 0.0, 1.0, levels=3)  # steps of 0.5
    np.testing.assert_allclose(y, [0.0, 0.0, 0.5, 0.5, 1.0])


def test_unsupported_layer_is_named(tool, tmp_path):
    xml = tmp_path / "net.xml"
    xml.write_text(
        '<net name="n" version="10"><layers>'
        '<layer id="0" name="data" type="Parameter" version="opset1">'
        '<data element_type="f32" shape="1,3,8,8"/><output><port id="0"><dim>1</dim><dim>3</dim>'
        "<dim>8</dim><dim>8</dim></port></output></layer>"
        '<layer id="1" name="odd" type="SpaceToDepth" version="opset1"><input><port id="0"/>'
        '</input><output><port id="1"/></output></layer>'
        '<layer id="2" name="out" type="Result" version="opset1"><input><port id="0"/></input>'
        "</layer></layers><edges>"
        '<edge from-layer="0" from-port="0" to-layer="1" to-port="0"/>'
        '<edge from-layer="1" from-port="1" to-layer="2" to-port="0"/></edges></net>'
    )
    (tmp_path / "net.bin").write_bytes(b"")
    with pytest.raises(tool.ConversionError, match="'odd': type SpaceToDepth is not supported"):
        tool.convert_ir(xml, tmp_path / "net.onnx")
    assert tool.main([str(xml), "-o", str(tmp_path / "net.onnx")]) == 1
