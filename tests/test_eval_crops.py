"""`follow eval crops` on the real crops, and its metrics."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from follow.config import IdentifyConfig
from follow.eval.crops import balanced_accuracy, evaluate_identifier, load_crops, roc_auc


def test_roc_auc_and_balanced_accuracy():
    assert roc_auc(np.array([0.9, 0.8]), np.array([0.1, -0.5])) == 1.0
    assert roc_auc(np.array([0.1]), np.array([0.9, -0.5])) == 0.5
    assert roc_auc(np.array([0.2]), np.array([0.2])) == 0.5
    assert balanced_accuracy(np.array([0.5, -0.1]), np.array([-0.3, -0.2])) == 0.75
    with pytest.raises(ValueError, match="at least one"):
        roc_auc(np.array([]), np.array([0.1]))


def test_ccf10_identifies_the_target_on_real_crops(data_path, model_path):
    model_path("ccf/ccf10")
    steps = load_crops(data_path("ccf_crops"))
    assert len(steps) == 14 and all(len(s.others) == 2 for s in steps)
    result = evaluate_identifier(steps, IdentifyConfig(identifier="ccf10"), 7, [0, 1])
    assert result["auc"] >= 0.95
    assert result["balanced_accuracy"] >= 0.8
    run = result["runs"][0]
    assert len(run["positive_scores"]) == 7 and len(run["negative_scores"]) == 14


def test_missing_crop_is_a_clear_error(data_path, tmp_path):
    src = data_path("ccf_crops")
    for f in src.glob("*.jpg"):
        shutil.copy(f, tmp_path / f.name)
    (tmp_path / "n05-02.jpg").unlink()
    with pytest.raises(ValueError, match="n05-02.jpg is missing"):
        load_crops(tmp_path)
    with pytest.raises(ValueError, match="not found"):
        load_crops(tmp_path / "nope")
