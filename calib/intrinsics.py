"""Camera matrix and lens distortion from chessboard views (OpenCV's calibrateCamera).

Views are screened before they are used: a view without the board, a blurred one
(motion blur shifts corners) or a near-copy of an already kept one (a video lingering
on one pose would weigh that pose many times) is rejected with the reason. After a first
calibration, views that reproject much worse than the others are dropped and the
calibration is run again. The corners of all kept views should cover the image, its
borders in particular, or the distortion is extrapolated there: a warning says where.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import cv2
import numpy as np
from tqdm import tqdm

from calib.chessboard import check_pattern_size, detect_chessboard, to_gray

log = logging.getLogger(__name__)

# Screening defaults.
MAX_EDGE_WIDTH_PX = 3.5  # estimateChessboardSharpness: mean edge width; sharp prints ~1.5-2.5
DUPLICATE_FRACTION = 0.015  # mean corner shift below this fraction of the diagonal: a copy
# ... unless the board's shape changed by this fraction of its own size (tilted in place,
# as the tilt rule asks: a small board turned 30 deg moves its corners only a few pixels,
# a board held still by hand changes shape by well under 1 %).
DUPLICATE_SHAPE_FRACTION = 0.02
MIN_VIEWS = 4
OUTLIER_VIEW_FACTOR = 3.0  # a view reprojecting worse than this x the median is dropped
OUTLIER_VIEW_MIN_PX = 0.5  # ... unless its RMS is below this anyway
# An overall RMS above this is warned about: a sharp, flat board fits to 0.1-0.3 px, and
# corners off by more (a bent board, blur, a lens the model cannot follow) bend K and the
# distortion with them.
RMS_WARNING_PX = 0.5
# Coverage: the image is cut in COVERAGE_GRID cells; a 3x3 region is "uncovered" when less
# than REGION_MIN_COVERED of its cells are touched by some view's board.
COVERAGE_GRID = (12, 9)
COVERAGE_WARN_FRACTION = 0.5
REGION_MIN_COVERED = 0.25
# Tilt: a board parallel to the image looks the same to a camera of focal length f at
# distance d as to one of 2f at 2d; only its foreshortening (perspective) tells them apart.
# A tilt about the image's vertical axis foreshortens the board along x and measures fx,
# one about the horizontal axis measures fy. On rendered views (calib.synthetic), boards
# parallel to the image or all turned about one image axis gave focal lengths 2.5-35% off
# at an RMS under 0.25 px; one view turned each way up to 17% off, two views each way
# about 0.5% at most.
# So each way, at least MIN_TILTED_VIEWS views must turn the board by MIN_TILT_DEG or more.
MIN_TILT_DEG = 15.0
MIN_TILTED_VIEWS = 2

DISTORTION_FLAGS = {
    "radial": cv2.CALIB_ZERO_TANGENT_DIST,  # k1, k2, k3
    "standard": 0,  # k1, k2, p1, p2, k3
    "rational": cv2.CALIB_RATIONAL_MODEL,  # k1..k6, p1, p2
}
# The camera file holds OpenCV's first 8 coefficients (k1, k2, p1, p2, k3, k4, k5, k6);
# with the rational model calibrateCamera returns 14, the last 6 (thin prism, tilt) unused.
CAMERA_FILE_DIST_COEFFS = 8
_REGION_NAMES = (
    ("top-left", "top", "top-right"),
    ("left", "centre", "right"),
    ("bottom-left", "bottom", "bottom-right"),
)


class CalibrationError(ValueError):
    """Not enough usable views to calibrate, or views that cannot fix the focal length."""


@dataclass(frozen=True)
class IntrinsicsResult:
    K: np.ndarray
    dist: np.ndarray
    image_size: tuple[int, int]
    rms_px: float  # over all corners of the kept views
    per_view_rms_px: dict[str, float]  # kept views
    rejected: list[tuple[str, str]]  # (view, reason)
    coverage_fraction: float
    uncovered_regions: list[str]
    warnings: list[str] = field(default_factory=list)

    @property
    def views_used(self) -> int:
        return len(self.per_view_rms_px)


@dataclass
class _View:
    name: str
    corners: np.ndarray  # (N, 2)


def _named(images: Iterable) -> Iterable[tuple[str, np.ndarray]]:
    for index, item in enumerate(images):
        if isinstance(item, tuple) and len(item) == 2 and isinstance(item[0], str):
            yield item
        else:
            yield f"view {index}", item


def _shape_change(a: np.ndarray, b: np.ndarray) -> float:
    """Mean corner displacement between two detections once each is centred on its own
    mean, as a fraction of the board's diagonal in the image (a change of tilt or
    distance, not of place), whichever end each starts from."""
    a0, b0 = a - a.mean(axis=0), b - b.mean(axis=0)
    size_px = max(float(np.linalg.norm(np.ptp(a, axis=0))), 1.0)
    return min(np.linalg.norm(a0 - b0, axis=1).mean(),
               np.linalg.norm(a0 - b0[::-1], axis=1).mean()) / size_px  # fmt: skip


def _mean_shift_px(a: np.ndarray, b: np.ndarray) -> float:
    """Mean corner displacement between two detections, whichever end each starts from."""
    return float(
        min(np.linalg.norm(a - b, axis=1).mean(), np.linalg.norm(a - b[::-1], axis=1).mean())
    )


def coverage(
    views: list[np.ndarray], image_size: tuple[int, int], pattern_size: tuple[int, int]
) -> tuple[float, list[str]]:
    """Fraction of image cells under some board, and the 3x3 regions left uncovered."""
    gw, gh = COVERAGE_GRID
    w, h = image_size
    mask = np.zeros((gh, gw), np.uint8)
    cols, rows = pattern_size
    for corners in views:
        grid = corners.reshape(rows, cols, 2)
        outline = np.array([grid[0, 0], grid[0, -1], grid[-1, -1], grid[-1, 0]])
        cells = outline / [w / gw, h / gh] - 0.5  # cell centres at integer coordinates
        cv2.fillConvexPoly(mask, np.round(cells * 16).astype(np.int32), 1, cv2.LINE_8, shift=4)
    fraction = float(mask.mean())
    uncovered = []
    for r in range(3):
        for c in range(3):
            region = mask[r * gh // 3 : (r + 1) * gh // 3, c * gw // 3 : (c + 1) * gw // 3]
            if region.mean() < REGION_MIN_COVERED:
                uncovered.append(_REGION_NAMES[r][c])
    return fraction, uncovered


def _calibrate(
    views: list[_View],
    object_pts: np.ndarray,
    image_size: tuple[int, int],
    flags: int,
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """RMS, K, distortion, per-view RMS and the board normals (N, 3) in the camera frame."""
    objects = [object_pts.astype(np.float32)] * len(views)
    points = [v.corners.astype(np.float32).reshape(-1, 1, 2) for v in views]
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    rms, K, dist, rvecs, _, _, _, per_view = cv2.calibrateCameraExtended(
        objects, points, image_size, None, None, flags=flags, criteria=criteria
    )
    normals = np.array([cv2.Rodrigues(rvec)[0][:, 2] for rvec in rvecs])
    return float(rms), K, _file_distortion(dist.ravel()), per_view.ravel(), normals


def check_tilts(board_normals: np.ndarray) -> None:
    """Raise CalibrationError unless the boards are tilted enough both ways (see
    MIN_TILT_DEG): otherwise the focal length is a guess however low the RMS."""
    lean = np.abs(np.asarray(board_normals, dtype=np.float64)[:, :2])  # sin of the tilt
    left_right, up_down = (lean > math.sin(math.radians(MIN_TILT_DEG))).sum(axis=0).tolist()
    if min(left_right, up_down) >= MIN_TILTED_VIEWS:
        return
    if left_right == up_down == 0:
        problem = "the board is nearly parallel to the image in every view"
    elif min(left_right, up_down) == 0:
        problem = f"the board is tilted {'up/down' if up_down else 'left/right'} only"
    else:
        problem = f"too few views tilt the board ({left_right} left/right, {up_down} up/down)"
    raise CalibrationError(
        f"{problem}, so the focal length cannot be told from the board's distance: add at "
        f"least {MIN_TILTED_VIEWS} views with the board tilted left/right and "
        f"{MIN_TILTED_VIEWS} tilted up/down, by {MIN_TILT_DEG:.0f}-45 degrees"
    )


def _file_distortion(dist: np.ndarray) -> np.ndarray:
    """OpenCV's distortion cut to the coefficients the camera file holds.

    The thin-prism and tilt terms past the eighth are zero unless their flags are set;
    one that is not would change the projection, so it is refused rather than dropped.
    """
    extra = dist[CAMERA_FILE_DIST_COEFFS:]
    if np.any(extra != 0.0):
        raise CalibrationError(
            f"distortion terms past the 8th are not zero ({extra.tolist()}): the camera file "
            "cannot hold them; use another --distortion-model"
        )
    return dist[:CAMERA_FILE_DIST_COEFFS]


def calibrate_intrinsics(
    images: Iterable,
    pattern_size: tuple[int, int],
    square_size_m: float,
    *,
    distortion_model: str = "standard",
    max_edge_width_px: float = MAX_EDGE_WIDTH_PX,
    duplicate_fraction: float = DUPLICATE_FRACTION,
    max_views: int | None = None,
    stop_at_views: int | None = None,
    progress: bool = True,
) -> IntrinsicsResult:
    """Calibrate from chessboard images (arrays, or (name, array) pairs).

    `stop_at_views`: stop reading `images` once this many views are kept (a camera's
    frames never run out).

    Raises CalibrationError when fewer than MIN_VIEWS views survive the screening, or when
    too few of them tilt the board left/right and up/down (`check_tilts`).
    """
    cols, rows = check_pattern_size(pattern_size)
    if not (math.isfinite(square_size_m) and square_size_m > 0):
        raise ValueError(f"square size must be positive metres, got {square_size_m}")
    if distortion_model not in DISTORTION_FLAGS:
        raise ValueError(
            f"distortion model must be one of {sorted(DISTORTION_FLAGS)}, got {distortion_model!r}"
        )
    jj, ii = np.mgrid[0:rows, 0:cols]
    object_pts = np.column_stack([ii.ravel(), jj.ravel(), np.zeros(ii.size)]) * square_size_m
    image_size: tuple[int, int] | None = None
    kept: list[_View] = []
    rejected: list[tuple[str, str]] = []
    for name, image in tqdm(_named(images), desc="detecting", unit="view", disable=not progress):
        gray = to_gray(image, name)
        size = (gray.shape[1], gray.shape[0])
        if image_size is None:
            image_size = size
        elif size != image_size:
            rejected.append(
                (name, f"size {size[0]}x{size[1]} differs from {image_size[0]}x{image_size[1]}")
            )
            continue
        detection = detect_chessboard(gray, (cols, rows), thorough=False)
        if detection is None:
            rejected.append((name, f"no {cols}x{rows} board found"))
            continue
        if not detection.sharpness_px <= max_edge_width_px:
            width = detection.sharpness_px
            why = (f"blurred (edge width {width:.1f} px > {max_edge_width_px})" if math.isfinite(width)
                   else "its edges' sharpness cannot be measured (squares too small?)")  # fmt: skip
            rejected.append((name, why))
            continue
        limit_px = duplicate_fraction * math.hypot(*image_size)
        twin = next(
            (v for v in kept
             if _mean_shift_px(v.corners, detection.corners_px) < limit_px
             and _shape_change(v.corners, detection.corners_px) < DUPLICATE_SHAPE_FRACTION),
            None,
        )  # fmt: skip
        if twin is not None:
            rejected.append((name, f"near-duplicate of {twin.name}"))
            continue
        kept.append(_View(name, detection.corners_px))
        if stop_at_views is not None and len(kept) >= stop_at_views:
            break
    if image_size is None:
        raise CalibrationError("no images to calibrate from")
    if max_views is not None and len(kept) > max_views:
        chosen = np.unique(np.linspace(0, len(kept) - 1, max_views).round().astype(int))
        for index in sorted(set(range(len(kept))) - set(chosen.tolist())):
            rejected.append((kept[index].name, f"not needed (more than {max_views} views)"))
        kept = [kept[i] for i in chosen]
    if len(kept) < MIN_VIEWS:
        reasons = "; ".join(f"{n}: {r}" for n, r in rejected[:10])
        raise CalibrationError(
            f"only {len(kept)} usable view(s), at least {MIN_VIEWS} are needed (10 or more "
            f"recommended). Rejected: {reasons or 'none'}"
        )
    flags = DISTORTION_FLAGS[distortion_model]
    rms, K, dist, per_view, normals = _calibrate(kept, object_pts, image_size, flags)
    limit = max(OUTLIER_VIEW_MIN_PX, OUTLIER_VIEW_FACTOR * float(np.median(per_view)))
    outliers = per_view > limit
    if outliers.any() and (~outliers).sum() >= MIN_VIEWS:
        for view, err in zip(kept, per_view, strict=True):
            if err > limit:
                rejected.append((view.name, f"reprojection error {err:.2f} px > {limit:.2f} px"))
        kept = [v for v, bad in zip(kept, outliers, strict=True) if not bad]
        rms, K, dist, per_view, normals = _calibrate(kept, object_pts, image_size, flags)
    check_tilts(normals)
    fraction, uncovered = coverage([v.corners for v in kept], image_size, (cols, rows))
    warnings = []
    if fraction < COVERAGE_WARN_FRACTION or uncovered:
        where = f"; uncovered: {', '.join(uncovered)}" if uncovered else ""
        warnings.append(
            f"the boards cover {100 * fraction:.0f}% of the image{where}: add views with the "
            "board near those parts, or the distortion there is a guess"
        )
    if rms > RMS_WARNING_PX:
        warnings.append(
            f"corners reproject with {rms:.2f} px RMS (> {RMS_WARNING_PX} px): check that the "
            "board is flat and the views sharp, or try --distortion-model rational"
        )
    if len(kept) < 10:
        warnings.append(f"only {len(kept)} views used; 10 or more give steadier intrinsics")
    for warning in warnings:
        log.warning(warning)
    return IntrinsicsResult(
        K=K,
        dist=dist,
        image_size=image_size,
        rms_px=rms,
        per_view_rms_px={v.name: float(e) for v, e in zip(kept, per_view, strict=True)},
        rejected=rejected,
        coverage_fraction=fraction,
        uncovered_regions=uncovered,
        warnings=warnings,
    )
