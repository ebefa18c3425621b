"""A deep re-identification embedding as a second opinion on who the target is.

The network (person-reidentification-retail-0248) maps a 256x128 BGR crop to a 256-d
embedding. A gallery of the target's embeddings is gathered while the target is tracked;
a person's similarity is the highest cosine similarity to the gallery, mapped linearly
to a confidence in [-1, 1] (`reid_same_similarity` -> 0, +-`reid_similarity_scale` ->
+-1). The graph has a fixed batch of one, so crops run one after another.

On the CPU the network runs on OpenVINO where that package is installed. On a CPU with
bfloat16 arithmetic (AVX-512 BF16, AMX) OpenVINO computes in it by default: a crop in
2.3-2.4 ms against onnxruntime's 4.1-4.3 ms on one core, the embeddings within cosine
0.999 of float32's, which moved no PETS identification figure (docs/identification.md).
Elsewhere it computes in float32, 5-8 % faster than onnxruntime, the same embeddings.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from follow.ccf.features import Roi, cut_crops, resize_crops
from follow.config import IdentifyConfig
from follow.config_bounds import REID_PROVIDERS
from follow.identify.gallery import add_keeping_diverse

log = logging.getLogger(__name__)

REID_INPUT_SIZE = (128, 256)  # (width, height) of the network input
EMBEDDING_SIZE = 256


def reid_runtime(provider: str, available: Sequence[str], openvino_here: Callable[[], bool]) -> str:
    """Which runtime `provider` puts the network on: "cuda" (onnxruntime's CUDA provider:
    with `cuda`, or `auto` where it is offered), "openvino" (with `cpu`, `openvino` or
    `auto` without CUDA, where the openvino package is installed), else "onnxruntime"
    (its CPU provider: always with `onnxruntime`, the plain install's runtime).
    `openvino_here` is asked only where the answer matters: importing openvino to ask
    costs about 16 MB of memory, which a process on onnxruntime should not carry."""
    if provider not in REID_PROVIDERS:
        raise ValueError(
            f"reid_provider '{provider}' unknown; choose one of {', '.join(REID_PROVIDERS)}"
        )
    cuda_here = "CUDAExecutionProvider" in available
    if provider == "cuda" and not cuda_here:
        log.warning(
            "re-id: reid_provider 'cuda' is not available (onnxruntime offers %s); "
            "running on the CPU",
            ", ".join(available),
        )
    if provider in ("cuda", "auto") and cuda_here:
        return "cuda"
    if provider in ("onnxruntime", "cuda"):
        return "onnxruntime"
    if openvino_here():
        return "openvino"
    if provider == "openvino":
        log.warning(
            "re-id: reid_provider 'openvino' is not available (the openvino package is not "
            "installed); running on onnxruntime"
        )
    return "onnxruntime"


class ReidEmbedder:
    """Unit-length embeddings of person crops (on the GPU where one is offered and
    `provider` allows it, so that a board's few CPU cores are left to the tracker; on
    the CPU by OpenVINO where installed, else onnxruntime)."""

    def __init__(self, model_path: Path, threads: int = 1, provider: str = "cpu"):
        import onnxruntime as ort

        from follow.pose.runtime import openvino_installed

        runtime = reid_runtime(provider, ort.get_available_providers(), openvino_installed)
        try:
            if runtime == "openvino":
                self._run_crop, self.backend_name = _openvino(model_path, threads)
            else:
                self._run_crop, self.backend_name = _onnxruntime(
                    model_path, threads, runtime == "cuda"
                )
        except ValueError:
            raise
        except Exception as exc:  # the runtimes raise their own exception types
            raise ValueError(f"re-id model {model_path}: cannot load ({exc})") from None
        log.info("re-id: network on %s", self.backend_name)
        if runtime != "onnxruntime":
            self._warm_up()

    def _warm_up(self) -> None:
        """One crop through the network now: on CUDA the first run searches cuDNN's
        convolution algorithms, which held the first frame that needed re-id 1.6 s
        (capture-to-command p95 1.7 s in `follow bench` on an H200) instead of start-up;
        OpenVINO's first run allocates its buffers."""
        width, height = REID_INPUT_SIZE
        self._embed(np.full((1, height, width, 3), 128, np.uint8))

    def _embed(self, crops: np.ndarray) -> np.ndarray:
        out = np.zeros((len(crops), EMBEDDING_SIZE), dtype=np.float32)
        for i, crop in enumerate(crops):
            out[i] = np.asarray(self._run_crop(crop)).reshape(-1)
        norms = np.linalg.norm(out, axis=1, keepdims=True)
        return out / np.maximum(norms, 1e-12)

    def embed(self, image_bgr: np.ndarray, rois: Sequence[Roi]) -> np.ndarray:
        """(N, 256) unit embeddings of the ROIs of a BGR uint8 image."""
        return self._embed(cut_crops(image_bgr, rois, REID_INPUT_SIZE))

    def embed_crops(self, crops_bgr: Sequence[np.ndarray]) -> np.ndarray:
        """(N, 256) unit embeddings of whole BGR uint8 crops."""
        return self._embed(resize_crops(crops_bgr, REID_INPUT_SIZE))


def _onnxruntime(model_path: Path, threads: int, cuda: bool) -> tuple[Callable, str]:
    """A crop -> embedding runner on onnxruntime (CUDA first with `cuda`), and its name."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = max(1, int(threads))
    options.inter_op_num_threads = 1
    providers = (["CUDAExecutionProvider"] if cuda else []) + ["CPUExecutionProvider"]
    session = ort.InferenceSession(str(model_path), options, providers=providers)
    inp = session.get_inputs()[0]
    _check_input_shape(model_path, inp.shape)
    name = inp.name
    return (
        lambda crop: session.run(None, {name: crop[None].astype(np.float32)})[0],
        f"onnxruntime:{session.get_providers()[0]}",
    )


def _openvino(model_path: Path, threads: int) -> tuple[Callable, str]:
    """A crop -> embedding runner on a compiled model that takes the uint8 crop (its
    conversion to float inside), and its name."""
    import openvino as ov
    from openvino.preprocess import PrePostProcessor

    from follow.pose.runtime import openvino_core

    core = openvino_core()
    model = core.read_model(str(model_path))
    shape = model.inputs[0].get_partial_shape()
    _check_input_shape(model_path, [d.get_length() if d.is_static else str(d) for d in shape])
    if shape.is_dynamic:  # a free batch dimension (onnxruntime takes it): one crop
        model.reshape([1, REID_INPUT_SIZE[1], REID_INPUT_SIZE[0], 3])
    steps = PrePostProcessor(model)
    steps.input().tensor().set_element_type(ov.Type.u8)
    config = {"PERFORMANCE_HINT": "LATENCY", "INFERENCE_NUM_THREADS": max(1, int(threads))}
    request = core.compile_model(steps.build(), "CPU", config).create_infer_request()

    def run(crop: np.ndarray) -> np.ndarray:
        request.infer({0: np.ascontiguousarray(crop[None])})
        return request.get_output_tensor(0).data

    return run, "openvino:CPU"


def _check_input_shape(model_path: Path, shape) -> None:
    if list(shape[1:]) != [REID_INPUT_SIZE[1], REID_INPUT_SIZE[0], 3]:
        raise ValueError(f"re-id model {model_path}: input {shape}, expected [1, 256, 128, 3] NHWC")


class ReidGallery:
    """The target's embeddings, kept diverse, and how similar another person is to them.

    A full gallery drops the most redundant embedding (one of the two most similar to
    each other) rather than the oldest, so that views from long ago and from other sides
    stay when the target has been seen from behind for a while.
    """

    def __init__(self, config: IdentifyConfig):
        if config.reid_gallery_size < 2 or config.reid_similarity_scale <= 0.0:
            raise ValueError("reid_gallery_size must be >= 2 and reid_similarity_scale > 0")
        self.config = config
        self._embeddings = np.zeros((config.reid_gallery_size, EMBEDDING_SIZE), np.float32)
        self._size = 0

    def __len__(self) -> int:
        return self._size

    def add(self, embedding: np.ndarray) -> None:
        self._size = add_keeping_diverse(
            self._embeddings, self._size, embedding, lambda a, b: a @ b.T
        )

    def similarity(self, embeddings: np.ndarray) -> np.ndarray:
        """Highest cosine similarity of each embedding (N, 256) to the gallery."""
        if self._size == 0:
            raise ValueError("re-id gallery is empty")
        return (embeddings @ self._embeddings[: self._size].T).max(axis=1)

    def confidence(self, embeddings: np.ndarray) -> np.ndarray:
        """Confidence in [-1, 1] that each embedding is the target."""
        cfg = self.config
        sim = self.similarity(embeddings)
        return np.clip((sim - cfg.reid_same_similarity) / cfg.reid_similarity_scale, -1.0, 1.0)
