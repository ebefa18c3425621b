"""Argument types and input handling shared by the `follow-calib` commands."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import numpy as np

from calib.chessboard import ImageInputError, is_video, iter_video_frames, read_image, to_gray
from follow.cli_args import picture_path, positive_float, refuse_overwriting


def pattern_size(text: str) -> tuple[int, int]:
    """'9x6' -> (9, 6): inner corners per row and per column."""
    match = re.fullmatch(r"\s*(\d+)\s*[xX,]\s*(\d+)\s*", text)
    if not match:
        raise argparse.ArgumentTypeError(
            f"pattern size must look like 9x6 (inner corners), got {text!r}"
        )
    cols, rows = int(match.group(1)), int(match.group(2))
    if cols < 2 or rows < 2:
        raise argparse.ArgumentTypeError(f"pattern size must be at least 2x2, got {text!r}")
    return cols, rows


IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")  # what OpenCV writes
image_path = picture_path(IMAGE_SUFFIXES, Path)


def add_board_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--pattern", type=pattern_size, required=True, metavar="COLSxROWS",
        help="inner corners of the chessboard, e.g. 9x6 for a board of 10x7 squares",
    )  # fmt: skip
    parser.add_argument(
        "--square-size-m", type=positive_float, required=True,
        help="side of one square in metres (measure the printed board)",
    )  # fmt: skip


def video_source(sources: list[Path]) -> str | None:
    """The one video file or camera index `sources` name, else None (image files)."""
    if len(sources) == 1 and (is_video(sources[0]) or str(sources[0]).isdigit()):
        return str(sources[0])
    return None


def refuse_videos_among_images(paths: list[Path]) -> None:
    """A video is read on its own: among image files it is an error, not skipped."""
    for path in paths:
        if is_video(path):
            raise ImageInputError(f"{path}: give a video on its own, not among images")


def read_grey_frames(
    sources: list[Path], every: int = 1, limit: int | None = None
) -> list[tuple[str, np.ndarray]]:
    """(name, grey frame) from image files, or from one video file or camera index. An
    image is named by its path as given, which an error can then point the user to."""
    source = video_source(sources)
    if source is not None:
        frames = [(name, to_gray(f, name)) for name, f in iter_video_frames(source, every, limit)]
        if not frames:
            raise ImageInputError(f"video {source}: no frames")
        return frames
    refuse_videos_among_images(sources)
    out = [(str(path), to_gray(read_image(path), str(path))) for path in sources]
    return out[:limit] if limit else out


def refuse_overwriting_inputs(inputs: dict, outputs: dict) -> None:
    """Refuse, before anything is read or written, an output that is one of the inputs
    (a photo, a video, a Tsai file, a camera file read but not rewritten) or another
    output, or that is a folder (`follow.cli_args.refuse_overwriting`, each input named
    with its path). `inputs`: name -> path, list of paths or None; `outputs`: name -> path."""
    labelled = {f"{name} {path}": path for name, value in inputs.items()
                for path in (value if isinstance(value, list) else [value])
                if path is not None}  # fmt: skip
    refuse_overwriting(labelled, outputs)
    for name, path in outputs.items():
        if Path(path).is_dir():
            raise ValueError(f"{name} {path} is a folder: give a file name")
