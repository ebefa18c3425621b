"""`follow eval ankle-height`: how high over the annotated ground point the detector's
ankle keypoints lie on PETS 2009, and the tracker setting that matches it.

The tracker back-projects an ankle keypoint from a modelled height over the floor
(`[tracker]`: a sole, a share of the neck height, the gait's lift). Where the network
puts the ankle at a given image scale, and what a ground truth calls a person's ground
point, decide what that height should be; with a camera 7 m up, 0.1 m of ankle height
moves a person 25 m away by 0.35 m along the viewing ray. For each detected person whose
neck lies in exactly one annotated, unhidden box, the height at which the ray through
its ankle point passes over that box's ground point is one sample.
"""

from __future__ import annotations

import numpy as np

from follow.cli_args import plot_path
from follow.eval.pets import GT_IMAGE_SIZE
from follow.eval.pets_setup import PetsSetup, add_evaluation_arguments, load_evaluation
from follow.ukf.models import population_ankle_height_m

MAX_HIDDEN_FRACTION = 0.2
RANGE_BINS_M = (0.0, 20.0, 25.0, 30.0, 40.0)


def add_arguments(p) -> None:
    add_evaluation_arguments(p)
    p.add_argument("--plot", type=plot_path, help="write a PNG histogram of the samples here")


def ankle_samples(setup: PetsSetup, frames, skeletons, config) -> tuple[np.ndarray, np.ndarray]:
    """(heights over the ground point, horizontal ranges from the camera) in metres."""
    from follow.pose.observations import skeletons_to_observations

    camera = setup.camera
    centre = camera.position_base  # (x, y, height) of the camera over the floor
    to_gt_px = GT_IMAGE_SIZE[0] / camera.image_size[0]
    heights, ranges = [], []
    for index in frames:
        _, ground, boxes = setup.ground_truth(index, MAX_HIDDEN_FRACTION)
        observations = skeletons_to_observations(skeletons[index], camera.image_size, config.pose)
        for obs in observations:
            if obs.ankle_px is None:
                continue
            neck = obs.neck_px * to_gt_px
            inside = [i for i, b in enumerate(boxes) if b.contains(*neck)]
            if len(inside) != 1:
                continue
            ray = camera.pixel_rays_base(obs.ankle_px[None].astype(float))[0]
            offset = ground[inside[0]] - centre[:2]
            along = offset @ ray[:2] / (ray[:2] @ ray[:2])  # nearest point over the ground point
            heights.append(centre[2] + along * ray[2])
            ranges.append(float(np.linalg.norm(offset)))
    return np.array(heights), np.array(ranges)


def walking_keypoint_height_m(tracker) -> float:
    """The modelled ankle keypoint height of a walking person of the default neck height
    (PETS people walk nearly all the time)."""
    return population_ankle_height_m(tracker) + tracker.walking_ankle_lift_m


def ankle_height_setting(keypoint_height_m: float, tracker) -> float:
    """`[tracker] ankle_height_m` that moves that modelled height to `keypoint_height_m`."""
    return tracker.ankle_height_m + keypoint_height_m - walking_keypoint_height_m(tracker)


def plot(heights: np.ndarray, modelled_m: float, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.hist(heights, bins=np.arange(-0.4, 0.8, 0.02), color="0.6")
    ax.axvline(np.median(heights), color="C3", label=f"median {np.median(heights):.3f} m")
    ax.axvline(modelled_m, color="C0", ls="--", label=f"tracker model {modelled_m:.3f} m")
    ax.set_xlabel("ankle keypoint height over the annotated ground point (m)")
    ax.set_ylabel("detections")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(args) -> dict:
    config, setup, frames, skeletons = load_evaluation(args)
    heights, ranges = ankle_samples(setup, frames, skeletons, config)
    if len(heights) == 0:
        raise ValueError("no detection with an ankle fell inside an annotated box")
    tracker = config.tracker
    median = float(np.median(heights))
    modelled = walking_keypoint_height_m(tracker)
    by_range = []
    for lo, hi in zip(RANGE_BINS_M[:-1], RANGE_BINS_M[1:], strict=True):
        inside = (ranges >= lo) & (ranges < hi)
        if inside.any():
            by_range.append({"range_m": [lo, hi], "samples": int(inside.sum()),
                             "median_m": float(np.median(heights[inside]))})  # fmt: skip
    result = {
        "frames": len(frames),
        "samples": int(len(heights)),
        "median_m": median,
        "quartiles_m": [float(q) for q in np.percentile(heights, [25, 75])],
        "by_range": by_range,
        "modelled_walking_m": modelled,
        "ankle_height_m": round(ankle_height_setting(median, tracker), 3),
    }
    if args.plot:
        plot(heights, modelled, args.plot)
    if not args.json:
        print(f"{len(heights)} detections in {len(frames)} frames: ankle keypoint "
              f"{median:.3f} m over the annotated ground point (quartiles "
              f"{result['quartiles_m'][0]:.3f}-{result['quartiles_m'][1]:.3f}); "
              f"the tracker models {modelled:.3f} m for a walking person")  # fmt: skip
        for row in by_range:
            lo, hi = row["range_m"]
            print(f"  {lo:4.0f}-{hi:<4.0f} m  {row['samples']:5d}  {row['median_m']:.3f} m")
        print(f"setting that matches: [tracker] ankle_height_m = {result['ankle_height_m']}")
    return result
