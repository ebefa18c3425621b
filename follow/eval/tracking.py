"""`follow eval tracking`: our tracker against the ground truth of PETS 2009 S2.L1 on
the floor (CLEAR MOT, IDF1, 1 m match threshold), side by side, on the same skeleton
detections, with the no-filter baseline, norfair on keypoints and ByteTrack on boxes."""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from follow.cli_args import plot_path, positive_float
from follow.config import Config
from follow.eval.mot import GroundPlaneMot
from follow.eval.perturb import SUITE, add_perturb_arguments, plot_spread, print_suite, run_suite
from follow.eval.perturb import selected_variants as perturb_variants
from follow.eval.pets_setup import (
    PETS_FPS,
    PetsSetup,
    add_evaluation_arguments,
    load_pets,
    variant_inputs,
)

METHODS = ("ours", "direct", "norfair", "bytetrack")
# Figures summarised over the perturbation suite: metric -> higher is better. Counts go
# in per 1000 ground-truth objects: a later start scores fewer frames, and its raw counts
# would make the whole-length variants look the worst.
COUNTS = ("id_switches", "misses", "false_positives")
SUITE_METRICS = {"mota": True, "idf1": True, "motp_m": False,
                 **{f"{k}_per_1000_gt": False for k in COUNTS}}  # fmt: skip


def add_arguments(p) -> None:
    add_evaluation_arguments(p)
    p.add_argument("--match-threshold-m", type=positive_float, default=1.0)
    p.add_argument("--score-from-frame", type=int, default=0,
                   help="run from the start but score only frames from this one on "
                        "(e.g. 400: the half not used to fit pets2009.toml)")  # fmt: skip
    p.add_argument("--score-until-frame", type=int, default=None,
                   help="score only frames before this one (e.g. 400: the half settings "
                        "are chosen on; the run and its cached detections stay whole)")  # fmt: skip
    p.add_argument("--plot", type=plot_path, help="write a PNG of MOTA and IDF1 per method here "
                                  "(with --perturb: their spread over the variants)")  # fmt: skip
    add_perturb_arguments(p)


class HungarianIds:
    """Frame-to-frame identities for unfiltered positions: Hungarian matching of this
    frame's points to the last frame's, within a gate; the unmatched get new ids."""

    def __init__(self, gate_m: float = 1.0):
        self.gate_m = gate_m
        self._ids: list[int] = []
        self._points = np.empty((0, 2))
        self._next = 1

    def update(self, points: np.ndarray) -> list[int]:
        points = np.asarray(points, float).reshape(-1, 2)
        ids = [0] * len(points)
        if len(points) and len(self._points):
            cost = np.linalg.norm(points[:, None] - self._points[None], axis=2)
            rows, cols = linear_sum_assignment(np.where(cost > self.gate_m, 1e6, cost))
            for r, c in zip(rows, cols, strict=True):
                if cost[r, c] <= self.gate_m:
                    ids[r] = self._ids[c]
        for i in range(len(ids)):
            if ids[i] == 0:
                ids[i], self._next = self._next, self._next + 1
        self._ids, self._points = ids, points
        return ids


def run_methods(setup: PetsSetup, frames: list[int], skeletons, config: Config):
    """Per method, per frame: (hypothesis ids, positions in metres)."""
    from follow.eval.peers import ByteTrackBoxTracker, NorfairKeypointTracker
    from follow.pose.observations import skeletons_to_observations
    from follow.ukf.direct import DirectBaseline
    from follow.ukf.models import population_ankle_height_m
    from follow.ukf.tracker import PeopleTracker

    camera = setup.camera
    ankle_m = population_ankle_height_m(config.tracker)  # the same geometry for everyone
    min_conf = config.pose.keypoint_min_confidence
    ours = PeopleTracker(camera, config.tracker)
    direct = DirectBaseline(camera, config.tracker)
    norfair = NorfairKeypointTracker(camera, min_conf, ankle_height_m=ankle_m)
    bytetrack = ByteTrackBoxTracker(camera, PETS_FPS, min_conf, ankle_height_m=ankle_m)
    direct_ids = HungarianIds(gate_m=1.0)
    out: dict[str, list] = {m: [] for m in METHODS}
    for index in frames:
        stamp = index / PETS_FPS
        observations = skeletons_to_observations(skeletons[index], camera.image_size, config.pose)
        tracks = [t for t in ours.update(observations, stamp) if t.confirmed]
        out["ours"].append(([t.track_id for t in tracks],
                            np.array([t.position_m for t in tracks]).reshape(-1, 2)))  # fmt: skip
        points = [p for p in direct.update(observations, stamp) if p is not None]
        ground = np.array(points).reshape(-1, 2)
        out["direct"].append((direct_ids.update(ground), ground))
        for name, tracker in (("norfair", norfair), ("bytetrack", bytetrack)):
            ids, pts = tracker.update(skeletons[index])
            ok = np.isfinite(pts).all(axis=1) if len(pts) else np.zeros(0, bool)
            out[name].append(([i for i, good in zip(ids, ok, strict=True) if good], pts[ok]))
    return out


def score(setup: PetsSetup, frames: list[int], hypotheses, threshold_m: float,
          first_scored_frame: int = 0, end_scored_frame: int | None = None) -> dict:  # fmt: skip
    results = {}
    for method, per_frame in hypotheses.items():
        mot = GroundPlaneMot(threshold_m)
        for index, (hyp_ids, hyp_xy) in zip(frames, per_frame, strict=True):
            if index < first_scored_frame or (end_scored_frame is not None
                                              and index >= end_scored_frame):  # fmt: skip
                continue
            gt_ids, gt_xy, _ = setup.ground_truth(index)
            mot.add_frame(gt_ids, gt_xy, hyp_ids, hyp_xy)
        results[method] = mot.summary()
    return results


def plot(results: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = list(results)
    x = np.arange(len(methods))
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for offset, key, label in ((-0.2, "mota", "MOTA"), (0.2, "idf1", "IDF1")):
        values = [results[m][key] for m in methods]
        bars = ax.bar(x + offset, values, 0.4, label=label)
        ax.bar_label(bars, fmt="%.2f", fontsize=8)
    ax.set_xticks(x, methods)
    ax.set_ylim(min(0.0, *(results[m]["mota"] for m in methods)), 1.05)
    ax.set_title("PETS 2009 S2.L1, ground plane, 1 m threshold")
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def evaluate(args, config: Config, setup: PetsSetup, variant=None) -> tuple[dict, list[int]]:
    """Every method's figures on the sequence (seen through `variant`), and the frames
    (their scored window checked by the caller, before the pose network runs)."""
    setup, frames, skeletons = variant_inputs(args, config, setup, variant)
    hypotheses = run_methods(setup, frames, skeletons, config)
    results = score(setup, frames, hypotheses, args.match_threshold_m, args.score_from_frame,
                    args.score_until_frame)  # fmt: skip
    return results, frames


def check_scored_frames(args, frames: list[int]) -> None:
    """Refuse `--score-from-frame` / `--score-until-frame` that leave the run `frames`
    nothing to score."""
    if args.score_from_frame and not frames[0] <= args.score_from_frame <= frames[-1]:
        raise ValueError(
            f"--score-from-frame {args.score_from_frame} is outside {frames[0]}..{frames[-1]}"
        )
    end = args.score_until_frame
    if end is not None and not max(frames[0], args.score_from_frame) < end:
        raise ValueError(f"--score-until-frame {end} leaves no frame to score")


def main(args) -> dict:
    config, setup = load_pets(args)
    variants = perturb_variants(args)
    if variants is not None:
        return main_perturbed(args, config, setup, variants)
    check_scored_frames(args, SUITE[0].frame_range(setup.frame_count, args.frames))
    results, frames = evaluate(args, config, setup)
    n = len(frames)
    if args.plot:
        plot(results, args.plot)
    if not args.json:
        scored = _scored_frames(args)
        print(f"PETS 2009 S2.L1, {n} frames{scored}, match threshold {args.match_threshold_m} m")
        print(f"{'method':10s} {'MOTA':>6s} {'MOTP m':>7s} {'IDF1':>6s} {'IDsw':>5s} "
              f"{'miss':>5s} {'FP':>5s}")  # fmt: skip
        for m, r in results.items():
            print(f"{m:10s} {r['mota']:6.3f} {r['motp_m']:7.3f} {r['idf1']:6.3f} "
                  f"{r['id_switches']:5d} {r['misses']:5d} {r['false_positives']:5d}")  # fmt: skip
    return {**results, "frames": n, "scored_from_frame": args.score_from_frame,
            "scored_until_frame": args.score_until_frame,
            "match_threshold_m": args.match_threshold_m}  # fmt: skip


def _scored_frames(args) -> str:
    """The scored frames as said after the frame count (empty when all are scored)."""
    text = f" from frame {args.score_from_frame}" if args.score_from_frame else ""
    if args.score_until_frame is not None:
        text += f" until frame {args.score_until_frame}"
    return f", scored{text}" if text else ""


def main_perturbed(args, config: Config, setup: PetsSetup, variants) -> dict:
    frames_run: dict[str, int] = {}
    for v in variants:  # every variant's window, before any of them runs
        try:
            check_scored_frames(args, v.frame_range(setup.frame_count, args.frames))
        except ValueError as error:
            raise ValueError(f"variant {v.name}: {error}") from None

    def one(variant) -> dict:
        results, frames = evaluate(args, config, setup, variant)
        frames_run[variant.name] = len(frames)
        for r in results.values():
            for k in COUNTS:
                r[f"{k}_per_1000_gt"] = round(1000.0 * r[k] / max(r["gt_objects"], 1), 2)
        return results

    suite = run_suite(variants, one, SUITE_METRICS)
    if args.plot:
        plot_spread(suite, ["mota", "idf1"], args.plot,
                    "PETS 2009 S2.L1 under perturbation, ground plane, 1 m threshold")  # fmt: skip
    if not args.json:
        scored = _scored_frames(args)
        print(f"PETS 2009 S2.L1 under {len(variants)} perturbations{scored}, "
              f"match threshold {args.match_threshold_m} m")  # fmt: skip
        print_suite(suite, ["mota", "idf1", *(f"{k}_per_1000_gt" for k in COUNTS)])
    return {**suite, "frames": frames_run, "scored_from_frame": args.score_from_frame,
            "scored_until_frame": args.score_until_frame,
            "match_threshold_m": args.match_threshold_m}  # fmt: skip
