"""Inference back-ends for the pose network, chosen by the `provider` option.

onnxruntime is the portable default (CPU everywhere, CUDA/TensorRT on GPU boards). The
OpenVINO runtime is an optional fast CPU path; it also reads the official IR (.xml).
A provider that is not available falls back to onnxruntime on the CPU with a warning
that says what was asked for, what is missing and what runs instead; `auto` checks that
the GPU provider it chose runs the session, else runs the CPU's choice (OpenVINO).
"""

from __future__ import annotations

import functools
import logging
from pathlib import Path
from typing import Protocol

import numpy as np

from follow.models import ModelError
from follow.pose.size_cache import RecentlyUsed

log = logging.getLogger(__name__)

PROVIDERS = ("auto", "cpu", "cuda", "tensorrt", "openvino")
HEATMAP_CHANNELS = 19
PAF_CHANNELS = 38


# Pose runtimes that run the network off the CPU (`PoseBackend.name` contains one).
ACCELERATED_POSE_BACKENDS = ("CUDAExecutionProvider", "TensorrtExecutionProvider")


def backend_runs_on_gpu(backend_name: str) -> bool:
    """Whether the back-end named `backend_name` (`PoseBackend.name`) runs on a GPU."""
    return any(name in backend_name for name in ACCELERATED_POSE_BACKENDS)


class PoseBackend(Protocol):
    """Runs the network on one image: a (1, 3, H, W) float32 tensor, or, for a back-end
    made with `frame_input`, the (1, H, W, 3) uint8 frame itself."""

    name: str
    frame_input: bool

    def run(self, tensor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(heatmaps (19, H/8, W/8), pafs (38, H/8, W/8)) for the single image."""
        ...


def with_frame_input(model_path: Path) -> bytes:
    """The ONNX network with a uint8 NHWC input in front of its float NCHW one.

    The frame goes to the runtime as the camera gives it (one byte per value, channels
    last); the transpose and the conversion to float run inside the graph, in the
    runtime's threads, instead of in Python before every frame. Values are unchanged:
    uint8 -> float32 is exact, so the outputs equal the float path's.
    """
    import onnx
    from onnx import TensorProto, helper

    model = onnx.load(str(model_path))
    graph = model.graph
    initializers = {t.name for t in graph.initializer}
    inputs = [i for i in graph.input if i.name not in initializers]
    if len(inputs) != 1 or len(inputs[0].type.tensor_type.shape.dim) != 4:
        raise ValueError(f"pose model {model_path}: expected one 4-d NCHW input")
    original = inputs[0]
    dims = [d.dim_value if d.HasField("dim_value") else (d.dim_param or None)
            for d in original.type.tensor_type.shape.dim]  # fmt: skip
    frame_name = f"{original.name}_uint8_nhwc"
    frame = helper.make_tensor_value_info(
        frame_name, TensorProto.UINT8, [dims[0], dims[2], dims[3], dims[1]]
    )
    nchw = f"{frame_name}_nchw"
    nodes = [
        helper.make_node("Transpose", [frame_name], [nchw], perm=[0, 3, 1, 2]),
        helper.make_node("Cast", [nchw], [original.name], to=TensorProto.FLOAT),
    ]
    graph.input.remove(original)
    graph.input.insert(0, frame)
    for node in reversed(nodes):
        graph.node.insert(0, node)
    return model.SerializeToString()


def check_pose_signature(model_path: Path, input_shape: list, output_shapes: list[list],
                         reshapes: bool = False) -> None:  # fmt: skip
    """Refuse, when it is loaded, a network that cannot be the pose network: one BGR
    image in (rank 4, 3 channels where the file fixes them), heatmaps and PAFs out (19
    and 38 channels where fixed), and, for a runtime that cannot reshape it (`reshapes`
    False: onnxruntime), an image size left free. Another network named by `[pose]
    model_file` (the re-id one), or one made with a fixed size, otherwise fails on the
    first frame inside the runtime, naming neither. Shapes as the runtimes give them: a
    dimension that is not an int is free."""

    def fixed(dim) -> int | None:
        return dim if isinstance(dim, int) and dim > 0 else None

    problem = None
    if len(input_shape) != 4 or fixed(input_shape[1]) not in (None, 3):
        problem = f"its input is {list(input_shape)}, not an image [1, 3, H, W]"
    elif not reshapes and (fixed(input_shape[2]) or fixed(input_shape[3])):
        problem = (f"its input fixes the image size ({list(input_shape)}), which the "
                   "network is fed at each camera's own size (made with "
                   "tools/ir_to_onnx.py --static? convert it again without)")  # fmt: skip
    elif len(output_shapes) < 2:
        problem = f"it has {len(output_shapes)} output(s), not heatmaps and PAFs"
    else:
        channels = [fixed(shape[1]) if len(shape) == 4 else -1 for shape in output_shapes]
        known = {c for c in channels if c is not None}
        if -1 in known or (known and not known <= {HEATMAP_CHANNELS, PAF_CHANNELS}):
            problem = (f"its outputs are {[list(s) for s in output_shapes]}, not heatmaps "
                       f"({HEATMAP_CHANNELS} channels) and PAFs ({PAF_CHANNELS})")  # fmt: skip
    if problem:
        raise ModelError(
            f"pose model {model_path} is not a pose network of this kind: {problem} "
            "([pose] model_file names another network?)"
        )


def _split_outputs(outputs: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Heatmaps and PAFs told apart by their channel counts (names differ between files)."""
    by_channels = {o.shape[1]: o for o in outputs}
    if HEATMAP_CHANNELS not in by_channels or PAF_CHANNELS not in by_channels:
        shapes = [o.shape for o in outputs]
        raise RuntimeError(
            f"pose network outputs {shapes}: expected one with {HEATMAP_CHANNELS} "
            f"(heatmaps) and one with {PAF_CHANNELS} channels (PAFs)"
        )
    return by_channels[HEATMAP_CHANNELS][0], by_channels[PAF_CHANNELS][0]


def tensorrt_options() -> dict[str, object]:
    """TensorRT provider options: built engines are cached beside the user's models,
    keyed by onnxruntime from the model and the device, so only the first start on a
    board pays the engine build (minutes on a Jetson). FP16 is on: the board's tensor
    cores run it, and the network's outputs are smooth maps that lose nothing to it."""
    from follow.models import cache_dir, make_cache_folder

    engines = make_cache_folder(cache_dir() / "tensorrt")
    return {
        "trt_engine_cache_enable": True,
        "trt_engine_cache_path": str(engines),
        "trt_timing_cache_enable": True,
        "trt_timing_cache_path": str(engines),
        "trt_fp16_enable": True,
    }


def provider_entries(providers: list[str]) -> list:
    """onnxruntime's providers argument, with options where a provider needs them."""
    return [
        (name, tensorrt_options()) if name == "TensorrtExecutionProvider" else name
        for name in providers
    ]


class OrtBackend:
    """onnxruntime session with the given execution providers (in priority order);
    with `frame_input` it takes the uint8 NHWC frame (`with_frame_input`)."""

    def __init__(
        self,
        model_path: Path,
        providers: list[str],
        cpu_threads: int = 0,
        frame_input: bool = False,
    ):
        import onnxruntime as ort

        options = ort.SessionOptions()
        if cpu_threads > 0:
            options.intra_op_num_threads = cpu_threads
        options.log_severity_level = 3
        # Idle worker threads sleep instead of spinning: the other stages of the pipeline
        # (and other runtimes in a benchmark) need the CPU between two frames.
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
        model = with_frame_input(model_path) if frame_input else str(model_path)
        self.session = ort.InferenceSession(model, options, providers=provider_entries(providers))
        shape = list(self.session.get_inputs()[0].shape)
        if frame_input:  # the frame's NHWC, checked as the network's own NCHW
            shape = [shape[0], shape[3], shape[1], shape[2]] if len(shape) == 4 else shape
        check_pose_signature(model_path, shape,
                             [o.shape for o in self.session.get_outputs()])  # fmt: skip
        self.input_name = self.session.get_inputs()[0].name
        active = self.session.get_providers()
        if active[0] != providers[0]:
            log.warning(
                "pose: onnxruntime could not start %s (missing libraries or device?); "
                "running on %s instead",
                providers[0],
                active[0],
            )
        self.name = f"onnxruntime:{active[0]}"
        self.frame_input = frame_input

    def run(self, tensor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return _split_outputs(self.session.run(None, {self.input_name: tensor}))


class OpenVinoBackend:
    """OpenVINO runtime on the CPU; reads ONNX or IR, one compiled model per input shape
    (the most recently used `size_cache.SHAPES_KEPT` kept: 25-30 MiB each); with
    `frame_input` it takes the uint8 NHWC frame (OpenVINO's own pre-processing converts
    it inside the compiled model)."""

    def __init__(self, model_path: Path, cpu_threads: int = 0, frame_input: bool = False):
        import openvino as ov

        self._core = openvino_core()
        self._model = self._core.read_model(str(model_path))
        check_pose_signature(model_path, _openvino_shape(self._model.inputs[0]),
                             [_openvino_shape(o) for o in self._model.outputs],
                             reshapes=True)  # fmt: skip
        if frame_input:
            from openvino.preprocess import PrePostProcessor

            steps = PrePostProcessor(self._model)
            steps.input().tensor().set_element_type(ov.Type.u8).set_layout(ov.Layout("NHWC"))
            steps.input().model().set_layout(ov.Layout("NCHW"))
            self._model = steps.build()
        self._config = {"PERFORMANCE_HINT": "LATENCY"}
        if cpu_threads > 0:
            self._config["INFERENCE_NUM_THREADS"] = cpu_threads
        self._compiled: RecentlyUsed = RecentlyUsed()
        self.name = "openvino:CPU"
        self.frame_input = frame_input

    def _request(self, shape: tuple[int, ...]):
        if shape not in self._compiled:
            model = self._model.clone()
            model.reshape({model.inputs[0].any_name: list(shape)})
            compiled = self._core.compile_model(model, "CPU", self._config)
            self._compiled[shape] = compiled.create_infer_request()
        return self._compiled[shape]

    def run(self, tensor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        request = self._request(tuple(tensor.shape))
        request.infer({0: tensor})
        return _split_outputs([request.get_output_tensor(i).data.copy() for i in range(2)])


def _openvino_shape(port) -> list:
    """An OpenVINO port's shape as onnxruntime gives one: ints where fixed, else None."""
    return [d.get_length() if d.is_static else None for d in port.get_partial_shape()]


@functools.cache
def openvino_core():
    """One OpenVINO Core for the process. A Core that is created and destroyed again
    (two back-ends made and dropped) unloads its CPU plugin, and a signal handled by
    Python afterwards (SIGINT, SIGTERM: the shutdown path) then crashed the process
    with a segmentation fault; a Core kept for the process's life never unloads it."""
    import openvino as ov

    return ov.Core()


def openvino_installed() -> bool:
    try:
        import openvino  # noqa: F401
    except ImportError:
        return False
    return True


def ort_available_providers() -> list[str]:
    import onnxruntime as ort

    return list(ort.get_available_providers())


GPU_PROVIDERS = {
    "cuda": ["CUDAExecutionProvider"],
    "tensorrt": ["TensorrtExecutionProvider", "CUDAExecutionProvider"],
}


# The GPU providers `auto` found listed by onnxruntime but not starting in this process,
# with why (`_started_gpu_backend`): `auto` chooses the CPU's runtime from then on.
GPU_FAILURES: dict[str, str] = {}


def _auto_gpu(available: list[str], is_ir: bool) -> str | None:
    """The GPU provider `auto` chooses here (TensorRT, else CUDA), or None."""
    for gpu in ("tensorrt", "cuda"):
        if not is_ir and GPU_PROVIDERS[gpu][0] in available and gpu not in GPU_FAILURES:
            return gpu
    return None


def auto_provider(model_path: Path) -> str:
    """The provider `auto` runs `model_path` on here: TensorRT, else CUDA (not for an
    OpenVINO IR; not once found not to start, GPU_FAILURES), else OpenVINO where
    installed, else onnxruntime on the CPU."""
    is_ir = Path(model_path).suffix == ".xml"
    return _auto_gpu(ort_available_providers(), is_ir) or (
        "openvino" if openvino_installed() else "cpu"
    )


def runs_on_gpu(provider: str) -> bool:
    """Whether `provider` will put the network on a GPU here, as `create_backend` does:
    `auto` with a GPU provider offered (and not found not to start), or `cuda` /
    `tensorrt` with any of theirs offered (TensorRT missing, its request runs on CUDA).
    Asked before the model file is chosen, since the INT8 model is for CPUs (docs/pose.md:
    slower than FP32 on CUDA)."""
    available = ort_available_providers()
    if provider == "auto":
        return _auto_gpu(available, is_ir=False) is not None
    return any(p in available for p in GPU_PROVIDERS.get(provider, ()))


def create_backend(provider: str, model_path: Path, cpu_threads: int = 0) -> PoseBackend:
    """The back-end for `provider`, falling back to onnxruntime CPU with a clear warning.

    The OpenVINO runtime takes the uint8 frame (`frame_input`): with the conversion in
    its compiled model it is about 2 % faster than on the float tensor, and Python's
    preparation halves. onnxruntime keeps the float input: with the transpose in its
    graph the INT8 network runs 10-13 % slower (`follow bench pose`, docs/pose.md).
    """
    if provider not in PROVIDERS:
        raise ValueError(f"pose provider '{provider}' unknown; choose one of {PROVIDERS}")
    model_path = Path(model_path)
    if not model_path.is_file():
        raise ModelError(f"pose model {model_path} is not a file ([pose] model_file?)")
    try:
        return _create_backend(provider, model_path, cpu_threads)
    except (ModelError, ValueError):
        raise
    except Exception as exc:  # the runtimes' parse errors name neither the file nor the key
        raise ModelError(
            f"pose model {model_path} cannot be loaded ({type(exc).__name__}: "
            f"{_last_line(exc)}); "
            "a truncated or wrong file? `[pose] model_file` names an explicit one, "
            "`follow models verify` checks the others"
        ) from exc


def _last_line(exc: Exception) -> str:
    """The last non-empty line of an error: where the runtimes put what went wrong."""
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    return lines[-1] if lines else "no detail"


def _create_backend(provider: str, model_path: Path, cpu_threads: int) -> PoseBackend:
    is_ir = model_path.suffix == ".xml"
    available = ort_available_providers()
    if provider == "auto":
        provider = auto_provider(model_path)
        while provider in GPU_PROVIDERS:  # listed; a broken install still lists it
            backend = _started_gpu_backend(provider, model_path, cpu_threads)
            if backend is not None:
                return backend
            provider = auto_provider(model_path)
        log.info("pose: provider 'auto' chose '%s'", provider)
    if provider == "openvino":
        if openvino_installed():
            return OpenVinoBackend(model_path, cpu_threads, frame_input=True)
        if not is_ir and "OpenVINOExecutionProvider" in available:
            return OrtBackend(
                model_path, ["OpenVINOExecutionProvider", "CPUExecutionProvider"], cpu_threads
            )
        _fallback_warning(provider, "the openvino package is not installed", available)
    elif provider in GPU_PROVIDERS:
        present = [p for p in GPU_PROVIDERS[provider] if p in available]
        if present and not is_ir:
            return OrtBackend(model_path, present + ["CPUExecutionProvider"], cpu_threads)
        _fallback_warning(
            provider, f"onnxruntime here has no {GPU_PROVIDERS[provider][0]}", available
        )
    if is_ir:
        raise ValueError(
            f"pose model {model_path} is an OpenVINO IR; onnxruntime cannot read it "
            "(install openvino and use provider 'openvino', or give the ONNX file)"
        )
    return OrtBackend(model_path, ["CPUExecutionProvider"], cpu_threads)


def _started_gpu_backend(gpu: str, model_path: Path, cpu_threads: int) -> OrtBackend | None:
    """The onnxruntime session `auto` chose `gpu` for, or None where it does not run on
    the GPU. onnxruntime lists a provider whose libraries are missing (no libcudart, a
    driver of another CUDA) and then runs the session on its CPU provider, FP32: slower
    than the CPU's own choice (OpenVINO, INT8 where made). Such a provider is warned of
    and recorded in GPU_FAILURES, and `auto` goes on as without it."""
    wanted = GPU_PROVIDERS[gpu]
    try:
        backend = OrtBackend(model_path, wanted + ["CPUExecutionProvider"], cpu_threads)
    except ModelError:
        raise  # the file is no pose network: no GPU changes that
    except Exception as exc:  # a provider that cannot start may raise instead
        if not _loads_on_cpu(model_path, cpu_threads):
            raise  # the file fails without the GPU too: the model's fault, not the GPU's
        failed, reason = [gpu], f"the session failed: {type(exc).__name__}: {_last_line(exc)}"
    else:
        active = backend.session.get_providers()
        if any(p in wanted for p in active):
            return backend
        failed = [g for g, names in GPU_PROVIDERS.items() if set(names) <= set(wanted)]
        reason = f"the session runs on {', '.join(active)} only"
    GPU_FAILURES.update(dict.fromkeys(failed, reason))
    log.warning(
        "pose: provider 'auto': onnxruntime lists %s, but it does not start here (%s; "
        "missing CUDA libraries or a driver mismatch?); running what a machine without a "
        "GPU runs instead",
        wanted[0],
        reason,
    )
    return None


def _loads_on_cpu(model_path: Path, cpu_threads: int) -> bool:
    """Whether onnxruntime's CPU provider loads `model_path`: a GPU session that raised on
    a file the CPU cannot load either (cut short, no network) says nothing of the GPU."""
    try:
        OrtBackend(model_path, ["CPUExecutionProvider"], cpu_threads)
    except Exception:
        return False
    return True


def _fallback_warning(provider: str, reason: str, available: list[str]) -> None:
    log.warning(
        "pose: provider '%s' is not available (%s; onnxruntime offers %s); "
        "falling back to onnxruntime on the CPU",
        provider,
        reason,
        ", ".join(available),
    )
