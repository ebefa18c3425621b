"""`follow-calib intrinsics`: camera matrix and distortion from chessboard views."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np

from calib import intrinsics as intr
from calib.camera_file import write_camera_file
from calib.chessboard import ImageInputError, iter_video_frames, list_inputs, read_image
from calib.cmd_common import (
    add_board_arguments,
    refuse_overwriting_inputs,
    refuse_videos_among_images,
    video_source,
)
from follow.camera import (
    PLACEHOLDER_POSE_NOTE,
    CameraFileError,
    CameraModel,
    CameraPose,
    has_placeholder_pose,
    is_placeholder_note,
    read_calibration_notes,
)
from follow.cli_args import non_negative_float, positive_float, refuse_unwritable

log = logging.getLogger(__name__)

DEFAULT_EVERY = 5  # a video's frames used: every 5th (the next ones show the same view)
# A new camera file needs some pose; this one is a placeholder until `ground` measures it.
PLACEHOLDER_HEIGHT_M = 1.0
# The note on a measured pose kept under new intrinsics: `follow` takes it as unmeasured.
STALE_POSE_NOTE = "placeholder: measured through earlier intrinsics; re-run `follow-calib ground`"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "inputs", type=Path, nargs="+",
        help="folder(s) or files of chessboard images, or one video file (or camera index)",
    )  # fmt: skip
    add_board_arguments(parser)
    parser.add_argument(
        "-o", "--output", type=Path, default=Path("camera.yaml"),
        help="camera file to write; an existing one keeps its pose (default camera.yaml)",
    )  # fmt: skip
    parser.add_argument(
        "--every", type=int, default=None, help="video: use every N-th frame (default 5)"
    )
    parser.add_argument(
        "--max-views", type=int, default=60,
        help="at most this many screened views go into the calibration (default 60); a "
        "camera is read until it has given this many",
    )  # fmt: skip
    parser.add_argument(
        "--max-edge-width-px", type=positive_float, default=intr.MAX_EDGE_WIDTH_PX,
        help="reject views whose board edges are wider (blurred) than this "
        f"(default {intr.MAX_EDGE_WIDTH_PX})",
    )  # fmt: skip
    parser.add_argument(
        "--duplicate-fraction", type=non_negative_float, default=intr.DUPLICATE_FRACTION,
        help="reject a view whose corners moved less than this fraction of the image diagonal "
        f"from a kept view (default {intr.DUPLICATE_FRACTION})",
    )  # fmt: skip
    parser.add_argument(
        "--distortion-model", choices=sorted(intr.DISTORTION_FLAGS), default="standard",
        help="radial: k1 k2 k3; standard: k1 k2 p1 p2 k3 (default); rational: 8 coefficients",
    )  # fmt: skip


def _image_files(inputs: list[Path]) -> list[Path] | None:
    """The image files of `inputs` (folders listed), or None for one video or camera."""
    if video_source(inputs) is not None:
        return None
    paths = list_inputs(inputs)
    refuse_videos_among_images(paths)
    return paths


def _frames(args: argparse.Namespace, paths: list[Path] | None, unreadable: list[tuple[str, str]]):
    """(name, image) of the inputs; unreadable image files are noted and skipped."""
    if paths is None:
        yield from iter_video_frames(video_source(args.inputs), every=args.every)
        return
    for path, label in zip(paths, view_labels(paths), strict=True):
        try:
            yield label, read_image(path)
        except ImageInputError as exc:
            log.warning("%s (skipped)", exc)
            unreadable.append((label, str(exc)))


def view_labels(paths: list[Path]) -> list[str]:
    """Each image's name in the report: its file name, or its path where two inputs share
    a file name (views are reported, and counted in the camera file, by this label)."""
    names = [p.name for p in paths]
    return [p.name if names.count(p.name) == 1 else str(p) for p in paths]


def _camera_to_keep(output: Path) -> CameraModel | None:
    """The existing camera file at `output`, whose pose is kept (only the intrinsics
    change), or None for a new file. A file that exists but cannot be read is refused
    before the calibration runs: writing over it would lose a measured pose."""
    if not output.exists():
        return None
    try:
        return CameraModel.load(output)
    except CameraFileError as exc:
        raise ValueError(
            f"{exc}; -o {output} exists but cannot be read, and writing the intrinsics over "
            "it would lose its pose: mend it, move it away, or give another -o"
        ) from exc


def _stale_pose_warning(output: Path, old: CameraModel, new: CameraModel) -> str | None:
    """A warning where `old`'s pose was measured by a tool through intrinsics that `new`
    replaces (`ground` solves it through K and the distortion: with new ones it is off),
    else None. A pose without a note was set by hand, and is no less right now."""
    note = read_calibration_notes(output).get("pose")
    same = (
        np.array_equal(old.K, new.K)
        and np.array_equal(old.dist, new.dist)
        and old.image_size == new.image_size
    )
    if note is None or is_placeholder_note(note) or same:
        return None
    return (
        f"{output}: its pose ({note}) was measured through the earlier camera matrix and "
        "distortion: it is kept, marked a placeholder (no base is driven on it); re-run "
        "`follow-calib ground`"
    )


def main(args: argparse.Namespace) -> dict:
    if args.every is not None and video_source(args.inputs) is None:
        raise ValueError("--every picks frames of a video or camera; image files are each "
                         "one view: leave it out")  # fmt: skip
    args.every = DEFAULT_EVERY if args.every is None else args.every
    if args.every < 1 or args.max_views < intr.MIN_VIEWS:
        raise ValueError(
            f"--every must be >= 1 and --max-views >= {intr.MIN_VIEWS}, "
            f"got {args.every} and {args.max_views}"
        )
    refuse_overwriting_inputs({"input": list(args.inputs)}, {"-o": args.output})
    paths = _image_files(args.inputs)
    camera_index = paths is None and video_source(args.inputs).isdigit()
    old = _camera_to_keep(args.output)
    refuse_unwritable(args.output, "-o")
    unreadable: list[tuple[str, str]] = []
    try:
        result = intr.calibrate_intrinsics(
            _frames(args, paths, unreadable),
            args.pattern,
            args.square_size_m,
            distortion_model=args.distortion_model,
            max_edge_width_px=args.max_edge_width_px,
            duplicate_fraction=args.duplicate_fraction,
            max_views=args.max_views,
            stop_at_views=args.max_views if camera_index else None,
            progress=not args.json,
        )
    except intr.CalibrationError as exc:
        if not unreadable:
            raise
        reasons = "; ".join(reason for _, reason in unreadable[:10])
        more = f" and {len(unreadable) - 10} more" if len(unreadable) > 10 else ""
        raise intr.CalibrationError(
            f"{exc}; {len(unreadable)} unreadable file(s): {reasons}{more}"
        ) from None
    notes = {
        "intrinsics": "follow-calib intrinsics",
        "intrinsics_rms_px": round(result.rms_px, 4),
        "intrinsics_views": result.views_used,
        "intrinsics_coverage": round(result.coverage_fraction, 3),
    }
    pose_kept = old is not None
    pose = old.pose if pose_kept else CameraPose(PLACEHOLDER_HEIGHT_M)
    model = CameraModel(result.K, result.dist, result.image_size, pose)
    warnings = list(result.warnings)
    if not pose_kept:
        notes["pose"] = PLACEHOLDER_POSE_NOTE  # `follow run` drives no base on it
    elif stale := _stale_pose_warning(args.output, old, model):
        warnings.append(stale)
        notes["pose"] = STALE_POSE_NOTE
    write_camera_file(args.output, model, notes)
    out = {
        "camera_file": str(args.output),
        "image_size": list(result.image_size),
        "fx_px": result.K[0, 0],
        "fy_px": result.K[1, 1],
        "cx_px": result.K[0, 2],
        "cy_px": result.K[1, 2],
        "distortion": result.dist.tolist(),
        "rms_px": result.rms_px,
        "views_used": result.views_used,
        "per_view_rms_px": result.per_view_rms_px,
        "rejected": [{"view": n, "reason": r} for n, r in unreadable + result.rejected],
        "coverage_fraction": result.coverage_fraction,
        "uncovered_regions": result.uncovered_regions,
        "pose_kept": pose_kept,
        "pose_placeholder": has_placeholder_pose(args.output),
        "warnings": warnings,
    }
    if not args.json:
        placeholder = " (pose is a placeholder)" if out["pose_placeholder"] else ""
        print(f"wrote {args.output}{placeholder}")
        print(f"  image       {result.image_size[0]} x {result.image_size[1]} px")
        print(f"  focal       fx {result.K[0, 0]:.2f}  fy {result.K[1, 1]:.2f} px")
        print(f"  principal   {result.K[0, 2]:.2f}, {result.K[1, 2]:.2f} px")
        print("  distortion  " + " ".join(f"{v:+.5f}" for v in result.dist))
        print(f"  RMS         {result.rms_px:.3f} px over {result.views_used} views, "
              f"coverage {100 * result.coverage_fraction:.0f}%")  # fmt: skip
        print("  per view RMS (px):")
        worst = float(np.max(list(result.per_view_rms_px.values())))
        for name, rms in result.per_view_rms_px.items():
            flag = "  <- worst" if rms == worst else ""
            print(f"    {name:<32} {rms:.3f}{flag}")
        if unreadable or result.rejected:
            print("  rejected:")
            for name, reason in unreadable + result.rejected:
                print(f"    {name:<32} {reason}")
        for warning in warnings:
            print(f"  warning: {warning}")
    return out
