"""`follow bench pose`: the pose network's runtimes side by side on the same frames.

Runtimes are interleaved frame by frame (in a fresh random order each frame) so that
load from other processes, and any runtime's after-effects, hit them alike; medians and the fast-path/reference ratio come from the same
run. Measured: onnxruntime FP32 on the CPU; the project's fast CPU path (the INT8 model
from tools/quantize_pose.py, on OpenVINO when installed, else on onnxruntime); the
onnxruntime INT8 path on its own; the OpenVINO runtime on the official INT8 IR as the
reference (skipped with a note when openvino is missing); the INT8 paths fed the uint8
frame with the transpose and conversion inside the graph (`*_frame_input`), with the
Python preparation of either input timed beside them; and decoding time, also on
"crowd" frames made of two PETS frames side by side (10+ people).
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from follow import models
from follow.cli_args import non_negative_int, positive_int, refuse_unwritable
from follow.config import PoseConfig
from follow.eval.pets import PetsSequence, evenly_spaced_frames
from follow.eval.pose import data_dir, input_height
from follow.pose.decode import decode
from follow.pose.detector import decode_params
from follow.pose.preprocess import FrameFilter, prepare_frame, prepare_input
from follow.pose.quantize import default_int8_path, quantize_pose_model
from follow.pose.runtime import OpenVinoBackend, OrtBackend, openvino_installed
from follow.pose.stages import initial_stage_file

log = logging.getLogger(__name__)

DEFAULT_FRAMES = 15
CALIBRATION_FRAMES = 16
CALIBRATION_OFFSET = 5  # calibration frames sit between the evenly spaced eval frames


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--frames", type=positive_int, default=DEFAULT_FRAMES, help="PETS frames to time")
    parser.add_argument(
        "--height",
        type=input_height,
        default=PoseConfig().input_height_px,
        help="network input height in px (default: the pose config's)",
    )
    parser.add_argument("--int8-model", type=Path, default=None, help="INT8 ONNX to time (made there first, calibrated on PETS frames, if missing)")
    parser.add_argument("--data-dir", type=Path, default=None, help="PETS 2009 folder")
    parser.add_argument("--threads", type=non_negative_int, default=0, help="CPU threads (0 = default)")


def calibration_indices(frame_count: int, count: int = CALIBRATION_FRAMES) -> list[int]:
    """PETS frames for INT8 calibration: between the evenly spaced frames the
    evaluation and the benchmark use, so that calibration and test frames differ."""
    return sorted(
        {
            min(i + CALIBRATION_OFFSET, frame_count - 1)
            for i in evenly_spaced_frames(frame_count, count)
        }
    )


def make_int8_model(
    sequence: PetsSequence, height: int, path: Path | None = None, count: int = CALIBRATION_FRAMES
) -> Path:
    """Quantise the registry's FP32 pose model, calibrated on `count` PETS frames."""
    frames = [img for _, img in sequence.frames(calibration_indices(sequence.frame_count, count))]
    fp32 = models.resolve("human-pose-estimation-0001")
    return quantize_pose_model(fp32, frames, height, path or default_int8_path(),
                               calibration=f"PETS 2009 S2.L1, {len(frames)} frames")  # fmt: skip


def ensure_int8_model(path: Path | None, sequence: PetsSequence, height: int) -> Path:
    """The INT8 model at `path` (calibrated on PETS frames, not the timed ones, if not
    there yet), else the one `follow models prepare` makes."""
    if path is None:
        from follow.pose.prepare import prepare_int8

        return prepare_int8()  # the model `precision = "auto"` runs
    if path.exists():
        return path
    refuse_unwritable(path, "--int8-model", "the model is made there when missing")
    log.info("no INT8 pose model at %s: calibrating one on PETS frames", path)
    return make_int8_model(sequence, height, path)


def main(args: argparse.Namespace) -> dict:
    sequence = PetsSequence(data_dir(args.data_dir))
    indices = evenly_spaced_frames(sequence.frame_count, args.frames)
    images = [img for _, img in sequence.frames(indices)]
    tensors = [prepare_input(img, args.height)[0] for img in images]
    frames = [prepare_frame(img, args.height)[0] for img in images]
    fp32 = models.resolve("human-pose-estimation-0001")
    int8 = ensure_int8_model(args.int8_model, sequence, args.height)
    notes = []
    runtimes = {
        "ort_fp32": OrtBackend(fp32, ["CPUExecutionProvider"], args.threads),
        "ort_int8": OrtBackend(int8, ["CPUExecutionProvider"], args.threads),
        "ort_int8_frame_input": OrtBackend(int8, ["CPUExecutionProvider"], args.threads, True),
    }
    if openvino_installed():
        runtimes["fast_path"] = OpenVinoBackend(int8, args.threads)
        runtimes["fast_path_frame_input"] = OpenVinoBackend(int8, args.threads, True)
        # What the detector runs by default (network_stages = 1): the same, initial stage only.
        runtimes["fast_path_initial_stage"] = OpenVinoBackend(
            initial_stage_file(int8), args.threads
        )
        runtimes["reference_openvino_int8"] = OpenVinoBackend(
            models.resolve("human-pose-estimation-0001-ir"), args.threads
        )
        fast_name = "openvino runtime on the INT8 ONNX"
    else:
        fast_name = "onnxruntime CPU on the INT8 ONNX"
        notes.append("openvino is not installed: reference skipped, fast path = ort_int8")
    def input_of(name: str, k: int) -> np.ndarray:
        return frames[k] if name.endswith("_frame_input") else tensors[k]

    for name, backend in runtimes.items():  # warm-up and per-shape compilation
        backend.run(input_of(name, 0))
    times: dict[str, list[float]] = {k: [] for k in runtimes}
    names = list(runtimes)
    outputs = []
    rng = np.random.default_rng(0)
    for k in tqdm(range(len(tensors)), desc="frames"):
        for name in rng.permutation(names):  # no runtime always follows the same one
            t0 = time.perf_counter()
            out = runtimes[name].run(input_of(name, k))
            times[name].append((time.perf_counter() - t0) * 1e3)
            if name == "ort_fp32":
                outputs.append(out)
    preparation = _time_preparation(images, args.height)
    if "fast_path" not in runtimes:
        times["fast_path"] = times["ort_int8"]
    params = decode_params(PoseConfig())
    decode_ms, people = _time_decode(outputs, params)
    crowd = [
        np.concatenate([images[i], images[(i + len(images) // 2) % len(images)]], axis=1)
        for i in range(min(len(images), 6))
    ]
    crowd_out = [runtimes["fast_path" if "fast_path" in runtimes else "ort_int8"].run(
        prepare_input(img, args.height)[0]) for img in crowd]  # fmt: skip
    crowd_ms, crowd_people = _time_decode(crowd_out, params)
    med = {k: float(np.median(v)) for k, v in times.items()}
    reference = med.get("reference_openvino_int8")
    result = {
        "input": [int(tensors[0].shape[3]), int(tensors[0].shape[2])],
        "frames": len(tensors),
        "ort_fp32_ms": med["ort_fp32"],
        "ort_int8_ms": med["ort_int8"],
        "ort_int8_frame_input_ms": med["ort_int8_frame_input"],
        "fast_path_frame_input_ms": med.get("fast_path_frame_input"),
        "prepare_input_ms": preparation["prepare_input"],
        "prepare_frame_ms": preparation["prepare_frame"],
        "prepare_input_median1_ms": preparation["prepare_input_median1"],
        "prepare_input_median1_unsharp_ms": preparation["prepare_input_median1_unsharp"],
        "fast_path_ms": med["fast_path"],
        "fast_path": fast_name,
        "fast_path_initial_stage_ms": med.get("fast_path_initial_stage"),
        "reference_openvino_int8_ms": reference,
        "fast_path_over_reference": med["fast_path"] / reference if reference else None,
        "ort_int8_over_reference": med["ort_int8"] / reference if reference else None,
        "decode_ms": float(np.median(decode_ms)),
        "decode_max_people": int(max(people)),
        "decode_crowd_ms": float(np.median(crowd_ms)),
        "decode_crowd_max_ms": float(np.max(crowd_ms)),
        "decode_crowd_people": int(max(crowd_people)),
        "notes": notes,
    }
    if not args.json:
        print(f"pose network at {result['input'][0]}x{result['input'][1]}, "
              f"{len(tensors)} PETS frames, medians (runtimes interleaved)")  # fmt: skip
        for key in ("ort_fp32", "ort_int8", "ort_int8_frame_input", "fast_path",
                    "fast_path_frame_input", "reference_openvino_int8",
                    "fast_path_initial_stage"):  # fmt: skip
            if key in med:
                print(f"  {key:26s} {med[key]:8.1f} ms")
        for key, value in preparation.items():
            print(f"  {key:30s} {value:4.2f} ms (Python, before the network)")
        if reference:
            print(f"  fast path / reference      {result['fast_path_over_reference']:8.2f}"
                  f"   ({fast_name})")  # fmt: skip
        print(f"  decode                     {result['decode_ms']:8.2f} ms "
              f"(up to {result['decode_max_people']} people)")  # fmt: skip
        print(f"  decode, crowd frames       {result['decode_crowd_ms']:8.2f} ms "
              f"(max {result['decode_crowd_max_ms']:.2f} ms, up to "
              f"{result['decode_crowd_people']} people)")  # fmt: skip
        for note in notes:
            print(f"  note: {note}")
    return result


def _time_preparation(images, height_px: int, repeats: int = 5) -> dict[str, float]:
    """Median of the per-frame best time to make each kind of network input, into
    reused buffers as the detector does (the float input also after a 3x3 median
    filter, `[pose] median_filter_radius_px = 1`, and after that and an unsharp mask,
    as the PETS settings have it)."""
    out = {}
    median = FrameFilter(median_radius_px=1)
    pets = FrameFilter(median_radius_px=1, unsharp_amount=0.5)
    kinds = (("prepare_input", prepare_input, None), ("prepare_frame", prepare_frame, None),
             ("prepare_input_median1", prepare_input, median),
             ("prepare_input_median1_unsharp", prepare_input, pets))  # fmt: skip
    for name, prepare, frame_filter in kinds:
        buffers: dict = {}
        per_frame = []
        for image in images:
            runs = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                prepare(image, height_px, buffers, frame_filter)
                runs.append((time.perf_counter() - t0) * 1e3)
            per_frame.append(min(runs))
        out[name] = float(np.median(per_frame))
    return out


def _time_decode(outputs, params, repeats: int = 5) -> tuple[list[float], list[int]]:
    """Per frame, the best of `repeats` decode times (decoding is deterministic, so the
    fastest run is the one least disturbed by other processes), and the people found."""
    times, counts = [], []
    for heatmaps, pafs in outputs:
        per = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            people = decode(heatmaps, pafs, params)
            per.append((time.perf_counter() - t0) * 1e3)
        times.append(float(np.min(per)))
        counts.append(len(people))
    return times, counts
