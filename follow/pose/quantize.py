"""INT8 static quantisation of the pose ONNX for onnxruntime, calibrated on real frames.

The result is a QDQ model (per-channel INT8 weights, UINT8 activations) that
onnxruntime's CPU provider runs with integer kernels, and that OpenVINO also runs in
INT8. It is written to the user cache (or a given path), never into the repository.
"""

from __future__ import annotations

import logging
import shutil
import tempfile
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from follow import model_manifest, models
from follow.pose.preprocess import prepare_input

log = logging.getLogger(__name__)


def default_int8_path() -> Path:
    """Where the quantised pose model lives in the user cache: keyed by what it is made
    from (follow/pose/prepare.py), so an older recipe's file is never picked up."""
    from follow.pose.prepare import int8_key

    return models.cache_dir() / "pose" / f"human-pose-estimation-0001-int8-{int8_key()}.onnx"


class _FrameReader:
    """onnxruntime CalibrationDataReader over preprocessed frames."""

    def __init__(self, tensors: list[np.ndarray], input_name: str, progress: bool = False):
        self._items = iter([{input_name: t} for t in tensors])
        self._bar = None
        if progress:
            from tqdm import tqdm

            self._bar = tqdm(total=len(tensors), desc="INT8 calibration", unit="frame")

    def get_next(self):
        item = next(self._items, None)
        if self._bar is not None:
            self._bar.update(item is not None)
            if item is None:
                self._bar.close()
        return item


def quantize_pose_model(
    fp32_path: Path,
    calibration_frames: Iterable[np.ndarray],
    input_height_px: int,
    output_path: Path | None = None,
    calibration: str = "",
    progress: bool = False,
) -> Path:
    """Write an INT8 QDQ copy of `fp32_path`, calibrated on BGR `calibration_frames`
    preprocessed exactly as the detector does at `input_height_px`, with its integrity
    record (`calibration` names the frames)."""
    import onnxruntime as ort
    from onnxruntime.quantization import (
        CalibrationMethod,
        QuantFormat,
        QuantType,
        quantize_static,
    )
    from onnxruntime.quantization.shape_inference import quant_pre_process

    output_path = Path(output_path) if output_path else default_int8_path()
    models.writable_cache_folder(output_path.parent)  # before the calibration, not after
    tensors = [prepare_input(f, input_height_px)[0] for f in calibration_frames]
    if not tensors:
        raise ValueError("INT8 calibration needs at least one frame")
    input_name = (
        ort.InferenceSession(str(fp32_path), providers=["CPUExecutionProvider"])
        .get_inputs()[0]
        .name
    )
    with tempfile.TemporaryDirectory() as tmp:
        prepared = Path(tmp) / "prepared.onnx"
        written = Path(tmp) / "int8.onnx"
        quant_pre_process(str(fp32_path), str(prepared), skip_symbolic_shape=True)
        quantize_static(
            str(prepared),
            str(written),
            _FrameReader(tensors, input_name, progress),
            quant_format=QuantFormat.QDQ,
            per_channel=True,
            activation_type=QuantType.QUInt8,
            weight_type=QuantType.QInt8,
            # Min/max ranges: histogram methods need tens of GB at 768x576 inputs.
            calibrate_method=CalibrationMethod.MinMax,
            extra_options={"CalibTensorRangeSymmetric": False},
        )
        made_from = {"calibration": calibration, "calibration_frames": len(tensors),
                     "input_height_px": input_height_px, "method": "static QDQ, MinMax"}  # fmt: skip
        # the temporary folder may be on another file system, where a move is a copy
        model_manifest.install(output_path, fp32_path, made_from,
                               lambda partial: shutil.move(str(written), str(partial)))  # fmt: skip
    log.info("INT8 pose model written to %s (%d calibration frames)", output_path, len(tensors))
    return output_path
