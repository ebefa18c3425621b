"""The pose network cut after its initial stage.

Lightweight OpenPose predicts heatmaps and PAFs once from the backbone's features (the
initial stage), then once more from those predictions and the features (the refinement
stage, whose outputs are the published network's). For our decoding the initial stage
is the better trade: on PETS 2009 at 768x576 it finds more of the small, far people
(neck recall 0.90 against 0.87, ankles 0.77 against 0.66, same precision) in 0.65x the
time, because the refinement sharpens the maps of large people at the expense of faint
ones. `[pose] network_stages = 2` runs the whole network.

The cut is found in the graph, not by tensor names, so it works on the FP32 ONNX and on
its INT8 (QDQ) copy alike: the first Concat that joins a 38-channel (PAF) and a
19-channel (heatmap) convolution output is the input of the refinement stage.
"""

from __future__ import annotations

from pathlib import Path

from follow import model_manifest, models
from follow.model_manifest import manifest_path
from follow.pose.runtime import HEATMAP_CHANNELS, PAF_CHANNELS

# Nodes that pass a tensor through without changing what it means.
_PASS_THROUGH = {"Identity", "Add", "QuantizeLinear", "DequantizeLinear"}
_QUANTIZATION = {"QuantizeLinear", "DequantizeLinear"}
STAGE_CHOICES = (1, 2)


class StageCutError(models.ModelError):
    """The graph has no initial stage we can recognise."""


def initial_stage_outputs(model) -> tuple[str, str]:
    """(PAF tensor, heatmap tensor) names of the initial stage in an onnx ModelProto."""
    graph = model.graph
    producers = {out: node for node in graph.node for out in node.output}
    initializers = {t.name: t for t in graph.initializer}
    for node in graph.node:
        if node.op_type != "Concat":
            continue
        found: dict[int, str] = {}
        for name in node.input:
            channels = _convolution_channels(name, producers, initializers)
            if channels in (PAF_CHANNELS, HEATMAP_CHANNELS):
                found[channels] = _before_quantization(name, producers)
        if len(found) == 2:
            return found[PAF_CHANNELS], found[HEATMAP_CHANNELS]
    raise StageCutError(
        "no Concat joins a 38-channel PAF and a 19-channel heatmap convolution: not a "
        "Lightweight OpenPose graph with a refinement stage (use network_stages = 2)"
    )


def _convolution_channels(tensor: str, producers: dict, initializers: dict) -> int | None:
    """Output channels of the convolution that `tensor` comes from (through bias adds,
    identities and quantisation), or None."""
    node = producers.get(tensor)
    for _ in range(8):
        if node is None:
            return None
        if node.op_type == "Conv":
            weight = node.input[1]
            if weight not in initializers:  # INT8: the weight is dequantised first
                dequantize = producers.get(weight)
                weight = dequantize.input[0] if dequantize is not None else weight
            return int(initializers[weight].dims[0]) if weight in initializers else None
        if node.op_type not in _PASS_THROUGH:
            return None
        node = producers.get(node.input[0])
    return None


def _before_quantization(tensor: str, producers: dict) -> str:
    """The float tensor a quantise/dequantise pair was made from (full precision)."""
    node = producers.get(tensor)
    while node is not None and node.op_type in _QUANTIZATION:
        tensor = node.input[0]
        node = producers.get(tensor)
    return tensor


def initial_stage_file(model_path: Path) -> Path:
    """A copy of the ONNX at `model_path` that ends after its initial stage, made once
    and kept in the user cache (keyed by the source file's hash, its own hash recorded
    beside it and checked on every later use; a cut without a record is made again)."""
    import onnx
    import onnx.utils

    model_path = Path(model_path)
    if not model_path.is_file():
        what = "a folder" if model_path.is_dir() else "no such file"
        raise StageCutError(f"pose model {model_path}: {what}, not an ONNX model file")
    if model_path.suffix != ".onnx":
        raise StageCutError(
            f"pose model {model_path}: network_stages = 1 cuts an ONNX graph; "
            "give the ONNX file or set network_stages = 2"
        )
    digest = models.sha256_of(model_path)[:16]
    target = models.cache_dir() / "pose" / f"{model_path.stem}-initial-stage-{digest}.onnx"
    if target.exists() and model_manifest.read_manifest(target) is not None:
        model_manifest.verify_derived(
            target, f"Delete it and {manifest_path(target).name}: it is cut again on the next run."
        )
        return target
    try:
        model = onnx.load(str(model_path))
    except Exception as exc:  # protobuf's DecodeError and onnx's own: a truncated or wrong file
        raise StageCutError(
            f"pose model {model_path}: not a readable ONNX model ({type(exc).__name__}: "
            f"{exc}); a truncated or wrong file? network_stages = 1 cuts an ONNX graph"
        ) from None
    try:
        outputs = initial_stage_outputs(model)
    except StageCutError as exc:
        raise StageCutError(f"pose model {model_path}: {exc}") from None
    weights = {t.name for t in model.graph.initializer}
    inputs = [i.name for i in model.graph.input if i.name not in weights]
    models.make_cache_folder(target.parent)
    model_manifest.install(
        target, model_path, {"cut": "initial stage"},
        lambda partial: onnx.utils.extract_model(str(model_path), str(partial), inputs,
                                                 list(outputs)),
    )  # fmt: skip
    return target
