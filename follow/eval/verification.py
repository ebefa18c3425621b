"""`follow eval verification`: open-set target verification on real person crops.

A following robot learns its target from a few seconds of views, then must accept that
person again later and reject everybody else, also when nobody else is in view to
compare with. Here each identity of CUHK03 (`$FOLLOW_DATA_DIR/cuhk03_val`: 100 people,
each seen by two cameras) is enrolled in turn from one camera's crops, as the
identifier learns a target (positives, with its recoloured copies as the only
negatives); then the identity's crops from the other camera must be accepted and every
crop of every other identity rejected. Both directions (A -> B, B -> A) count.

Identities are split: the even ones calibrate the re-id similarity bar (the similarity
that 1 % and 0.1 % of other people's crops reach, `reid_accept_similarity` and
`reid_strict_similarity`), the odd ones are scored. The robot-camera crops
(`ccf_crops`: p01-p05 enrol the target, p06-p14 are probes, the two hard negatives
n*.jpg are the others) are scored too.

With `--perturb` (or `--variants`) the same is done over the pixel changes of the
perturbation suite (re-encoding, light, noise, blur: docs/robustness.md), every crop seen
through each in turn; with `--only-after-learning` the target is enrolled from its crops
as they are and only the crops scored after it are changed, as when the light or the
focus changes once the robot knows its target.

The score of an identifier is its re-identification decision moved to 0: the lowest of
the fused confidence over `reid_confidence`, with two cues the boosted classifier's own
confidence over the same bar, and, with re-id, the gallery similarity over its bar; so
`score >= 0` is what the shipped settings accept.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import os
from pathlib import Path

import cv2
import numpy as np

from follow.cli_args import identifier_list
from follow.config import Config, IdentifyConfig
from follow.eval.crops import ranked_scores, roc_auc
from follow.eval.perturb import (
    Variant,
    add_learnt_target_perturb_arguments,
    print_suite,
    run_suite,
    selected_pixel_variants,
)

log = logging.getLogger(__name__)

IDENTIFIERS = ("ccf10", "reid", "ccf10+reid")
FARS = (0.01, 0.001)
ENROL_CCF_CROPS = 5
MIN_IDENTITIES = 4  # `--identities`: 2 even (calibration) and 2 odd (scored) at least
# Figures summarised over the perturbation suite: metric -> higher is better.
SUITE_METRICS = {"auc": True, "tar_at_far_0.01": True, "shipped_tar": True,
                 "shipped_far": False}  # fmt: skip


def add_arguments(p) -> None:
    p.add_argument("--data-dir", help="folder holding cuhk03_val/ and ccf_crops/ "
                   "(default $FOLLOW_DATA_DIR)")  # fmt: skip
    p.add_argument("--identifiers", default=",".join(IDENTIFIERS), type=identifier_list,
                   help=f"comma-separated identifier configurations (default {','.join(IDENTIFIERS)})")  # fmt: skip
    p.add_argument("--identities", type=int,
                   help=f"use only the first N CUHK03 identities, N >= {MIN_IDENTITIES} "
                        "(a quick run)")  # fmt: skip
    p.add_argument("--config", help="TOML configuration ([identify] section used)")
    add_learnt_target_perturb_arguments(p)


@dataclasses.dataclass(frozen=True)
class Person:
    """One identity's crops from each camera."""

    identity: int
    views: tuple[list[np.ndarray], list[np.ndarray]]


def _read(path: Path) -> np.ndarray:
    image = cv2.imread(str(path))
    if image is None:
        raise ValueError(f"crop {path} is not a readable image")
    return image


def load_cuhk03(folder: Path, limit: int | None = None) -> list[Person]:
    """CUHK03 crops `NNNN_KK.jpg` (KK 00-04 camera A, 05-09 camera B) by identity."""
    folder = Path(folder)
    files = sorted(folder.glob("*_*.jpg")) if folder.is_dir() else []
    if not files:
        raise ValueError(f"no CUHK03 crops (NNNN_KK.jpg) in {folder}")
    people: dict[int, tuple[list, list]] = {}
    for path in files:
        identity, view = _identity_and_view(path)
        people.setdefault(identity, ([], []))[view >= 5].append(_read(path))
    out = [Person(i, v) for i, v in sorted(people.items()) if v[0] and v[1]]
    return out[:limit] if limit else out


def _identity_and_view(path: Path) -> tuple[int, int]:
    """(identity, view) of a crop named `NNNN_KK.jpg`; a file named otherwise in the
    folder is an error naming it, not a bare unpacking or int() error."""
    parts = path.stem.split("_")
    if len(parts) != 2 or not all(p.isdigit() for p in parts):
        raise ValueError(f"{path}: not a CUHK03 crop name (NNNN_KK.jpg: identity, view 00-09)")
    return int(parts[0]), int(parts[1])


def perturbed_people(people: list[Person], variant: Variant) -> list[Person]:
    """The same people with every crop seen through `variant` (the k-th crop of the list
    seeds its noise, so a run is repeatable)."""
    index = itertools.count()
    return [
        Person(p.identity, tuple([variant.apply(c, next(index)) for c in view] for view in p.views))
        for p in people
    ]


def decision_scores(model, enrol: list, probes: list, config: IdentifyConfig) -> np.ndarray:
    """Enrol the target from `enrol` (appearances with their crops), then the score of
    each probe appearance: >= 0 where the shipped settings accept it."""
    model.reset()
    updates = max(config.initial_training_frames, len(enrol))
    for k in range(updates):
        appearance, crop = enrol[k % len(enrol)]
        synthetic = model.synthetic_negatives(crop, config.min_negatives_per_update)
        model.learn([appearance], [], synthetic, model.mirrored_positives(crop))
    scores = []
    if model.classifier is not None:
        scores.append(model.confidence(probes) - config.reid_confidence)
        alone = model.classifier_confidence(probes)  # with two cues each must agree
        if alone is not None:
            scores.append(alone - config.reid_confidence)
    similarity = model.similarity(probes)
    if similarity is not None:
        if model.classifier is None:  # re-id alone: its confidence is its similarity
            scores.append(model.confidence(probes) - config.reid_confidence)
        scores.append(similarity - config.reid_accept_similarity)
    parts = model.part_distances(probes)  # every part must match
    if parts is not None:
        scores.append(config.reid_part_colour_distance - parts)
    return np.min(scores, axis=0)


def far_bar(neg: np.ndarray, far: float) -> float:
    """The lowest score bar that at most `far` of the negatives pass (score > bar): the
    negative with floor(far * n) others above it. An interpolated quantile lies below
    the highest negative of a small set (the robot crops' 28), which then passes. With
    fewer than 1 / `far` negatives none may pass: the bar is then at FAR 0."""
    ranked = np.sort(ranked_scores(neg))
    allowed = int(np.floor(far * len(ranked) + 1e-9))
    return float(ranked[len(ranked) - 1 - allowed])


def operating_figures(pos: np.ndarray, neg: np.ndarray) -> dict:
    """AUC, true-accept rate at each false-accept rate (and the false-accept rate its bar
    gives: lower where the negatives are too few to resolve it), and at the shipped
    score 0."""
    out = {"auc": roc_auc(pos, neg), "positives": len(pos), "negatives": len(neg)}
    for far in FARS:
        bar = far_bar(neg, far)
        # a NaN score (a crop without a cue) passes no bar, as it ranks in `far_bar`
        out[f"tar_at_far_{far:g}"] = float((np.asarray(pos) > bar).mean())
        out[f"realised_far_at_far_{far:g}"] = float((np.asarray(neg) > bar).mean())
    out["shipped_tar"] = float((pos >= 0).mean())
    out["shipped_far"] = float((neg >= 0).mean())
    return out


def verify_cuhk03(model, people: list[Person], config: IdentifyConfig,
                  seen: list[Person] | None = None) -> tuple[dict, dict]:  # fmt: skip
    """(figures, raw scores) over enrolments of every identity in `people`, both ways;
    the crops scored after each enrolment are those of `seen` (the same people, e.g. seen
    through a perturbation; default `people`)."""
    from tqdm import tqdm

    described = {p.identity: [model.describe_crops(v) for v in p.views] for p in people}
    scored = described if seen is None or seen is people else {
        p.identity: [model.describe_crops(v) for v in p.views] for p in seen
    }  # fmt: skip
    crops = {p.identity: p.views for p in people}
    pos, neg = [], []
    for person in tqdm(people, desc=f"enrolments ({model.name})", unit="id", leave=False):
        for cam in (0, 1):
            crops_size = (config.crop_width_px, config.crop_height_px)
            enrol = [
                (a, cv2.resize(c, crops_size, interpolation=cv2.INTER_AREA))
                for a, c in zip(
                    described[person.identity][cam], crops[person.identity][cam], strict=True
                )  # fmt: skip
            ]
            probes = list(scored[person.identity][1 - cam])
            others = [a for p in people if p.identity != person.identity
                      for view in scored[p.identity] for a in view]  # fmt: skip
            scores = decision_scores(model, enrol, probes + others, config)
            pos.append(scores[: len(probes)])
            neg.append(scores[len(probes) :])
    pos, neg = np.concatenate(pos), np.concatenate(neg)
    return operating_figures(pos, neg), {"positive": pos, "negative": neg}


def gallery_similarities(views: dict) -> tuple[np.ndarray, np.ndarray]:
    """Highest similarity to a gallery of one camera's embeddings of a person, for the
    same person's embeddings from the other camera (positives) and for every other
    person's (negatives), both directions; `views`: {identity: (camera A, camera B)}
    unit embeddings."""
    positives, negatives = [], []
    for identity, pair in views.items():
        others = np.concatenate([v for i, p in views.items() if i != identity for v in p])
        for cam in (0, 1):
            gallery = pair[cam]
            positives.append((pair[1 - cam] @ gallery.T).max(axis=1))
            negatives.append((others @ gallery.T).max(axis=1))
    return np.concatenate(positives), np.concatenate(negatives)


def calibrate_similarity(model, people: list[Person], config: IdentifyConfig) -> dict:
    """The re-id similarity that other people reach at each false-accept rate (gallery
    of one camera's crops, probes of everyone else), on `people`."""
    views = {p.identity: tuple(model.reid.embed_crops(v) for v in p.views) for p in people}
    _, negatives = gallery_similarities(views)
    if len(negatives) * min(FARS) < 1:
        log.warning("re-id calibration on %d stranger pairs cannot resolve FAR %g: the "
                    "bars are those of fewer pairs passing", len(negatives), min(FARS))  # fmt: skip
    return {f"similarity_at_far_{far:g}": far_bar(negatives, far) for far in FARS}


PART_COLOUR_TAR = 0.99  # the part-colour bar keeps this share of one person's crops


def calibrate_part_colours(people: list[Person], config: IdentifyConfig) -> dict:
    """The part-colour distance (`reid_part_colour_distance`) within which
    `PART_COLOUR_TAR` of one person's crops stay, in their least alike part, of the
    colours of their other crops from the same camera (each crop against the others,
    as a robot sees its target again), the crops seen as they are and through each
    pixel change of the perturbation suite, pooled; on `people`. And the share of other
    people's crops (the other camera's) that the rule alone would then turn away."""
    from follow.ccf.features import resize_crops
    from follow.eval.perturb import SUITE
    from follow.identify.parts import colour_distances, part_colours

    size = (config.crop_width_px, config.crop_height_px)

    def colours(crops) -> np.ndarray:
        return part_colours(resize_crops(crops, size), config)

    learnt = {p.identity: [colours(v) for v in p.views] for p in people}
    same = []
    for variant in [None] + [v for v in SUITE if v.changes_pixels]:
        index = itertools.count()
        for person in people:
            for cam, crops in enumerate(person.views):
                if len(crops) < 2:
                    continue
                gallery = learnt[person.identity][cam]
                seen = gallery if variant is None else colours(
                    [variant.apply(c, next(index)) for c in crops])  # fmt: skip
                for i in range(len(crops)):
                    others = np.delete(gallery, i, axis=0)
                    same.append(colour_distances(seen[i : i + 1], others).min(axis=1).max())
    bar = float(np.quantile(same, PART_COLOUR_TAR))
    other = [
        colour_distances(np.concatenate([learnt[q.identity][1 - cam] for q in people
                                         if q.identity != p.identity]),
                         learnt[p.identity][cam]).min(axis=1).max(axis=1)
        for p in people for cam in (0, 1)
    ]  # fmt: skip
    return {
        f"part_colour_distance_at_tar_{PART_COLOUR_TAR:g}": bar,
        "part_colour_others_turned_away": float((np.concatenate(other) > bar).mean()),
    }


def verify_robot_crops(model, folder: Path, config: IdentifyConfig, variant: Variant | None = None,
                       only_after_learning: bool = False) -> dict:  # fmt: skip
    """Enrol p01-p05 of the robot-camera crops; p06-p14 must pass, n*.jpg must not. With
    a `variant` every crop is seen through it (only those after enrolment with
    `only_after_learning`)."""
    targets = [_read(folder / f"p{i:02d}.jpg") for i in range(1, 15)]
    others = [_read(p) for p in sorted(folder.glob("n*.jpg"))]
    if not others:
        raise ValueError(f"no hard negatives n*.jpg in {folder}")
    size = (config.crop_width_px, config.crop_height_px)
    enrol_crops = targets[:ENROL_CCF_CROPS]
    if variant is not None:
        seen = [variant.apply(c, k) for k, c in enumerate(targets + others)]
        targets, others = seen[: len(targets)], seen[len(targets) :]
        enrol_crops = enrol_crops if only_after_learning else targets[:ENROL_CCF_CROPS]
    enrol = list(zip(model.describe_crops(enrol_crops),
                     [cv2.resize(c, size, interpolation=cv2.INTER_AREA) for c in enrol_crops],
                     strict=True))  # fmt: skip
    probes = model.describe_crops(targets[ENROL_CCF_CROPS:])
    scores = decision_scores(model, enrol, probes + model.describe_crops(others), config)
    return operating_figures(scores[: len(probes)], scores[len(probes) :])


def data_root(data_dir: str | None, has_option: bool = True) -> Path:
    """The data folder: `--data-dir`, else $FOLLOW_DATA_DIR; an error names which one
    is missing or is no folder (`has_option` False: a command without --data-dir)."""
    if data_dir:
        source, root = "--data-dir", data_dir
    else:
        source, root = "$FOLLOW_DATA_DIR", os.environ.get("FOLLOW_DATA_DIR") or ""
    if not root:
        given = "no --data-dir given and " if has_option else ""
        raise ValueError(f"{given}$FOLLOW_DATA_DIR is not set")
    if not Path(root).is_dir():
        raise ValueError(f"{source} {root}: no such folder")
    return Path(root)


def main(args) -> dict:
    from follow.identify.factory import build_appearance_model, parse_identifier

    if args.identities is not None and args.identities < MIN_IDENTITIES:
        raise ValueError(
            f"--identities must be >= {MIN_IDENTITIES} (2 even ones calibrate, 2 odd ones "
            f"are scored), got {args.identities}"
        )
    config = Config.load(args.config).identify if args.config else IdentifyConfig()
    root = data_root(args.data_dir)
    variants = selected_pixel_variants(args, "verification")
    if not (root / "ccf_crops").is_dir():  # scored last: say so before CUHK03's minutes
        raise ValueError(f"{root}: no ccf_crops/ folder (the robot-camera crops this "
                         "evaluation scores besides cuhk03_val/)")  # fmt: skip
    people = load_cuhk03(root / "cuhk03_val", args.identities)
    calibration = [p for p in people if p.identity % 2 == 0]
    test = [p for p in people if p.identity % 2 == 1]
    if len(calibration) < 2 or len(test) < 2:
        raise ValueError("need at least 2 even and 2 odd identities")
    identifiers = [s.strip() for s in args.identifiers.split(",") if s.strip()]
    models = {}
    for name in identifiers:
        parse_identifier(name)
        models[name] = build_appearance_model(dataclasses.replace(config, identifier=name))
    reid = next((m for m in models.values() if m.reid is not None), None)
    results: dict = {
        "calibration": {
            **({} if reid is None else calibrate_similarity(reid, calibration, config)),
            **calibrate_part_colours(calibration, config),
        }
    }
    after = getattr(args, "only_after_learning", False)

    def verify(variant: Variant | None) -> dict:
        seen = test if variant is None else perturbed_people(test, variant)
        enrolled = test if after else seen
        return {
            name: {
                "cuhk03_test": verify_cuhk03(model, enrolled, config, seen)[0],
                "robot_crops": verify_robot_crops(
                    model, root / "ccf_crops", config, variant, after
                ),
            }
            for name, model in models.items()
        }

    if variants is None:
        results["identifiers"] = verify(None)
        if not args.json:
            _print(results, len(calibration), len(test))
        return results

    def one(variant: Variant) -> dict:  # {"<identifier> <set>": figures}
        return {f"{name} {key}": figures for name, sets in verify(variant).items()
                for key, figures in sets.items()}  # fmt: skip

    results.update(run_suite(variants, one, SUITE_METRICS))
    results["only_after_learning"] = after
    if not args.json:
        print(f"open-set verification under {len(variants)} pixel changes"
              f"{' after learning' if after else ''}, {len(test)} CUHK03 test identities")  # fmt: skip
        print_suite(results, list(SUITE_METRICS), "identifier set")
    return results


def _print(results: dict, n_calibration: int, n_test: int) -> None:
    c = results["calibration"]
    if "similarity_at_far_0.01" in c:
        print(f"re-id similarity reached by other people, {n_calibration} calibration "
              f"identities: {c['similarity_at_far_0.01']:.3f} at FAR 1 %, "
              f"{c['similarity_at_far_0.001']:.3f} at FAR 0.1 %")  # fmt: skip
    bar = c[f"part_colour_distance_at_tar_{PART_COLOUR_TAR:g}"]
    print(f"part-colour distance within which {PART_COLOUR_TAR:.0%} of one person's crops "
          f"stay of their other crops from the same camera, under the suite's pixel changes "
          f"too: {bar:.3f} (other people turned away by it alone: "
          f"{c['part_colour_others_turned_away']:.1%})")  # fmt: skip
    print(f"{'identifier':<12} {'set':<12} {'AUC':>6} {'TAR@1%':>7} {'TAR@0.1%':>9} "
          f"{'shipped TAR':>12} {'FAR':>7}")  # fmt: skip
    for name, sets in results["identifiers"].items():
        for label, key in (
            ("CUHK03 " + str(n_test), "cuhk03_test"),
            ("robot crops", "robot_crops"),
        ):
            r = sets[key]
            print(f"{name:<12} {label:<12} {r['auc']:6.3f} {r['tar_at_far_0.01']:7.3f} "
                  f"{r['tar_at_far_0.001']:9.3f} {r['shipped_tar']:12.3f} {r['shipped_far']:7.4f}")  # fmt: skip
    negatives = {label: r["negatives"] for sets in results["identifiers"].values()
                 for label, r in (("CUHK03", sets["cuhk03_test"]),
                                  ("robot crops", sets["robot_crops"]))}  # fmt: skip
    for label, n in negatives.items():
        if n * min(FARS) < 1:
            print(f"{label}: {n} negatives resolve no FAR under {1 / n:.2%}; TAR at a lower "
                  "FAR is at the one its bar gives (realised_far_at_far_* in --json)")
