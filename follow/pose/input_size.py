"""The network input height a camera needs, from the farthest person to be followed.

The detector finds a person reliably once they are about `min_person_input_px` tall in
the network input (85 px with the INT8 model, 74 px with FP32; `follow eval pose-near`,
docs/pose.md). A person `far_person_height_m` tall, `far_person_distance_m` away, is
`f_y * height / distance` px tall in the camera image; the input height is the image
height scaled so that this person reaches the reliable size. A narrow camera then runs a
smaller, faster input; a wide one a larger input, so that its far people are still found.
Without a camera (a bare video, the benchmarks) the configured `input_height_px` is used.
"""

from __future__ import annotations

import dataclasses
import logging
import math

from follow.pose.preprocess import NETWORK_STRIDE_PX

# The range of input sizes the detector was measured at, far and near people alike
# (docs/pose.md, `follow eval pose-near`): the rule stays inside what was measured.
MIN_INPUT_HEIGHT_PX = 256
MAX_INPUT_HEIGHT_PX = 576
# The height in the input from which neck and ankles are found on 95 % of the robot
# camera's crops, per precision (`[pose] min_person_input_px = "auto"`; docs/pose.md).
RELIABLE_PERSON_INPUT_PX = {"int8": 85.0, "fp32": 74.0}

log = logging.getLogger(__name__)


def reliable_person_input_px(config) -> float:
    """`config.min_person_input_px`, with "auto" settled by the precision that runs."""
    if config.min_person_input_px != "auto":
        return float(config.min_person_input_px)
    from follow.pose.detector import resolved_precision

    return RELIABLE_PERSON_INPUT_PX[resolved_precision(config)]


def far_person_height_px(focal_y_px: float, config) -> float:
    """How tall (px, in the camera image) the farthest person to be followed appears."""
    return focal_y_px * config.far_person_height_m / config.far_person_distance_m


def input_height_for_camera(focal_y_px: float, image_height_px: int, config) -> int:
    """The network input height (a multiple of the network's stride) at which a person
    `config.far_person_height_m` tall, `config.far_person_distance_m` away, is at least
    `reliable_person_input_px` tall, within 256-576 px."""
    if not (math.isfinite(focal_y_px) and focal_y_px > 0):
        raise ValueError(f"camera focal length f_y must be positive, got {focal_y_px}")
    if image_height_px <= 0:
        raise ValueError(f"camera image height must be positive, got {image_height_px}")
    scale = reliable_person_input_px(config) / far_person_height_px(focal_y_px, config)
    needed = math.ceil(image_height_px * scale / NETWORK_STRIDE_PX) * NETWORK_STRIDE_PX
    return int(min(max(needed, MIN_INPUT_HEIGHT_PX), MAX_INPUT_HEIGHT_PX))


def far_person_input_px(config, camera) -> float:
    """How tall the farthest person to be followed is in the network input (px)."""
    person_px = far_person_height_px(float(camera.K[1, 1]), config)
    return person_px * config.input_height_px / camera.image_size[1]


def camera_input_height_px(config, camera) -> int:
    """The full input height the detector runs for `camera`: chosen for it with
    `input_height_from_camera`, else the configured one."""
    if not config.input_height_from_camera:
        return config.input_height_px
    return input_height_for_camera(float(camera.K[1, 1]), camera.image_size[1], config)


def pose_config_for_camera(config, camera):
    """`config` (a PoseConfig) with its input height chosen for `camera` when
    `input_height_from_camera` is on (unchanged otherwise); logs the choice, and warns
    when a configured height leaves the far person under the reliable size."""
    config = dataclasses.replace(config, input_height_px=camera_input_height_px(config, camera))
    in_input = far_person_input_px(config, camera)
    reliable_px = reliable_person_input_px(config)
    source = "chosen for the camera" if config.input_height_from_camera else "as configured"
    log.info(
        "pose input %d px (%s): a %g m person %g m away is %.0f px tall in it "
        "(found reliably from %g px)", config.input_height_px, source,
        config.far_person_height_m, config.far_person_distance_m, in_input,
        reliable_px,
    )  # fmt: skip
    if in_input < reliable_px:
        advice = ("a wider input than the rule's 576 px limit, a narrower camera or a nearer "
                  "[pose] far_person_distance_m" if config.input_height_from_camera else
                  "[pose] input_height_from_camera = true sizes the input for the camera")  # fmt: skip
        log.warning(
            "pose input %d px: a person %g m away is only %.0f px tall in it, under the "
            "%g px the detector needs: it may miss them (%s)", config.input_height_px,
            config.far_person_distance_m, in_input, reliable_px, advice,
        )  # fmt: skip
    return config
