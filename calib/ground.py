"""The camera's pose over the floor from one view of a chessboard lying on it.

The board's plane is the floor: its normal, seen from the camera, gives pitch and roll,
and the camera's distance to the plane is its height. Yaw and the offsets cannot be seen
from a board alone; they are kept from the existing camera file, or derived when the user
says where the board lies in `base`.

Pose convention (follow.camera): R_base_from_cam = Rz(yaw) Ry(pitch) Rx(roll) R0, so the
floor normal (base +z) expressed in the camera frame is
n = (-cos(pitch) sin(roll), -cos(pitch) cos(roll), -sin(pitch)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from calib.chessboard import BoardNotFoundError, Detection, check_pattern_size, detect_chessboard
from follow.camera import CameraPose
from follow.frames import rotation_2d

OUTLIER_ROUNDS = 3
OUTLIER_FACTOR = 4.0
OUTLIER_MIN_PX = 1.0
MIN_INLIER_FRACTION = 0.7
# Roll is read from the floor normal's sideways lean, which shrinks as cos(pitch): looking
# (nearly) straight down there is none, and any roll (traded against yaw) fits the board.
# On rendered views a 2 deg roll came out within 0.2 deg up to 78 deg of pitch, 0.7 deg off
# at 82 and 3 deg off at 85. --board-in-base fixes the camera's whole rotation but still not
# how it splits into yaw and roll, nor which of the board's symmetric yaws is meant (the
# one nearest the file's yaw), so a steeper camera is refused either way.
MAX_PITCH_DEG = 80.0


class GroundPoseError(ValueError):
    """The board was seen but the camera's pose cannot be measured from it."""


@dataclass(frozen=True)
class GroundPoseResult:
    """Camera pose over the floor and where the board lies, from one board view."""

    height_m: float
    pitch_rad: float
    roll_rad: float
    # The board in the camera's level frame: origin on the floor under the camera, x along
    # the optical axis' floor projection, y left, z up (i.e. `base` with yaw = x = y = 0).
    board_origin_level_m: np.ndarray  # (2,) first detected inner corner
    board_centre_level_m: np.ndarray  # (2,) centre of the inner corners
    board_yaw_level_rad: float  # direction of the board's first row (detected order)
    reprojection_rms_px: float  # over the corners used
    outlier_corners: int  # corners left out: the detector misplaced them
    corners_px: np.ndarray  # (N, 2) detected corners
    sharpness_px: float
    pattern_size: tuple[int, int]

    @property
    def board_distance_m(self) -> float:
        return float(np.linalg.norm(self.board_centre_level_m))

    def pose(self, yaw_rad: float = 0.0, x_m: float = 0.0, y_m: float = 0.0) -> CameraPose:
        return CameraPose(self.height_m, self.pitch_rad, self.roll_rad, yaw_rad, x_m, y_m)

    def pose_from_board_in_base(
        self,
        board_centre_base_m: tuple[float, float],
        board_yaw_base_rad: float,
        prior_yaw_rad: float = 0.0,
    ) -> CameraPose:
        """The full pose when the board's centre and row direction in `base` are known.

        A row's direction is only known up to a half turn (the detector may start at either
        end; on a square pattern rows and columns may swap, a quarter turn): of the camera
        yaws this allows, the one nearest `prior_yaw_rad` is taken.
        """
        cols, rows = self.pattern_size
        step = math.pi / 2 if cols == rows else math.pi
        raw = board_yaw_base_rad - self.board_yaw_level_rad
        k = round((prior_yaw_rad - raw) / step)
        dyaw = raw + k * step
        rotated = rotation_2d(dyaw) @ self.board_centre_level_m
        offset = np.asarray(board_centre_base_m, dtype=np.float64) - rotated
        yaw = math.atan2(math.sin(dyaw), math.cos(dyaw))
        return self.pose(yaw, float(offset[0]), float(offset[1]))


def _board_pose(
    object_pts: np.ndarray, corners: np.ndarray, K: np.ndarray, dist: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Board pose (rvec, tvec) and the mask of corners used.

    IPPE gives the planar solution directly and Levenberg-Marquardt polishes it. On
    steeply foreshortened boards the detector sometimes misplaces a corner by several
    pixels; such corners (residual above OUTLIER_FACTOR x the median, and above
    OUTLIER_MIN_PX) are dropped and the pose solved again.
    """
    inliers = np.ones(len(corners), dtype=bool)
    for _ in range(OUTLIER_ROUNDS):
        ok, rvec, tvec = cv2.solvePnP(
            object_pts[inliers], corners[inliers], K, dist, flags=cv2.SOLVEPNP_IPPE
        )
        if not ok:
            raise BoardNotFoundError("the board's corners do not give a pose (degenerate view)")
        rvec, tvec = cv2.solvePnPRefineLM(
            object_pts[inliers], corners[inliers], K, dist, rvec, tvec
        )
        projected = cv2.projectPoints(object_pts, rvec, tvec, K, dist)[0].reshape(-1, 2)
        residuals = np.linalg.norm(projected - corners, axis=1)
        limit = max(OUTLIER_MIN_PX, OUTLIER_FACTOR * float(np.median(residuals[inliers])))
        keep = residuals <= limit
        if keep.sum() < MIN_INLIER_FRACTION * len(corners) or np.array_equal(keep, inliers):
            break
        inliers = keep
    return rvec, tvec, inliers


def pitch_roll_from_up(up_cam: np.ndarray) -> tuple[float, float]:
    """Pitch and roll (rad) of a camera whose floor normal in its own frame is `up_cam`."""
    n = np.asarray(up_cam, dtype=np.float64)
    n = n / np.linalg.norm(n)
    pitch = math.asin(float(np.clip(-n[2], -1.0, 1.0)))
    roll = math.atan2(-n[0], -n[1])
    return pitch, roll


def estimate_ground_pose(
    image_or_gray: np.ndarray,
    K: np.ndarray,
    dist: np.ndarray,
    pattern_size: tuple[int, int],
    square_size_m: float,
    detection: Detection | None = None,
    image_name: str = "the image",
) -> GroundPoseResult:
    """Height, pitch and roll of the camera over the floor the board lies on.

    Works whatever the board's orientation and corner order in the image: the floor
    normal is taken on the camera's side of the board. Raises BoardNotFoundError when no
    board of `pattern_size` inner corners is seen, GroundPoseError when the camera looks
    down more steeply than MAX_PITCH_DEG (its roll cannot be measured). `image_name` says
    in the error which image (or frames) had no board: the user may have given several.
    """
    cols, rows = check_pattern_size(pattern_size)
    if not (math.isfinite(square_size_m) and square_size_m > 0):
        raise ValueError(f"square size must be positive metres, got {square_size_m}")
    K = np.asarray(K, dtype=np.float64)
    dist = np.asarray(dist, dtype=np.float64).ravel()
    if detection is None:
        detection = detect_chessboard(image_or_gray, (cols, rows))
    if detection is None:
        raise BoardNotFoundError(
            f"no {cols}x{rows} chessboard (inner corners) found in {image_name}; check the "
            "pattern size, that the whole board with its white margin is in view, and focus"
        )
    corners = detection.corners_px
    jj, ii = np.mgrid[0:rows, 0:cols]
    object_pts = np.column_stack([ii.ravel(), jj.ravel(), np.zeros(ii.size)]) * square_size_m
    rvec, tvec, inliers = _board_pose(object_pts, corners, K, dist)
    projected = cv2.projectPoints(object_pts, rvec, tvec, K, dist)[0].reshape(-1, 2)
    residuals = np.linalg.norm(projected - corners, axis=1)
    rms = float(np.sqrt(np.mean(residuals[inliers] ** 2)))
    R_cam_from_board = cv2.Rodrigues(rvec)[0]
    t = tvec.ravel()
    up = R_cam_from_board[:, 2]
    height = -float(up @ t)  # camera's signed distance above the board plane
    if height < 0:  # the detected corner order made the board's z point into the floor
        up, height = -up, -height
    pitch, roll = pitch_roll_from_up(up)
    if abs(pitch) > math.radians(MAX_PITCH_DEG):
        raise GroundPoseError(
            f"the camera looks {math.degrees(pitch):.0f} deg down, more than {MAX_PITCH_DEG:.0f}: "
            "looking (nearly) straight down its roll cannot be measured from a board on the "
            f"floor; pitch it to at most {MAX_PITCH_DEG:.0f} deg (follow needs to see people "
            "ahead anyway) or enter the pose in the camera file by hand"
        )
    level = CameraPose(height, pitch, roll).rotation_base_from_cam()
    camera_level = np.array([0.0, 0.0, height])

    def to_level(point_board: np.ndarray) -> np.ndarray:
        return level @ (R_cam_from_board @ point_board + t) + camera_level

    origin = to_level(np.zeros(3))
    centre = to_level(np.array([(cols - 1) / 2.0, (rows - 1) / 2.0, 0.0]) * square_size_m)
    row_dir = level @ R_cam_from_board[:, 0]
    return GroundPoseResult(
        height_m=height,
        pitch_rad=pitch,
        roll_rad=roll,
        board_origin_level_m=origin[:2],
        board_centre_level_m=centre[:2],
        board_yaw_level_rad=math.atan2(row_dir[1], row_dir[0]),
        reprojection_rms_px=rms,
        outlier_corners=int((~inliers).sum()),
        corners_px=corners,
        sharpness_px=detection.sharpness_px,
        pattern_size=(cols, rows),
    )


def average_frames(frames: list[np.ndarray], names: list[str] | None = None) -> np.ndarray:
    """The mean of several grey frames of a still scene (less noise for the corners).
    `names` (one per frame, e.g. the image files) name the frames of another size in the
    error: by their index alone the user cannot tell which file to look at."""
    if not frames:
        raise ValueError("no frames to average")
    if names is None:
        names = [f"frame {index}" for index in range(len(frames))]
    shape = frames[0].shape
    total = np.zeros(shape, dtype=np.float64)
    for name, frame in zip(names, frames, strict=True):
        if frame.shape != shape:
            raise ValueError(
                f"{name} is {frame.shape[1]}x{frame.shape[0]}, {names[0]} is "
                f"{shape[1]}x{shape[0]}: frames to average must have one size"
            )
        total += frame
    return np.clip(np.round(total / len(frames)), 0, 255).astype(np.uint8)
