"""`follow-calib ground`: the camera's height, pitch and roll from a board on the floor."""

from __future__ import annotations

import argparse
import logging
import math
from pathlib import Path

from calib.camera_file import write_camera_file, write_image_atomic
from calib.chessboard import ImageInputError
from calib.cmd_common import (
    add_board_arguments,
    image_path,
    read_grey_frames,
    refuse_overwriting_inputs,
    video_source,
)
from calib.ground import average_frames, estimate_ground_pose
from calib.overlay import calibration_overlay
from follow.camera import CameraModel
from follow.cli_args import finite_float
from follow.frames import rotation_2d

log = logging.getLogger(__name__)

# Corners reprojecting worse than this (px RMS) suggest a wrong pattern, intrinsics or a
# board that is not flat: the result is still written, with a warning.
RMS_WARNING_PX = 0.5
# A camera height outside this band is no robot's (0.5-1.5 m is usual): a board size in
# millimetres or centimetres given as metres scales the height with it.
PLAUSIBLE_HEIGHT_M = (0.1, 5.0)
# Images named in an error about their average; the rest are counted.
MAX_IMAGES_NAMED = 5


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "inputs", type=Path, nargs="+",
        help="image(s) of the board lying flat on the floor (several are averaged), or "
        "one video file or camera index (its first --frames frames are averaged)",
    )  # fmt: skip
    parser.add_argument(
        "--camera", type=Path, required=True,
        help="camera file with the intrinsics (from `follow-calib intrinsics`)",
    )  # fmt: skip
    add_board_arguments(parser)
    parser.add_argument(
        "-o", "--output", type=Path,
        help="camera file to write (default: update --camera in place)",
    )  # fmt: skip
    parser.add_argument(
        "--overlay", type=image_path,
        help="overlay PNG to write (default: <output stem>_ground.png next to the output)",
    )  # fmt: skip
    parser.add_argument(
        "--frames", type=int, default=10, help="video frames to average (default 10)"
    )
    parser.add_argument(
        "--board-in-base", type=finite_float, nargs=3, metavar=("X_M", "Y_M", "YAW_DEG"),
        help="where the board lies in `base`: its inner-corner centre and the direction of its "
        "rows (the side with COLS corners; either way along it): also sets the camera's yaw "
        "(the one nearest the file's) and x/y offsets",
    )  # fmt: skip


def _searched_image(inputs: list[Path], frames: list[tuple[str, object]]) -> str:
    """What the board was looked for in, for the error when none is found: the image file,
    or which images or frames were averaged (any of them may lack the board)."""
    source = video_source(inputs)
    if source is not None:
        what = f"camera {source}" if source.isdigit() else source
        return f"the average of the first {len(frames)} frame(s) of {what}"
    names = [name for name, _ in frames]
    if len(names) == 1:
        return names[0]
    listed = ", ".join(names[:MAX_IMAGES_NAMED])
    more = len(names) - MAX_IMAGES_NAMED
    return f"the average of {listed}" + (f" and {more} more image(s)" if more > 0 else "")


def main(args: argparse.Namespace) -> dict:
    output = args.output or args.camera
    overlay_path = args.overlay or output.with_name(output.stem + "_ground.png")
    inputs = {"input": list(args.inputs)}
    if output.resolve() != args.camera.resolve():  # else the camera file is rewritten in place
        inputs["--camera"] = args.camera
    refuse_overwriting_inputs(inputs, {"-o": output, "--overlay": overlay_path})
    camera = CameraModel.load(args.camera)
    if args.frames < 1:
        raise ValueError(f"--frames must be >= 1, got {args.frames}")
    frames = read_grey_frames(args.inputs, limit=args.frames)
    image = average_frames([f for _, f in frames], [name for name, _ in frames])
    h, w = image.shape
    try:
        seen = camera.for_image_size(w, h)
    except ValueError as exc:
        raise ImageInputError(f"image against the camera file {args.camera}: {exc}") from None
    try:
        result = estimate_ground_pose(image, seen.K, seen.dist, args.pattern, args.square_size_m,
                                      image_name=_searched_image(args.inputs, frames))  # fmt: skip
        if args.board_in_base is not None:
            bx, by, byaw_deg = args.board_in_base
            prior = camera.pose.yaw_rad
            pose = result.pose_from_board_in_base((bx, by), math.radians(byaw_deg), prior)
        else:
            old = camera.pose
            pose = result.pose(old.yaw_rad, old.x_m, old.y_m)
    except ValueError as exc:  # the board's scale sets the height: a square in cm is 100x
        if "not a possible mounting" not in str(exc):
            raise
        raise ValueError(f"{exc}; is --square-size-m ({args.square_size_m:g}) the side of "
                         "one square in metres?") from None  # fmt: skip
    calibrated = camera.with_pose(pose)
    notes = {
        "pose": "follow-calib ground",
        "pose_board_rms_px": round(result.reprojection_rms_px, 4),
        "pose_frames_averaged": len(frames),
    }

    # The board's centre in `base`, through the final pose.
    centre_base = rotation_2d(pose.yaw_rad) @ result.board_centre_level_m + [pose.x_m, pose.y_m]
    board_yaw_base = math.degrees(result.board_yaw_level_rad + pose.yaw_rad)
    board_yaw_base = (board_yaw_base + 180.0) % 360.0 - 180.0
    lines = [
        f"height {pose.height_m:.3f} m  pitch {math.degrees(pose.pitch_rad):.2f} deg  "
        f"roll {math.degrees(pose.roll_rad):.2f} deg",
        f"board at x {centre_base[0]:.2f} y {centre_base[1]:.2f} m  "
        f"rms {result.reprojection_rms_px:.2f} px  grid 1 m, red: base axes, blue: horizon",
    ]
    overlay = calibration_overlay(
        image, calibrated.scaled(w, h), result.corners_px, args.pattern, lines=lines
    )
    output.parent.mkdir(parents=True, exist_ok=True)  # the default overlay goes beside it
    write_image_atomic(overlay_path, overlay)  # before the camera file
    write_camera_file(output, calibrated, notes, notes_from=args.camera)  # its intrinsics' notes
    warnings = []
    if result.reprojection_rms_px > RMS_WARNING_PX:
        warnings.append(
            f"board corners reproject with {result.reprojection_rms_px:.2f} px RMS (> "
            f"{RMS_WARNING_PX}): check the intrinsics, the pattern size and that the board is flat"
        )
    low, high = PLAUSIBLE_HEIGHT_M
    if not low <= pose.height_m <= high:
        warnings.append(
            f"camera height {pose.height_m:.3f} m is outside {low:g}-{high:g} m: is "
            f"--square-size-m ({args.square_size_m:g}) the side of one square in metres?"
        )
    for warning in warnings:
        log.warning(warning)
    out = {
        "camera_file": str(output),
        "overlay": str(overlay_path),
        "frames_averaged": len(frames),
        "height_m": pose.height_m,
        "pitch_deg": math.degrees(pose.pitch_rad),
        "roll_deg": math.degrees(pose.roll_rad),
        "yaw_deg": math.degrees(pose.yaw_rad),
        "x_m": pose.x_m,
        "y_m": pose.y_m,
        "board_centre_base_m": centre_base.tolist(),
        "board_yaw_base_deg": board_yaw_base,
        "board_distance_m": result.board_distance_m,
        "reprojection_rms_px": result.reprojection_rms_px,
        "sharpness_px": result.sharpness_px,
        "warnings": warnings,
    }
    if not args.json:
        print(f"wrote {output} and {overlay_path}")
        print(f"  height   {out['height_m']:.3f} m")
        print(f"  pitch    {out['pitch_deg']:.2f} deg (positive: looking down)")
        print(f"  roll     {out['roll_deg']:.2f} deg")
        print(f"  yaw      {out['yaw_deg']:.2f} deg, offsets x {pose.x_m:.3f} y {pose.y_m:.3f} m")
        print(
            f"  board    centre at x {centre_base[0]:.3f} y {centre_base[1]:.3f} m "
            f"({out['board_distance_m']:.2f} m away), rows at {board_yaw_base:.1f} deg"
        )
        width = result.sharpness_px
        edges = f"edge width {width:.2f} px" if math.isfinite(width) else "edge width not measured"
        print(f"  corners  {result.reprojection_rms_px:.3f} px RMS, {edges}, "
              f"{len(frames)} frame(s) averaged")  # fmt: skip
    return out
