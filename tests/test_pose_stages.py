import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

from follow.config import PoseConfig
from follow.onnx_ir import portable_model
from follow.pose.detector import model_file_for
from follow.pose.stages import StageCutError, initial_stage_file, initial_stage_outputs

ONNX = "pose/human-pose-estimation-0001.onnx"


def _weight(name: str, out_channels: int, in_channels: int) -> onnx.TensorProto:
    return numpy_helper.from_array(
        np.full((out_channels, in_channels, 1, 1), 0.01, np.float32), name
    )


def _two_stage_graph(quantized_paf: bool) -> onnx.ModelProto:
    """A miniature OpenPose: features -> (PAF, heatmap) -> Concat -> refinement convs."""
    nodes = [
        helper.make_node("Conv", ["x", "w_feat"], ["feat"]),
        helper.make_node("Conv", ["feat", "w_paf"], ["paf_raw"]),
        helper.make_node("Conv", ["feat", "w_heat"], ["heat_conv"]),
        helper.make_node("Add", ["heat_conv", "bias"], ["heat_biased"]),
        helper.make_node("Identity", ["heat_biased"], ["heat"]),
    ]
    initializers = [
        _weight("w_feat", 8, 3),
        _weight("w_heat", 19, 8),
        numpy_helper.from_array(np.zeros((1, 19, 1, 1), np.float32), "bias"),
        _weight("w_paf", 38, 8),
        _weight("w_ref_paf", 38, 65),
        _weight("w_ref_heat", 19, 65),
    ]
    paf = "paf_raw"
    if quantized_paf:
        initializers += [
            numpy_helper.from_array(np.array(0.01, np.float32), "scale"),
            numpy_helper.from_array(np.array(128, np.uint8), "zero"),
        ]
        nodes += [
            helper.make_node("QuantizeLinear", ["paf_raw", "scale", "zero"], ["paf_q"]),
            helper.make_node("DequantizeLinear", ["paf_q", "scale", "zero"], ["paf_dq"]),
        ]
        paf = "paf_dq"
    nodes += [
        helper.make_node("Concat", [paf, "heat", "feat"], ["joined"], axis=1),
        helper.make_node("Conv", ["joined", "w_ref_paf"], ["out_paf"]),
        helper.make_node("Conv", ["joined", "w_ref_heat"], ["out_heat"]),
    ]
    graph = helper.make_graph(
        nodes,
        "mini_openpose",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 3, 16, 16])],
        [
            helper.make_tensor_value_info("out_paf", TensorProto.FLOAT, None),
            helper.make_tensor_value_info("out_heat", TensorProto.FLOAT, None),
        ],
        initializers,
    )
    return portable_model(graph)


@pytest.mark.parametrize("quantized", [False, True])
def test_the_cut_is_found_by_structure_and_keeps_full_precision(quantized):
    paf, heat = initial_stage_outputs(_two_stage_graph(quantized))
    # Through the bias add and identity for the heatmaps; before quantisation for PAFs.
    assert (paf, heat) == ("paf_raw", "heat")


def test_a_graph_without_a_refinement_stage_is_refused():
    model = _two_stage_graph(False)
    del model.graph.node[5:]  # no Concat any more
    with pytest.raises(StageCutError, match="network_stages = 2"):
        initial_stage_outputs(model)


def test_an_openvino_ir_cannot_be_cut(tmp_path):
    ir = tmp_path / "net.xml"
    ir.write_text("<net/>")
    with pytest.raises(StageCutError, match="give the ONNX file"):
        initial_stage_file(ir)


def test_unknown_stage_count_is_an_error(model_path):
    with pytest.raises(ValueError, match="network_stages must be one of"):
        model_file_for(PoseConfig(network_stages=3), model_path(ONNX))


def test_the_real_network_cut_gives_initial_stage_maps_and_is_made_once(model_path):
    full_path = model_path(ONNX)
    cut_path = model_file_for(PoseConfig(network_stages=1), full_path)
    assert cut_path != full_path and "initial-stage" in cut_path.name
    made_at = cut_path.stat().st_mtime_ns
    assert model_file_for(PoseConfig(network_stages=1), full_path) == cut_path
    assert cut_path.stat().st_mtime_ns == made_at  # reused, not rewritten

    x = np.random.default_rng(0).random((1, 3, 128, 96), np.float32)
    full = ort.InferenceSession(str(full_path), providers=["CPUExecutionProvider"])
    cut = ort.InferenceSession(str(cut_path), providers=["CPUExecutionProvider"])
    full_out = {o.shape[1]: o for o in full.run(None, {full.get_inputs()[0].name: x})}
    cut_out = {o.shape[1]: o for o in cut.run(None, {cut.get_inputs()[0].name: x})}
    assert sorted(cut_out) == [19, 38]
    for channels in (19, 38):
        assert cut_out[channels].shape == full_out[channels].shape == (1, channels, 16, 12)
    # The cut stops before the refinement stage: its maps differ from the final ones.
    assert not np.allclose(cut_out[19], full_out[19], atol=1e-3)
    assert len(cut.get_inputs()) == 1
