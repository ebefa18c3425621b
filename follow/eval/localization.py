"""`follow eval localization`: ground-plane position error against distance, simulated.

The set-up is the localisation experiment of Koide et al.: a camera 0.6 m over the
floor with a 70 deg horizontal field of view, 1920x1080 images on which the skeleton
detector runs at 1/3 scale, 15 frames per second, people walking 2-25 m away. The
synthetic detector's noise is fixed (not tuned): 2 px on the neck and 3 px on each
ankle at the detector's resolution, on top of the gait's ankle motion, 5 % of keypoints
missed, ankles lost outside the image. Each confirmed track updated in a frame is scored
against the person its observation came from; the no-filter baseline is scored on every
observation with an ankle.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from follow.cli_args import non_negative_int, plot_path, positive_float
from follow.config import TrackerConfig
from follow.sim.people import random_walker
from follow.sim.skeletons import DetectorNoiseConfig, SyntheticDetector, observations_with_ids
from follow.sim.world import SimCameraConfig, World
from follow.ukf.direct import DirectBaseline
from follow.ukf.tracker import PeopleTracker

BINS_M = ((2, 5), (5, 10), (10, 15), (15, 20), (20, 25))
PEOPLE_RANGE_M = (2.0, 25.0)
PEOPLE_BEARING_RAD = (-0.5, 0.5)


@dataclass
class LocalizationSamples:
    """Errors (m) against the true distance from the camera (m), per method."""

    ukf_distance_m: list[float] = field(default_factory=list)
    ukf_error_m: list[float] = field(default_factory=list)
    direct_distance_m: list[float] = field(default_factory=list)
    direct_error_m: list[float] = field(default_factory=list)


def simulate(
    seed: int = 0,
    duration_s: float = 60.0,
    num_people: int = 6,
    tracker_config: TrackerConfig | None = None,
    camera: SimCameraConfig | None = None,
    noise: DetectorNoiseConfig | None = None,
    progress: bool = False,
) -> LocalizationSamples:
    """Run the world, the synthetic detector, the tracker and the baseline; collect errors."""
    camera = camera if camera is not None else SimCameraConfig()
    noise = noise if noise is not None else DetectorNoiseConfig()
    rng = np.random.default_rng(seed)
    walkers = [
        random_walker(i + 1, rng, duration_s, PEOPLE_RANGE_M, PEOPLE_BEARING_RAD)
        for i in range(num_people)
    ]
    world = World(walkers, camera, seed=seed)
    det_camera = camera.detection_camera()
    detector = SyntheticDetector(det_camera, noise, seed=seed + 1)
    tracker = PeopleTracker(det_camera, tracker_config)
    direct = DirectBaseline(det_camera, tracker_config)
    out = LocalizationSamples()
    n_frames = int(round(duration_s * camera.fps))
    frames = world.run(n_frames)
    if progress:
        frames = tqdm(frames, total=n_frames, desc="localization", unit="frame", leave=False)
    for frame in frames:
        observations, ids = observations_with_ids(detector.detect(frame))
        truth = {p.person_id: p for p in frame.people}
        robot_xy = np.array([frame.robot.x_m, frame.robot.y_m])
        owner = {id(o.skeleton): pid for o, pid in zip(observations, ids, strict=True)}
        for state in tracker.update(observations, frame.stamp_s, frame.odometry):
            if not state.confirmed or state.observation is None:
                continue
            person = truth[owner[id(state.observation.skeleton)]]
            out.ukf_distance_m.append(float(np.linalg.norm(person.position_m - robot_xy)))
            out.ukf_error_m.append(float(np.linalg.norm(state.position_m - person.position_m)))
        for estimate, pid in zip(
            direct.update(observations, frame.stamp_s, frame.odometry), ids, strict=True
        ):
            if estimate is None:
                continue
            person = truth[pid]
            out.direct_distance_m.append(float(np.linalg.norm(person.position_m - robot_xy)))
            out.direct_error_m.append(float(np.linalg.norm(estimate - person.position_m)))
    return out


def _stats(distance: list[float], error: list[float], lo: float, hi: float):
    d, e = np.asarray(distance), np.asarray(error)
    sel = e[(d >= lo) & (d < hi)]
    if sel.size == 0:
        return None, None, 0
    return float(np.median(sel)), float(np.percentile(sel, 90)), int(sel.size)


def binned(samples: LocalizationSamples) -> list[dict]:
    rows = []
    for lo, hi in BINS_M:
        um, up, un = _stats(samples.ukf_distance_m, samples.ukf_error_m, lo, hi)
        dm, dp, dn = _stats(samples.direct_distance_m, samples.direct_error_m, lo, hi)
        rows.append({
            "range_m": [lo, hi],
            "ukf_median_m": um, "ukf_p90_m": up, "ukf_samples": un,
            "direct_median_m": dm, "direct_p90_m": dp, "direct_samples": dn,
        })  # fmt: skip
    return rows


def plot(samples: LocalizationSamples, path: str) -> None:
    """Error against distance for both methods: scattered samples, median and 90th
    percentile per metre."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=120)
    edges = np.arange(PEOPLE_RANGE_M[0], PEOPLE_RANGE_M[1] + 1.0, 1.0)
    centres = 0.5 * (edges[:-1] + edges[1:])
    for name, d, e, colour in (
        ("no filter (ankle back-projection)", samples.direct_distance_m, samples.direct_error_m, "tab:orange"),
        ("UKF", samples.ukf_distance_m, samples.ukf_error_m, "tab:blue"),
    ):  # fmt: skip
        d, e = np.asarray(d), np.asarray(e)
        step = max(1, len(d) // 4000)
        ax.scatter(d[::step], e[::step], s=2, alpha=0.15, color=colour, linewidths=0)
        med, p90 = [], []
        for lo, hi in zip(edges[:-1], edges[1:], strict=True):
            sel = e[(d >= lo) & (d < hi)]
            med.append(np.median(sel) if sel.size else np.nan)
            p90.append(np.percentile(sel, 90) if sel.size else np.nan)
        ax.plot(centres, med, color=colour, lw=2, label=f"{name}: median")
        ax.plot(centres, p90, color=colour, lw=1, ls="--", label=f"{name}: 90th percentile")
    ax.axhline(0.5, color="grey", lw=0.8, ls=":")
    ax.set_xlabel("distance from the camera [m]")
    ax.set_ylabel("ground-plane position error [m]")
    ax.set_xlim(*PEOPLE_RANGE_M)
    ax.set_ylim(0, 3.0)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title("Localisation error vs distance (simulated, camera 0.6 m, HFOV 70 deg)")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--plot", type=plot_path, metavar="FILE.png", help="write error vs distance to a PNG")
    parser.add_argument("--seed", type=non_negative_int, default=0, help="simulation seed (default 0)")
    parser.add_argument(
        "--duration-s", type=positive_float, default=60.0, help="simulated seconds (default 60)"
    )
    parser.add_argument("--people", type=int, default=6, help="people walking at once (default 6)")
    parser.add_argument("--config", metavar="FILE.toml", help="follow config ([tracker])")


def main(args: argparse.Namespace) -> dict:
    from follow.config import Config

    if args.duration_s <= 0 or args.people < 1:
        raise ValueError("--duration-s must be > 0 and --people >= 1")
    tracker_config = Config.load(args.config).tracker if args.config else TrackerConfig()
    camera, noise = SimCameraConfig(), DetectorNoiseConfig()
    # Dropped observations are part of the benchmark, not news.
    tracker_log = logging.getLogger("follow.ukf")
    level = tracker_log.level
    tracker_log.setLevel(logging.ERROR)
    try:
        samples = simulate(
            args.seed, args.duration_s, args.people, tracker_config, camera, noise, progress=True
        )
    finally:
        tracker_log.setLevel(level)
    rows = binned(samples)
    if args.plot:
        plot(samples, args.plot)
    if not args.json:
        _print_table(rows)
        if args.plot:
            print(f"plot written to {args.plot}")
    return {
        "bins": rows,
        "sim": {
            "seed": args.seed,
            "duration_s": args.duration_s,
            "people": args.people,
            "people_range_m": list(PEOPLE_RANGE_M),
            "people_bearing_rad": list(PEOPLE_BEARING_RAD),
            "camera": dataclasses.asdict(camera),
            "detector": dataclasses.asdict(noise),
        },
    }


def _print_table(rows: list[dict]) -> None:
    def f(v):
        return "   -  " if v is None else f"{v:6.2f}"

    print("range [m]   UKF median  UKF p90   direct median  direct p90   samples (UKF/direct)")
    for r in rows:
        lo, hi = r["range_m"]
        print(
            f"{lo:>3}-{hi:<3}       {f(r['ukf_median_m'])}   {f(r['ukf_p90_m'])}"
            f"        {f(r['direct_median_m'])}      {f(r['direct_p90_m'])}"
            f"   {r['ukf_samples']}/{r['direct_samples']}"
        )
