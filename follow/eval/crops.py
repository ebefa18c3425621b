"""`follow eval crops`: target identification on real person crops.

The crops folder holds 14 crops of one target person (`p01..p14.jpg`) and two crops of
each of 14 other people per step (`nXX-01.jpg`, `nXX-02.jpg`). Each identifier learns
online from the first `--train-steps` steps (one step = the target crop as positive and
that step's two other crops as negatives, like one frame of the tracker), then scores
every remaining crop. Reported per identifier: ROC AUC of the confidences and balanced
accuracy at confidence 0, averaged over `--seeds` seeds of the classifier.
"""

from __future__ import annotations

import dataclasses
import logging
import os
from pathlib import Path

import cv2
import numpy as np

from follow.cli_args import identifier_list, plot_path
from follow.config import Config, IdentifyConfig

log = logging.getLogger(__name__)

IDENTIFIERS = ("ccf10", "ccf25", "channels", "reid", "ccf10+reid")
NUM_STEPS = 14
DEFAULT_TRAIN_STEPS = 7
DEFAULT_SEEDS = 5


def add_arguments(p) -> None:
    p.add_argument(
        "--crops-dir", help="folder of p*.jpg / n*.jpg (default $FOLLOW_DATA_DIR/ccf_crops)"
    )
    p.add_argument("--identifiers", default=",".join(IDENTIFIERS), type=identifier_list,
                   help=f"comma-separated identifier configurations (default {','.join(IDENTIFIERS)})")  # fmt: skip
    p.add_argument("--train-steps", type=int, default=DEFAULT_TRAIN_STEPS,
                   help="steps learnt online before scoring the rest (default 7)")  # fmt: skip
    p.add_argument("--seeds", type=int, default=DEFAULT_SEEDS,
                   help="classifier seeds averaged over (default 5)")  # fmt: skip
    p.add_argument("--config", help="TOML configuration ([identify] section used)")
    p.add_argument("--plot", type=plot_path, help="write a PNG of the ROC curves here")


@dataclasses.dataclass(frozen=True)
class CropSet:
    """The crops of one step: the target and the others, BGR uint8."""

    target: np.ndarray
    others: tuple[np.ndarray, ...]


def default_crops_dir() -> Path:
    root = os.environ.get("FOLLOW_DATA_DIR")
    if not root:
        raise ValueError("no --crops-dir given and $FOLLOW_DATA_DIR is not set")
    return Path(root) / "ccf_crops"


def load_crops(folder: Path) -> list[CropSet]:
    """The 14 steps of the crops folder; a missing or unreadable image is an error."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"crops folder {folder} not found")

    def read(name: str) -> np.ndarray:
        path = folder / name
        image = cv2.imread(str(path)) if path.exists() else None
        if image is None:
            raise ValueError(f"crop {path} is missing or not a readable image")
        return image

    return [
        CropSet(read(f"p{i:02d}.jpg"), (read(f"n{i:02d}-01.jpg"), read(f"n{i:02d}-02.jpg")))
        for i in range(1, NUM_STEPS + 1)
    ]


def ranked_scores(scores) -> np.ndarray:
    """Scores as floats for ranking, NaN (a crop without a cue: it passes no bar) as the
    lowest: sorted as the highest, one NaN negative made every bar NaN (TAR 0) and
    outranked every positive in the AUC."""
    out = np.asarray(scores, dtype=float).copy()
    out[np.isnan(out)] = -np.inf
    return out


def roc_auc(positive_scores: np.ndarray, negative_scores: np.ndarray) -> float:
    """Probability that a positive scores above a negative (ties count one half; a NaN
    score ranks lowest)."""
    p = ranked_scores(positive_scores)[:, None]
    n = ranked_scores(negative_scores)[None, :]
    if p.size == 0 or n.size == 0:
        raise ValueError("ROC AUC needs at least one positive and one negative score")
    return float((p > n).mean() + 0.5 * (p == n).mean())


def roc_curve(positive_scores: np.ndarray, negative_scores: np.ndarray):
    """(false positive rate, true positive rate) over all thresholds."""
    thresholds = np.unique(np.concatenate([positive_scores, negative_scores, [np.inf]]))[::-1]
    tpr = np.array([(positive_scores >= t).mean() for t in thresholds])
    fpr = np.array([(negative_scores >= t).mean() for t in thresholds])
    return np.concatenate([[0.0], fpr, [1.0]]), np.concatenate([[0.0], tpr, [1.0]])


def balanced_accuracy(positive_scores: np.ndarray, negative_scores: np.ndarray) -> float:
    """Mean of the target and non-target recalls at confidence 0."""
    return float(0.5 * ((positive_scores > 0).mean() + (negative_scores <= 0).mean()))


def evaluate_identifier(
    steps: list[CropSet], config: IdentifyConfig, train_steps: int, seeds: list[int]
) -> dict:
    """AUC and balanced accuracy (means over seeds) and the scores of every seed."""
    from follow.identify.factory import build_appearance_model

    if not 1 <= train_steps < len(steps):
        raise ValueError(f"--train-steps must lie in 1..{len(steps) - 1}, got {train_steps}")
    model = build_appearance_model(config)
    train, test = steps[:train_steps], steps[train_steps:]
    train_cues = [
        (model.describe_crops([s.target]), model.describe_crops(list(s.others))) for s in train
    ]
    test_pos = model.describe_crops([s.target for s in test])
    test_neg = model.describe_crops([o for s in test for o in s.others])
    runs = []
    for seed in seeds:
        model.config = dataclasses.replace(config, seed=seed)
        model.reset()
        for positives, negatives in train_cues:
            model.learn(positives, negatives)
        pos, neg = model.confidence(test_pos), model.confidence(test_neg)
        runs.append(
            {"auc": roc_auc(pos, neg), "balanced_accuracy": balanced_accuracy(pos, neg),
             "positive_scores": pos, "negative_scores": neg}
        )  # fmt: skip
    return {
        "auc": float(np.mean([r["auc"] for r in runs])),
        "balanced_accuracy": float(np.mean([r["balanced_accuracy"] for r in runs])),
        "runs": runs,
    }


def evaluate_crops(
    steps: list[CropSet], identifiers: list[str], config: IdentifyConfig, train_steps: int,
    seeds: list[int],
) -> dict:  # fmt: skip
    """{identifier: evaluate_identifier(...)} with a progress bar."""
    from tqdm import tqdm

    out = {}
    for name in tqdm(identifiers, desc="identifiers", unit="id", leave=False):
        out[name] = evaluate_identifier(
            steps, dataclasses.replace(config, identifier=name), train_steps, seeds
        )
    return out


def _plot(results: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 5))
    for name, res in results.items():
        run = res["runs"][0]
        fpr, tpr = roc_curve(run["positive_scores"], run["negative_scores"])
        ax.plot(fpr, tpr, drawstyle="steps-post", label=f"{name} (AUC {res['auc']:.3f})")
    ax.plot([0, 1], [0, 1], color="0.7", lw=0.8, ls="--")
    ax.set_xlabel("false positive rate")
    ax.set_ylabel("true positive rate")
    ax.set_title("target identification on person crops (first seed)")
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(args) -> dict:
    config = Config.load(args.config).identify if args.config else IdentifyConfig()
    folder = Path(args.crops_dir) if args.crops_dir else default_crops_dir()
    identifiers = [s.strip() for s in args.identifiers.split(",") if s.strip()]
    if args.seeds < 1:
        raise ValueError(f"--seeds must be >= 1, got {args.seeds}")
    seeds = [config.seed + k for k in range(args.seeds)]
    steps = load_crops(folder)
    results = evaluate_crops(steps, identifiers, config, args.train_steps, seeds)
    if not args.json:
        n_test = NUM_STEPS - args.train_steps
        print(f"crops: {folder}  trained on steps 1-{args.train_steps}, scored "
              f"{n_test} target and {2 * n_test} other crops, {len(seeds)} seed(s)")  # fmt: skip
        print(f"{'identifier':<14} {'AUC':>6} {'min AUC':>8} {'bal. acc.':>10}")
        for name, res in results.items():
            min_auc = min(r["auc"] for r in res["runs"])
            print(f"{name:<14} {res['auc']:6.3f} {min_auc:8.3f} {res['balanced_accuracy']:10.3f}")
    if args.plot:
        _plot(results, args.plot)
        log.info("ROC curves written to %s", args.plot)
    return {
        name: {"auc": res["auc"], "balanced_accuracy": res["balanced_accuracy"]}
        for name, res in results.items()
    }
