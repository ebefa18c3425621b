"""`follow-calib import-tsai`: a Tsai calibration (PETS 2009 XML) to a camera file."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from calib.camera_file import without_typed_file_advice, write_camera_file
from calib.cmd_common import refuse_overwriting_inputs
from calib.gt_boxes import motion_figures, read_boxes
from calib.tsai import CHECK_GRID_DIVISOR, MAX_GRID_POINTS, TsaiCamera, TsaiFileError
from follow.camera import CameraModel
from follow.cli_args import finite_float, positive_float

# A converted camera further than this from the Tsai model anywhere in the image is not
# written: OpenCV's k1, k2, k3 cannot follow that lens (PETS 2009 view 1: 0.0015 px).
MAX_DISCREPANCY_PX = 1.0
DEFAULT_ANNOTATION_FPS = 7.0  # PETS 2009 S2.L1's
# The finest --grid-step-px: Tsai's distortion is smooth, so pixels closer than one add
# nothing to the fit, while the grid grows as the inverse square of the step.
MIN_GRID_STEP_PX = 1.0


def grid_step_px(text: str) -> float:
    """An argparse type: a grid step of at least MIN_GRID_STEP_PX pixels."""
    value = finite_float(text)
    if not value >= MIN_GRID_STEP_PX:
        raise argparse.ArgumentTypeError(
            f"expected a number of pixels >= {MIN_GRID_STEP_PX:g} (a finer grid adds nothing "
            f"to the fit), got {text!r}"
        )
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("tsai_xml", type=Path, help="Tsai calibration XML (world units mm)")
    parser.add_argument(
        "-o", "--output", type=Path, default=Path("camera.yaml"),
        help="camera file to write (.yaml/.yml or .json; default camera.yaml)",
    )  # fmt: skip
    parser.add_argument(
        "--grid-step-px", type=grid_step_px, default=8.0,
        help=f"pixel spacing of the grid the distortion is fitted on, at least "
        f"{MIN_GRID_STEP_PX:g} (default 8)",
    )  # fmt: skip
    parser.add_argument(
        "--boxes", type=Path,
        help="optional person-box annotation XML (PETS style): report the median walking "
        "speed and stature it implies through the converted camera, as a sanity check",
    )  # fmt: skip
    parser.add_argument(
        "--fps", type=positive_float, default=None,
        help="with --boxes: frame rate of the annotation (default 7)",
    )  # fmt: skip


def _refuse_too_fine_a_grid(tsai: TsaiCamera, path: Path, step_px: float) -> None:
    """Refuse, naming the option, a step whose checking grid (the finer one) would hold
    more than MAX_GRID_POINTS pixels of this image: numpy would run out of memory."""
    count = tsai.grid_point_count(step_px / CHECK_GRID_DIVISOR)
    if count > MAX_GRID_POINTS:
        w, h = tsai.image_size
        raise ValueError(
            f"--grid-step-px {step_px:g} is too fine for the {w}x{h} image of {path}: the "
            f"conversion would be checked at {count:.3g} pixels, more than "
            f"{MAX_GRID_POINTS:.3g}; give a larger step"
        )


def _convert(tsai: TsaiCamera, path: Path, step_px: float) -> tuple[CameraModel, float]:
    """The camera file's model of `tsai` and its discrepancy (px); TsaiFileError naming
    the Tsai file where its values make a camera that `follow` cannot use (a focal length
    or principal point typed wrong): the user wrote no camera_matrix to check."""
    try:
        model, discrepancy_px = tsai.to_camera_model(step_px=step_px)
        CameraModel.from_dict(model.to_dict(), source=str(path))  # as follow will read it
    except ValueError as exc:
        reason = without_typed_file_advice(str(exc).removeprefix(f"{path}: "))
        raise TsaiFileError(
            f"Tsai file {path}: its values make a camera follow cannot use: {reason}; "
            f"check {_fields_behind(reason)}"
        ) from None
    return model, discrepancy_px


def _fields_behind(reason: str) -> str:
    """Which of the Tsai file's values make the part of the camera `reason` refuses."""
    if reason.startswith("camera pose"):
        return "<Extrinsic> (world in mm, z up)"
    if reason.startswith("camera distortion"):
        return "<Intrinsic> kappa1"
    return (
        "<Geometry> dpx, dpy, width, height and <Intrinsic> focal, sx, cx, cy (fx = "
        "focal sx / dpx, fy = focal / dpy, principal point (cx, cy))"
    )


def main(args: argparse.Namespace) -> dict:
    if args.fps is not None and args.boxes is None:
        raise ValueError("--fps is the frame rate of the --boxes annotation: give --boxes too, "
                         "or leave it out")  # fmt: skip
    args.fps = DEFAULT_ANNOTATION_FPS if args.fps is None else args.fps
    refuse_overwriting_inputs({"Tsai file": args.tsai_xml, "--boxes": args.boxes},
                              {"-o": args.output})  # fmt: skip
    tsai = TsaiCamera.from_xml(args.tsai_xml)
    # Read before the camera file is written: a bad box file must not cost the old one.
    boxes = read_boxes(args.boxes) if args.boxes is not None else None
    _refuse_too_fine_a_grid(tsai, args.tsai_xml, args.grid_step_px)
    model, discrepancy_px = _convert(tsai, args.tsai_xml, args.grid_step_px)
    if not discrepancy_px <= MAX_DISCREPANCY_PX:  # NaN too
        raise ValueError(
            f"Tsai file {args.tsai_xml}: the converted camera is {discrepancy_px:.3g} px off "
            f"the Tsai model in places (more than {MAX_DISCREPANCY_PX:g} px): OpenCV's radial "
            f"distortion cannot follow kappa1 = {tsai.kappa1_per_mm2:g} over the whole image; "
            "no camera file written"
        )
    notes = {
        "intrinsics": f"follow-calib import-tsai {args.tsai_xml.name}",
        "pose": f"follow-calib import-tsai {args.tsai_xml.name}",
        "tsai_max_discrepancy_px": round(discrepancy_px, 5),
        "frame": "base is the calibration's world frame (m, z up, ground z = 0)",
    }
    write_camera_file(args.output, model, notes, keep_notes=False)  # all of it is new
    p = model.pose
    result = {
        "camera_file": str(args.output),
        "image_size": list(model.image_size),
        "fx_px": model.K[0, 0],
        "fy_px": model.K[1, 1],
        "cx_px": model.K[0, 2],
        "cy_px": model.K[1, 2],
        "distortion": model.dist.tolist(),
        "height_m": p.height_m,
        "pitch_deg": math.degrees(p.pitch_rad),
        "roll_deg": math.degrees(p.roll_rad),
        "yaw_deg": math.degrees(p.yaw_rad),
        "x_m": p.x_m,
        "y_m": p.y_m,
        "max_discrepancy_px": discrepancy_px,
    }
    if boxes is not None:
        result["tsai"] = motion_figures(tsai, boxes, args.fps)
        result["converted"] = motion_figures(model, boxes, args.fps)
    if not args.json:
        print(f"wrote {args.output}")
        print(f"  image            {model.image_size[0]} x {model.image_size[1]} px")
        print(f"  focal            fx {model.K[0, 0]:.2f}  fy {model.K[1, 1]:.2f} px")
        print(f"  principal point  {model.K[0, 2]:.2f}, {model.K[1, 2]:.2f} px")
        print("  distortion       " + " ".join(f"{v:+.5f}" for v in model.dist))
        print(
            f"  pose             height {p.height_m:.3f} m  pitch {result['pitch_deg']:.2f} deg"
            f"  roll {result['roll_deg']:.2f} deg  yaw {result['yaw_deg']:.2f} deg"
            f"  at x {p.x_m:.3f} y {p.y_m:.3f} m"
        )
        print(f"  largest discrepancy between the two models over the image: "
              f"{discrepancy_px:.4f} px")  # fmt: skip
        if boxes is not None:
            for name in ("tsai", "converted"):
                f = result[name]
                print(
                    f"  {name:<9} model: {f['boxes']} boxes, median walking speed "
                    f"{f['median_walking_speed_mps']:.3f} m/s, median stature "
                    f"{f['median_stature_m']:.3f} m"
                )
    return result
