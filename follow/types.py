"""Small frozen dataclasses passed between the stages.

They hold numpy arrays and validate their shapes and values on construction, so that a
bad value is caught where it is made rather than three stages later. No other logic.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np

NUM_KEYPOINTS = 18
NECK = 1
R_ANKLE = 10
L_ANKLE = 13
KEYPOINT_NAMES = (
    "nose", "neck", "r_shoulder", "r_elbow", "r_wrist", "l_shoulder", "l_elbow", "l_wrist",
    "r_hip", "r_knee", "r_ankle", "l_hip", "l_knee", "l_ankle", "r_eye", "l_eye", "r_ear", "l_ear",
)  # fmt: skip


class InvalidInput(ValueError):
    """Input data that a stage cannot use: raised with a message naming what is wrong."""


def _as_array(value, shape: tuple[int, ...], name: str, allow_nan: bool = False) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != shape:
        raise InvalidInput(f"{name}: expected shape {shape}, got {arr.shape}")
    bad = ~np.isfinite(arr) if not allow_nan else np.isinf(arr)
    if bad.any():
        raise InvalidInput(f"{name}: contains non-finite values {arr.tolist()}")
    arr = arr.copy()
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True)
class Frame:
    """One camera image (BGR, uint8, HxWx3) and its capture time."""

    image: np.ndarray
    stamp_s: float

    def __post_init__(self):
        img = self.image
        if not isinstance(img, np.ndarray) or img.ndim != 3 or img.shape[2] != 3:
            raise InvalidInput(
                f"frame image: expected an HxWx3 BGR array, got "
                f"{getattr(img, 'shape', type(img).__name__)}"
            )
        if img.dtype != np.uint8:
            raise InvalidInput(f"frame image: expected dtype uint8, got {img.dtype}")
        if img.shape[0] < 8 or img.shape[1] < 8:
            raise InvalidInput(f"frame image: too small ({img.shape[1]}x{img.shape[0]})")
        if not np.isfinite(self.stamp_s):
            raise InvalidInput(f"frame stamp_s is not finite: {self.stamp_s}")


@dataclass(frozen=True)
class Skeleton:
    """One detected person: 18 keypoints in original-image pixels.

    Missing keypoints have NaN coordinates and zero confidence.
    """

    keypoints_px: np.ndarray  # (18, 2), NaN where missing
    confidences: np.ndarray  # (18,), 0 where missing
    score: float = 0.0

    def __post_init__(self):
        object.__setattr__(
            self,
            "keypoints_px",
            _as_array(self.keypoints_px, (NUM_KEYPOINTS, 2), "skeleton keypoints_px", True),
        )
        conf = _as_array(self.confidences, (NUM_KEYPOINTS,), "skeleton confidences", True)
        conf = np.where(np.isnan(conf), 0.0, conf)
        conf.flags.writeable = False
        object.__setattr__(self, "confidences", conf)

    def has(self, index: int, min_confidence: float = 0.0) -> bool:
        """Whether keypoint `index` was found with at least `min_confidence`."""
        return bool(
            np.isfinite(self.keypoints_px[index]).all() and self.confidences[index] > min_confidence
        )


@dataclass(frozen=True)
class Observation:
    """What the tracker uses of one person in one frame, in pixels of the camera model's
    resolution: the neck, and the ankle point when one was seen."""

    neck_px: np.ndarray  # (2,)
    ankle_px: np.ndarray | None = None  # (2,) or None when no ankle was seen
    touches_border: bool = False
    skeleton: Skeleton | None = field(default=None, compare=False, repr=False)

    def __post_init__(self):
        object.__setattr__(self, "neck_px", _as_array(self.neck_px, (2,), "observation neck_px"))
        if self.ankle_px is not None:
            object.__setattr__(
                self, "ankle_px", _as_array(self.ankle_px, (2,), "observation ankle_px")
            )

    @property
    def has_ankle(self) -> bool:
        return self.ankle_px is not None


@dataclass(frozen=True)
class Odometry:
    """The robot's pose in the fixed `odom` frame at a time."""

    x_m: float
    y_m: float
    yaw_rad: float
    stamp_s: float

    def __post_init__(self):
        for name in ("x_m", "y_m", "yaw_rad", "stamp_s"):
            if not np.isfinite(getattr(self, name)):
                raise InvalidInput(f"odometry {name} is not finite: {getattr(self, name)}")

    @classmethod
    def origin(cls, stamp_s: float = 0.0) -> Odometry:
        return cls(0.0, 0.0, 0.0, stamp_s)


@dataclass(frozen=True)
class TrackState:
    """A tracked person: state [x, y, vx, vy, h] in `odom` (h = neck height), with the
    expected neck/ankle pixels (and covariances) in the current frame."""

    track_id: int
    mean: np.ndarray  # (5,)
    cov: np.ndarray  # (5, 5)
    confirmed: bool
    last_seen_s: float
    expected_neck_px: np.ndarray | None = None  # (2,)
    expected_neck_cov: np.ndarray | None = None  # (2, 2)
    expected_ankle_px: np.ndarray | None = None  # (2,)
    expected_ankle_cov: np.ndarray | None = None  # (2, 2)
    observation: Observation | None = field(default=None, compare=False, repr=False)

    def __post_init__(self):
        object.__setattr__(self, "mean", _as_array(self.mean, (5,), f"track {self.track_id} mean"))
        object.__setattr__(self, "cov", _as_array(self.cov, (5, 5), f"track {self.track_id} cov"))

    @property
    def position_m(self) -> np.ndarray:
        return self.mean[:2]

    @property
    def velocity_mps(self) -> np.ndarray:
        return self.mean[2:4]

    @property
    def neck_height_m(self) -> float:
        return float(self.mean[4])


class TargetStatus(str, enum.Enum):
    """The identification state machine's states."""

    INITIAL = "initial"
    INITIAL_TRAINING = "initial_training"
    TRACKING = "tracking"
    REIDENTIFICATION = "reidentification"


@dataclass(frozen=True)
class TargetEstimate:
    """Which track is the target in this frame, and every track's confidence in [-1, 1]."""

    status: TargetStatus
    target_id: int | None
    confidences: dict[int, float] = field(default_factory=dict)
    stamp_s: float = 0.0
    # Whether the target's track was observed in this frame (not only predicted): the
    # controller drives toward an unseen target only for a bounded time.
    target_seen: bool = False


@dataclass(frozen=True)
class VelocityCommand:
    """A body-frame velocity command for the base."""

    forward_mps: float
    yaw_rate_radps: float
    stamp_s: float

    def __post_init__(self):
        for name in ("forward_mps", "yaw_rate_radps", "stamp_s"):
            if not np.isfinite(getattr(self, name)):
                raise InvalidInput(f"velocity command {name} is not finite")

    @classmethod
    def stop(cls, stamp_s: float) -> VelocityCommand:
        return cls(0.0, 0.0, stamp_s)

    @property
    def is_stop(self) -> bool:
        return self.forward_mps == 0.0 and self.yaw_rate_radps == 0.0
