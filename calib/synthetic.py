"""Rendered chessboard views from known cameras, to measure the calibration tools.

A view is rendered exactly: every output pixel is supersampled, each sample's viewing
ray (through the lens distortion) is intersected with the board plane, and the board's
colour there is looked up analytically; the samples are then box-averaged. The result
is an anti-aliased image whose corner positions are known to a small fraction of a pixel.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.ndimage import map_coordinates

from follow.camera import CameraModel

BLACK_LEVEL = 25.0
WHITE_LEVEL = 225.0
FLOOR_LEVEL = 110.0
SKY_LEVEL = 160.0


@dataclass(frozen=True)
class BoardSpec:
    """A chessboard: inner corners (columns, rows) and square side in metres."""

    pattern_size: tuple[int, int]
    square_size_m: float

    def object_points(self) -> np.ndarray:
        """Inner-corner positions (N, 3) in the board frame, row by row."""
        cols, rows = self.pattern_size
        jj, ii = np.mgrid[0:rows, 0:cols]
        pts = np.column_stack([ii.ravel(), jj.ravel(), np.zeros(ii.size)])
        return pts * self.square_size_m

    @property
    def centre_m(self) -> np.ndarray:
        cols, rows = self.pattern_size
        return np.array([(cols - 1) / 2.0, (rows - 1) / 2.0]) * self.square_size_m


@functools.lru_cache(maxsize=4)
def _normalized_sample_rays(
    K_bytes: bytes, dist_bytes: bytes, image_size: tuple[int, int], supersample: int
) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalised coordinates of every sub-pixel sample (cached per camera)."""
    K = np.frombuffer(K_bytes).reshape(3, 3)
    dist = np.frombuffer(dist_bytes)
    w, h = image_size
    # Exact undistortion on a pixel lattice with a one-pixel margin, then bilinear
    # interpolation to the sub-pixel samples (the map is smooth at this scale).
    uc, vc = np.meshgrid(np.arange(-1.0, w + 1.0), np.arange(-1.0, h + 1.0))
    lattice = np.column_stack([uc.ravel(), vc.ravel()]).reshape(-1, 1, 2)
    if dist.size:
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
        norm = cv2.undistortPointsIter(lattice, K, dist, None, None, criteria).reshape(
            uc.shape + (2,)
        )
    else:
        Kinv = np.linalg.inv(K)
        flat = lattice.reshape(-1, 2) @ Kinv[:2, :2].T + Kinv[:2, 2]
        norm = flat.reshape(uc.shape + (2,))
    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    us = (np.arange(w)[:, None] + offsets[None, :]).ravel()
    vs = (np.arange(h)[:, None] + offsets[None, :]).ravel()
    vv, uu = np.meshgrid(vs + 1.0, us + 1.0, indexing="ij")  # lattice index space
    coords = np.stack([vv, uu])
    xn = map_coordinates(norm[..., 0], coords, order=1)
    yn = map_coordinates(norm[..., 1], coords, order=1)
    return xn, yn


def render_board(
    camera: CameraModel,
    board: BoardSpec,
    rotation_cam_from_board: np.ndarray,
    translation_cam_from_board_m: np.ndarray,
    *,
    supersample: int = 2,
    noise_sigma: float = 1.5,
    blur_sigma_px: float = 0.0,
    floor_horizon: bool = False,
    seed: int = 0,
) -> np.ndarray:
    """A grey image (uint8) of `board` seen by `camera` at the given board pose.

    The board has a white margin one square wide around its squares. Samples that miss
    the board are floor grey, or sky grey where `floor_horizon` is set and the sample's ray
    points above the board plane's horizon.
    """
    R = np.asarray(rotation_cam_from_board, dtype=np.float64)
    t = np.asarray(translation_cam_from_board_m, dtype=np.float64).ravel()
    xn, yn = _normalized_sample_rays(
        camera.K.tobytes(), camera.dist.tobytes(), camera.image_size, supersample
    )
    H = np.column_stack([R[:, 0], R[:, 1], t])
    Hinv = np.linalg.inv(H)
    a = Hinv[0, 0] * xn + Hinv[0, 1] * yn + Hinv[0, 2]
    b = Hinv[1, 0] * xn + Hinv[1, 1] * yn + Hinv[1, 2]
    c = Hinv[2, 0] * xn + Hinv[2, 1] * yn + Hinv[2, 2]
    in_front = c > 1e-12
    with np.errstate(divide="ignore", invalid="ignore"):
        bx = a / c / board.square_size_m
        by = b / c / board.square_size_m
    cols, rows = board.pattern_size
    # Squares span [-1, cols] x [-1, rows] in square units; the margin one more square.
    sq_x = np.floor(bx)
    sq_y = np.floor(by)
    on_squares = in_front & (sq_x >= -1) & (sq_x <= cols - 1) & (sq_y >= -1) & (sq_y <= rows - 1)
    on_board = in_front & (bx >= -2) & (bx < cols + 1) & (by >= -2) & (by < rows + 1)
    black = on_squares & (np.mod(sq_x + sq_y, 2) == 0)
    image = np.where(on_board, WHITE_LEVEL, FLOOR_LEVEL)
    image = np.where(black, BLACK_LEVEL, image)
    if floor_horizon:
        image = np.where(in_front, image, SKY_LEVEL)
    w, h = camera.image_size
    s = supersample
    image = image.reshape(h, s, w, s).mean(axis=(1, 3))
    if blur_sigma_px > 0:
        image = cv2.GaussianBlur(image, (0, 0), blur_sigma_px)
    if noise_sigma > 0:
        image = image + np.random.default_rng(seed).normal(0.0, noise_sigma, image.shape)
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def floor_board_pose(
    camera: CameraModel, board_x_m: float, board_y_m: float, board_yaw_rad: float
) -> tuple[np.ndarray, np.ndarray]:
    """Camera-from-board rotation and translation of a board lying on the floor.

    The board's first inner corner is at (board_x_m, board_y_m) in `base`, its x axis at
    `board_yaw_rad` from base x, its z axis up.
    """
    c, s = math.cos(board_yaw_rad), math.sin(board_yaw_rad)
    R_base_from_board = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    origin_base = np.array([board_x_m, board_y_m, 0.0])
    R_bc = camera.rotation_base_from_cam
    R = R_bc.T @ R_base_from_board
    t = R_bc.T @ (origin_base - camera.position_base)
    return R, t


def render_floor_board(
    camera: CameraModel,
    board: BoardSpec,
    board_x_m: float,
    board_y_m: float,
    board_yaw_rad: float = 0.0,
    **kwargs,
) -> np.ndarray:
    """A view of `board` lying on the floor in front of `camera` (see `floor_board_pose`)."""
    R, t = floor_board_pose(camera, board_x_m, board_y_m, board_yaw_rad)
    return render_board(camera, board, R, t, floor_horizon=True, **kwargs)


def rotation_from_euler_deg(rx_deg: float, ry_deg: float, rz_deg: float) -> np.ndarray:
    rvec_x = cv2.Rodrigues(np.array([math.radians(rx_deg), 0.0, 0.0]))[0]
    rvec_y = cv2.Rodrigues(np.array([0.0, math.radians(ry_deg), 0.0]))[0]
    rvec_z = cv2.Rodrigues(np.array([0.0, 0.0, math.radians(rz_deg)]))[0]
    return rvec_z @ rvec_y @ rvec_x


def board_fully_visible(
    camera: CameraModel, board: BoardSpec, R: np.ndarray, t: np.ndarray, margin_px: float = 3.0
) -> bool:
    """True when the whole board, white margin included, is inside the image."""
    cols, rows = board.pattern_size
    s = board.square_size_m
    edge = np.linspace(0.0, 1.0, 9)
    x0, x1, y0, y1 = -2 * s, (cols + 1) * s, -2 * s, (rows + 1) * s
    outline = np.concatenate(
        [
            np.column_stack([x0 + (x1 - x0) * edge, np.full(9, y0)]),
            np.column_stack([x0 + (x1 - x0) * edge, np.full(9, y1)]),
            np.column_stack([np.full(9, x0), y0 + (y1 - y0) * edge]),
            np.column_stack([np.full(9, x1), y0 + (y1 - y0) * edge]),
        ]
    )
    pts_cam = np.column_stack([outline, np.zeros(len(outline))]) @ R.T + t
    if (pts_cam[:, 2] <= 0.05).any():
        return False
    pts_base = pts_cam @ camera.rotation_base_from_cam.T + camera.position_base
    return bool(camera.in_image(camera.project(pts_base), margin_px).all())


def calibration_views(
    camera: CameraModel,
    board: BoardSpec,
    count: int,
    *,
    distance_m: tuple[float, float] = (0.35, 0.6),
    max_tilt_deg: float = 40.0,
    seed: int = 0,
    **render_kwargs,
) -> list[tuple[str, np.ndarray]]:
    """`count` hand-held-like views of `board`: tilted, at several distances, spread over
    the image (the board's centre is aimed at a 3x3 grid of image points, then at random
    ones), each fully inside the image."""
    rng = np.random.default_rng(seed)
    w, h = camera.image_size
    aims = [(u, v) for v in (0.22, 0.5, 0.78) for u in (0.2, 0.5, 0.8)]
    Kinv = np.linalg.inv(camera.K)
    views = []
    for index in range(count):
        u, v = aims[index] if index < len(aims) else rng.uniform(0.25, 0.75, 2)
        for _ in range(50):
            R = rotation_from_euler_deg(
                rng.uniform(-max_tilt_deg, max_tilt_deg),
                rng.uniform(-max_tilt_deg, max_tilt_deg),
                rng.uniform(-25.0, 25.0),
            )
            depth = rng.uniform(*distance_m)
            centre = Kinv @ np.array([u * w, v * h, 1.0]) * depth
            t = centre - R @ np.array([*board.centre_m, 0.0])
            if board_fully_visible(camera, board, R, t):
                break
            u, v = 0.5 + (u - 0.5) * 0.92, 0.5 + (v - 0.5) * 0.92  # aim nearer the centre
        else:
            raise RuntimeError("could not place the board inside the image; use a smaller one")
        image = render_board(camera, board, R, t, seed=seed * 1000 + index, **render_kwargs)
        views.append((f"synthetic {index:02d}", image))
    return views
