"""Pinhole camera with OpenCV distortion, mounted on the robot over a flat floor.

Frames: `base` is x forward, y left, z up, origin on the floor under the robot; the
camera frame is OpenCV's (x right, y down, z forward). The camera's pose in `base` is
given by its height over the floor, its offsets, and yaw/pitch/roll, where positive
pitch tilts the optical axis down towards the floor and positive roll turns the image
clockwise as seen from behind the camera (rotation about the forward axis).

The ground plane is z = 0 in `base`. A pixel on or above the horizon has no ground
point: back-projection returns NaN for it (and `ground_point` returns None) rather
than a point behind the camera.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

# Camera axes expressed in `base` for zero yaw/pitch/roll: x_cam = -y_base,
# y_cam = -z_base, z_cam = +x_base (columns are the camera axes).
_BASE_FROM_CAM_LEVEL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])

_HORIZON_EPS = 1e-9


def undistort_points(pixels: np.ndarray, K: np.ndarray, dist: np.ndarray, criteria) -> np.ndarray:
    """Normalised coordinates of distorted pixels (N, 1, 2), iterated to `criteria`.

    OpenCV 4's Python `undistortPoints` takes no termination criteria (its default 5
    iterations are too few for strong distortion); that overload is `undistortPointsIter`.
    """
    if hasattr(cv2, "undistortPointsIter"):
        return cv2.undistortPointsIter(pixels, K, dist, None, None, criteria)
    return cv2.undistortPoints(pixels, K, dist, criteria=criteria)


class CameraFileError(ValueError):
    """A camera file that cannot be read: the message names the file and the field."""


class PlaceholderPoseError(ValueError):
    """A base would be driven on a camera pose that was never measured."""


def _rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


# Physically possible mounting poses: (lowest, highest) per field. A pitch beyond
# straight down or straight up (|pitch| > pi/2) is no camera orientation of its own
# (the same one is written with |pitch| <= pi/2 and the roll and yaw turned by pi);
# roll and yaw are angles within one turn; a surveillance view (PETS 2009) sits up to
# tens of metres off the robot's origin, no camera 50 m over the floor.
POSE_BOUNDS: dict[str, tuple[float, float]] = {
    "height_m": (1e-3, 50.0),
    "pitch_rad": (-math.pi / 2, math.pi / 2),
    "roll_rad": (-math.pi, math.pi),
    "yaw_rad": (-2 * math.pi, 2 * math.pi),
    "x_m": (-100.0, 100.0),
    "y_m": (-100.0, 100.0),
}


# The keys of a camera file (docs/calibration.md); `calibration` is follow-calib's record
# of how the file was measured (calib/camera_file.py), for people: follow ignores it.
FILE_KEYS = ("image_width", "image_height", "camera_matrix", "distortion", "pose", "calibration")

# The `calibration` note on a pose nobody measured: `follow-calib intrinsics` gives a new
# camera file a level camera 1 m high with it, and `follow-calib ground` replaces it.
PLACEHOLDER_POSE_NOTE = "placeholder: measure it with `follow-calib ground`"


def _unique_keys(pairs: list[tuple]) -> dict:
    """A mapping whose keys are all different: YAML and JSON readers keep the last of two
    equal keys, so a second `pitch_rad` would silently replace the measured one."""
    out = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"duplicate key {key!r}")
        out[key] = value
    return out


def _parse_yaml(text: str):
    """`yaml.safe_load`, refusing a key given twice in one mapping (see `_unique_keys`)."""
    import yaml

    class UniqueKeyLoader(yaml.SafeLoader):
        def construct_mapping(self, node, deep=False):
            seen = set()
            for key_node, _ in node.value:  # before merging `<<` in: those may be overridden
                if key_node.tag == "tag:yaml.org,2002:merge" or not isinstance(
                    key_node, yaml.ScalarNode
                ):
                    continue
                key = self.construct_object(key_node)
                if key in seen:
                    line = key_node.start_mark.line + 1
                    raise ValueError(f"duplicate key {key!r} at line {line}")
                seen.add(key)
            return super().construct_mapping(node, deep)

    # YAML 1.1 reads an exponent without a dot (1e6) and a number without a leading digit
    # (-.5) as text; YAML 1.2 and every other reader as numbers: so does this one (a
    # quoted "1e6" stays text, and is refused).
    UniqueKeyLoader.add_implicit_resolver(
        "tag:yaml.org,2002:float", _YAML12_FLOAT, list("-+0123456789.")
    )
    return yaml.load(text, Loader=UniqueKeyLoader)


_YAML12_FLOAT = re.compile(r"^[-+]?(?:\.[0-9_]+|[0-9][0-9_]*(?:\.[0-9_]*)?)(?:[eE][-+]?[0-9]+)?$")


@dataclass(frozen=True)
class CameraPose:
    """Where the camera sits on the robot (in `base`); a pose outside POSE_BOUNDS, or a
    field that is not a real number, is refused with a ValueError naming the field."""

    height_m: float
    pitch_rad: float = 0.0
    roll_rad: float = 0.0
    yaw_rad: float = 0.0
    x_m: float = 0.0
    y_m: float = 0.0

    def __post_init__(self):
        for name, (lo, hi) in POSE_BOUNDS.items():
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating)):
                raise ValueError(f"camera pose {name} must be a number, got {value!r}")
            if not (math.isfinite(value) and lo <= value <= hi):
                raise ValueError(
                    f"camera pose {name} = {value!r} is not a possible mounting: "
                    f"allowed {lo:.4g} .. {hi:.4g}"
                )
            # Plain floats: YAML and JSON cannot write numpy's (a pose solved with numpy).
            object.__setattr__(self, name, float(value))

    def rotation_base_from_cam(self) -> np.ndarray:
        # Positive pitch = nose down = rotation about +y_base by +pitch.
        body = _rot_z(self.yaw_rad) @ _rot_y(self.pitch_rad) @ _rot_x(self.roll_rad)
        return body @ _BASE_FROM_CAM_LEVEL

    def position_base(self) -> np.ndarray:
        return np.array([self.x_m, self.y_m, self.height_m])


def _radial_factor(d: np.ndarray, r2: np.ndarray) -> np.ndarray:
    """OpenCV's radial distortion factor at squared normalised radius `r2` (d: 8 coeffs)."""
    k1, k2, _, _, k3, k4, k5, k6 = d
    return (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))


def _tangential_shift(d: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple:
    """OpenCV's tangential distortion (dx, dy) at normalised (x, y) (d: 8 coeffs)."""
    p1, p2 = d[2], d[3]
    r2 = x * x + y * y
    return 2 * p1 * x * y + p2 * (r2 + 2 * x * x), p1 * (r2 + 2 * y * y) + 2 * p2 * x * y


# A pixel whose ray projects back farther than this from it has no ray (NaN): undistortion
# iterates, and can settle on a wrong point (tens of pixels off). Half a pixel keeps every
# ray that lands in its own pixel: those next to a lens's fold, where the iteration is
# slow, land up to 0.05 px off.
RAY_ROUND_TRIP_PX = 0.5

FOLD_SEARCH_RADIUS = 10.0  # normalised radius (84 deg off axis) searched for a fold
FOLD_BAND = 0.9  # from this share of a radial fold's radius out to it, its slope is ~0


def _radial_fold_r2(dist: np.ndarray) -> float:
    """The squared normalised radius up to which the distorted radius r * factor(r^2)
    still grows (infinite where it grows over the whole search): past it the polynomial,
    fitted to the image, folds back."""
    if not dist.size:
        return math.inf
    d = np.zeros(8)
    d[: dist.size] = dist
    r = np.linspace(0.0, FOLD_SEARCH_RADIUS, 20001)
    distorted = r * _radial_factor(d, r * r)
    turns = np.nonzero(np.diff(distorted) <= 0)[0]
    return math.inf if not len(turns) else float(r[turns[0]] ** 2)


def _check_distortion_covers_image(K: np.ndarray, dist: np.ndarray, fold_r2: float,
                                   width: int, height: int) -> None:  # fmt: skip
    """Refuse distortion whose polynomial turns back before the nearest edge of the image
    (k1 = -1.8 for -0.18): the pixels past the fold have no ray, and the rays inside it
    land far from where the lens puts them; or that squeezes the image into a field of
    view no following camera has (k1 = 1e9). A calibration folding only near the
    corners, beyond the views it was fitted to, is a lens's and is kept."""
    if not dist.size:
        return
    d = np.zeros(8)
    d[: dist.size] = dist
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    nearest_edge = min((cx + 0.5) / fx, (width - 0.5 - cx) / fx,
                       (cy + 0.5) / fy, (height - 0.5 - cy) / fy)  # fmt: skip
    reach = math.sqrt(min(fold_r2, FOLD_SEARCH_RADIUS**2))
    widest = reach * float(_radial_factor(d, np.array(reach * reach)))
    if math.isfinite(fold_r2) and not widest >= nearest_edge:
        raise ValueError(
            f"camera distortion {dist.tolist()} turns back {widest:.3g} focal lengths off "
            f"the axis, inside the image (its nearest edge is {nearest_edge:.3g} off): "
            "no lens does that (a typing error in distortion?)"
        )
    if widest < nearest_edge:
        return  # the edge lies past the search: a field of view near 170 deg or more
    # The ray through the nearest edge (where the growing distorted radius reaches it):
    # a strong pincushion (k1 = 1e9) squeezes the whole image into a pencil of rays.
    low, high = 0.0, reach
    for _ in range(60):
        middle = 0.5 * (low + high)
        if middle * float(_radial_factor(d, np.array(middle * middle))) < nearest_edge:
            low = middle
        else:
            high = middle
    narrowest_deg = math.degrees(2.0 * math.atan(high))
    if narrowest_deg < MIN_FIELD_OF_VIEW_DEG:
        raise ValueError(
            f"camera distortion {dist.tolist()} squeezes the image into {narrowest_deg:.2g} "
            f"deg (across its narrowest way), under the {MIN_FIELD_OF_VIEW_DEG:g} deg of any "
            "camera that can follow a person (a typing error in distortion?)"
        )


def _only_numbers(value) -> bool:
    """Whether `value` is a number (not a bool, not text) or nested lists of them."""
    if isinstance(value, list | tuple):
        return all(_only_numbers(v) for v in value)
    return isinstance(value, int | float) and not isinstance(value, bool)


# How far a camera's principal point may lie from the image centre, as a share of the
# width and of the height. Lens and sensor are centred to a few per cent: of the cameras
# the project ships or tests, the Tsai-imported PETS 2009 view is farthest off (7.7 % of
# the width, 0.9 % of the height); the demo's lies at the centre, calibrated ones within
# 1 %. A matrix for frames twice (or half) the size puts it 25 % or more off: 20 % tells
# the two apart with room either side. (One for 1.25x the size, 10 % off, cannot be told.)
MAX_PRINCIPAL_POINT_OFFSET = 0.2


def _check_finite_matrix(K: np.ndarray) -> None:
    """Refuse a camera matrix that is not 3x3 or holds NaN or an infinity."""
    if K.shape != (3, 3) or not np.isfinite(K).all():
        raise ValueError(f"camera K must be a finite 3x3 matrix, got {K.tolist()}")


def _check_principal_point(K: np.ndarray, width: int, height: int, centred: bool) -> None:
    """Refuse a principal point outside the image, or, for a whole sensor's image
    (`centred`: a camera file), far from its centre: the matrix was calibrated for frames
    of another size (640x480 in a file for 1280x960), and every ground point would be
    off. An image cropped to a region of interest (a ROS camera_info's `roi`) may have
    it anywhere inside."""
    cx, cy = K[0, 2], K[1, 2]
    off_x = abs(cx - (width - 1) / 2.0) / width
    off_y = abs(cy - (height - 1) / 2.0) / height
    inside = -0.5 <= cx <= width - 0.5 and -0.5 <= cy <= height - 0.5
    if inside and (not centred or max(off_x, off_y) <= MAX_PRINCIPAL_POINT_OFFSET):
        return
    where = (
        f"{100 * off_x:.0f} % of the width and {100 * off_y:.0f} % of the height off the "
        f"centre of the {width}x{height} image (a camera's lies within "
        f"{100 * MAX_PRINCIPAL_POINT_OFFSET:.0f} %)"
        if inside
        else f"outside the {width}x{height} image"
    )
    raise ValueError(
        f"camera principal point ({cx:g}, {cy:g}) lies {where}: a camera_matrix for another "
        "image size?"
    )


# Focal lengths no camera a robot follows people with can have: pixels taller or wider
# than twice their other side (real sensors' are square within a few per cent), or a
# field of view under MIN_FIELD_OF_VIEW_DEG (a person 8 m away would fill 0.7 m of it).
MAX_PIXEL_ASPECT = 2.0
MIN_FIELD_OF_VIEW_DEG = 5.0
# Nor a field of view near 180 deg through the pinhole model (f_x = 1 on a 640 px image:
# 179.6 deg; a fish-eye lens calibrated with OpenCV's usual model reads well under it),
# nor pixels sheared by more than this share of f_x (OpenCV calibrates none; 5000 is a
# typing error in camera_matrix[0][1]).
MAX_FIELD_OF_VIEW_DEG = 160.0
MAX_SKEW_PER_FOCAL = 0.1


def _check_focal_lengths(K: np.ndarray, width: int, height: int) -> None:
    """Refuse focal lengths that are a typing error (500 and 5, or 1e6), not a lens: the
    file loads, and every distance measured through it is wrong."""
    fx, fy = K[0, 0], K[1, 1]
    if not 1.0 / MAX_PIXEL_ASPECT <= fx / fy <= MAX_PIXEL_ASPECT:
        raise ValueError(
            f"camera focal lengths f_x {fx:g} and f_y {fy:g} differ by more than "
            f"{MAX_PIXEL_ASPECT:g}x: no camera's pixels are that far from square (a typing "
            "error in camera_matrix?)"
        )
    if abs(K[0, 1]) > MAX_SKEW_PER_FOCAL * fx:
        raise ValueError(
            f"camera_matrix[0][1] (skew) {K[0, 1]:g} is over {MAX_SKEW_PER_FOCAL:g} of f_x "
            f"{fx:g}: no camera's pixels are that sheared (a typing error? OpenCV writes 0)"
        )
    fov_deg = math.degrees(2.0 * math.atan(max(width / fx, height / fy) / 2.0))
    if fov_deg > MAX_FIELD_OF_VIEW_DEG:
        raise ValueError(
            f"camera focal lengths ({fx:g}, {fy:g}) give a {width}x{height} image a "
            f"{fov_deg:.4g} deg field of view, over the {MAX_FIELD_OF_VIEW_DEG:g} deg the "
            "pinhole model can describe (a typing error in camera_matrix?)"
        )
    if fov_deg < MIN_FIELD_OF_VIEW_DEG:
        raise ValueError(
            f"camera focal lengths ({fx:g}, {fy:g}) give a {width}x{height} image a "
            f"{fov_deg:.2g} deg field of view, under the {MIN_FIELD_OF_VIEW_DEG:g} deg of "
            "any camera that can follow a person (a typing error in camera_matrix?)"
        )


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics, distortion, image size and mounting pose of one camera."""

    K: np.ndarray  # (3, 3)
    dist: np.ndarray  # OpenCV coefficients: 0, 4, 5 or 8 of (k1, k2, p1, p2, k3, k4, k5, k6)
    image_size: tuple[int, int]  # (width, height) in pixels
    pose: CameraPose
    _R: np.ndarray = field(init=False, repr=False, compare=False)
    _t: np.ndarray = field(init=False, repr=False, compare=False)
    _fold_r2: float = field(init=False, repr=False, compare=False)
    _coeffs: np.ndarray = field(init=False, repr=False, compare=False)  # dist, 8 zero-padded
    _fold_scale: float = field(init=False, repr=False, compare=False)  # radial factor there

    def __post_init__(self):
        K = np.asarray(self.K, dtype=np.float64)
        _check_finite_matrix(K)
        if K[2].tolist() != [0.0, 0.0, 1.0]:  # projecting assumes it, never reads it
            raise ValueError(f"camera_matrix last row must be [0, 0, 1], got {K[2].tolist()}")
        if K[1, 0] != 0.0:  # projecting assumes an upper-triangular K, as OpenCV's
            raise ValueError(f"camera_matrix[1][0] must be 0 (no vertical skew), got {K[1, 0]}")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise ValueError(f"camera focal lengths must be positive, got {K[0, 0]}, {K[1, 1]}")
        dist = np.asarray(self.dist, dtype=np.float64).ravel()
        if dist.size not in (0, 4, 5, 8) or not np.isfinite(dist).all():
            raise ValueError(
                f"camera distortion must hold 0, 4, 5 or 8 finite values, got {dist.tolist()}"
            )
        w, h = (int(v) for v in self.image_size)
        if w <= 0 or h <= 0:
            raise ValueError(f"camera image_size must be positive, got {self.image_size}")
        _check_principal_point(K, w, h, centred=False)
        _check_focal_lengths(K, w, h)
        if not (self.pose.height_m > 0 and math.isfinite(self.pose.height_m)):
            raise ValueError(f"camera height_m must be positive, got {self.pose.height_m}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist)
        object.__setattr__(self, "image_size", (w, h))
        object.__setattr__(self, "_R", self.pose.rotation_base_from_cam())
        object.__setattr__(self, "_t", self.pose.position_base())
        object.__setattr__(self, "_fold_r2", _radial_fold_r2(dist))
        object.__setattr__(self, "_coeffs", np.pad(dist, (0, 8 - dist.size)))
        fold_finite = math.isfinite(self._fold_r2)
        fold_scale = float(_radial_factor(self._coeffs, self._fold_r2)) if fold_finite else 1.0
        object.__setattr__(self, "_fold_scale", fold_scale)
        _check_distortion_covers_image(K, dist, self._fold_r2, w, h)
        self._check_distortion_does_not_fold()

    def _check_distortion_does_not_fold(self) -> None:
        """Refuse tangential distortion that folds the image over itself (p1 = 0.2 for
        0.002): where the map's Jacobian determinant turns negative, two rays share a pixel
        and back-projection takes either. Screened over the rays seen out to the image's
        corners; the radial terms alone are screened by `_check_distortion_covers_image`,
        and next to their own fold (kept past the nearest edge) any tangential term tips
        the determinant: that band, FOLD_BAND of the fold's radius, is left out."""
        d = self._coeffs
        if not d[2:4].any():
            return
        w, h = self.image_size
        corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]])
        Kinv = np.linalg.inv(self.K)
        corner_r = np.hypot(*(corners @ Kinv[:2, :2].T + Kinv[:2, 2]).T).max()
        # The corners' undistorted radius through the radial terms (as `_distort_to_pixels`
        # extends them: growing), with room for the tangential shift.
        r = np.linspace(0.0, FOLD_SEARCH_RADIUS, 2001)
        distorted_r = r * _radial_factor(d, np.minimum(r * r, self._fold_r2))
        reach = min(1.5 * np.interp(corner_r, distorted_r, r), FOLD_SEARCH_RADIUS)
        side = np.linspace(-reach, reach, 121)
        x, y = np.meshgrid(side, side)
        uv = self._distort_to_pixels(x, y)
        du_dy, du_dx = np.gradient(uv[..., 0], side, side)
        dv_dy, dv_dx = np.gradient(uv[..., 1], side, side)
        det = du_dx * dv_dy - du_dy * dv_dx
        r2 = x * x + y * y
        near_fold = (r2 >= FOLD_BAND**2 * self._fold_r2) & (r2 <= self._fold_r2)
        folded = self.in_image(uv.reshape(-1, 2)).reshape(x.shape) & ~near_fold & (det <= 0)
        if folded.any():
            u, v = uv[folded][np.argmin(det[folded])]
            raise ValueError(
                f"camera distortion {self.dist.tolist()} folds the image over itself (near "
                f"pixel ({u:.0f}, {v:.0f})): tangential p1 {d[2]:g}, p2 {d[3]:g} are no "
                "lens's (a typing error in distortion?)"
            )

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_fov(
        cls,
        image_size: tuple[int, int],
        horizontal_fov_deg: float,
        pose: CameraPose,
        dist: np.ndarray | None = None,
    ) -> CameraModel:
        """An ideal camera with square pixels and the principal point at the centre."""
        w, h = image_size
        f = (w / 2.0) / math.tan(math.radians(horizontal_fov_deg) / 2.0)
        K = np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
        return cls(K, np.zeros(0) if dist is None else dist, (w, h), pose)

    def scaled(self, width: int, height: int) -> CameraModel:
        """The same camera for an image resized to `width` x `height`.

        Pixel centres sit at integer coordinates (OpenCV), so u' = (u + 0.5) * s - 0.5.
        """
        sx, sy = width / self.image_size[0], height / self.image_size[1]
        K = self.K.copy()
        K[0, 0] *= sx
        K[0, 1] *= sx
        K[1, 1] *= sy
        K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
        K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
        return CameraModel(K, self.dist.copy(), (int(width), int(height)), self.pose)

    def for_image_size(self, width: int, height: int) -> CameraModel:
        """This camera for frames of `width` x `height`: itself, or scaled to a resized
        frame of the same view. Another aspect ratio is another camera mode: ValueError."""
        if (int(width), int(height)) == self.image_size:
            return self
        cw, ch = self.image_size
        if abs(width / height - cw / ch) > 0.01:
            raise ValueError(
                f"camera is for {cw}x{ch} images, not {width}x{height} (another aspect "
                "ratio): calibrate this camera mode"
            )
        return self.scaled(width, height)

    def with_pose(self, pose: CameraPose) -> CameraModel:
        return CameraModel(self.K.copy(), self.dist.copy(), self.image_size, pose)

    # ------------------------------------------------------------------ geometry
    @property
    def rotation_base_from_cam(self) -> np.ndarray:
        return self._R

    @property
    def position_base(self) -> np.ndarray:
        return self._t

    def base_to_camera(self, points_base: np.ndarray) -> np.ndarray:
        """Points (N, 3) in `base` to the camera frame."""
        return (np.asarray(points_base, dtype=np.float64) - self._t) @ self._R

    def project(self, points_base: np.ndarray) -> np.ndarray:
        """Project points (N, 3) or (3,) in `base` to pixels (N, 2) or (2,).

        Points at or behind the camera plane project to NaN.
        """
        pts = np.asarray(points_base, dtype=np.float64)
        single = pts.ndim == 1
        pc = self.base_to_camera(np.atleast_2d(pts))
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xn = np.where(z > _HORIZON_EPS, pc[:, 0] / z, np.nan)
            yn = np.where(z > _HORIZON_EPS, pc[:, 1] / z, np.nan)
        uv = self._distort_to_pixels(xn, yn)
        return uv[0] if single else uv

    def _distort_to_pixels(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        d = self._coeffs
        if self.dist.size:
            r2 = x * x + y * y
            # Beyond the radius where the lens polynomial turns back, it would fold points
            # outside the view into the image: there the radius grows on at its last
            # scale instead (outward, never back).
            radial = _radial_factor(d, np.minimum(r2, self._fold_r2))
            radial = np.where(radial > 0, radial, np.nan)
            shift_x, shift_y = _tangential_shift(d, x, y)
            xd, yd = x * radial + shift_x, y * radial + shift_y
        else:
            xd, yd = x, y
        K = self.K
        return np.stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=-1)

    def _undistort(self, distorted: np.ndarray) -> np.ndarray:
        """Undistorted normalised coordinates (N, 2) of distorted ones (N, 2)."""
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10)
        norm = undistort_points(distorted.reshape(-1, 1, 2), np.eye(3), self.dist, criteria)
        norm = norm.reshape(-1, 2)
        if not math.isfinite(self._fold_r2):
            return norm
        # Past the fold `_distort_to_pixels` scales the radius by the fold's factor, where
        # OpenCV follows the polynomial back: invert that scaling (the tangential shift,
        # small beside it, by fixed-point iteration), and keep it where it lies past. Only
        # points beyond 80 % of the fold's distorted radius are tried (image corners).
        scale = self._fold_scale
        fold_distorted_r2 = self._fold_r2 * scale**2
        near = np.flatnonzero((distorted * distorted).sum(axis=1) > 0.8**2 * fold_distorted_r2)
        past = distorted[near] / scale
        for _ in range(30 if len(near) and self._coeffs[2:4].any() else 0):
            shift = np.column_stack(_tangential_shift(self._coeffs, past[:, 0], past[:, 1]))
            past = (distorted[near] - shift) / scale
        beyond = (past * past).sum(axis=1) > self._fold_r2
        norm[near[beyond]] = past[beyond]
        return norm

    def pixel_rays_base(self, pixels: np.ndarray) -> np.ndarray:
        """Unit viewing rays (N, 3) in `base` through image pixels (N, 2); NaN for a pixel
        no ray projects onto (within RAY_ROUND_TRIP_PX) rather than a ray through
        somewhere else."""
        px = np.atleast_2d(np.asarray(pixels, dtype=np.float64)).reshape(-1, 2)
        Kinv = np.linalg.inv(self.K)
        norm = px @ Kinv[:2, :2].T + Kinv[:2, 2]
        if self.dist.size:
            # K^-1 first, then undistort with the identity: OpenCV's undistortPoints would
            # ignore the skew K[0][1] that `_distort_to_pixels` applies.
            norm = self._undistort(norm)
            off_px = np.hypot(*(self._distort_to_pixels(norm[:, 0], norm[:, 1]) - px).T)
            norm[~(off_px <= RAY_ROUND_TRIP_PX)] = np.nan
        rays_cam = np.column_stack([norm, np.ones(len(norm))])
        rays = rays_cam @ self._R.T
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)

    def back_project_to_plane(self, pixels: np.ndarray, plane_height_m: float) -> np.ndarray:
        """Intersect the rays through pixels (N, 2) or (2,) with the plane z = height.

        Returns (N, 3) or (3,) points in `base`; NaN where the ray never reaches the
        plane in front of the camera (e.g. a ground pixel on or above the horizon).
        """
        pix = np.asarray(pixels, dtype=np.float64)
        single = pix.ndim == 1
        rays = self.pixel_rays_base(pix)
        dz = rays[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):  # a ray along the plane: inf * 0
            t = (plane_height_m - self._t[2]) / dz
            pts = self._t + t[:, None] * rays
        ok = np.isfinite(t) & (t > 0) & (np.abs(dz) > _HORIZON_EPS)
        pts = np.where(ok[:, None], pts, np.nan)
        return pts[0] if single else pts

    def back_project_to_ground(self, pixels: np.ndarray) -> np.ndarray:
        """Ground points (N, 2) or (2,) in `base` seen at pixels; NaN above the horizon."""
        pts = self.back_project_to_plane(pixels, 0.0)
        return pts[..., :2]

    def ground_point(self, pixel: np.ndarray) -> np.ndarray | None:
        """The ground point (2,) under one pixel, or None if it is on or above the horizon."""
        p = self.back_project_to_ground(np.asarray(pixel, dtype=np.float64).reshape(2))
        return None if np.isnan(p).any() else p

    def is_below_horizon(self, pixels: np.ndarray) -> np.ndarray:
        """True for pixels whose viewing ray meets the floor in front of the camera."""
        return self.pixel_rays_base(pixels)[:, 2] < -_HORIZON_EPS

    def horizon_line(self) -> np.ndarray | None:
        """The horizon as a line (a, b, c) with a*u + b*v + c = 0 in undistorted pixels,
        normalised so that a*u + b*v + c > 0 below the horizon; None if the camera looks
        straight down (no horizon)."""
        n_cam = self._R.T @ np.array([0.0, 0.0, 1.0])  # floor normal in the camera frame
        line = np.linalg.inv(self.K).T @ n_cam
        if np.hypot(line[0], line[1]) < 1e-12:
            return None
        # Rays pointing down have n_cam . ray < 0, so flip to make "below" positive.
        return -line / np.hypot(line[0], line[1])

    def in_image(self, pixels: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
        """True for pixels (N, 2) inside the image, `margin_px` away from its border."""
        p = np.atleast_2d(np.asarray(pixels, dtype=np.float64))
        w, h = self.image_size
        return (
            np.isfinite(p).all(axis=1)
            & (p[:, 0] >= -0.5 + margin_px)
            & (p[:, 0] <= w - 0.5 - margin_px)
            & (p[:, 1] >= -0.5 + margin_px)
            & (p[:, 1] <= h - 0.5 - margin_px)
        )

    # ------------------------------------------------------------------ files
    def to_dict(self) -> dict:
        p = self.pose
        return {
            "image_width": self.image_size[0],
            "image_height": self.image_size[1],
            "camera_matrix": self.K.tolist(),
            "distortion": self.dist.tolist(),
            "pose": {
                "height_m": p.height_m,
                "pitch_rad": p.pitch_rad,
                "roll_rad": p.roll_rad,
                "yaw_rad": p.yaw_rad,
                "x_m": p.x_m,
                "y_m": p.y_m,
            },
        }

    @classmethod
    def from_dict(cls, data: dict, source: str = "camera file") -> CameraModel:
        """The camera a file's mapping describes. An unknown key, at the top or in `pose`,
        is refused: a misspelt `pose.rol_rad` would silently leave the roll at 0."""
        if not isinstance(data, dict):
            raise CameraFileError(f"{source}: expected a mapping at the top level")

        def only_known(mapping: dict, known, where: str) -> None:
            unknown = sorted(str(k) for k in mapping if k not in known)
            if unknown:
                names = ", ".join(f"'{where}{k}'" for k in unknown)
                raise CameraFileError(
                    f"{source}: unknown key{'s' if len(unknown) > 1 else ''} {names}; "
                    f"known: {sorted(known)}"
                )

        def need(mapping: dict, key: str, where: str):
            if key not in mapping:
                raise CameraFileError(f"{source}: missing field '{where}{key}'")
            return mapping[key]

        def number(mapping: dict, key: str, where: str = "", default=None) -> float:
            value = mapping.get(key, default) if default is not None else need(mapping, key, where)
            if isinstance(value, bool | str):  # "1.0": quoted, so written as something else
                raise CameraFileError(
                    f"{source}: field '{where}{key}' must be a number, got {value!r}"
                )
            try:
                out = float(value)
            except (TypeError, ValueError, OverflowError):  # Overflow: an int beyond floats
                raise CameraFileError(
                    f"{source}: field '{where}{key}' must be a number, got {value!r}"
                ) from None
            if not math.isfinite(out):
                raise CameraFileError(f"{source}: field '{where}{key}' is not finite")
            return out

        def pixels(key: str) -> int:
            value = need(data, key, "")
            whole = isinstance(value, int) or (isinstance(value, float) and value.is_integer())
            if isinstance(value, bool) or not whole:
                raise CameraFileError(
                    f"{source}: field '{key}' must be a whole number of pixels, got {value!r}"
                )
            if value <= 0:  # before the matrix is checked against a 0-wide image
                raise CameraFileError(
                    f"{source}: field '{key}' must be a positive number of pixels, got {value!r}"
                )
            return int(value)

        only_known(data, FILE_KEYS, "")
        width = pixels("image_width")
        height = pixels("image_height")

        def numbers(key: str, value) -> np.ndarray:
            """Nested lists of numbers, never of quoted ones ("500" is no focal length)."""
            try:
                if not _only_numbers(value):
                    raise ValueError
                return np.asarray(value, dtype=np.float64)
            except (TypeError, ValueError, OverflowError):
                raise CameraFileError(f"{source}: field '{key}' is not numeric") from None

        K = numbers("camera_matrix", need(data, "camera_matrix", ""))
        if K.shape != (3, 3):
            raise CameraFileError(f"{source}: field 'camera_matrix' must be 3x3, got {K.shape}")
        dist = numbers("distortion", data.get("distortion", []))
        if sum(n > 1 for n in dist.shape) > 1:  # a row, a column or flat: never a grid
            raise CameraFileError(
                f"{source}: field 'distortion' must be one list of coefficients, got shape "
                f"{dist.shape}"
            )
        dist = dist.ravel()
        pose_data = need(data, "pose", "")
        if not isinstance(pose_data, dict):
            raise CameraFileError(f"{source}: field 'pose' must be a mapping")
        only_known(pose_data, POSE_BOUNDS, "pose.")
        fields = {"height_m": None, "pitch_rad": None, "roll_rad": 0.0, "yaw_rad": 0.0,
                  "x_m": 0.0, "y_m": 0.0}  # fmt: skip
        values = {k: number(pose_data, k, "pose.", default) for k, default in fields.items()}
        try:
            _check_finite_matrix(K)  # a NaN c_x is not finite, not off the image
            _check_principal_point(K, width, height, centred=True)
            return cls(K, dist, (width, height), CameraPose(**values))
        except ValueError as exc:
            raise CameraFileError(f"{source}: {exc}") from None

    def save(self, path: str | Path) -> None:
        """Write YAML (.yaml/.yml) or JSON (anything else)."""
        path = Path(path)
        data = self.to_dict()
        if path.suffix.lower() in (".yaml", ".yml"):
            import yaml

            path.write_text(yaml.safe_dump(data, sort_keys=False))
        else:
            path.write_text(json.dumps(data, indent=2) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> CameraModel:
        return cls.from_dict(read_camera_data(path), source=f"camera file {path}")


def read_camera_data(path: str | Path):
    """The parsed contents of a camera file, YAML (.yaml/.yml) or JSON; CameraFileError
    naming the file where it cannot be read or parsed."""
    if not str(path).strip():  # Path("") is the current folder: "cannot read ." says nothing
        raise CameraFileError("camera file: no path given (an empty --camera?)")
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")  # a byte order mark is dropped
    except OSError as exc:
        raise CameraFileError(f"camera file {path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise CameraFileError(
            f"camera file {path}: not a text camera file (YAML/JSON; not UTF-8 at byte {exc.start})"
        ) from None
    if path.suffix.lower() in (".yaml", ".yml"):
        try:
            return _parse_yaml(text)
        except Exception as exc:  # yaml's errors, and a key given twice
            raise CameraFileError(f"camera file {path}: not valid YAML ({exc})") from None
    try:
        return json.loads(text, object_pairs_hook=_unique_keys)
    except Exception as exc:  # json's errors, and a key given twice
        raise CameraFileError(
            f"camera file {path}: not valid JSON ({exc}); files not named .yaml/.yml are read "
            "as JSON (name a YAML camera file .yaml or .yml)"
        ) from None


def read_calibration_notes(path: str | Path) -> dict:
    """The `calibration` section of a camera file ({} if none, or if the file cannot be
    read: `CameraModel.load` is what reports a broken file). A section written by hand
    as one line or a list is kept under `note`, so that the next write keeps it."""
    try:
        data = read_camera_data(path)
    except CameraFileError:
        return {}
    notes = data.get("calibration") if isinstance(data, dict) else None
    if isinstance(notes, dict):
        return dict(notes)
    return {} if notes is None or notes == "" else {"note": notes}


def has_placeholder_pose(path: str | Path) -> bool:
    """Whether the camera file's notes say its pose is a placeholder, not measured (see
    `PLACEHOLDER_POSE_NOTE`). A file without notes (written by hand, imported, saved by
    `CameraModel.save`) has a pose someone chose: it is taken as measured."""
    return is_placeholder_note(read_calibration_notes(path).get("pose"))


def is_placeholder_note(note) -> bool:
    """Whether a `calibration` note (of the pose) says it is a placeholder, not measured."""
    return isinstance(note, str) and note.strip().lower().startswith("placeholder")


def check_pose_measured(path: str | Path, drives_base: bool, warn: Callable[[str], None]) -> None:
    """Refuse (`PlaceholderPoseError`) to drive a base with a camera file whose pose is a
    placeholder: every distance to a person would be wrong. Without a base, `warn` says so
    and the run goes on."""
    if not has_placeholder_pose(path):
        return
    if drives_base:
        raise PlaceholderPoseError(
            f"camera file {path}: the camera's pose on the robot is a placeholder, not "
            "measured; run `follow-calib ground` before driving a base (or, having measured "
            "the pose by hand, delete the `pose` note of its `calibration` section)"
        )
    warn(
        f"camera file {path}: the camera's pose is a placeholder (run `follow-calib ground`): "
        "distances to people are not measured"
    )
