"""`follow models prepare`: make the INT8 pose model the fast CPU path runs.

The INT8 model's activation ranges come from its calibration frames, so they must look
like what it will see: here both PETS 2009 frames (many small, distant people) and
robot-distance frames (the real person crops of `ccf_crops/` pasted at 192-432 px tall,
as `follow eval pose-near` does). The file's name carries a key of what it is made from
(the FP32 model's pinned hash and INT8_RECIPE), so a change to either makes a new file
instead of silently reusing an old one; its integrity record lists the same.
"""

from __future__ import annotations

import hashlib
import json
import logging
from pathlib import Path

import numpy as np

from follow import models

log = logging.getLogger(__name__)

SOURCE_MODEL = "human-pose-estimation-0001"
# What the INT8 model is calibrated on and at: changing any value makes a new file.
INT8_RECIPE = {
    "pets_frames": 16,  # PETS 2009 S2.L1, between the frames the evaluations use
    "near_frames": 12,  # ccf_crops pasted into 640x480 frames
    "near_person_heights_px": [192, 320, 432],
    "input_height_px": 368,  # the default [pose] input_height_px
    "method": "onnxruntime static QDQ, per-channel INT8 weights, MinMax",
}


def int8_key() -> str:
    """A short digest of what the INT8 model is made from."""
    source_sha = models.get_spec(SOURCE_MODEL).files[0].sha256
    text = json.dumps({"source_sha256": source_sha, "recipe": INT8_RECIPE}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def calibration_frames() -> list[np.ndarray]:
    """The PETS frames and robot-distance frames of INT8_RECIPE (BGR)."""
    from follow.eval.bench_pose import calibration_indices
    from follow.eval.pets import PetsSequence
    from follow.eval.pets_setup import data_dir
    from follow.eval.pose_near import crop_files, frames_with_people

    sequence = PetsSequence(data_dir())
    indices = calibration_indices(sequence.frame_count, INT8_RECIPE["pets_frames"])
    frames = [image for _, image in sequence.frames(indices)]
    crops = crop_files(None)
    heights = INT8_RECIPE["near_person_heights_px"]
    for i in range(INT8_RECIPE["near_frames"]):
        crop = crops[(i * 7) % len(crops)]  # spread over the crops
        frame, _ = frames_with_people([crop], heights[i % len(heights)])[0]
        frames.append(frame)
    return frames


def prepare_int8(force: bool = False) -> Path:
    """The INT8 model for the current recipe, made (with a progress bar) if absent."""
    from follow import model_manifest
    from follow.pose.quantize import default_int8_path, quantize_pose_model

    target = default_int8_path()
    if target.exists() and not force and model_manifest.check(target) == "ok":
        log.info("INT8 pose model already made: %s", target)
        return target
    fp32 = models.resolve(SOURCE_MODEL)
    models.writable_cache_folder(target.parent)  # before the frames are read, not after
    log.info("making the INT8 pose model %s from %s (a few minutes)", target, fp32)
    frames = calibration_frames()
    description = (
        f"PETS 2009 S2.L1 x{INT8_RECIPE['pets_frames']} + ccf_crops at robot scale "
        f"x{INT8_RECIPE['near_frames']}"
    )
    return quantize_pose_model(fp32, frames, INT8_RECIPE["input_height_px"], target,
                               calibration=description, progress=True)  # fmt: skip
