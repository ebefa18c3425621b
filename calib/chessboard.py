"""Chessboard corner detection and the image/video input of the calibration commands."""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from follow.cli_args import (
    EARLY_END_TOLERANCE_FRAMES,
    MAX_UNDECODABLE_RUN,
    camera_index_too_large,
    frame_count_fits_file,
    no_camera_at,
)

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp")
VIDEO_SUFFIXES = (".avi", ".mp4", ".mkv", ".mov", ".webm", ".m4v", ".mpg", ".mpeg")

# Classic detector refinement: cornerSubPix's window half-size is a fraction of the
# smallest corner spacing (a window reaching the next corner biases it), within limits.
SUBPIX_WINDOW_FRACTION = 0.35
SUBPIX_WINDOW_MIN_PX = 2
SUBPIX_WINDOW_MAX_PX = 6
UPSCALE = 2.0  # last resort: look for the board at this magnification
UNMEASURED_EDGE_WIDTH_PX = 9999.0  # what estimateChessboardSharpness gives when it cannot
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4)


class ImageInputError(ValueError):
    """An image or video that cannot be used: the message names the file and the problem."""


class BoardNotFoundError(ValueError):
    """No chessboard of the expected size in an image."""


@dataclass(frozen=True)
class Detection:
    """Inner corners (N, 2) in pixels, row by row as OpenCV orders them."""

    corners_px: np.ndarray
    image_size: tuple[int, int]  # (width, height)
    # mean edge width across the board's squares (lower = sharper); NaN: not measured
    sharpness_px: float


def check_pattern_size(pattern_size: tuple[int, int]) -> tuple[int, int]:
    cols, rows = (int(v) for v in pattern_size)
    if cols < 2 or rows < 2:
        raise ValueError(f"pattern size counts inner corners and must be >= 2x2, got {cols}x{rows}")
    return cols, rows


def to_gray(image: np.ndarray, source: str = "image") -> np.ndarray:
    """An 8-bit single-channel copy of a grey, BGR or BGRA image."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3 and img.shape[2] in (3, 4):
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if img.ndim != 2 or img.size == 0:
        raise ImageInputError(f"{source}: expected a grey or colour image, got shape {img.shape}")
    if img.dtype != np.uint8:
        if not np.isfinite(img).all():
            raise ImageInputError(f"{source}: image holds NaN or infinite values")
        img = np.clip(np.round(img), 0, 255).astype(np.uint8)
    return img


def read_image(path: str | Path) -> np.ndarray:
    """A BGR image from a file; a clear error when it is missing or not an image."""
    path = Path(path)
    if path.is_dir():  # `intrinsics` takes folders; this command takes one image
        raise ImageInputError(f"image {path}: a folder, not an image file (give one image)")
    if not path.is_file():
        raise ImageInputError(f"image {path}: no such file")
    try:
        data = np.fromfile(str(path), dtype=np.uint8)
    except OSError as exc:  # no permission to read it, a failing disk
        raise ImageInputError(f"image {path}: cannot read ({exc.strerror or exc})") from None
    image = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    if image is None:
        raise ImageInputError(f"image {path}: not a readable image (corrupt or unknown format)")
    return image


def is_video(path: Path) -> bool:
    return path.suffix.lower() in VIDEO_SUFFIXES


def iter_video_frames(
    source: str | Path | int, every: int = 1, limit: int | None = None
) -> Iterator[tuple[str, np.ndarray]]:
    """(name, BGR frame) for every `every`-th frame of a video file or camera index."""
    if every < 1:
        raise ValueError(f"frame step must be >= 1, got {every}")
    camera_index = not isinstance(source, (str, Path)) or str(source).isdigit()
    if not camera_index:
        if not Path(source).is_file():
            raise ImageInputError(f"video {source}: no such file")
        capture = cv2.VideoCapture(str(source))
    else:
        if too_large := camera_index_too_large(str(source)):
            raise ImageInputError(f"camera {source}: {too_large}")
        capture = cv2.VideoCapture(int(source))
    if not capture.isOpened():
        if camera_index:
            raise ImageInputError(f"camera {source}: {no_camera_at(source)}")
        raise ImageInputError(f"video {source}: cannot be opened")
    count = 0 if camera_index else capture.get(cv2.CAP_PROP_FRAME_COUNT)
    announced = int(count) if count and np.isfinite(count) and count > 0 else 0
    # A damaged stretch of any length before a count the file could hold is skipped;
    # without one, MAX_UNDECODABLE_RUN failed reads in a row end the video.
    count_trusted = not camera_index and frame_count_fits_file(source, announced)
    try:
        index = taken = damaged = failures = 0
        while limit is None or taken < limit:
            ok, frame = capture.read()
            if not ok:
                # A file's damaged frame, before the frames its header announces: skipped,
                # as `follow run` does, not taken for the end of the video.
                within_run = count_trusted or failures < MAX_UNDECODABLE_RUN
                if index < announced - EARLY_END_TOLERANCE_FRAMES and within_run:
                    failures += 1
                    damaged += 1
                    index += 1
                    continue
                break
            failures = 0
            if index % every == 0:
                yield f"frame {index}", frame
                taken += 1
            index += 1
        if index == damaged:
            raise ImageInputError(f"video {source}: no frame could be decoded")
        if damaged:
            log.warning("video %s: %d damaged frame(s) skipped", source, damaged)
        if limit is None and index < announced - EARLY_END_TOLERANCE_FRAMES:
            log.warning("video %s: ends after %d of the %d frames its header announces "
                        "(cut short or damaged)", source, index, announced)  # fmt: skip
    finally:
        capture.release()


def list_inputs(paths: list[Path]) -> list[Path]:
    """Image files of the given files and folders (folders are listed, sorted)."""
    out: list[Path] = []
    for path in paths:
        if path.is_dir():
            found = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
            if not found:
                raise ImageInputError(f"folder {path}: holds no image files ({IMAGE_SUFFIXES})")
            out.extend(found)
        elif path.exists():
            out.append(path)
        else:
            raise ImageInputError(f"{path}: no such file or folder")
    return out


def _find_sector_based(
    gray: np.ndarray, pattern_size: tuple[int, int], exhaustive: bool = True
) -> np.ndarray | None:
    flags = cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_NORMALIZE_IMAGE
    for extra in (0, cv2.CALIB_CB_EXHAUSTIVE) if exhaustive else (0,):  # exhaustive is slower
        found, corners = cv2.findChessboardCornersSB(gray, pattern_size, flags=flags | extra)
        if found:
            return corners.reshape(-1, 2).astype(np.float64)
    return None


def _find_classic(gray: np.ndarray, pattern_size: tuple[int, int]) -> np.ndarray | None:
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    try:
        found, corners = cv2.findChessboardCorners(gray, pattern_size, flags=flags)
    except cv2.error:  # its threshold window asserts on images under ~15 px: no board there
        return None
    return corners.reshape(-1, 2).astype(np.float64) if found else None


def refine_corners(
    gray: np.ndarray, corners: np.ndarray, pattern_size: tuple[int, int]
) -> np.ndarray:
    """Saddle-point refinement (cornerSubPix) in a window that stays inside the squares.

    The sector-based detector's corners carry a small systematic offset (a few hundredths
    of a pixel) that biases the focal length by a few tenths of a percent; cornerSubPix
    removes it.
    """
    half = int(SUBPIX_WINDOW_FRACTION * min_corner_spacing_px(corners, pattern_size))
    half = min(max(half, SUBPIX_WINDOW_MIN_PX), SUBPIX_WINDOW_MAX_PX)
    start = np.asarray(corners, dtype=np.float32).reshape(-1, 1, 2)
    refined = cv2.cornerSubPix(gray, start, (half, half), (-1, -1), SUBPIX_CRITERIA)
    return refined.reshape(-1, 2).astype(np.float64)


def min_corner_spacing_px(corners: np.ndarray, pattern_size: tuple[int, int]) -> float:
    """The smallest distance between neighbouring inner corners of a detected grid."""
    cols, rows = pattern_size
    grid = np.asarray(corners, dtype=np.float64).reshape(rows, cols, 2)
    along_rows = np.linalg.norm(np.diff(grid, axis=1), axis=2)
    along_cols = np.linalg.norm(np.diff(grid, axis=0), axis=2)
    return float(min(along_rows.min(), along_cols.min()))


def detect_chessboard(
    image: np.ndarray, pattern_size: tuple[int, int], thorough: bool = True
) -> Detection | None:
    """The board's inner corners, or None when no board of that size is seen.

    The sector-based detector (findChessboardCornersSB) is tried first: it is robust to
    blur; then the classic detector; last the sector-based one on a 2x enlarged image.
    The corners are then refined with cornerSubPix in a window scaled to the squares.
    `thorough=False` skips the slow searches (exhaustive and enlarged): for screening many
    views, where a board that is hard to find makes a poor view anyway.
    """
    pattern_size = check_pattern_size(pattern_size)
    gray = to_gray(image)
    corners = _find_sector_based(gray, pattern_size, exhaustive=thorough)
    if corners is None:
        corners = _find_classic(gray, pattern_size)
    if corners is None and not thorough:
        return None
    if corners is None:
        # Small or steeply foreshortened squares (a board far away on the floor) are
        # found more often at twice the resolution.
        big = cv2.resize(gray, None, fx=UPSCALE, fy=UPSCALE, interpolation=cv2.INTER_CUBIC)
        found = _find_sector_based(big, pattern_size)
        if found is None:
            return None
        corners = (found + 0.5) / UPSCALE - 0.5  # pixel centres at integer coordinates
    corners = refine_corners(gray, corners, pattern_size)
    sharpness = cv2.estimateChessboardSharpness(gray, pattern_size, corners.astype(np.float32))
    edge_width_px = float(sharpness[0][0])
    if edge_width_px >= UNMEASURED_EDGE_WIDTH_PX:  # OpenCV's "could not measure" (small squares)
        edge_width_px = math.nan
    return Detection(corners, (gray.shape[1], gray.shape[0]), edge_width_px)
