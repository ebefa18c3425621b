"""A pose model file that cannot be loaded is refused naming the file and where it was
given, on every runtime (the runtimes' own parse errors name neither)."""

from __future__ import annotations

import pytest

from follow.models import ModelError
from follow.pose.runtime import PROVIDERS, create_backend, openvino_installed


def test_a_directory_is_not_a_model(tmp_path):
    with pytest.raises(ModelError, match=r"is not a file \(\[pose\] model_file"):
        create_backend("cpu", tmp_path)


@pytest.mark.parametrize("provider", ["cpu", "openvino"])
def test_a_file_that_is_no_model_is_refused_by_name(tmp_path, provider):
    assert provider in PROVIDERS
    if provider == "openvino" and not openvino_installed():
        pytest.skip("openvino is not installed")
    broken = tmp_path / "pose.onnx"
    broken.write_bytes(b"\x08\x07" + bytes(range(256)) * 8)  # not a protobuf model
    with pytest.raises(ModelError, match=r"pose model .*pose\.onnx cannot be loaded .*model_file"):
        create_backend(provider, broken)


@pytest.mark.parametrize("content", [b"\x08\x07" + bytes(range(256)) * 8, b""])
def test_a_file_that_is_no_model_is_refused_by_name_when_cut_to_one_stage(tmp_path, content):
    from follow.pose.stages import initial_stage_file

    broken = tmp_path / "pose.onnx"
    broken.write_bytes(content)
    with pytest.raises(ModelError, match=r"pose model .*pose\.onnx.*network_stages"):
        initial_stage_file(broken)


def test_a_folder_or_a_missing_file_to_cut_is_named_as_such(tmp_path):
    """`eval pose --model-file notes/` was told that network_stages = 1 cuts an ONNX
    graph, not that it gave a folder."""
    from follow.pose.stages import initial_stage_file

    (tmp_path / "notes").mkdir()
    with pytest.raises(ModelError, match=r"notes: a folder, not an ONNX model file"):
        initial_stage_file(tmp_path / "notes")
    with pytest.raises(ModelError, match=r"gone\.onnx: no such file, not an ONNX model file"):
        initial_stage_file(tmp_path / "gone.onnx")


@pytest.mark.parametrize("provider", ["cpu", "openvino"])
def test_another_network_named_as_the_pose_model_is_refused_when_loaded(model_path, provider):
    """The re-id network given as `[pose] model_file`: refused naming the file and its
    input, not by the runtime on the first frame (a shape check deep in OpenVINO)."""
    if provider == "openvino" and not openvino_installed():
        pytest.skip("openvino is not installed")
    reid = model_path("reid/person-reidentification-retail-0248.onnx")
    with pytest.raises(ModelError, match=r"person-reid.*is not a pose network of this kind: "
                       r"its input is \[1, 256, 128, 3\]"):  # fmt: skip
        create_backend(provider, reid)
    assert create_backend(provider, model_path("pose/human-pose-estimation-0001.onnx")).name


def test_the_pose_signature_takes_free_dimensions_and_refuses_other_shapes():
    from follow.pose.runtime import check_pose_signature

    outputs = [[1, 38, "h8", "w8"], [1, 19, "h8", "w8"]]
    check_pose_signature("p.onnx", [1, 3, "height", "width"], outputs)
    check_pose_signature("p.onnx", ["n", None, None, None], [[1, None, None, None]] * 2)
    for shape, outs, what in (([1, 256, 128, 3], outputs, "its input"),
                              ([1, 3, 256], outputs, "its input"),
                              ([1, 3, "h", "w"], [[1, 38, "h", "w"]], "1 output"),
                              ([1, 3, "h", "w"], [[1, 256], [1, 19, 2, 2]], "its outputs"),
                              ([1, 3, "h", "w"], [[1, 17, 2, 2], [1, 34, 2, 2]], "its outputs"),
                              ([1, 3, 256, 456], outputs, r"fixes the image size.*--static")):  # fmt: skip
        with pytest.raises(ModelError, match=what):
            check_pose_signature("p.onnx", shape, outs)
    # OpenVINO reshapes a network made for one size (the official IR) to each camera's
    check_pose_signature("p.xml", [1, 3, 256, 456], outputs, reshapes=True)


def test_a_pose_network_made_for_one_image_size_is_refused_where_it_cannot_be_reshaped(
    model_path, tmp_path
):
    """A file made with `tools/ir_to_onnx.py --static` failed on onnxruntime at the first
    frame of another size, with a message naming neither the file nor the setting."""
    import onnx

    model = onnx.load(str(model_path("pose/human-pose-estimation-0001.onnx")))
    dims = model.graph.input[0].type.tensor_type.shape.dim
    dims[2].dim_value, dims[3].dim_value = 256, 456
    static = tmp_path / "static.onnx"
    onnx.save(model, str(static))
    with pytest.raises(ModelError, match=r"static\.onnx .*fixes the image size.*--static"):
        create_backend("cpu", static)
    if openvino_installed():  # OpenVINO reshapes it to each camera's size
        assert create_backend("openvino", static).name
