#!/usr/bin/env python3
"""Could the head's colours tell a stranger in the target's clothes apart? A measurement.

The simulated twin of `follow eval identification-sim` wears the target's shirt and
trousers and differs only above the neck. This computes a head part the way
`follow/identify/parts.py` computes the torso and the legs (its coarse colour histogram,
over the crop from its top to just above the neck row of `body_rows`, the middle 40 %
of the width) and prints the Hellinger distances of real people's heads (CUHK03: one
person by the same camera, by the other camera, two people; the robot-camera crops:
the target's later views and the two hard negatives against its first five) beside the
twin's head against the target's, rendered where the target stood:

    python tools/head_colours.py [--data-dir D] [--json]

Nothing is written; no identifier rule uses the head (docs/identification.md says why).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
from pathlib import Path

import cv2
import numpy as np

QUANTILES = (0.5, 0.9, 0.95, 0.99)
CROP_SIZE = (64, 128)  # width, height: the identifier's crop shape
HEAD_COLUMNS = (0.3, 0.7)
ROBOT_ENROL = 5
OTHERS_SAMPLE = 0.05  # of the CUHK03 pairs of two people, drawn with a fixed seed


def head_histogram(crop_bgr: np.ndarray) -> np.ndarray:
    """The head part's colour histogram of a crop cut as the identifier cuts it."""
    from follow.ccf.roi import body_rows
    from follow.config import IdentifyConfig
    from follow.identify.parts import _histograms

    crop = cv2.resize(crop_bgr, CROP_SIZE)
    height, width = crop.shape[:2]
    neck = body_rows(IdentifyConfig())[0]
    top, bottom = int(0.02 * height), max(int(0.02 * height) + 1, int((neck - 0.01) * height))
    left, right = int(HEAD_COLUMNS[0] * width), int(HEAD_COLUMNS[1] * width)
    band = np.ascontiguousarray(crop[top:bottom, left:right])
    return _histograms(cv2.cvtColor(band, cv2.COLOR_BGR2HSV).reshape(1, -1, 3))[0]


def distance(a: np.ndarray, b: np.ndarray) -> float:
    """The parts' Hellinger distance (`colour_distances`) between two head histograms."""
    from follow.identify.parts import colour_distances

    return float(colour_distances(a[None, None], b[None, None])[0, 0, 0])


def cuhk03_distances(folder: Path) -> dict[str, list[float]]:
    heads = {}
    for path in sorted(folder.glob("*.jpg")):
        person, view = path.stem.split("_")
        heads[(person, int(view))] = head_histogram(cv2.imread(str(path)))
    rng = np.random.default_rng(0)
    out: dict[str, list[float]] = {"same camera": [], "other camera": [], "two people": []}
    for a, b in itertools.combinations(sorted(heads), 2):
        if a[0] == b[0]:
            same_camera = (a[1] < 5) == (b[1] < 5)  # views 00-04 camera A, 05-09 camera B
            out["same camera" if same_camera else "other camera"].append(
                distance(heads[a], heads[b])
            )
        elif rng.random() < OTHERS_SAMPLE:
            out["two people"].append(distance(heads[a], heads[b]))
    return out


def robot_crop_distances(folder: Path) -> dict[str, list[float]]:
    target = [head_histogram(cv2.imread(str(p))) for p in sorted(folder.glob("p*.jpg"))]
    others = [head_histogram(cv2.imread(str(p))) for p in sorted(folder.glob("n*.jpg"))]
    enrolled = target[:ROBOT_ENROL]

    def nearest(h):
        return min(distance(h, e) for e in enrolled)

    return {"target's later views": [nearest(h) for h in target[ROBOT_ENROL:]],
            "hard negatives": [nearest(h) for h in others]}  # fmt: skip


def simulated_heads(look, from_y_m: float) -> list[np.ndarray]:
    """Head histograms of a person in `look` walking in from the side to where the
    stranger scenario's people stand, and standing there."""
    from follow.ccf.roi import roi_from_keypoints
    from follow.config import IdentifyConfig
    from follow.sim.appearance import render_scene
    from follow.sim.demo import DEMO_CAMERA, horizon_row, person_views
    from follow.sim.people import Walker
    from follow.sim.world import World
    from follow.types import Odometry

    camera = DEMO_CAMERA.detection_camera()
    walker = Walker(1, 1.74, np.array([[3.0, from_y_m], [3.0, 0.0], [3.0, -from_y_m]]),
                    pauses_s=np.array([5.0, 0.0]))  # fmt: skip
    world = World([walker], camera=DEMO_CAMERA, seed=0)
    out = []
    for k in range(int(6.0 / world.dt_s)):
        frame = world.step()
        if k % 10:
            continue
        views = person_views(frame, Odometry.origin(), camera, {1: look})
        if not views:
            continue
        image = render_scene(camera.image_size, horizon_row(camera), views, seed=0)
        kp = views[0].keypoints_px
        roi = roi_from_keypoints(
            kp[1], 0.5 * (kp[10] + kp[13]), camera.image_size, IdentifyConfig()
        )
        if roi is not None:
            x0, y0, x1, y1 = roi
            out.append(head_histogram(image[y0:y1, x0:x1]))
    return out


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data-dir", default=os.environ.get("FOLLOW_DATA_DIR"),
                   help="the shared data folder (default $FOLLOW_DATA_DIR)")  # fmt: skip
    p.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    args = p.parse_args(argv)
    if not args.data_dir:
        sys.exit("head_colours: give --data-dir or set FOLLOW_DATA_DIR")
    data = Path(args.data_dir)
    from follow.eval.strangers import TWIN
    from follow.sim.demo import TARGET_LOOK

    target = simulated_heads(TARGET_LOOK, 3.0)
    twin = simulated_heads(TWIN, -3.0)
    rows = {**{f"CUHK03, {k}": v for k, v in cuhk03_distances(data / "cuhk03_val").items()},
            **{f"robot crops, {k}": v for k, v in robot_crop_distances(data / "ccf_crops").items()},
            "simulation, twin to target": [min(distance(t, s) for s in target) for t in twin]}  # fmt: skip
    out = {name: {"pairs": len(v), "quantiles": [round(float(q), 3) for q in np.quantile(v, QUANTILES)]}
           for name, v in rows.items()}  # fmt: skip
    if args.json:
        print(json.dumps(out))
    else:
        print(
            f"{'pairs':<40} {'n':>6}  Hellinger distance at "
            + " / ".join(f"{q:.0%}" for q in QUANTILES)
        )
        for name, r in out.items():
            print(f"{name:<40} {r['pairs']:>6}  " + " / ".join(f"{q:.2f}" for q in r["quantiles"]))
    return out


if __name__ == "__main__":
    main()
