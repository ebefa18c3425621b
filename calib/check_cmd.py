"""`follow-calib check`: draw a camera file's ground grid over a frame, to eyeball it.

The floor grid (1 m by default, the `base` axes in red) and the horizon are drawn through
the camera model, lens distortion included. Floor tiles, walls' feet and people's feet
should sit on the grid as a person expects; if they do not, the calibration is off.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from calib.camera_file import write_image_atomic
from calib.chessboard import ImageInputError, is_video, iter_video_frames, read_image
from calib.cmd_common import image_path, refuse_overwriting_inputs
from calib.overlay import calibration_overlay, visible_ground_extent
from follow.camera import CameraModel
from follow.cli_args import positive_float


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "source", help="image file, video file or camera index (e.g. 0) to take a frame from"
    )
    parser.add_argument("--camera", type=Path, required=True, help="camera file to check")
    parser.add_argument(
        "--frame", type=int, default=None,
        help="video/camera: index of the frame to use (default 0)",
    )
    parser.add_argument(
        "-o", "--output", type=image_path, default=Path("check.png"),
        help="overlay PNG to write (default check.png)",
    )  # fmt: skip
    parser.add_argument(
        "--grid-step-m", type=positive_float, default=1.0, help="grid spacing, metres (default 1)"
    )
    parser.add_argument(
        "--max-range-m", type=positive_float, default=20.0,
        help="draw the grid up to this distance from the camera (default 20 m)",
    )  # fmt: skip


def _frame(source: str, index: int | None):
    if index is not None and index < 0:
        raise ValueError(f"--frame must be >= 0, got {index}")
    if source.isdigit() or is_video(Path(source)):
        index = index or 0
        count = 0
        for _, frame in iter_video_frames(source, every=1, limit=None):
            if count == index:
                return frame
            count += 1
        raise ImageInputError(
            f"video {source}: has no frame {index} (--frame); it has {count} frames, 0..{count - 1}"
        )
    if index is not None:
        raise ValueError(f"--frame picks a frame of a video or camera; {source} is one image: "
                         "leave it out")  # fmt: skip
    return read_image(source)


def main(args: argparse.Namespace) -> dict:
    refuse_overwriting_inputs({"source": args.source, "--camera": args.camera}, {"-o": args.output})
    camera = CameraModel.load(args.camera)
    frame = _frame(args.source, args.frame)
    h, w = frame.shape[:2]
    try:
        seen = camera.for_image_size(w, h)
    except ValueError as exc:
        raise ImageInputError(f"frame of {args.source} against {args.camera}: {exc}") from None
    p = camera.pose
    lines = [
        f"{args.camera.name}: height {p.height_m:.2f} m  pitch {math.degrees(p.pitch_rad):.1f} "
        f"deg  roll {math.degrees(p.roll_rad):.1f} deg  yaw {math.degrees(p.yaw_rad):.1f} deg",
        f"ground grid {args.grid_step_m:g} m, red: base axes, blue: horizon",
    ]
    overlay = calibration_overlay(
        frame, seen, grid_step_m=args.grid_step_m, max_range_m=args.max_range_m, lines=lines
    )
    write_image_atomic(args.output, overlay)  # a failed write keeps the old overlay
    extent = visible_ground_extent(seen, args.max_range_m)
    horizon = seen.horizon_line()
    horizon_v = None
    if horizon is not None and abs(horizon[1]) > 1e-9:
        horizon_v = float(-(horizon[0] * (w - 1) / 2.0 + horizon[2]) / horizon[1])
    out = {
        "overlay": str(args.output),
        "frame_size": [w, h],
        "camera_scaled_from": None if seen is camera else list(camera.image_size),
        "visible_ground_m": None if extent is None else [float(v) for v in extent],
        "horizon_row_at_centre_px": horizon_v,
    }
    if not args.json:
        print(f"wrote {args.output} ({w}x{h})")
        if extent is None:
            print("  no floor in view: the camera looks above the horizon")
        else:
            x0, x1, y0, y1 = extent
            print(f"  floor in view (within {args.max_range_m:g} m): x {x0:.1f}..{x1:.1f} m, "
                  f"y {y0:.1f}..{y1:.1f} m")  # fmt: skip
    return out
