"""Tsai camera calibrations (as published with PETS 2009) and their conversion.

Tsai's model (world units mm): camera = R * world + T with R = Rz(rz) Ry(ry) Rx(rx);
the ideal sensor point is Xu = f xc / zc, Yu = f yc / zc [mm]; the distorted point
satisfies Xu = Xd (1 + kappa1 (Xd^2 + Yd^2)) (same for Y); pixels are
u = Xd sx / dpx + cx, v = Yd / dpy + cy.

`TsaiCamera` evaluates that model exactly (both directions) so that other models can
be checked against it; `to_camera_model` turns it into the pinhole + OpenCV distortion
`CameraModel` that `follow` reads, whose `base` frame is then the calibration's world
frame in metres (z up, ground z = 0).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from follow.camera import CameraModel, CameraPose

MM_PER_M = 1000.0

# The XML layout: element -> attributes that must be present (all numeric).
_REQUIRED = {
    "Geometry": ("width", "height", "dpx", "dpy"),
    "Intrinsic": ("focal", "kappa1", "cx", "cy", "sx"),
    "Extrinsic": ("tx", "ty", "tz", "rx", "ry", "rz"),
}

# The OpenCV camera looks along +z with x right and y down: the same as Tsai's camera frame.
_NEWTON_ITERATIONS = 30
_FIT_GRID_STEP_PX = 8.0
_CHECK_DEPTH_M = 10.0
# An image side beyond any camera's: the conversion samples the whole image, so a
# typing error (1e6) would ask for a grid of a trillion points.
MAX_IMAGE_SIDE_PX = 16384
# The most pixels the conversion is fitted or checked at: each costs about 200 bytes and
# 2 us, so this bounds it to about 1 GB and 10 s. The default 8 px step (checked at 4 px)
# stays under it for images up to 8000 px a side; a step of a hundredth of a pixel asked
# numpy for terabytes.
MAX_GRID_POINTS = 5_000_000
# The conversion is checked on a grid this many times finer than it is fitted on: between
# the pixels it was fitted at too.
CHECK_GRID_DIVISOR = 2.0
# A camera centre lower than this over the ground z = 0 is a world in other units than mm
# (in metres a camera sits 1000 times too low: PETS's 7 m mast at 7 mm) or with z down.
MIN_CAMERA_HEIGHT_M = 0.05


class TsaiFileError(ValueError):
    """A Tsai calibration file that cannot be used: the message names the file and field."""


def _rotation_zyx(rx: float, ry: float, rz: float) -> np.ndarray:
    cx, sx = math.cos(rx), math.sin(rx)
    cy, sy = math.cos(ry), math.sin(ry)
    cz, sz = math.cos(rz), math.sin(rz)
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    Ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    Rz = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    return Rz @ Ry @ Rx


def _grid_axis_count(side_px: int, step_px: float) -> int:
    """Grid positions along one side: every `step_px` from 0, and the last pixel."""
    return math.ceil((side_px - 1) / step_px) + 1 if side_px > 1 else 1


@dataclass(frozen=True)
class TsaiCamera:
    """One Tsai-calibrated camera; lengths in mm as in the file, angles in radians."""

    image_size: tuple[int, int]  # (width, height) px
    focal_mm: float
    kappa1_per_mm2: float
    cx_px: float
    cy_px: float
    sx: float
    dpx_mm: float
    dpy_mm: float
    translation_mm: tuple[float, float, float]
    rotation_rad: tuple[float, float, float]  # (rx, ry, rz)

    def __post_init__(self):
        values = {
            "focal": self.focal_mm, "dpx": self.dpx_mm, "dpy": self.dpy_mm, "sx": self.sx,
        }  # fmt: skip
        for name, value in values.items():
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"Tsai parameter '{name}' must be positive, got {value}")
        if min(self.image_size) <= 0:
            raise ValueError(f"Tsai image size must be positive, got {self.image_size}")

    # ------------------------------------------------------------------ reading
    @classmethod
    def from_xml(cls, path: str | Path) -> TsaiCamera:
        """Read a PETS-style calibration XML (`Camera` with Geometry/Intrinsic/Extrinsic)."""
        path = Path(path)
        try:
            root = ET.parse(path).getroot()
        except OSError as exc:
            raise TsaiFileError(f"Tsai file {path}: cannot read ({exc.strerror})") from None
        except ET.ParseError as exc:
            raise TsaiFileError(f"Tsai file {path}: not valid XML ({exc})") from None
        values: dict[str, dict[str, float]] = {}
        for tag, attributes in _REQUIRED.items():
            element = root if root.tag == tag else root.find(f".//{tag}")
            if element is None:
                raise TsaiFileError(f"Tsai file {path}: missing element <{tag}>")
            values[tag] = {}
            for attribute in attributes:
                text = element.get(attribute)
                if text is None:
                    raise TsaiFileError(
                        f"Tsai file {path}: element <{tag}> lacks attribute '{attribute}'"
                    )
                try:
                    number = float(text)
                except ValueError:
                    raise TsaiFileError(
                        f"Tsai file {path}: <{tag}> attribute '{attribute}' is not a number: "
                        f"{text!r}"
                    ) from None
                if not math.isfinite(number):
                    raise TsaiFileError(
                        f"Tsai file {path}: <{tag}> attribute '{attribute}' is not finite"
                    )
                values[tag][attribute] = number
        g, i, e = values["Geometry"], values["Intrinsic"], values["Extrinsic"]
        for key in ("width", "height"):
            if not (g[key].is_integer() and 0 < g[key] <= MAX_IMAGE_SIDE_PX):
                raise TsaiFileError(
                    f"Tsai file {path}: <Geometry> attribute '{key}' must be a whole number "
                    f"of pixels, 1 to {MAX_IMAGE_SIDE_PX}, got {g[key]:g}"
                )
        try:
            camera = cls(
                image_size=(int(g["width"]), int(g["height"])),
                focal_mm=i["focal"],
                kappa1_per_mm2=i["kappa1"],
                cx_px=i["cx"],
                cy_px=i["cy"],
                sx=i["sx"],
                dpx_mm=g["dpx"],
                dpy_mm=g["dpy"],
                translation_mm=(e["tx"], e["ty"], e["tz"]),
                rotation_rad=(e["rx"], e["ry"], e["rz"]),
            )
        except ValueError as exc:
            raise TsaiFileError(f"Tsai file {path}: {exc}") from None
        height_m = float(camera.position_world_m[2])
        if not height_m >= MIN_CAMERA_HEIGHT_M:
            raise TsaiFileError(
                f"Tsai file {path}: the camera centre is at z = {height_m:.4g} m, not "
                f"{MIN_CAMERA_HEIGHT_M:g} m or more over the ground z = 0: the world units must "
                "be mm (in metres the camera sits 1000 times too low) and z must point up"
            )
        return camera

    # ------------------------------------------------------------------ geometry
    @property
    def rotation_cam_from_world(self) -> np.ndarray:
        return _rotation_zyx(*self.rotation_rad)

    @property
    def position_world_m(self) -> np.ndarray:
        """The camera centre in the world frame, metres."""
        R = self.rotation_cam_from_world
        return -R.T @ np.asarray(self.translation_mm) / MM_PER_M

    def _sensor_from_undistorted(self, xu: np.ndarray, yu: np.ndarray):
        """Distorted sensor point (Xd, Yd) for ideal (Xu, Yu), mm: solve r_u = r_d (1 + k r_d^2)."""
        ru = np.hypot(xu, yu)
        k = self.kappa1_per_mm2
        rd = ru.copy()
        for _ in range(_NEWTON_ITERATIONS):
            rd = rd - (rd + k * rd**3 - ru) / (1.0 + 3.0 * k * rd**2)
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(ru > 0, rd / ru, 1.0)
        # No real distorted radius (strong barrel distortion past its fold): no pixel.
        bad = ~np.isfinite(rd) | (np.abs(rd + k * rd**3 - ru) > 1e-9 * (1.0 + ru))
        scale = np.where(bad, np.nan, scale)
        return xu * scale, yu * scale

    def project(self, points_world_m: np.ndarray) -> np.ndarray:
        """World points (N, 3) or (3,) in metres to pixels (N, 2) or (2,); NaN behind."""
        pts = np.asarray(points_world_m, dtype=np.float64)
        single = pts.ndim == 1
        pw = np.atleast_2d(pts) * MM_PER_M
        pc = pw @ self.rotation_cam_from_world.T + np.asarray(self.translation_mm)
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xu = np.where(z > 0, self.focal_mm * pc[:, 0] / z, np.nan)
            yu = np.where(z > 0, self.focal_mm * pc[:, 1] / z, np.nan)
        xd, yd = self._sensor_from_undistorted(xu, yu)
        uv = np.column_stack(
            [xd * self.sx / self.dpx_mm + self.cx_px, yd / self.dpy_mm + self.cy_px]
        )
        return uv[0] if single else uv

    def normalized_rays(self, pixels: np.ndarray) -> np.ndarray:
        """Undistorted normalised image coordinates (N, 2) (x/z, y/z in the camera frame)."""
        px = np.atleast_2d(np.asarray(pixels, dtype=np.float64))
        xd = (px[:, 0] - self.cx_px) * self.dpx_mm / self.sx
        yd = (px[:, 1] - self.cy_px) * self.dpy_mm
        factor = 1.0 + self.kappa1_per_mm2 * (xd * xd + yd * yd)
        return np.column_stack([xd * factor, yd * factor]) / self.focal_mm

    def pixel_rays_world(self, pixels: np.ndarray) -> np.ndarray:
        """Unit viewing rays (N, 3) in the world frame through pixels (N, 2)."""
        norm = self.normalized_rays(pixels)
        rays_cam = np.column_stack([norm, np.ones(len(norm))])
        rays = rays_cam @ self.rotation_cam_from_world  # R^T applied to each row
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)

    def back_project_to_plane(self, pixels: np.ndarray, plane_height_m: float) -> np.ndarray:
        """World points (N, 3) or (3,) in metres where pixel rays meet z = height; NaN if never."""
        pix = np.asarray(pixels, dtype=np.float64)
        single = pix.ndim == 1
        rays = self.pixel_rays_world(pix)
        centre = self.position_world_m
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (plane_height_m - centre[2]) / rays[:, 2]
        ok = np.isfinite(t) & (t > 0)
        pts = np.where(ok[:, None], centre + t[:, None] * rays, np.nan)
        return pts[0] if single else pts

    def back_project_to_ground(self, pixels: np.ndarray) -> np.ndarray:
        """Ground points (N, 2) or (2,) (world x, y in metres, z = 0) seen at pixels.

        Same shape convention as `CameraModel.back_project_to_ground`; NaN above the horizon.
        """
        return self.back_project_to_plane(pixels, 0.0)[..., :2]

    # ------------------------------------------------------------------ conversion
    def camera_matrix(self) -> np.ndarray:
        return np.array(
            [
                [self.focal_mm * self.sx / self.dpx_mm, 0.0, self.cx_px],
                [0.0, self.focal_mm / self.dpy_mm, self.cy_px],
                [0.0, 0.0, 1.0],
            ]
        )

    def pose(self) -> CameraPose:
        """The camera pose in the world frame, in `follow`'s yaw/pitch/roll convention."""
        level = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
        body = self.rotation_cam_from_world.T @ level.T  # Rz(yaw) Ry(pitch) Rx(roll)
        pitch = math.asin(float(np.clip(-body[2, 0], -1.0, 1.0)))
        roll = math.atan2(body[2, 1], body[2, 2])
        yaw = math.atan2(body[1, 0], body[0, 0])
        c = self.position_world_m
        return CameraPose(
            height_m=float(c[2]), pitch_rad=pitch, roll_rad=roll, yaw_rad=yaw,
            x_m=float(c[0]), y_m=float(c[1]),
        )  # fmt: skip

    def grid_point_count(self, step_px: float) -> int:
        """How many pixels `image_grid(step_px)` holds, counted before any is made."""
        w, h = self.image_size
        return _grid_axis_count(w, step_px) * _grid_axis_count(h, step_px)

    def image_grid(self, step_px: float = _FIT_GRID_STEP_PX) -> np.ndarray:
        """Pixels (N, 2) covering the whole image, corners included. A step that is not
        positive is refused: it would leave one pixel to fit and to check the model at; so
        is one that makes more than MAX_GRID_POINTS (more memory than a machine has)."""
        if not (math.isfinite(step_px) and step_px > 0):
            raise ValueError(f"grid step must be a positive number of pixels, got {step_px}")
        w, h = self.image_size
        count = self.grid_point_count(step_px)
        if count > MAX_GRID_POINTS:
            raise ValueError(
                f"a grid step of {step_px:g} px makes {count:.3g} pixels of the {w}x{h} image "
                f"to fit or check at, more than {MAX_GRID_POINTS:.3g}: give a larger step"
            )
        us = np.unique(np.append(np.arange(0.0, w - 1, step_px), w - 1.0))
        vs = np.unique(np.append(np.arange(0.0, h - 1, step_px), h - 1.0))
        uu, vv = np.meshgrid(us, vs)
        return np.column_stack([uu.ravel(), vv.ravel()])

    def fit_opencv_distortion(self, step_px: float = _FIT_GRID_STEP_PX) -> np.ndarray:
        """OpenCV (k1, k2, p1, p2, k3) reproducing Tsai's radial distortion over the image.

        Tsai's model maps distorted to undistorted; OpenCV's maps undistorted to distorted,
        so the inverse is fitted by least squares on the radial ratio r_d / r_u (linear in
        k1, k2, k3) at pixels spanning the image.
        """
        grid = self.image_grid(step_px)
        K = self.camera_matrix()
        und = self.normalized_rays(grid)
        dist_norm = np.column_stack(
            [(grid[:, 0] - K[0, 2]) / K[0, 0], (grid[:, 1] - K[1, 2]) / K[1, 1]]
        )
        r2 = np.sum(und * und, axis=1)
        keep = r2 > 1e-12
        ratio = np.sqrt(np.sum(dist_norm[keep] ** 2, axis=1) / r2[keep])
        r2 = r2[keep]
        A = np.column_stack([r2, r2**2, r2**3])
        k1, k2, k3 = np.linalg.lstsq(A, ratio - 1.0, rcond=None)[0]
        return np.array([k1, k2, 0.0, 0.0, k3])

    def to_camera_model(self, step_px: float = _FIT_GRID_STEP_PX) -> tuple[CameraModel, float]:
        """The equivalent `CameraModel` and the largest discrepancy between the two, in px.

        The discrepancy is measured at pixels spanning the whole image: each is carried by
        Tsai's model to a world point (on its ray, 10 m away) and reprojected through the
        converted model, so it covers intrinsics, distortion and pose at once.
        """
        model = CameraModel(
            self.camera_matrix(), self.fit_opencv_distortion(step_px), self.image_size,
            self.pose(),
        )  # fmt: skip
        return model, self.max_discrepancy_px(model, step_px / CHECK_GRID_DIVISOR)

    def max_discrepancy_px(self, model: CameraModel, step_px: float = _FIT_GRID_STEP_PX) -> float:
        grid = self.image_grid(step_px)
        points = self.position_world_m + _CHECK_DEPTH_M * self.pixel_rays_world(grid)
        reprojected = model.project(points)
        return float(np.max(np.linalg.norm(reprojected - grid, axis=1)))
