"""PoseDetector: BGR frame -> multi-person skeletons in original-image pixels."""

from __future__ import annotations

import dataclasses
import logging
import time
from pathlib import Path

import numpy as np

from follow import model_manifest, models
from follow.config import PoseConfig
from follow.pose.decode import DecodedPerson, DecodeParams, decode
from follow.pose.input_size import reliable_person_input_px
from follow.pose.people_sized_input import PeopleSizedInput
from follow.pose.prepare import SOURCE_MODEL
from follow.pose.preprocess import (
    NETWORK_STRIDE_PX,
    FrameFilter,
    Letterbox,
    heatmap_to_network_px,
    prepare_frame,
    prepare_input,
)
from follow.pose.runtime import PoseBackend, backend_runs_on_gpu, create_backend, runs_on_gpu
from follow.pose.size_cache import RecentlyUsed
from follow.pose.stages import STAGE_CHOICES, initial_stage_file
from follow.types import Skeleton

log = logging.getLogger(__name__)

REBUILD_INT8 = "Delete it and make it again with `follow models prepare`."


def decode_params(config: PoseConfig) -> DecodeParams:
    return DecodeParams(
        peak_threshold=config.heatmap_peak_threshold,
        paf_samples=config.paf_samples,
        paf_min_sample_score=config.paf_min_sample_score,
        paf_min_sample_fraction=config.paf_min_sample_fraction,
        min_keypoints_per_person=config.min_keypoints_per_person,
        min_person_mean_score=config.min_person_mean_score,
        duplicate_keypoint_distance=config.duplicate_keypoint_distance,
        duplicate_shared_keypoints=config.duplicate_shared_keypoints,
        duplicate_box_containment=config.duplicate_box_containment,
        top_edge_margin_cells=config.top_edge_margin_cells,
        bottom_edge_margin_cells=config.bottom_edge_margin_cells,
    )


def to_skeleton(person: DecodedPerson, plan: Letterbox) -> Skeleton:
    """A decoded person (heatmap cells) as a Skeleton in original-image pixels, inside
    the frame."""
    return Skeleton(
        plan.clip_to_original(plan.to_original(heatmap_to_network_px(person.keypoints_cells))),
        person.confidences,
        person.score,
    )


def model_file_for(config: PoseConfig, model_path: Path | None = None) -> Path:
    """The network file to run: `model_path`, else the one the config asks for (an
    explicit file, the INT8 model in the user cache, or the registry's hash-checked FP32
    model); cut after its initial stage when `network_stages` is 1."""
    if config.network_stages not in STAGE_CHOICES:
        raise ValueError(
            f"pose network_stages must be one of {STAGE_CHOICES}, got {config.network_stages}"
        )
    if model_path:  # `--model-file`: held to the same settings as `[pose] model_file`
        check_model_file_settings(dataclasses.replace(config, model_file=str(model_path)))
    source = Path(model_path) if model_path else _source_model_file(config)
    if not source.exists():
        raise models.ModelError(f"pose model file {source} does not exist")
    if (model_path or config.model_file) and model_manifest.read_manifest(source) is not None:
        # a file made here (tools/quantize_pose.py -o) and named: checked as the cache's are
        model_manifest.verify_derived(
            source, f"Make it again, or delete {model_manifest.manifest_path(source).name} "
            "beside it if the file was replaced on purpose."
        )  # fmt: skip
    if config.network_stages == 1:
        return initial_stage_file(source)
    return source


def resolved_precision(config: PoseConfig) -> str:
    """What the pose network runs in, "int8" or "fp32", once `precision = "auto"` is
    settled for this machine: INT8 only on a CPU with 8-bit dot products (VNNI; where
    the flags cannot be read it is assumed), once `follow models prepare` has made it,
    for the registry's source model. Elsewhere INT8 is no faster than FP32 and finds far
    people less well (docs/pose.md). A named `model_file` is what its name says."""
    if config.model_file:
        return "int8" if "int8" in Path(config.model_file).name.lower() else "fp32"
    if config.precision not in CHOSEN_HERE:
        return config.precision
    return "fp32" if auto_fp32_reason(config) else "int8"


def check_model_file_settings(config: PoseConfig) -> None:
    """A `model_file` names the network to run: a `model` or a fixed `precision` that says
    otherwise would be ignored in silence (an FP32 file run where INT8 was asked for)."""
    if config.model != SOURCE_MODEL:
        raise models.ModelError(
            f"[pose] model_file {config.model_file} and model '{config.model}' both name the "
            "network to run: give one"
        )
    named = resolved_precision(config)  # by the file's name
    if config.precision in ("int8", "fp32") and config.precision != named:
        raise models.ModelError(
            f"[pose] precision '{config.precision}', but model_file {config.model_file} is "
            f"{'an INT8' if named == 'int8' else 'not an INT8'} model by its name (INT8 "
            "files have 'int8' in it): leave precision at 'auto' with a model_file"
        )


# The precisions settled on the machine that runs: "auto" by its CPU and cache,
# "int8_if_made" by its cache alone (settings chosen with the INT8 model, on any CPU).
CHOSEN_HERE = ("auto", "int8_if_made")


def auto_fp32_reason(config: PoseConfig) -> str | None:
    """Why `precision = "auto"` (or "int8_if_made") runs FP32 here, or None where it
    runs INT8."""
    from follow.pose.cpu_features import cpu_flags, has_int8_dot_product
    from follow.pose.quantize import default_int8_path

    if config.model != SOURCE_MODEL:
        return f"the INT8 model is made from {SOURCE_MODEL}, not {config.model}"
    if runs_on_gpu(config.provider):
        return "on a GPU (the INT8 model is for CPUs)"
    if config.precision == "auto" and has_int8_dot_product(cpu_flags()) is False:
        return ("this CPU has no 8-bit dot-product instructions (VNNI): INT8 would run no "
                "faster and find far people less well")  # fmt: skip
    if not default_int8_path().exists():
        return ("no INT8 model in the cache (`follow models prepare` makes it once; about 2x "
                "faster on this CPU)")  # fmt: skip
    return None


def _source_model_file(config: PoseConfig) -> Path:
    if config.model_file:
        check_model_file_settings(config)
        return Path(config.model_file)
    from follow.pose.quantize import default_int8_path

    models.get_spec(config.model)  # an unknown [pose] model is refused by name
    if config.precision == "int8" and config.model != SOURCE_MODEL:
        raise models.ModelError(
            f"pose precision 'int8': the INT8 model is made from {SOURCE_MODEL}, not "
            f"[pose] model '{config.model}'; use precision 'fp32' or 'auto' with it"
        )
    if config.precision in CHOSEN_HERE:
        reason = auto_fp32_reason(config)
        if reason is None:
            model_manifest.verify_derived(default_int8_path(), REBUILD_INT8)
            return default_int8_path()
        log.info("pose: precision '%s': FP32, %s", config.precision, reason)
        config = dataclasses.replace(config, precision="fp32")
    if config.precision == "int8":
        path = default_int8_path()
        if not path.exists():
            raise models.ModelError(
                f"pose precision 'int8': {path} does not exist; make it with "
                "`follow models prepare` (calibrates on PETS 2009 and robot-distance frames)"
            )
        model_manifest.verify_derived(path, REBUILD_INT8)
        return path
    if config.precision != "fp32":
        raise ValueError(f"pose precision '{config.precision}' unknown; choose auto, fp32, "
                         "int8 or int8_if_made")  # fmt: skip
    return models.resolve(config.model)


def _advise_on_int8_without_dot_product(model_path: Path, backend_name: str) -> None:
    """A CPU without 8-bit dot products runs the INT8 model no faster than FP32, and the
    INT8 model finds far people less well (docs/pose.md): say so, with the setting."""
    from follow.pose.cpu_features import cpu_flags, has_int8_dot_product

    int8 = "int8" in Path(model_path).name.lower()
    if int8 and "CPU" in backend_name and has_int8_dot_product(cpu_flags()) is False:
        log.warning("pose: this CPU has no 8-bit dot-product instructions (VNNI), so the INT8 "
                    "model runs no faster than FP32 and finds far people less well: "
                    '[pose] precision = "fp32" (or "auto", which runs it on such a CPU; docs/pose.md)')  # fmt: skip


def network_and_backend(config: PoseConfig, model_path: Path | None = None
                        ) -> tuple[Path, PoseBackend]:  # fmt: skip
    """The network file (`model_file_for`) and the back-end that runs it. Where `auto`
    chose a GPU that then did not start (runtime.create_backend ran the CPU's runtime),
    the file is chosen again for the CPU, as on a machine without a GPU: INT8 where made,
    not the GPU's FP32."""
    on_gpu = runs_on_gpu(config.provider)
    path = model_file_for(config, model_path)
    backend = create_backend(config.provider, path, config.cpu_threads)
    if on_gpu and not runs_on_gpu(config.provider):
        cpu_path = model_file_for(config, model_path)
        if cpu_path != path:
            path, backend = cpu_path, create_backend(config.provider, cpu_path, config.cpu_threads)
    return path, backend


class PoseDetector:
    """Lightweight OpenPose on onnxruntime (or OpenVINO), with our own decoding.

    `last_timing_ms` holds the split of the latest `detect` call: `preprocess`,
    `inference`, `decode` and `total` milliseconds; `last_input_height_px` the input
    height it ran at (smaller than the configured one where every person in view is
    large: `input_height_from_people`, follow/pose/people_sized_input.py).
    """

    # PoseConfig is frozen, so one shared default instance is safe.
    def __init__(
        self,
        config: PoseConfig = PoseConfig(),  # noqa: B008
        model_path: Path | None = None,
        frame_size: tuple[int, int] = (640, 480),
    ):
        """`frame_size` (width, height) is the size of the frames to come, for warm-up."""
        self.config = config
        if config.input_height_px <= 0 or config.input_height_px % NETWORK_STRIDE_PX:
            raise ValueError(
                f"pose input_height_px must be a positive multiple of {NETWORK_STRIDE_PX}, "
                f"got {config.input_height_px}"
            )
        self.model_path, self.backend = network_and_backend(config, model_path)
        self.params = decode_params(config)
        self.last_timing_ms: dict[str, float] = {}
        log.info("pose: running %s (sha256 %s) on %s", self.model_path,
                 models.sha256_of(self.model_path)[:16], self.backend.name)  # fmt: skip
        if config.precision != "int8_if_made":  # chosen for settings made with INT8
            _advise_on_int8_without_dot_product(self.model_path, self.backend.name)
        self._input_buffers: RecentlyUsed = RecentlyUsed()  # per frame size and height
        self._frame_filter = FrameFilter.from_config(self.config)
        self.reset_input_sizing()
        if config.input_height_from_people and self.input_sizing is None:
            log.info("pose: one input height (%d px) on the GPU: input_height_from_people "
                     "is for CPUs", config.input_height_px)  # fmt: skip
        if self.input_sizing is not None:
            log.info("pose: input height from the people in view: %s px, the full %d px "
                     "every %d frames", "/".join(map(str, self.input_sizing.heights_px)),
                     config.input_height_px, config.full_input_every_frames)  # fmt: skip
        self.last_input_height_px = config.input_height_px
        self.warm_up(frame_size)

    def reset_input_sizing(self) -> None:
        """Forget the people of earlier frames (before another video): the next frame
        runs at the full input height. On a GPU the input keeps one height: there a new
        input shape costs a convolution-algorithm search (cuDNN) or an engine build
        (TensorRT), and the smaller input saves little (`people_sized_input_here`)."""
        config = self.config
        self.input_sizing = (
            PeopleSizedInput(config.input_height_px, reliable_person_input_px(config),
                             config.full_input_every_frames)
            if self.people_sized_input_here() else None
        )  # fmt: skip

    def people_sized_input_here(self) -> bool:
        """`input_height_from_people`, unless the network runs on a GPU: measured on an
        H200 (robot scene, 5 people), switching between the input heights held single
        frames 1.0-1.9 s even after each height had been warmed up (cuDNN searched the
        convolution algorithms again), which dropped the runner from the camera's 30 fps
        to 16 fps and stopped the base on the stall watchdog; at one height inference was
        3.3-3.5 ms a frame and the runner kept the camera's rate."""
        return self.config.input_height_from_people and not backend_runs_on_gpu(self.backend.name)

    @property
    def backend_name(self) -> str:
        return self.backend.name

    def warm_up(self, frame_size: tuple[int, int] = (640, 480)) -> None:
        """Run the network `warmup_runs` times on a grey frame, at every input height it
        may run at, so that one-off costs (allocation, kernel selection, compilation) do
        not hit a real frame."""
        grey = np.full((frame_size[1], frame_size[0], 3), 128, np.uint8)
        heights = self.input_sizing.heights_px if self.input_sizing else [None]
        for height in heights:
            for _ in range(self.config.warmup_runs):
                self.infer(grey, height)

    def infer(self, image_bgr: np.ndarray, input_height_px: int | None = None
              ) -> tuple[np.ndarray, np.ndarray, Letterbox]:  # fmt: skip
        """(heatmaps, pafs, letterbox plan) of one frame, at `input_height_px` (default:
        the configured height); raises InvalidInput on a bad frame."""
        t0 = time.perf_counter()
        prepare = prepare_frame if self.backend.frame_input else prepare_input
        height = input_height_px or self.config.input_height_px
        tensor, plan = prepare(image_bgr, height, self._input_buffers, self._frame_filter)
        t1 = time.perf_counter()
        heatmaps, pafs = self.backend.run(tensor)
        t2 = time.perf_counter()
        self.last_timing_ms = {"preprocess": (t1 - t0) * 1e3, "inference": (t2 - t1) * 1e3}
        return heatmaps, pafs, plan

    def decode(self, heatmaps: np.ndarray, pafs: np.ndarray, plan: Letterbox) -> list[Skeleton]:
        """Skeletons from network outputs, in the original frame's pixels."""
        t0 = time.perf_counter()
        people = decode(heatmaps, pafs, self.params)
        skeletons = [to_skeleton(p, plan) for p in people]
        self.last_timing_ms["decode"] = (time.perf_counter() - t0) * 1e3
        return skeletons

    def detect(self, image_bgr: np.ndarray) -> list[Skeleton]:
        """All people in a BGR uint8 frame (HxWx3); keypoints in the frame's pixels."""
        t0 = time.perf_counter()
        height = None
        if self.input_sizing is not None and isinstance(image_bgr, np.ndarray) and image_bgr.ndim:
            height = self.input_sizing.next_height_px(image_bgr.shape[0])
        heatmaps, pafs, plan = self.infer(image_bgr, height)
        skeletons = self.decode(heatmaps, pafs, plan)
        self.last_input_height_px = plan.input_size[1]
        if self.input_sizing is not None:
            self.input_sizing.observe(skeletons, plan.input_size[1], plan.original_size[1])
        self.last_timing_ms["total"] = (time.perf_counter() - t0) * 1e3
        return skeletons
