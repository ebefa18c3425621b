"""`follow eval pose`: skeleton detector recall and precision on PETS 2009 S2.L1.

For each network input height, on evenly spaced frames of the sequence:
- neck recall: ground-truth people (not more than half hidden behind nearer people)
  matched one-to-one with a detected neck inside their box;
- ankle recall: the same people whose matched detection also has an ankle point in the
  lower fifth of the box;
- precision: detections whose neck lies in some ground-truth box (hidden or not);
- ms: median wall time of `PoseDetector.detect` per frame.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment
from tqdm import tqdm

from follow.cli_args import non_negative_int, plot_path, positive_int
from follow.config import PoseConfig
from follow.config_bounds import POSE_PRECISIONS
from follow.eval.perturb import PerturbedSequence, add_perturb_arguments, plot_spread, print_suite
from follow.eval.perturb import selected_variants as perturb_variants
from follow.eval.pets import GtBox, PetsSequence, evenly_spaced_frames
from follow.types import Observation

log = logging.getLogger(__name__)

DEFAULT_SIZES = (256, 368, 480, 576)
DEFAULT_FRAMES = 60
MAX_HIDDEN_FRACTION = 0.5
ANKLE_ZONE_FRACTION = 0.2  # the lower fifth of the box
NECK_EXPECTED_REL_Y = 0.15  # typical neck height in a box, from the top (for matching)
# Figures summarised over the perturbation suite: metric -> higher is better.
SUITE_METRICS = {"neck_recall": True, "ankle_recall": True, "precision": True}


@dataclass
class Counts:
    """Running totals for one input size."""

    people: int = 0  # counted ground-truth people
    neck_hits: int = 0
    ankle_hits: int = 0
    detections: int = 0  # observations (skeletons with a neck)
    detections_in_boxes: int = 0

    def add(self, other: Counts) -> None:
        for f in dataclasses.fields(self):
            setattr(self, f.name, getattr(self, f.name) + getattr(other, f.name))

    def summary(self) -> dict:
        return {
            "neck_recall": self.neck_hits / self.people if self.people else float("nan"),
            "ankle_recall": self.ankle_hits / self.people if self.people else float("nan"),
            "precision": (
                self.detections_in_boxes / self.detections if self.detections else float("nan")
            ),
            "people": self.people,
            "detections": self.detections,
        }


def score_frame(
    observations: list[Observation],
    boxes: list[GtBox],
    max_hidden_fraction: float = MAX_HIDDEN_FRACTION,
) -> Counts:
    """Match one frame's observations to its ground-truth boxes (same pixel frame).

    Necks are assigned one-to-one to boxes containing them (closest to the box's typical
    neck point first), so one detection never counts for two overlapping people.
    """
    counts = Counts(detections=len(observations))
    counted = [b.hidden_fraction <= max_hidden_fraction for b in boxes]
    counts.people = int(sum(counted))
    counts.detections_in_boxes = sum(
        any(b.contains(*o.neck_px) for b in boxes) for o in observations
    )
    if not observations or not boxes:
        return counts
    big = 1e9
    cost = np.full((len(boxes), len(observations)), big)
    for i, box in enumerate(boxes):
        expected = np.array([box.xc, box.top + NECK_EXPECTED_REL_Y * box.h])
        for j, obs in enumerate(observations):
            if box.contains(*obs.neck_px):
                cost[i, j] = np.linalg.norm((obs.neck_px - expected) / box.h)
    rows, cols = linear_sum_assignment(cost)
    for i, j in zip(rows, cols, strict=True):
        if cost[i, j] >= big or not counted[i]:
            continue
        counts.neck_hits += 1
        ankle = observations[j].ankle_px
        box = boxes[i]
        if ankle is not None and box.left <= ankle[0] <= box.right:
            if box.bottom - ANKLE_ZONE_FRACTION * box.h <= ankle[1] <= box.bottom:
                counts.ankle_hits += 1
    return counts


def evaluate_size(
    sequence: PetsSequence,
    frames: list[int],
    config: PoseConfig,
    model_path: Path | None = None,
) -> dict:
    """Metrics and median ms for one PoseConfig over the given frames."""
    from follow.pose.detector import PoseDetector
    from follow.pose.observations import skeletons_to_observations

    # every frame at the size measured (the frames are spread over the sequence)
    config = dataclasses.replace(config, input_height_from_people=False)
    detector = PoseDetector(config, model_path)
    totals = Counts()
    times_ms = []
    input_size = None
    for index, image in tqdm(
        sequence.frames(frames),
        total=len(frames),
        desc=f"pose h={config.input_height_px}",
        leave=False,
    ):
        skeletons = detector.detect(image)
        times_ms.append(detector.last_timing_ms["total"])
        size = (image.shape[1], image.shape[0])
        observations = skeletons_to_observations(skeletons, size, config)
        totals.add(score_frame(observations, sequence.boxes_video_px(index)))
        if input_size is None:
            from follow.pose.preprocess import plan_letterbox

            input_size = list(plan_letterbox(size, config.input_height_px).input_size)
    return {
        "input": input_size,
        **totals.summary(),
        "ms": float(np.median(times_ms)),
        "backend": detector.backend_name,
        "model": detector.model_path.name,
    }


def input_height(text: str) -> int:
    """An argparse type: a network input height `[pose] input_height_px` takes. The
    detector refuses any other only when its size's turn comes, after the sizes before it
    have run."""
    from follow.config_bounds import BOUNDS

    value = positive_int(text)
    allowed = BOUNDS["pose"]["input_height_px"]
    if not allowed.contains(value):
        raise argparse.ArgumentTypeError(f"expected {allowed.describe()}, got {text!r}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--frames", type=positive_int, default=DEFAULT_FRAMES, help="evenly spaced frames to use"
    )
    parser.add_argument("--from-frame", type=non_negative_int, default=0,
                        help="take the frames from this one on (e.g. 400: the half that "
                             "checks settings chosen on the first)")  # fmt: skip
    parser.add_argument("--until-frame", type=positive_int, default=None,
                        help="take the frames before this one (e.g. 400: the half settings "
                             "are chosen on)")  # fmt: skip
    parser.add_argument(
        "--sizes",
        type=input_height,
        nargs="+",
        default=list(DEFAULT_SIZES),
        help="network input heights in px (multiples of 8)",
    )
    parser.add_argument("--provider", default=None, help="override the pose provider")
    parser.add_argument(
        "--precision", choices=POSE_PRECISIONS, default=None,
        help="override the pose precision (the PETS settings: int8_if_made)",
    )
    parser.add_argument("--model-file", type=Path, default=None, help="a pose model file")
    parser.add_argument(
        "--data-dir",
        type=Path,
        default=None,
        help="folder with View_001.avi and PETS2009-S2L1.xml "
        "(default: $FOLLOW_DATA_DIR/pets2009_s2l1)",
    )
    parser.add_argument("--config", type=Path, default=None,
                        help="TOML configuration, over the PETS settings (pets2009.toml)")  # fmt: skip
    parser.add_argument("--plot", type=plot_path, default=None, help="write a PNG of the results")
    add_perturb_arguments(parser)


def data_dir(arg: Path | None) -> Path:
    if arg is not None:
        return arg
    root = os.environ.get("FOLLOW_DATA_DIR")
    if not root:
        raise ValueError("PETS 2009 not found: give --data-dir or set $FOLLOW_DATA_DIR")
    return Path(root) / "pets2009_s2l1"


def main(args: argparse.Namespace) -> dict:
    from follow.eval.pets_setup import pets_config

    base = pets_config(args.config).pose
    if args.provider:
        base = dataclasses.replace(base, provider=args.provider)
    if args.precision:
        base = dataclasses.replace(base, precision=args.precision)
    sequence = PetsSequence(data_dir(args.data_dir))
    variants = perturb_variants(args)
    if variants is not None:
        return main_perturbed(args, base, sequence, variants)
    frames = frame_range(sequence.frame_count, args.frames, args.from_frame, args.until_frame)
    results = []
    for height in tqdm(args.sizes, desc="input sizes"):
        config = dataclasses.replace(base, input_height_px=height)
        results.append(evaluate_size(sequence, frames, config, args.model_file))
    if not args.json:
        print(f"PETS 2009 S2.L1, {len(frames)} frames, default height {base.input_height_px} px")
        print(f"{'input':>10} {'neck rec':>9} {'ankle rec':>9} {'precision':>9} {'ms':>7}")
        for r in results:
            size = f"{r['input'][0]}x{r['input'][1]}"
            print(
                f"{size:>10} {r['neck_recall']:9.3f} {r['ankle_recall']:9.3f} "
                f"{r['precision']:9.3f} {r['ms']:7.1f}"
            )
    if args.plot:
        write_plot(results, args.plot)
    return {"sizes": results, "frames": len(frames), "default_height": base.input_height_px,
            **asked_range(args, sequence.frame_count)}  # fmt: skip


def asked_range(args: argparse.Namespace, frame_count: int) -> dict:
    """The frame range the frames were taken from, as the JSON reports it."""
    end = frame_count if args.until_frame is None else min(args.until_frame, frame_count)
    return {"from_frame": args.from_frame, "until_frame": end}


def frame_range(frame_count: int, count: int, first: int = 0, end: int | None = None) -> list[int]:
    """`count` evenly spaced frames of first .. end - 1 (end: the sequence's end)."""
    end = frame_count if end is None else min(end, frame_count)
    if count < 1:
        raise ValueError(f"--frames must be at least 1, got {count}")
    if not 0 <= first < end:
        raise ValueError(f"no frames from {first} until {end} (the sequence has {frame_count})")
    return [first + i for i in evenly_spaced_frames(end - first, count)]


def variant_frames(frame_count: int, count: int, variant, first: int = 0,
                   end: int | None = None) -> list[int]:  # fmt: skip
    """`count` evenly spaced frames from the variant's first frame (or `first`, if
    later) until `end`."""
    try:
        return frame_range(frame_count, count, max(first, variant.first_frame), end)
    except ValueError as error:
        raise ValueError(f"variant {variant.name}: {error}") from None


def main_perturbed(args: argparse.Namespace, base: PoseConfig, sequence, variants) -> dict:
    """Every input size on every variant of the suite; per size the mean and the worst."""
    from follow.eval.perturb import run_suite

    frames_run: dict[str, int] = {}
    frames_of = {v.name: variant_frames(sequence.frame_count, args.frames, v, args.from_frame,
                                        args.until_frame) for v in variants}  # fmt: skip
    same_as = repeated_runs(variants, frames_of)
    variants = [v for v in variants if v.name not in same_as]

    def one(variant) -> dict:
        seen = PerturbedSequence(sequence, variant) if variant.changes_pixels else sequence
        frames = frames_of[variant.name]
        frames_run[variant.name] = len(frames)
        out = {}
        for height in args.sizes:
            config = dataclasses.replace(base, input_height_px=height)
            out[str(height)] = evaluate_size(seen, frames, config, args.model_file)
        return out

    suite = run_suite(variants, one, SUITE_METRICS)
    if not args.json:
        print(f"PETS 2009 S2.L1 under {len(variants)} perturbations, "
              f"{args.frames} evenly spaced frames, by network input height")  # fmt: skip
        for name, first in same_as.items():
            print(f"{name}: the same frames and pixels as {first}, counted once")
        print_suite(suite, list(SUITE_METRICS), method_label="height px")
    if args.plot:
        plot_spread(suite, list(SUITE_METRICS), str(args.plot),
                    "Pose detector on PETS 2009 S2.L1 under perturbation, by input height")  # fmt: skip
    model = next(iter(next(iter(suite["variants"].values())).values()))["model"]
    return {**suite, "frames": frames_run, "default_height": base.input_height_px, "model": model,
            "same_as": same_as, **asked_range(args, sequence.frame_count)}  # fmt: skip


def repeated_runs(variants, frames_of: dict[str, list[int]]) -> dict[str, str]:
    """{variant: the earlier variant it repeats}: the same pixel changes on the same
    frames (a later start whose first frame lies before the frames asked for is the
    original there). The detector keeps nothing from frame to frame, so such a run gives
    the same figures, and counted again it would pull the mean towards them."""
    seen: dict[tuple, str] = {}
    same_as: dict[str, str] = {}
    for v in variants:
        key = (dataclasses.replace(v, name="", description="", first_frame=0),
               tuple(frames_of[v.name]))  # fmt: skip
        if key in seen:
            same_as[v.name] = seen[key]
        else:
            seen[key] = v.name
    return same_as


def write_plot(results: list[dict], path: str | Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    heights = [r["input"][1] for r in results]
    fig, ax = plt.subplots(figsize=(6, 4))
    for key in ("neck_recall", "ankle_recall", "precision"):
        ax.plot(heights, [r[key] for r in results], marker="o", label=key.replace("_", " "))
    ax.set_xlabel("network input height [px]")
    ax.set_ylim(0, 1.02)
    ax.grid(True, alpha=0.3)
    ax2 = ax.twinx()
    ax2.plot(heights, [r["ms"] for r in results], "k--", marker="x", label="ms / frame")
    ax2.set_ylabel("median ms per frame")
    lines = ax.get_lines() + ax2.get_lines()
    ax.legend(lines, [line.get_label() for line in lines], loc="lower right")
    ax.set_title("Pose detector on PETS 2009 S2.L1")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
