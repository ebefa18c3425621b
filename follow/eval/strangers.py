"""`follow eval identification-sim`: strangers walk in after the target has left.

The worst thing a follower can do is drive after the wrong person. In a simulated
room seen by a still robot, the target stands in front of the camera while the
identifier learns it, then walks out of view; people then walk in one at a time and
stand where the target stood, some dressed like the target (same shirt, or the same
shirt and trousers); finally the target comes back. Everything runs as on the robot:
rendered images, the synthetic skeleton detector, the UKF tracker, the identifier and
the controller. The truth is exact, so the evaluation reports:

- wrong-person seconds: frames in which the named target is someone else;
- driving toward a stranger: frames with a forward command while the target is not
  the named one;
- re-acquisition: seconds from the target's first detection on its return until it is
  the named target again for good, named from then to the end of the run (goal: within
  3 s); a pick that probation drops again is no re-acquisition.

With `--perturb` (or `--variants`) the rendered images are seen through each pixel
change of the perturbation suite (docs/robustness.md); with `--only-after-learning` only
from the moment the target starts to leave, as when the light changes after the target
was learnt. The skeletons are the simulation's, so what is tested is the identifier.
"""

from __future__ import annotations

import logging

import numpy as np

from follow.cli_args import identifier_list, non_negative_int, positive_int
from follow.config import Config
from follow.eval.perturb import (
    Variant,
    add_learnt_target_perturb_arguments,
    print_suite,
    run_suite,
    selected_pixel_variants,
    summarise,
)
from follow.sim.appearance import Appearance, render_scene
from follow.sim.demo import DEMO_CAMERA, LOOKALIKE, TARGET_LOOK, horizon_row, person_views
from follow.sim.people import Walker
from follow.sim.world import World
from follow.types import Frame, Odometry

log = logging.getLogger(__name__)

TARGET_ID = 1
STAND_M = np.array([3.0, 0.0])  # where everyone stands, in front of the robot
OUT_LEFT_M = np.array([3.0, 5.0])  # beyond the edge of the view at 3 m
LEARN_S = 8.0
STAND_S = 4.0
WALK_MPS = 1.2
# The target's shirt and trousers on a stranger: only the face and hair differ.
TWIN = Appearance(TARGET_LOOK.shirt_bgr, TARGET_LOOK.trousers_bgr, (60, 90, 140), (20, 20, 20))
# Figures summarised over the perturbation suite: metric -> higher is better.
SUITE_METRICS = {"wrong_person_s": False, "driving_toward_stranger_s": False,
                 "reacquired_after_s": False, "never_reacquired": False}  # fmt: skip


def add_arguments(p) -> None:
    p.add_argument("--identifiers", default="ccf10,ccf10+reid", type=identifier_list,
                   help="comma-separated identifier configurations (default ccf10,ccf10+reid)")  # fmt: skip
    p.add_argument("--strangers", type=positive_int, default=5, help="people who walk in (default 5)")
    p.add_argument("--seed", type=non_negative_int, default=None,
                   help="the strangers' heights and looks, and the detector's noise (default 0)")  # fmt: skip
    p.add_argument("--seeds", help="run several draws of the scenario, e.g. 0-4 or 0,3,7, and "
                   "report each plus the mean and the worst (not with --perturb)")  # fmt: skip
    p.add_argument("--config", help="TOML configuration over the defaults")
    add_learnt_target_perturb_arguments(p)


def scenario(strangers: int, rng: np.random.Generator):
    """Walkers, their looks and the time the target starts back into view."""
    walk_s = float(np.linalg.norm(OUT_LEFT_M - STAND_M)) / WALK_MPS
    cycle_s = 2 * walk_s + STAND_S
    leave_s = LEARN_S
    first_in_s = leave_s + walk_s + 1.0
    back_s = first_in_s + strangers * (cycle_s + 0.5) + 1.0
    target = Walker(
        TARGET_ID, 1.74, np.array([STAND_M, OUT_LEFT_M, STAND_M]), speeds_mps=WALK_MPS,
        pauses_s=np.array([back_s - leave_s - walk_s, 0.0]), start_s=leave_s,
    )  # fmt: skip
    walkers, looks = [target], {TARGET_ID: TARGET_LOOK}
    dressed = [LOOKALIKE, TWIN]
    for k in range(strangers):
        pid = 10 + k
        side = OUT_LEFT_M if k % 2 == 0 else OUT_LEFT_M * np.array([1.0, -1.0])
        start = first_in_s + k * (cycle_s + 0.5)
        walkers.append(Walker(pid, float(rng.uniform(1.6, 1.9)), np.array([side, STAND_M, side]),
                              speeds_mps=WALK_MPS, pauses_s=np.array([STAND_S, 0.0]),
                              start_s=start))  # fmt: skip
        looks[pid] = dressed[k // 2] if k % 2 == 1 and k // 2 < len(dressed) else (
            Appearance.random(rng))  # fmt: skip
    end_s = back_s + walk_s + 6.0
    return walkers, looks, back_s, end_s


def run_scenario(config: Config, strangers: int = 5, seed: int = 0, variant: Variant | None = None,
                 perturb_from_s: float = 0.0) -> dict:  # fmt: skip
    """Run it for the identifier in `config`; the figures of the module docstring. With a
    `variant`, every image from `perturb_from_s` on is seen through it."""
    from follow.control.controller import FollowingController
    from follow.identify.factory import build_identifier
    from follow.pipeline import Perception, target_motion
    from follow.pose.observations import skeletons_to_observations
    from follow.sim.skeletons import SyntheticDetector
    from follow.ukf.tracker import PeopleTracker

    rng = np.random.default_rng(seed)
    walkers, looks, back_s, end_s = scenario(strangers, rng)
    world = World(walkers, camera=DEMO_CAMERA, seed=seed)
    camera = DEMO_CAMERA.detection_camera()
    detector = SyntheticDetector(camera, seed=seed)
    horizon = horizon_row(camera)
    current: dict = {}

    def detect(frame: Frame):
        return [d.skeleton for d in current["detections"]]

    perception = Perception(
        detect, lambda s: skeletons_to_observations(s, camera.image_size, config.pose),
        PeopleTracker(camera, config.tracker), build_identifier(config.identify),
    )  # fmt: skip
    controller = FollowingController(config.control)
    robot = Odometry.origin()
    wrong_s = driving_to_stranger_s = 0.0
    strangers_named: set[int] = set()
    target_back_seen_s = None
    target_named: list[tuple[float, bool]] = []  # (stamp, the target is the named one)
    track_people: dict[int, int] = {}  # track id -> the person it last saw
    for k in range(int(end_s / world.dt_s)):
        wf = world.step()
        detections = detector.detect(wf)
        current["detections"] = detections
        image = render_scene(camera.image_size, horizon,
                             person_views(wf, robot, camera, looks), seed=seed)  # fmt: skip
        if variant is not None and wf.stamp_s >= perturb_from_s:
            image = variant.apply(image, k)
        result = perception.process(Frame(image, wf.stamp_s), Odometry(0, 0, 0, wf.stamp_s), k)
        command = controller.update(target_motion(result, robot), wf.stamp_s)
        note_track_people(track_people, result.tracks, detections)
        named = _person_of(result, wf, track_people)
        if named is not None and named != TARGET_ID:
            wrong_s += world.dt_s
            strangers_named.add(named)
            if command.forward_mps > 0.0:
                driving_to_stranger_s += world.dt_s
        seen = any(d.person_id == TARGET_ID for d in detections)
        if wf.stamp_s >= back_s and seen and target_back_seen_s is None:
            target_back_seen_s = wf.stamp_s
        target_named.append((wf.stamp_s, named == TARGET_ID))
    reacquired_s = reacquisition_s(target_named, target_back_seen_s)
    return {
        "wrong_person_s": round(wrong_s, 2),
        "driving_toward_stranger_s": round(driving_to_stranger_s, 2),
        "strangers_named": sorted(strangers_named),
        "reacquired_after_s": None if reacquired_s is None else round(reacquired_s, 2),
        "strangers": strangers,
        "seconds_simulated": round(end_s, 1),
    }


def reacquisition_s(target_named: list[tuple[float, bool]], back_seen_s: float | None):
    """Seconds from `back_seen_s` (the target first seen on its return) to the start of
    the last run of frames naming it, if that run lasts to the end (it stands before the
    robot then); else None. A pick that probation drops again is no re-acquisition."""
    if back_seen_s is None or not target_named or not target_named[-1][1]:
        return None
    since_s = target_named[-1][0]
    for stamp_s, named in reversed(target_named):
        if not named or stamp_s < back_seen_s:
            break
        since_s = stamp_s
    return since_s - back_seen_s


def note_track_people(track_people: dict[int, int], tracks, detections) -> None:
    """Remember, for each track updated this frame, whose detection updated it."""
    person_of_skeleton = {id(d.skeleton): d.person_id for d in detections}
    for track in tracks:
        skeleton = None if track.observation is None else track.observation.skeleton
        if skeleton is not None and id(skeleton) in person_of_skeleton:
            track_people[track.track_id] = person_of_skeleton[id(skeleton)]


def _person_of(result, world_frame, track_people: dict[int, int]) -> int | None:
    """The simulated person the named target's track is: the one whose detection last
    updated it (a track coasting out of view stays theirs, wherever others wait), else
    the one it stands on (within 1 m; -1 for nobody)."""
    track = result.target_track
    if track is None:
        return None
    if track.track_id in track_people:
        return track_people[track.track_id]
    dist, pid = min((float(np.linalg.norm(p.position_m - track.position_m)), p.person_id)
                    for p in world_frame.people)  # fmt: skip
    return pid if dist <= 1.0 else -1


def main(args) -> dict:
    from tqdm import tqdm

    base = Config.load(args.config) if args.config else Config()
    variants = selected_pixel_variants(args, "identification-sim")
    names = [s.strip() for s in args.identifiers.split(",") if s.strip()]
    seeds = parse_seeds(args.seeds) if getattr(args, "seeds", None) else None
    if seeds is not None and args.seed is not None:  # one of the two would be ignored
        raise ValueError("give --seed or --seeds, not both")
    args.seed = args.seed if args.seed is not None else 0
    if seeds is not None:
        if variants is not None:
            raise ValueError("--seeds runs the plain scenario: take --perturb one --seed at a time")
        return _main_seeds(args, base, names, seeds)
    configs = {n: base.replace("identify", identifier=n, seed=args.seed) for n in names}
    if variants is not None:
        return _main_perturbed(args, configs, variants)
    out = {}
    for name in tqdm(names, desc="identifiers", unit="id", leave=False):
        out[name] = run_scenario(configs[name], args.strangers, args.seed)
    if not args.json:
        print(
            f"{'identifier':<12} {'wrong s':>8} {'driving s':>10} {'re-acquired s':>14}  strangers named"
        )
        for name, r in out.items():
            back = "never" if r["reacquired_after_s"] is None else f"{r['reacquired_after_s']:.2f}"
            print(f"{name:<12} {r['wrong_person_s']:8.2f} {r['driving_toward_stranger_s']:10.2f} "
                  f"{back:>14}  {r['strangers_named'] or '-'}")  # fmt: skip
    return out


def parse_seeds(text: str) -> list[int]:
    """`0-4` or `0,3,7` (or both: `0-2,9`) as a list of distinct seeds, in order."""
    seeds: list[int] = []
    try:
        for part in (p.strip() for p in text.split(",")):
            if not part:
                continue
            first, _, last = part.partition("-")
            lo, hi = int(first), int(last) if last else int(first)
            if hi < lo:
                raise ValueError
            seeds += [s for s in range(lo, hi + 1) if s not in seeds]
    except ValueError:
        raise ValueError(f"--seeds must look like 0-4 or 0,3,7 (seeds >= 0), got {text!r}") from None
    if not seeds:
        raise ValueError(f"--seeds names no seed: {text!r}")
    return seeds


def _suite_row(result: dict) -> dict:
    """One run's figures for a summary over runs: a target never re-acquired has no time
    to average, so it is counted apart (`never_reacquired`) and its time left out."""
    row = {**result, "never_reacquired": int(result["reacquired_after_s"] is None)}
    return {k: v for k, v in row.items() if v is not None}


def _main_seeds(args, base: Config, names: list[str], seeds: list[int]) -> dict:
    """One run per seed and identifier: a single draw of the strangers' heights decides
    whether stature can tell the one in the target's clothes apart, so one seed is not a
    figure (docs/identification.md)."""
    from tqdm import tqdm

    per_seed: dict[str, dict] = {}
    for seed in tqdm(seeds, desc="seeds", unit="seed"):
        row = {}
        for name in names:
            config = base.replace("identify", identifier=name, seed=seed)
            row[name] = _suite_row(run_scenario(config, args.strangers, seed))
        per_seed[f"seed {seed}"] = row
        log.info("seed %d: %s", seed, row)
    summary = summarise(per_seed, SUITE_METRICS)
    summary["worst_seed"] = summary.pop("worst_variant")
    out = {"seeds": per_seed, **summary}
    out["runs_with_a_stranger_named"] = {
        name: sum(bool(r[name]["strangers_named"]) for r in per_seed.values()) for name in names
    }
    if not args.json:
        print(f"stranger scenario over {len(seeds)} seeds, {args.strangers} strangers")
        print_suite(out, list(SUITE_METRICS), "identifier", rows_key="seeds")
        for name, count in out["runs_with_a_stranger_named"].items():
            print(f"{name}: a stranger named in {count} of {len(seeds)} runs")
    return out


def _main_perturbed(args, configs: dict[str, Config], variants: list[Variant]) -> dict:
    from_s = LEARN_S if args.only_after_learning else 0.0

    def one(variant: Variant) -> dict:
        out = {}
        for name, config in configs.items():
            out[name] = _suite_row(run_scenario(config, args.strangers, args.seed, variant,
                                                from_s))  # fmt: skip
        return out

    suite = run_suite(variants, one, SUITE_METRICS)
    suite["only_after_learning"] = args.only_after_learning
    if not args.json:
        print(f"stranger scenario under {len(variants)} pixel changes"
              f"{' after learning' if args.only_after_learning else ''}, "
              f"{args.strangers} strangers")  # fmt: skip
        print_suite(suite, list(SUITE_METRICS), "identifier")
    return suite
