"""ONNX graphs built in code, stamped with an IR version every supported runtime reads.

onnx's `helper.make_model` stamps the newest IR version of the installed onnx, which an
older onnxruntime refuses ("Unsupported model IR version: 14, max supported IR version:
13": onnx 1.23 beside onnxruntime-gpu 1.31 on a GPU machine). IR 8 (ONNX 1.10) holds
every operator these graphs use and loads in every onnxruntime the project supports."""

from __future__ import annotations

from onnx import GraphProto, ModelProto, helper

PORTABLE_IR_VERSION = 8


def portable_model(graph: GraphProto, opset: int = 13) -> ModelProto:
    """`graph` as a model of the default domain's `opset`, at `PORTABLE_IR_VERSION`."""
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", opset)])
    model.ir_version = PORTABLE_IR_VERSION
    return model
