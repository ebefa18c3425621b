"""`follow eval identification`: who is the target, on PETS 2009 S2.L1.

Each ground-truth person visible for at least `--min-visible-s` becomes the target in
turn: once one confirmed track, the same for a second, can be picked out as theirs, as
a user clicking on them would (its detected neck in their box and in no one else's, its
position within the match distance), that track is selected and the identifier learns
from there on. That frame (the identifier names the track it is told) and every
later one is then CT, CL, WT or WL (see `identification_metrics`); a target never
selected is reported as unscored. A person is
visible when annotated and not more than half hidden behind someone nearer the camera;
a named track is the target when its position lies within the match distance of the
target's annotated position.

By default each target is scored only until its last annotated frame: the ground truth
gives a person who leaves the view and comes back a new id, so after a trajectory ends
it cannot tell whether a person named later is the target returning (right) or someone
else (wrong). `--whole-sequence` scores to the end, with the ids that are one physical
person joined (`pets2009_same_person.toml`, built by looking at their crops): naming
the returning target is right, naming anyone else while it is away is wrong tracking.
Each person is then one target, under the id they are first annotated with.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import NamedTuple

import numpy as np

from follow.cli_args import (
    float_within,
    identifier_list,
    non_negative_int,
    plot_path,
    positive_float,
)
from follow.config import Config
from follow.eval.identification_metrics import OUTCOMES, OutcomeTally, classify
from follow.eval.perturb import add_perturb_arguments, plot_spread, print_suite, run_suite
from follow.eval.perturb import selected_variants as perturb_variants
from follow.eval.pets import GT_IMAGE_SIZE, GtBox
from follow.eval.pets_setup import (
    PETS_FPS,
    PetsSetup,
    add_evaluation_arguments,
    load_pets,
    variant_inputs,
)
from follow.types import TargetStatus

log = logging.getLogger(__name__)

IDENTIFIERS = ("ccf10", "ccf10+reid", "reid")

NAMING_STATES = (TargetStatus.INITIAL_TRAINING, TargetStatus.TRACKING)
PICK_STEADY_S = 1.0  # a target is selected on a track picked out as its own this long
# Figures summarised over the perturbation suite: metric -> higher is better.
SUITE_METRICS = {"ct": True, "cl": True, "ct_cl": True, "wt": False, "wl": False}


class Annotated(NamedTuple):
    """One annotated person in one frame: ground point, hidden fraction and box (in the
    camera model's pixels, where the tracks' observations are)."""

    position_m: np.ndarray
    hidden_fraction: float
    box: GtBox


def add_arguments(p) -> None:
    add_evaluation_arguments(p)
    p.add_argument("--identifiers", default=",".join(IDENTIFIERS), type=identifier_list,
                   help=f"comma-separated identifier configurations (default {','.join(IDENTIFIERS)})")  # fmt: skip
    p.add_argument("--min-visible-s", type=positive_float, default=20.0,
                   help="people visible at least this long become targets")  # fmt: skip
    p.add_argument("--max-targets", type=non_negative_int, default=0,
                   help="evaluate at most this many targets (0 = all)")  # fmt: skip
    p.add_argument("--match-distance-m", type=positive_float, default=1.0,
                   help="a named track within this of the target on the floor is the target")  # fmt: skip
    p.add_argument("--max-hidden-fraction", type=float_within(0.0, 1.0), default=0.5,
                   help="the target counts as visible while at most this much of its box "
                        "is hidden")  # fmt: skip
    p.add_argument("--whole-sequence", action="store_true",
                   help="score every target to the end of the sequence, not only until its "
                        "last annotated frame; the ids of one person who leaves and returns "
                        "(pets2009_same_person.toml) are one target")  # fmt: skip
    p.add_argument("--plot", type=plot_path, help="write a PNG timeline of outcomes per target here "
                                  "(with --perturb: the spread of CT+CL and CT over the variants)")  # fmt: skip
    add_perturb_arguments(p)


class _CachedDescribe:
    """Memoises an appearance model's `describe` and `complete` per (frame, ROI): the
    cues of a person in a frame do not depend on which target is being learnt. Each
    ROI's re-id embedding is computed once for all the targets, but handed to the
    identifier only where it asks for one (`describe`'s `embed`, then `complete`), as on
    a robot: there, while the target is tracked, the other people are scored by the
    classifier alone. (Handing every embedding over scored them with both cues, so the
    rules that compare the target with the others decided otherwise than live.)"""

    def __init__(self, model):
        self.model = model
        self._describe = model.describe
        self.frame_index = -1
        self.cache: dict = {}

    def _cues(self, image_bgr, rois) -> list:
        missing = [r for r in rois if (self.frame_index, tuple(r)) not in self.cache]
        if missing:
            for roi, cue in zip(missing, self._describe(image_bgr, missing), strict=True):
                self.cache[(self.frame_index, tuple(roi))] = cue
        return [self.cache[(self.frame_index, tuple(r))] for r in rois]

    def describe(self, image_bgr, rois, embed=None) -> list:
        cues = self._cues(image_bgr, rois)
        if embed is None:
            return cues
        return [c if wanted else dataclasses.replace(c, embedding=None)
                for c, wanted in zip(cues, embed, strict=True)]  # fmt: skip

    def complete(self, image_bgr, rois, appearances) -> list:
        cues = self._cues(image_bgr, rois)
        return [dataclasses.replace(a, embedding=c.embedding) if self.model.lacks_embedding(a)
                else a for a, c in zip(appearances, cues, strict=True)]  # fmt: skip


def _nearest(candidates, position_m, max_distance_m: float):
    """The key of the (key, position) pair nearest `position_m` on the floor, within
    `max_distance_m` (None: none that near)."""
    best, best_d = None, max_distance_m
    for key, p in candidates:
        d = float(np.linalg.norm(p - position_m))
        if d <= best_d:
            best, best_d = key, d
    return best


def evaluate(setup: PetsSetup, frames: list[int], tracks_per_frame, gt_per_frame, target_ids,
             identifier_name: str, config: Config, match_m: float, max_hidden: float,
             whole_sequence: bool = False):  # fmt: skip
    """Per target: the OutcomeTally over the frames from its selection on, up to its last
    annotated frame (to the end with `whole_sequence`)."""
    from follow.identify.factory import build_identifier

    section = dataclasses.replace(config.identify, identifier=identifier_name)
    same_person = load_same_person() if whole_sequence else {}
    undecided = load_undecided(same_person=same_person) if whole_sequence else {}
    cache = None
    out = {}
    for target in target_ids:
        identifier = build_identifier(section)
        if cache is None:
            cache = _CachedDescribe(identifier.model)
        identifier.model.describe = cache.describe
        identifier.model.complete = cache.complete
        tally = OutcomeTally()
        maybe_target = undecided.get(target, frozenset())
        picker = TargetPicker(round(PICK_STEADY_S * PETS_FPS))
        ids = same_person.get(target, (target,))
        last = last_annotated(gt_per_frame, target) if not whole_sequence else len(frames) - 1
        for position, (index, image) in enumerate(setup.sequence.frames(frames[: last + 1])):
            tracks = tracks_per_frame[position]
            people = gt_per_frame[position]
            target_box = _person_box(people, ids)
            visible = target_box is not None and target_box.hidden_fraction <= max_hidden
            chosen = picker.update(identifier.status, tracks, people, ids,
                                   target_box if visible else None, match_m)  # fmt: skip
            if chosen is not None:
                identifier.select_target(chosen)
            if picker.selected_id is None:
                continue
            cache.frame_index = index
            estimate = identifier.update(image, tracks, index / PETS_FPS)
            named = estimate.target_id if estimate.status in NAMING_STATES else None
            track = next((t for t in tracks if t.track_id == named), None)
            named_is_target = (
                track is not None and target_box is not None
                and bool(np.linalg.norm(track.position_m - target_box.position_m) <= match_m)
            )  # fmt: skip
            outcome = classify(visible, named, named_is_target)
            tally.add(outcome, 1.0 / PETS_FPS, undecided=(
                outcome == "wt" and track is not None
                and _person_at(people, track.position_m, match_m) in maybe_target
            ))  # fmt: skip
        out[target] = tally
    return out


SAME_PERSON_FILE = Path(__file__).with_name("pets2009_same_person.toml")


def _id_lists(path: Path, table: str, what: str) -> list[list[int]]:
    """The `ids = [...]` lists of the `[[table]]` entries of the TOML file `path`, each
    checked to hold two or more ints (`what` names an entry in errors)."""
    from follow.config import tomllib

    try:
        data = tomllib.loads(Path(path).read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"same-person map {path}: {exc}") from None
    out = []
    for k, entry in enumerate(data.get(table, [])):
        ids = entry.get("ids") if isinstance(entry, dict) else None
        if (
            not isinstance(ids, list)
            or len(ids) < 2
            or not all(isinstance(i, int) and not isinstance(i, bool) for i in ids)
        ):
            raise ValueError(
                f"same-person map {path}: {what} {k + 1} needs ids = [two or more ints]"
            )
        out.append(ids)
    return out


def load_same_person(path: Path = SAME_PERSON_FILE) -> dict[int, tuple[int, ...]]:
    """GT id -> every GT id of the same physical person (itself included), from the
    `[[same_person]] ids = [...]` tables of `path`; ids not listed map to themselves."""
    out: dict[int, tuple[int, ...]] = {}
    for ids in _id_lists(path, "same_person", "group"):
        for i in ids:
            if i in out:
                raise ValueError(f"same-person map {path}: id {i} is in two groups")
            out[i] = tuple(ids)
    return out


def load_undecided(
    path: Path = SAME_PERSON_FILE, same_person: dict[int, tuple[int, ...]] | None = None
) -> dict[int, frozenset[int]]:
    """GT id -> the GT ids that may be the same physical person but could not be told
    apart (`[[undecided]] ids = [...]` of `path`), each id standing for its whole
    same-person group."""
    same_person = load_same_person(path) if same_person is None else same_person
    out: dict[int, set[int]] = {}
    for k, ids in enumerate(_id_lists(path, "undecided", "undecided entry")):
        groups = [set(same_person.get(i, (i,))) for i in ids]
        for a, group in enumerate(groups):
            others = set().union(*(g for b, g in enumerate(groups) if b != a))
            if group & others:
                raise ValueError(
                    f"same-person map {path}: undecided entry {k + 1} joins ids that are "
                    "already one person"
                )
            for i in group:
                out.setdefault(i, set()).update(others)
    return {i: frozenset(v) for i, v in out.items()}


def _person_at(people: dict, position_m: np.ndarray, max_distance_m: float) -> int | None:
    """The annotated person nearest `position_m` on the floor, within `max_distance_m`."""
    return _nearest(((i, a.position_m) for i, a in people.items()), position_m, max_distance_m)


class TargetPicker:
    """Which track to select for the target, as a user would: one that has been picked
    out as the target's (`_picked_out`), alone, for `PICK_STEADY_S` in a row (a user
    watches a moment before clicking, and a click on one frame where two people overlap
    is a guess); and again if the selected track ended before the target was learnt
    (the identifier would wait for that id for ever)."""

    def __init__(self, steady_frames: int):
        self.steady_frames = steady_frames
        self.selected_id: int | None = None
        self._candidate: int | None = None
        self._streak = 0

    def update(self, status: TargetStatus, tracks, people: dict, ids: tuple[int, ...],
               target_box, match_m: float) -> int | None:  # fmt: skip
        """The track id to select in this frame (`target_box`: the target's annotation,
        None when not visible), else None."""
        lost_untrained = (
            self.selected_id is not None and status == TargetStatus.INITIAL
            and all(t.track_id != self.selected_id for t in tracks)
        )  # fmt: skip
        if not (self.selected_id is None or lost_untrained):
            return None
        mine = [] if target_box is None else [
            t for t in tracks
            if t.confirmed and _picked_out(t, people, ids, target_box.box)
            and float(np.linalg.norm(t.position_m - target_box.position_m)) <= match_m
        ]  # fmt: skip
        only = mine[0].track_id if len(mine) == 1 else None
        self._streak = self._streak + 1 if only is not None and only == self._candidate else (
            int(only is not None))  # fmt: skip
        self._candidate = only
        if only is None or self._streak < self.steady_frames:
            return None
        self.selected_id, self._streak = only, 0
        return only


# Where a neck lies in an annotated PETS box: 99 % of the necks of tracks matched to an
# unhidden person (one box, within 0.5 m on the floor) within this fraction of the box's
# height from its top (0.296 in the original video's first half; 99.9 % of the second
# half's, 0.298).
NECK_FROM_BOX_TOP = 0.30


def _picked_out(track, people: dict, ids: tuple[int, ...], target_box) -> bool:
    """Whether a user clicking on the target would get this track: it was detected in
    this frame with its neck where the target's neck is (inside its box `target_box`, in
    the top `NECK_FROM_BOX_TOP` of it) and inside no one else's box. People walking together
    overlap in the image and their ground points (from boxes partly hidden) are noisy by
    tenths of a metre, so a track nearest the target on the floor may be its
    companion's; the user waits for a frame where the two are apart. A track whose neck
    lies at the target's waist is another body, or a fragment of one (a companion's
    skeleton broken by compression was picked so, and followed as the target for the
    rest of the run)."""
    if track.observation is None:
        return False
    neck = track.observation.neck_px
    if not all(a.box.contains(*neck) == (i in ids) for i, a in people.items()):
        return False
    return neck[1] - target_box.top <= NECK_FROM_BOX_TOP * target_box.h


def _person_box(people: dict, ids: tuple[int, ...]):
    """The annotation of whichever of the person's ids is present in this frame."""
    return next((people[i] for i in ids if i in people), None)


def first_of_each_person(targets: list[int], gt_per_frame, same_person: dict) -> list[int]:
    """One target per physical person: the id under which they are first annotated."""

    def first(i: int) -> int:
        return min((k for k, people in enumerate(gt_per_frame) if i in people), default=-1)

    out = []
    for t in targets:
        earlier = [o for o in same_person.get(t, ()) if o in targets and first(o) < first(t)]
        if not earlier:
            out.append(t)
    return out


def last_annotated(gt_per_frame, person_id: int) -> int:
    """Position of the last frame in which the person is annotated (-1: never)."""
    return max((i for i, people in enumerate(gt_per_frame) if person_id in people), default=-1)


def plot(per_identifier: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    colours = {"ct": "#2ca02c", "cl": "#98df8a", "wt": "#d62728", "wl": "#ff9896"}
    labels = {"wt?": "WT, may be the target"}
    if any("wt?" in tally.timeline for per_target in per_identifier.values()
           for tally in per_target.values()):  # fmt: skip
        colours["wt?"] = "#ff7f0e"  # the ground truth cannot tell
    rows = [(name, t, tally) for name, per_target in per_identifier.items()
            for t, tally in per_target.items()]  # fmt: skip
    fig, ax = plt.subplots(figsize=(9, 0.3 * len(rows) + 1.2))
    for y, (_, _, tally) in enumerate(rows):
        start = 0
        timeline = tally.timeline
        for x in range(1, len(timeline) + 1):  # one bar per run of equal outcomes
            if x == len(timeline) or timeline[x] != timeline[start]:
                ax.barh(y, (x - start) / PETS_FPS, left=start / PETS_FPS,
                        color=colours[timeline[start]], height=0.8)  # fmt: skip
                start = x
    ax.set_yticks(range(len(rows)), [f"{n} #{t}" for n, t, _ in rows], fontsize=7)
    ax.invert_yaxis()
    ax.set_xlabel("seconds after the target was selected")
    ax.legend(handles=[Patch(color=c, label=labels.get(k, k.upper())) for k, c in colours.items()],
              ncol=len(colours), loc="upper right", fontsize=7)  # fmt: skip
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(args) -> dict:
    config, setup = load_pets(args)
    variants = perturb_variants(args)
    if variants is not None:
        return main_perturbed(args, config, setup, variants)
    result, per_identifier, targets, n = evaluate_variant(args, config, setup)
    if args.plot:
        plot(per_identifier, args.plot)
    if not args.json:
        print(f"PETS 2009 S2.L1, {n} frames, {len(targets)} targets: {targets}")
        print(f"{'identifier':12s} " + " ".join(f"{k.upper():>6s}" for k in OUTCOMES))
        for name, r in result.items():
            print(f"{name:12s} " + " ".join(f"{r[k]:6.3f}" for k in OUTCOMES))
        if args.whole_sequence:
            for name, r in result.items():
                print(
                    f"{name}: of WT {r['wt']:.3f}, {r['wt_undecided']:.3f} names a person "
                    "the annotation cannot tell from the target (undecided in "
                    f"{SAME_PERSON_FILE.name})"
                )
    return {**result, "targets": targets, "frames": n}


def evaluate_variant(args, config: Config, setup: PetsSetup, variant=None):
    """(per identifier its fractions, per identifier per target its tally, the targets,
    the number of frames) on the sequence seen through `variant`."""
    from follow.pose.observations import skeletons_to_observations
    from follow.ukf.tracker import PeopleTracker

    setup, frames, skeletons = variant_inputs(args, config, setup, variant)
    n = len(frames)
    tracker = PeopleTracker(setup.camera, config.tracker)
    tracks_per_frame, gt_per_frame = [], []
    to_camera_px = setup.camera.image_size[0] / GT_IMAGE_SIZE[0]
    visible_frames: dict[int, int] = {}
    for index in frames:
        observations = skeletons_to_observations(skeletons[index], setup.camera.image_size,
                                                 config.pose)  # fmt: skip
        tracks_per_frame.append(tracker.update(observations, index / PETS_FPS))
        ids, positions, boxes = setup.ground_truth(index)
        gt_per_frame.append({i: Annotated(p, b.hidden_fraction, b.scaled(to_camera_px))
                             for i, p, b in zip(ids, positions, boxes, strict=True)})  # fmt: skip
        for i, b in zip(ids, boxes, strict=True):
            if b.hidden_fraction <= args.max_hidden_fraction:
                visible_frames[i] = visible_frames.get(i, 0) + 1
    min_frames = args.min_visible_s * PETS_FPS
    targets = sorted(i for i, c in visible_frames.items() if c >= min_frames)
    if args.max_targets:
        targets = targets[: args.max_targets]
    if args.whole_sequence:
        targets = first_of_each_person(targets, gt_per_frame, load_same_person())
    if not targets:
        raise ValueError(f"no person is visible for {args.min_visible_s} s in {n} frames")
    names = [s.strip() for s in args.identifiers.split(",") if s.strip()]
    per_identifier, result = {}, {}
    for name in names:
        per_target = evaluate(setup, frames, tracks_per_frame, gt_per_frame, targets, name,
                              config, args.match_distance_m, args.max_hidden_fraction,
                              whole_sequence=args.whole_sequence)  # fmt: skip
        per_identifier[name] = per_target
        result[name] = summarise_targets(per_target, args.whole_sequence)
        if result[name]["unscored_targets"]:
            log.warning("%s: targets %s were never selected (no track picked out as theirs "
                        "for %.0f s): their time is in no figure", name,
                        result[name]["unscored_targets"], PICK_STEADY_S)  # fmt: skip
    return result, per_identifier, targets, n


def summarise_targets(per_target: dict, whole_sequence: bool = False) -> dict:
    """One identifier's figures over its targets' pooled time, each target's own, and the
    targets never selected (their rows are empty, and their time is in no figure)."""
    total = OutcomeTally()
    for tally in per_target.values():
        total.merge(tally)
    return {
        **{k: round(v, 4) for k, v in total.fractions().items()},
        "seconds": {k: round(v, 1) for k, v in total.seconds.items()},
        **(
            {
                "wt_undecided": round(total.wt_undecided_fraction(), 4),
                "wt_undecided_s": round(total.wt_undecided_s, 1),
            }
            if whole_sequence
            else {}
        ),  # fmt: skip
        "per_target": {
            str(t): {k: round(v, 4) for k, v in tally.fractions().items()}
            for t, tally in per_target.items() if tally.total_s > 0
        },  # fmt: skip
        "unscored_targets": [t for t, tally in per_target.items() if tally.total_s == 0],
    }


def main_perturbed(args, config: Config, setup: PetsSetup, variants) -> dict:
    runs: dict[str, dict] = {}

    def one(variant) -> dict:
        result, _, targets, n = evaluate_variant(args, config, setup, variant)
        runs[variant.name] = {"frames": n, "targets": targets}
        for r in result.values():
            r["ct_cl"] = round(r["ct"] + r["cl"], 4)
        return result

    suite = run_suite(variants, one, SUITE_METRICS)
    if args.plot:
        plot_spread(suite, ["ct_cl", "ct"], args.plot,
                    "Target identification on PETS 2009 S2.L1 under perturbation")  # fmt: skip
    if not args.json:
        print(f"PETS 2009 S2.L1 under {len(variants)} perturbations")
        print_suite(suite, list(SUITE_METRICS), method_label="identifier")
    return {**suite, "runs": runs}
