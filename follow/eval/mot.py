"""CLEAR MOT and IDF1 on the ground plane, with motmetrics.

Ground truth and hypotheses are positions in metres; a pair can match when they are at
most `match_threshold_m` apart. MOTP is reported in metres (mean distance of matches).
"""

from __future__ import annotations

import warnings

import numpy as np


class GroundPlaneMot:
    """Accumulates frames of (ids, positions) and computes the metrics at the end."""

    def __init__(self, match_threshold_m: float = 1.0):
        import motmetrics as mm

        self._mm = mm
        self.match_threshold_m = match_threshold_m
        self._acc = mm.MOTAccumulator(auto_id=True)

    def add_frame(
        self,
        gt_ids: list[int],
        gt_xy_m: np.ndarray,
        hyp_ids: list[int],
        hyp_xy_m: np.ndarray,
    ) -> None:
        gt = np.asarray(gt_xy_m, float).reshape(-1, 2)
        hyp = np.asarray(hyp_xy_m, float).reshape(-1, 2)
        if len(gt) and len(hyp):
            dist = np.linalg.norm(gt[:, None, :] - hyp[None, :, :], axis=2)
            dist[dist > self.match_threshold_m] = np.nan
        else:
            dist = np.empty((len(gt), len(hyp)))
        self._acc.update(list(gt_ids), list(hyp_ids), dist)

    def summary(self) -> dict:
        mm = self._mm
        metrics = ["mota", "motp", "idf1", "num_switches", "num_misses",
                   "num_false_positives", "num_objects", "precision", "recall"]  # fmt: skip
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            df = mm.metrics.create().compute(self._acc, metrics=metrics, name="all")
        row = df.loc["all"]

        def f(name: str) -> float:
            v = float(row[name])
            return v if np.isfinite(v) else float("nan")

        return {
            "mota": round(f("mota"), 4),
            "motp_m": round(f("motp"), 4),
            "idf1": round(f("idf1"), 4),
            "id_switches": int(row["num_switches"]),
            "misses": int(row["num_misses"]),
            "false_positives": int(row["num_false_positives"]),
            "gt_objects": int(row["num_objects"]),
            "precision": round(f("precision"), 4),
            "recall": round(f("recall"), 4),
        }
