#!/usr/bin/env python3
"""Convert an OpenVINO IR (v10/v11 `.xml` + `.bin`, as Intel publishes it) to ONNX.

Reads the layer graph from the XML and the constants from the .bin, folds every
constant sub-graph in numpy (so FP16 or INT8-with-scale weights become plain FP32
initializers), and writes the remaining layers as standard ONNX operators (opset 13):

    python tools/ir_to_onnx.py human-pose-estimation-0001.xml -o pose.onnx

FakeQuantize layers on activations (the INT8 IR's quantisation points) are either
dropped (`--fake-quantize drop`, the default: a float network with the INT8 weights'
values) or written out as the float operations that reproduce them
(`--fake-quantize emulate`: clamp, scale, round). FakeQuantize on weights is always
applied while folding. The input keeps its batch and channels; height and width are
made dynamic unless `--static`.

Layer types handled: Parameter, Result, Const, Convert, Add, Subtract, Multiply,
Divide, Reshape, FakeQuantize, Convolution, GroupConvolution, ReLU, Elu, Sigmoid,
Clamp, Concat, MaxPool, AvgPool. Any other type is reported by name and id.
"""

from __future__ import annotations

import argparse
import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

OPSET = 13
DTYPES = {
    "f16": np.float16,
    "f32": np.float32,
    "f64": np.float64,
    "i8": np.int8,
    "u8": np.uint8,
    "i16": np.int16,
    "u16": np.uint16,
    "i32": np.int32,
    "u32": np.uint32,
    "i64": np.int64,
    "u64": np.uint64,
    "boolean": np.bool_,
}
FAKE_QUANTIZE_MODES = ("drop", "emulate")


class ConversionError(ValueError):
    """An IR that cannot be converted; the message names the layer."""


@dataclass
class Layer:
    id: str
    name: str
    type: str
    data: dict[str, str]
    inputs: list[str] = field(default_factory=list)  # input port ids, in order
    outputs: list[str] = field(default_factory=list)  # output port ids, in order
    out_names: dict[str, str] = field(default_factory=dict)  # port -> tensor name(s)
    out_dims: dict[str, list[int]] = field(default_factory=dict)
    in_dims: list[list[int]] = field(default_factory=list)


def parse_ir(xml_path: Path) -> tuple[dict[str, Layer], dict[tuple[str, str], tuple[str, str]]]:
    """Layers by id, and edges (to-layer, to-port) -> (from-layer, from-port)."""
    try:
        root = ET.parse(xml_path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise ConversionError(f"{xml_path}: cannot read the IR XML ({exc})") from None
    if root.tag != "net":
        raise ConversionError(f"{xml_path}: not an OpenVINO IR (root <{root.tag}>)")
    layers: dict[str, Layer] = {}
    for el in root.find("layers"):
        data_el = el.find("data")
        layer = Layer(
            el.get("id"), el.get("name"), el.get("type"),
            dict(data_el.attrib) if data_el is not None else {},
        )  # fmt: skip
        inp = el.find("input")
        if inp is not None:
            layer.inputs = [p.get("id") for p in inp.findall("port")]
            layer.in_dims = [[int(d.text) for d in p.findall("dim")] for p in inp.findall("port")]
        out = el.find("output")
        if out is not None:
            for p in out.findall("port"):
                layer.outputs.append(p.get("id"))
                if p.get("names"):
                    layer.out_names[p.get("id")] = p.get("names").split(",")[0]
                layer.out_dims[p.get("id")] = [int(d.text) for d in p.findall("dim")]
        layers[layer.id] = layer
    edges = {}
    for e in root.find("edges"):
        edges[(e.get("to-layer"), e.get("to-port"))] = (e.get("from-layer"), e.get("from-port"))
    return layers, edges


def topological_order(layers: dict[str, Layer], edges) -> list[str]:
    deps = {lid: [edges[(lid, p)][0] for p in layer.inputs if (lid, p) in edges]
            for lid, layer in layers.items()}  # fmt: skip
    order, state = [], {}
    for start in layers:
        stack = [(start, False)]
        while stack:
            lid, done = stack.pop()
            if done:
                state[lid] = 2
                order.append(lid)
                continue
            if state.get(lid):
                continue
            state[lid] = 1
            stack.append((lid, True))
            stack.extend((d, False) for d in deps[lid] if not state.get(d))
    return order


def fake_quantize(x, in_low, in_high, out_low, out_high, levels: int):
    """OpenVINO FakeQuantize on numpy arrays (float64 maths, as its reference)."""
    x = np.asarray(x, np.float64)
    in_low, in_high = np.asarray(in_low, np.float64), np.asarray(in_high, np.float64)
    out_low, out_high = np.asarray(out_low, np.float64), np.asarray(out_high, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        q = np.round((x - in_low) / (in_high - in_low) * (levels - 1))
        y = q / (levels - 1) * (out_high - out_low) + out_low
    y = np.where(x <= np.minimum(in_low, in_high), out_low, y)
    y = np.where(x > np.maximum(in_low, in_high), out_high, y)
    return y


class Converter:
    def __init__(self, xml_path: Path, bin_path: Path, fake_quantize_mode: str, dynamic_hw: bool):
        if fake_quantize_mode not in FAKE_QUANTIZE_MODES:
            raise ConversionError(f"--fake-quantize must be one of {FAKE_QUANTIZE_MODES}")
        self.layers, self.edges = parse_ir(xml_path)
        try:
            self.blob = np.fromfile(bin_path, dtype=np.uint8)
        except OSError as exc:
            raise ConversionError(f"{bin_path}: cannot read the IR weights ({exc})") from None
        self.fq_mode = fake_quantize_mode
        self.dynamic_hw = dynamic_hw
        self.consts: dict[tuple[str, str], np.ndarray] = {}  # folded values
        self.nodes, self.initializers, self.inputs, self.outputs = [], [], [], []
        self._names: set[str] = set()
        self._value_names: dict[tuple[str, str], str] = {}
        # IR tensor names may repeat (a fused bias add keeps its convolution's name):
        # give every output port its own ONNX name, inputs (Parameters) first.
        ordered = sorted(self.layers.values(), key=lambda lyr: lyr.type != "Parameter")
        for layer in ordered:
            for port in layer.outputs:
                base = layer.out_names.get(port) or f"{layer.name}:{port}"
                self._value_names[(layer.id, port)] = self.unique(base)

    # -- helpers -----------------------------------------------------------------------
    def source(self, layer: Layer, index: int) -> tuple[str, str]:
        try:
            return self.edges[(layer.id, layer.inputs[index])]
        except (KeyError, IndexError):
            raise ConversionError(
                f"layer {layer.id} '{layer.name}' ({layer.type}): input {index} not connected"
            ) from None

    def is_const(self, layer: Layer, index: int) -> bool:
        return self.source(layer, index) in self.consts

    def const(self, layer: Layer, index: int) -> np.ndarray:
        return self.consts[self.source(layer, index)]

    def tensor(self, layer: Layer, index: int) -> str:
        """The ONNX name of a layer input; constants become initializers on demand."""
        src = self.source(layer, index)
        if src in self.consts:
            return self.initializer(self.consts[src], f"{self.layers[src[0]].name}_const")
        return self.value_name(*src)

    def value_name(self, layer_id: str, port: str) -> str:
        return self._value_names[(layer_id, port)]

    def unique(self, base: str) -> str:
        name, i = base, 1
        while name in self._names:
            name, i = f"{base}_{i}", i + 1
        self._names.add(name)
        return name

    def initializer(self, value: np.ndarray, base: str) -> str:
        from onnx import numpy_helper

        value = np.asarray(value)
        if value.dtype.kind == "f":
            value = value.astype(np.float32)
        name = self.unique(base)
        self.initializers.append(numpy_helper.from_array(value, name))
        return name

    def node(self, op: str, inputs: list[str], layer: Layer, **attrs) -> str:
        from onnx import helper

        out = self.value_name(layer.id, layer.outputs[0])
        self.nodes.append(helper.make_node(op, inputs, [out], name=layer.name, **attrs))
        return out

    def extra(self, op: str, inputs: list[str], base: str, **attrs) -> str:
        from onnx import helper

        out = self.unique(base)
        self.nodes.append(helper.make_node(op, inputs, [out], name=out, **attrs))
        return out

    # -- constant folding --------------------------------------------------------------
    def fold(self, layer: Layer) -> bool:
        """Evaluate `layer` in numpy when all its inputs are constants."""
        t = layer.type
        if t == "Const":
            dtype = DTYPES.get(layer.data.get("element_type"))
            if dtype is None:
                raise ConversionError(
                    f"layer {layer.id} '{layer.name}': element type "
                    f"{layer.data.get('element_type')} not supported"
                )
            offset, size = int(layer.data["offset"]), int(layer.data["size"])
            if offset + size > self.blob.size:
                raise ConversionError(f"layer {layer.id} '{layer.name}': beyond the .bin end")
            shape = [int(s) for s in layer.data.get("shape", "").split(",") if s != ""]
            value = self.blob[offset : offset + size].view(dtype).reshape(shape)
            self.consts[(layer.id, layer.outputs[0])] = value
            return True
        if not layer.inputs or not all(self.is_const(layer, i) for i in range(len(layer.inputs))):
            return False
        args = [self.const(layer, i) for i in range(len(layer.inputs))]
        if t == "Convert":
            value = args[0].astype(np.float32 if layer.data["destination_type"].startswith("f")
                                   else DTYPES[layer.data["destination_type"]])  # fmt: skip
        elif t in ("Add", "Subtract", "Multiply", "Divide"):
            a, b = (x.astype(np.float32) if x.dtype.kind == "f" else x for x in args)
            value = {"Add": np.add, "Subtract": np.subtract, "Multiply": np.multiply,
                     "Divide": np.divide}[t](a, b)  # fmt: skip
        elif t == "Reshape":
            target = [int(v) for v in args[1].ravel()]
            if layer.data.get("special_zero", "false") == "true":
                target = [args[0].shape[i] if v == 0 else v for i, v in enumerate(target)]
            value = args[0].reshape(target)
        elif t == "FakeQuantize":
            value = fake_quantize(*args, int(layer.data["levels"])).astype(np.float32)
        elif t == "Concat":
            value = np.concatenate(args, axis=int(layer.data["axis"]))
        else:
            return False
        self.consts[(layer.id, layer.outputs[0])] = np.asarray(value)
        return True

    # -- graph layers ------------------------------------------------------------------
    def emit(self, layer: Layer) -> None:
        from onnx import TensorProto, helper

        t = layer.type
        if t == "Parameter":
            dims = [int(s) for s in layer.data.get("shape", "").split(",") if s]
            if self.dynamic_hw and len(dims) == 4:
                dims = dims[:2] + ["height", "width"]
            name = self.value_name(layer.id, layer.outputs[0])
            self.inputs.append(helper.make_tensor_value_info(name, TensorProto.FLOAT, dims))
        elif t == "Result":
            src = self.tensor(layer, 0)
            wanted = layer.name.split("/sink_port")[0]
            name = src if src == wanted else self.unique(wanted)
            if name != src:
                self.nodes.append(helper.make_node("Identity", [src], [name], name=layer.name))
            dims = list(layer.in_dims[0]) if layer.in_dims else []
            if self.dynamic_hw and len(dims) == 4:
                dims = dims[:2] + [f"{name}_height", f"{name}_width"]
            self.outputs.append(helper.make_tensor_value_info(name, TensorProto.FLOAT, dims))
        elif t in ("Add", "Subtract", "Multiply", "Divide"):
            op = {"Add": "Add", "Subtract": "Sub", "Multiply": "Mul", "Divide": "Div"}[t]
            self.node(op, [self.tensor(layer, 0), self.tensor(layer, 1)], layer)
        elif t in ("Convolution", "GroupConvolution"):
            self.emit_conv(layer)
        elif t == "ReLU":
            self.node("Relu", [self.tensor(layer, 0)], layer)
        elif t == "Sigmoid":
            self.node("Sigmoid", [self.tensor(layer, 0)], layer)
        elif t == "Elu":
            self.node("Elu", [self.tensor(layer, 0)], layer, alpha=float(layer.data["alpha"]))
        elif t == "Clamp":
            lo = self.initializer(np.float32(layer.data["min"]), f"{layer.name}_min")
            hi = self.initializer(np.float32(layer.data["max"]), f"{layer.name}_max")
            self.node("Clip", [self.tensor(layer, 0), lo, hi], layer)
        elif t == "Concat":
            ins = [self.tensor(layer, i) for i in range(len(layer.inputs))]
            self.node("Concat", ins, layer, axis=int(layer.data["axis"]))
        elif t in ("MaxPool", "AvgPool"):
            self.emit_pool(layer)
        elif t == "Reshape":
            if not self.is_const(layer, 1):
                raise ConversionError(f"layer {layer.id} '{layer.name}': dynamic Reshape")
            target = self.const(layer, 1).astype(np.int64).ravel()
            if layer.data.get("special_zero", "false") != "true" and (target == 0).any():
                raise ConversionError(f"layer {layer.id} '{layer.name}': zero dims without "
                                      "special_zero")  # fmt: skip
            shape = self.initializer(target, f"{layer.name}_shape")
            self.node("Reshape", [self.tensor(layer, 0), shape], layer)
        elif t == "FakeQuantize":
            self.emit_fake_quantize(layer)
        elif t == "Convert":
            self.node("Identity", [self.tensor(layer, 0)], layer)
        else:
            raise ConversionError(
                f"layer {layer.id} '{layer.name}': type {t} is not supported by this converter"
            )

    def emit_conv(self, layer: Layer) -> None:
        if not self.is_const(layer, 1):
            raise ConversionError(f"layer {layer.id} '{layer.name}': weights are not constant")
        weights = self.const(layer, 1).astype(np.float32)
        attrs = {
            "strides": [int(v) for v in layer.data["strides"].split(",")],
            "dilations": [int(v) for v in layer.data["dilations"].split(",")],
        }
        if layer.type == "GroupConvolution":
            groups = weights.shape[0]
            weights = weights.reshape((groups * weights.shape[1],) + weights.shape[2:])
            attrs["group"] = groups
        attrs["kernel_shape"] = list(weights.shape[2:])
        auto_pad = layer.data.get("auto_pad", "explicit")
        if auto_pad in ("same_upper", "same_lower"):
            attrs["auto_pad"] = auto_pad.upper()
        elif auto_pad == "valid":
            attrs["auto_pad"] = "VALID"
        else:
            attrs["pads"] = [int(v) for v in layer.data["pads_begin"].split(",")] + [
                int(v) for v in layer.data["pads_end"].split(",")
            ]
        w = self.initializer(weights, f"{layer.name}_weights")
        self.node("Conv", [self.tensor(layer, 0), w], layer, **attrs)

    def emit_pool(self, layer: Layer) -> None:
        attrs = {
            "kernel_shape": [int(v) for v in layer.data["kernel"].split(",")],
            "strides": [int(v) for v in layer.data["strides"].split(",")],
            "pads": [int(v) for v in layer.data["pads_begin"].split(",")]
            + [int(v) for v in layer.data["pads_end"].split(",")],
        }
        if layer.data.get("rounding_type", "floor") == "ceil":
            attrs["ceil_mode"] = 1
        if layer.type == "AvgPool":
            attrs["count_include_pad"] = 0 if layer.data.get("exclude-pad") == "true" else 1
            self.node("AveragePool", [self.tensor(layer, 0)], layer, **attrs)
        else:
            self.node("MaxPool", [self.tensor(layer, 0)], layer, **attrs)

    def emit_fake_quantize(self, layer: Layer) -> None:
        x = self.tensor(layer, 0)
        if self.fq_mode == "drop":
            self.node("Identity", [x], layer)
            return
        if not all(self.is_const(layer, i) for i in range(1, 5)):
            raise ConversionError(f"layer {layer.id} '{layer.name}': FakeQuantize bounds vary")
        lo, hi, olo, ohi = (self.const(layer, i).astype(np.float64) for i in range(1, 5))
        steps = int(layer.data["levels"]) - 1
        base = layer.name
        # y = round((clip(x, lo, hi) - lo) * steps / (hi - lo)) * (ohi - olo) / steps + olo
        c_lo = self.initializer(np.minimum(lo, hi), f"{base}_lo")
        c_hi = self.initializer(np.maximum(lo, hi), f"{base}_hi")
        clipped = self.extra("Min", [self.extra("Max", [x, c_lo], f"{base}_max"), c_hi],
                             f"{base}_min")  # fmt: skip
        shifted = self.extra("Sub", [clipped, self.initializer(lo, f"{base}_in_low")],
                             f"{base}_sub")  # fmt: skip
        with np.errstate(divide="ignore", invalid="ignore"):
            scale_in = np.where(hi != lo, steps / (hi - lo), 0.0)
        q = self.extra("Round", [self.extra("Mul", [shifted, self.initializer(
            scale_in, f"{base}_scale_in")], f"{base}_mul")], f"{base}_round")  # fmt: skip
        scaled = self.extra("Mul", [q, self.initializer((ohi - olo) / steps, f"{base}_scale_out")],
                            f"{base}_mul_out")  # fmt: skip
        self.node("Add", [scaled, self.initializer(olo, f"{base}_out_low")], layer)

    def convert(self, graph_name: str):
        from onnx import helper

        for lid in topological_order(self.layers, self.edges):
            layer = self.layers[lid]
            if layer.type not in ("Parameter", "Result") and self.fold(layer):
                continue
            self.emit(layer)
        graph = helper.make_graph(self.nodes, graph_name, self.inputs, self.outputs,
                                  self.initializers)  # fmt: skip
        model = helper.make_model(
            graph, producer_name="follow-ir_to_onnx", opset_imports=[helper.make_opsetid("", OPSET)]
        )
        model.ir_version = 8
        return model


def convert_ir(
    xml_path: Path,
    output_path: Path,
    bin_path: Path | None = None,
    fake_quantize_mode: str = "drop",
    dynamic_hw: bool = True,
) -> Path:
    """Convert `xml_path` (+ `bin_path`, default: beside it) and write `output_path`."""
    import onnx

    xml_path = Path(xml_path)
    bin_path = Path(bin_path) if bin_path else xml_path.with_suffix(".bin")
    model = Converter(xml_path, bin_path, fake_quantize_mode, dynamic_hw).convert(xml_path.stem)
    onnx.checker.check_model(model)
    output_path = Path(output_path)
    output_path.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(model, str(output_path))
    return output_path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("xml", type=Path, help="the IR's .xml file")
    parser.add_argument("-o", "--output", type=Path, required=True, help="ONNX file to write")
    parser.add_argument("--bin", type=Path, default=None, help="weights (default: beside .xml)")
    parser.add_argument("--fake-quantize", choices=FAKE_QUANTIZE_MODES, default="drop",
                        help="what to do with activation FakeQuantize layers")  # fmt: skip
    parser.add_argument("--static", action="store_true", help="keep the IR's fixed H and W")
    args = parser.parse_args(argv)
    try:
        out = convert_ir(args.xml, args.output, args.bin, args.fake_quantize, not args.static)
    except ConversionError as exc:
        print(f"ir_to_onnx: error: {exc}", file=sys.stderr)
        return 1
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
