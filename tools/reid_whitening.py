#!/usr/bin/env python3
"""Would a learnt metric on the re-id embeddings make verification safer? A measurement.

Within-class whitening (WCCN: subtract the mean embedding, whiten by the regularised
covariance of each person's embeddings around their own mean, renormalise) is fitted
on CUHK03's even identities, its regularisation chosen by two-fold cross-validation
among them; the odd identities are scored as `follow eval verification` scores them
(gallery of one camera, probes from the other, highest cosine similarity). Then the
same transform is applied to the robot-camera crops (`ccf_crops`), where what matters
is where the two hard negatives fall against the accept bar calibrated on the even
identities:

    python tools/reid_whitening.py [--data-dir D] [--model-dir M] [--json]

Nothing is written; the transform is not used by the identifier (docs/identification.md
says why).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

REGULARISATIONS = (0.1, 0.3, 1.0, 3.0, 10.0)
ROBOT_ENROL = 5


def fit_whitening(groups: list[np.ndarray], regularisation: float):
    """A function mapping unit embeddings to whitened unit embeddings, fitted on
    `groups` (one array of embeddings per person)."""
    everything = np.concatenate(groups)
    mean = everything.mean(axis=0)
    spread = np.concatenate([g - g.mean(axis=0) for g in groups])
    within = spread.T @ spread / len(spread)
    dim = within.shape[0]
    within += regularisation * np.trace(within) / dim * np.eye(dim)
    values, vectors = np.linalg.eigh(within)
    project = vectors / np.sqrt(values)

    def transform(embeddings: np.ndarray) -> np.ndarray:
        z = (embeddings - mean) @ project
        return z / np.linalg.norm(z, axis=1, keepdims=True)

    return transform


def verification_scores(views: dict, transform) -> tuple[np.ndarray, np.ndarray]:
    """Same-person and other-person gallery similarities over `views`
    ({identity: (camera A embeddings, camera B embeddings)}) after `transform`, as
    `follow eval verification` computes them."""
    from follow.eval.verification import gallery_similarities

    return gallery_similarities({i: tuple(transform(v) for v in pair) for i, pair in views.items()})


def figures(positive: np.ndarray, negative: np.ndarray) -> dict:
    from follow.eval.crops import roc_auc

    out = {"auc": roc_auc(positive, negative)}
    for far in (0.01, 0.001):
        out[f"tar_at_far_{far:g}"] = float((positive > np.quantile(negative, 1 - far)).mean())
    return out


def main(argv=None) -> int:
    from follow.eval.verification import _read, load_cuhk03
    from follow.identify.reid import ReidEmbedder

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data-dir", default=os.environ.get("FOLLOW_DATA_DIR"))
    p.add_argument("--model-dir", default=os.environ.get("FOLLOW_MODEL_DIR"))
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    if not args.data_dir or not args.model_dir:
        p.error("--data-dir and --model-dir (or FOLLOW_DATA_DIR / FOLLOW_MODEL_DIR) are needed")
    data, models = Path(args.data_dir), Path(args.model_dir)
    embedder = ReidEmbedder(models / "reid" / "person-reidentification-retail-0248.onnx", 2)
    views = {
        person.identity: tuple(embedder.embed_crops(v) for v in person.views)
        for person in load_cuhk03(data / "cuhk03_val")
    }
    even = {i: v for i, v in views.items() if i % 2 == 0}
    odd = {i: v for i, v in views.items() if i % 2 == 1}
    halves = [dict(list(even.items())[k::2]) for k in (0, 1)]

    def groups(subset):
        return [np.concatenate(v) for v in subset.values()]

    cross_validation = {}
    for reg in REGULARISATIONS:
        folds = [
            figures(*verification_scores(halves[1 - k], fit_whitening(groups(halves[k]), reg)))
            for k in (0, 1)
        ]  # fmt: skip
        cross_validation[reg] = float(np.mean([f["tar_at_far_0.01"] for f in folds]))
    chosen = max(cross_validation, key=cross_validation.get)

    crops = data / "ccf_crops"
    target = embedder.embed_crops([_read(crops / f"p{i:02d}.jpg") for i in range(1, 15)])
    strangers = embedder.embed_crops([_read(p) for p in sorted(crops.glob("n*.jpg"))])
    results = {"cross_validation_tar_at_far_0.01": cross_validation, "regularisation": chosen}
    for name, transform in (
        ("raw", lambda e: e),
        ("whitened", fit_whitening(groups(even), chosen)),
    ):
        _, calibration_negative = verification_scores(even, transform)
        gallery = transform(target[:ROBOT_ENROL])
        robot_pos = (transform(target[ROBOT_ENROL:]) @ gallery.T).max(axis=1)
        robot_neg = (transform(strangers) @ gallery.T).max(axis=1)
        results[name] = {
            "cuhk03_odd": figures(*verification_scores(odd, transform)),
            "accept_bar_far_0.01": float(np.quantile(calibration_negative, 0.99)),
            "robot_target_lowest": float(robot_pos.min()),
            "robot_stranger_highest": float(robot_neg.max()),
            # how rare, among calibration strangers, the robot's hardest stranger is
            "robot_stranger_far": float((calibration_negative >= robot_neg.max()).mean()),
        }
    if args.json:
        print(json.dumps(results))
        return 0
    print(f"regularisation {chosen} (2-fold cross-validation on the even identities: "
          + ", ".join(f"{r:g} -> {t:.3f}" for r, t in cross_validation.items()) + ")")  # fmt: skip
    print(f"{'space':<9} {'AUC':>6} {'TAR@1%':>7} {'TAR@0.1%':>9} {'bar@1%':>7} "
          f"{'robot target min':>17} {'robot stranger max':>19} {'its FAR':>8}")  # fmt: skip
    for name in ("raw", "whitened"):
        r = results[name]
        c = r["cuhk03_odd"]
        print(f"{name:<9} {c['auc']:6.3f} {c['tar_at_far_0.01']:7.3f} {c['tar_at_far_0.001']:9.3f} "
              f"{r['accept_bar_far_0.01']:7.3f} {r['robot_target_lowest']:17.3f} "
              f"{r['robot_stranger_highest']:19.3f} {r['robot_stranger_far']:8.4f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
