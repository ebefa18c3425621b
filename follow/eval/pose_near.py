"""`follow eval pose-near`: the skeleton detector on people seen large, as a following
robot sees them.

PETS 2009 shows people 35-95 px tall; a robot 1.5-4 m behind its target sees them
several times larger. This pastes the 42 real person crops of `ccf_crops/` (about 128 px
tall, tightly cut) at a given height into the middle of a grey 640x480 frame and counts
the crops whose neck the detector finds in the upper 40 % of the person and whose ankle
it finds in the lower quarter, for each network input height and stage count, and the
skeletons beyond the first whose neck lies on the person (duplicates: one body must
give one skeleton, or the tracker makes a ghost track of the second). The grey
surround is plainer than a real scene, so the rates are an upper bound on clutter but a
fair comparison between settings.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np

from follow.cli_args import int_at_least, non_negative_int
from follow.eval.pose import input_height
from follow.pose.preprocess import NETWORK_STRIDE_PX

FRAME_SIZE = (640, 480)
NECK_ZONE = 0.4  # upper share of the person where the neck must lie
ANKLE_ZONE = 0.75  # the ankle must lie below this share of the person's height
MIN_PERSON_HEIGHT_PX = 16  # two cells of the network's stride: smaller is no person to it


def add_arguments(p) -> None:
    p.add_argument("--person-heights", type=int_at_least(MIN_PERSON_HEIGHT_PX), nargs="+",
                   default=[192, 320, 432],
                   help="heights in px the crops are scaled to (frame 640x480)")  # fmt: skip
    p.add_argument("--sizes", type=input_height, nargs="+", default=[256, 368, 576],
                   help="network input heights in px (multiples of 8)")  # fmt: skip
    p.add_argument("--stages", type=int, nargs="+", default=[1, 2], help="network_stages")
    p.add_argument("--config", help="TOML configuration (pose settings)")
    p.add_argument(
        "--crops-dir", help="folder of person crops (default $FOLLOW_DATA_DIR/ccf_crops)"
    )
    p.add_argument("--max-crops", type=non_negative_int, default=0,
                   help="use at most this many crops, evenly spaced in name order (0 = all)")
    p.add_argument("--cut-bottom", type=cut_share, default=0.0,
                   help="share of each person's height placed below the frame's bottom edge "
                        "(feet out of view, as a near person is seen; default 0)")  # fmt: skip
    p.add_argument("--cut-top", type=cut_share, default=0.0,
                   help="share of each person's height placed above the frame's top edge "
                        "(head out of view; default 0)")  # fmt: skip
    p.add_argument("--variants", default="original",
                   help="comma-separated pixel changes of the perturbation suite to apply to "
                        "the frames (docs/robustness.md; default original)")  # fmt: skip


def cut_share(text: str) -> float:
    """A share of a person's height in [0, 0.5), for --cut-bottom and --cut-top."""
    import argparse

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0.0 <= value < 0.5:
        raise argparse.ArgumentTypeError(f"must be at least 0 and under 0.5, got {text}")
    return value


def crop_files(given: str | None, max_crops: int = 0) -> list[Path]:
    """The .jpg crops in the folder (`follow eval crops`'s folder by default): all, or
    `max_crops` of them evenly spaced in name order (a large folder such as CUHK03's)."""
    from follow.eval.crops import default_crops_dir

    folder = Path(given) if given else default_crops_dir()
    crops = sorted(folder.glob("*.jpg"))
    if not crops:
        raise ValueError(f"no .jpg person crops in {folder}")
    if max_crops < 0:
        raise ValueError(f"--max-crops must be >= 0, got {max_crops}")
    if 0 < max_crops < len(crops):
        picks = np.linspace(0, len(crops) - 1, max_crops).round().astype(int)
        crops = [crops[i] for i in picks]
    return crops


def frames_with_people(crop_paths, person_height_px: int, cut_bottom: float = 0.0,
                       cut_top: float = 0.0):  # fmt: skip
    """(frame, (x0, y0, w, h)) with each crop scaled to the height, centred; or, with a
    cut, placed with that share of its height beyond the frame's bottom (`cut_bottom`) or
    top (`cut_top`) edge, `y0` then lying beyond the frame."""
    width, height = FRAME_SIZE
    if cut_bottom and cut_top:
        raise ValueError("a person can be cut at the bottom or at the top, not both")
    shown_px = person_height_px * (1.0 - cut_bottom - cut_top)
    if not 0 < person_height_px or shown_px > height - (0 if cut_bottom or cut_top else 16):
        raise ValueError(f"person height {person_height_px} px does not fit a {height} px frame")
    out = []
    for path in crop_paths:
        crop = cv2.imread(str(path))
        if crop is None:
            raise ValueError(f"cannot read {path}")
        scale = person_height_px / crop.shape[0]
        crop = cv2.resize(crop, None, fx=scale, fy=scale, interpolation=cv2.INTER_CUBIC)
        h, w = crop.shape[:2]
        frame = np.full((height, width, 3), 128, np.uint8)
        x0 = (width - w) // 2
        if cut_bottom:
            y0 = height - int(round(h * (1.0 - cut_bottom)))
        elif cut_top:
            y0 = -int(round(h * cut_top))
        else:
            y0 = (height - h) // 2
        top, bottom = max(y0, 0), min(y0 + h, height)
        frame[top:bottom, x0 : x0 + w] = crop[top - y0 : bottom - y0]
        out.append((frame, (x0, y0, w, h)))
    return out


def observations_on_person(observations, box) -> list:
    """The observations whose neck lies on the person of `box` (x0, y0, w, h): within its
    width, in the upper NECK_ZONE of its height."""
    x0, y0, w, h = box
    return [o for o in observations
            if x0 <= o.neck_px[0] <= x0 + w and y0 <= o.neck_px[1] <= y0 + NECK_ZONE * h]  # fmt: skip


def ankle_found(on_person, box) -> bool:
    """Whether one of the person's observations has its ankle in the lower part of `box`."""
    _, y0, _, h = box
    return any(o.ankle_px is not None and o.ankle_px[1] >= y0 + ANKLE_ZONE * h for o in on_person)


def detection_rates(detector, frames) -> tuple[float, float, float, float | None]:
    """(share with the neck found, share with neck and ankle found, extra skeletons
    on the person per person, median height of the found ankles over the frame's bottom
    edge in heatmap cells (None when none was found): 0.5 is the centre of the last row,
    where the network puts the ankles of feet below the frame)."""
    from tqdm import tqdm

    from follow.pose.observations import skeletons_to_observations

    necks = ankles = extra = 0
    over_edge_cells = []
    for frame, box in tqdm(frames, desc=f"pose-near h={detector.config.input_height_px}",
                           unit="frame", leave=False):  # fmt: skip
        observations = skeletons_to_observations(detector.detect(frame), FRAME_SIZE,
                                                 detector.config)  # fmt: skip
        on_person = observations_on_person(observations, box)
        necks += bool(on_person)
        extra += max(len(on_person) - 1, 0)
        ankles += ankle_found(on_person, box)
        cell_px = NETWORK_STRIDE_PX * FRAME_SIZE[1] / detector.last_input_height_px
        over_edge_cells += [(FRAME_SIZE[1] - 0.5 - o.ankle_px[1]) / cell_px
                            for o in on_person[:1] if o.ankle_px is not None]  # fmt: skip
    median = float(np.median(over_edge_cells)) if over_edge_cells else None
    return necks / len(frames), ankles / len(frames), extra / len(frames), median


def main(args) -> dict:
    from follow.config import Config
    from follow.eval.perturb import selected_pixel_variants
    from follow.pose.detector import PoseDetector

    config = Config.load(args.config) if args.config else Config()
    crop_paths = crop_files(args.crops_dir, args.max_crops)
    variants = selected_pixel_variants(args, "pose-near")
    rows = []
    for person_px in args.person_heights:
        pasted = frames_with_people(crop_paths, person_px, args.cut_bottom, args.cut_top)
        for v in variants:
            frames = [(v.apply(frame, i), box) for i, (frame, box) in enumerate(pasted)]
            for stages in args.stages:
                for size in args.sizes:
                    # each frame at the size measured (unrelated frames, in no order)
                    pose = dataclasses.replace(config.pose, input_height_px=size,
                                               network_stages=stages, warmup_runs=0,
                                               input_height_from_people=False)  # fmt: skip
                    neck, ankle, dup, over_edge = detection_rates(PoseDetector(pose), frames)
                    rows.append({"person_px": person_px,
                                 "person_input_px": round(person_px * size / FRAME_SIZE[1], 1),
                                 "variant": v.name, "cut_bottom": args.cut_bottom,
                                 "cut_top": args.cut_top,
                                 "network_stages": stages, "input_height_px": size,
                                 "neck": neck, "ankle": ankle,
                                 "duplicates_per_person": dup,
                                 "ankle_over_bottom_edge_cells": over_edge})  # fmt: skip
    if not args.json:
        cut = (f", {args.cut_bottom:.0%} of each below its bottom edge" if args.cut_bottom else
               f", {args.cut_top:.0%} of each above its top edge" if args.cut_top else "")
        print(f"{len(crop_paths)} real person crops pasted into a 640x480 frame{cut}")
        print(f"{'person px':>9s} {'in input':>8s} {'variant':>12s} {'stages':>6s} "
              f"{'input':>5s} {'neck':>6s} {'ankle':>6s} {'dup':>5s} {'ankle over edge':>15s}")  # fmt: skip
        for r in rows:
            over = r["ankle_over_bottom_edge_cells"]
            over = "-" if over is None else f"{over:.2f} cells"
            print(f"{r['person_px']:9d} {r['person_input_px']:8.0f} {r['variant']:>12s} "
                  f"{r['network_stages']:6d} {r['input_height_px']:5d} {r['neck']:6.2f} "
                  f"{r['ankle']:6.2f} {r['duplicates_per_person']:5.2f} {over:>15s}")  # fmt: skip
    return {"crops": len(crop_paths), "rows": rows}
