"""Open-set verification on real crops: strangers rejected, the target accepted."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from follow.eval.verification import load_cuhk03, main, operating_figures


def test_operating_figures_count_accepts_at_zero_and_at_each_false_accept_rate():
    neg = np.linspace(-1.0, 0.0, 1000, endpoint=False)  # none accepted at score >= 0
    pos = np.array([-0.5, 0.1, 0.2, 0.3])
    figures = operating_figures(pos, neg)
    assert figures["shipped_far"] == 0.0 and figures["shipped_tar"] == 0.75
    assert figures["tar_at_far_0.01"] == 0.75  # -0.5 lies below the 99th percentile
    assert figures["auc"] == pytest.approx((0.5 + 3) / 4, abs=1e-3)  # -0.5 beats half the negatives


def test_true_accepts_at_a_false_accept_rate_let_through_no_more_negatives_than_it():
    # The robot crops' 28 negatives: at FAR 1 % not one of them may pass the bar, so a
    # target crop scoring below the highest negative is not accepted there.
    neg = np.append(np.linspace(-1.0, -0.1, 27), -0.01)
    pos = np.array([-0.02, 0.5, 0.6])
    figures = operating_figures(pos, neg)
    assert figures["tar_at_far_0.01"] == pytest.approx(2 / 3)
    assert figures["tar_at_far_0.001"] == pytest.approx(2 / 3)
    # With 1000 negatives, 1 % is 10 of them: the bar is the 11th highest.
    neg = np.linspace(-1.0, 0.0, 1000, endpoint=False)
    pos = np.array([neg[-11] + 1e-4, neg[-12] + 1e-4])
    assert operating_figures(pos, neg)["tar_at_far_0.01"] == 0.5


def test_a_crop_without_a_cue_ranks_lowest_and_breaks_no_figure():
    """A NaN score (no embedding or part colours: it passes no bar) sorted as the highest:
    one NaN negative made the bar NaN, TAR 0, and outranked every positive in the AUC."""
    neg = np.append(np.linspace(-1.0, -0.1, 27), np.nan)
    pos = np.array([0.2, 0.5, np.nan])
    figures = operating_figures(pos, neg)
    assert figures["tar_at_far_0.01"] == figures["tar_at_far_0.001"] == pytest.approx(2 / 3)
    assert figures["auc"] == pytest.approx((2 * 28 + 0.5) / 84)  # the NaN pair ties


def test_a_false_accept_rate_too_fine_for_the_negatives_is_reported_as_the_one_reached():
    neg = np.linspace(-1.0, 0.0, 28)  # 28 negatives resolve nothing under 1/28
    figures = operating_figures(np.array([0.5]), neg)
    assert figures["realised_far_at_far_0.01"] == figures["realised_far_at_far_0.001"] == 0.0
    neg = np.linspace(-1.0, 0.0, 1000, endpoint=False)
    assert operating_figures(np.array([0.5]), neg)["realised_far_at_far_0.01"] == 0.01


def test_cuhk03_reader_groups_views_by_camera(data_path):
    people = load_cuhk03(data_path("cuhk03_val"), limit=3)
    assert [p.identity for p in people] == sorted(p.identity for p in people)
    assert all(len(p.views[0]) >= 1 and len(p.views[1]) >= 1 for p in people)


def test_reid_rejects_every_hard_negative_and_accepts_the_target_on_robot_crops(
    data_path, model_path, tmp_path
):
    model_path("reid/person-reidentification-retail-0248.onnx")
    root = data_path("cuhk03_val").parent
    # ccf10 alone learns mirrored positives too, as it does inside ccf10+reid
    config = tmp_path / "mirrored.toml"
    config.write_text('[identify]\nmirrored_positives = "always"\n')
    args = argparse.Namespace(data_dir=str(root), identifiers="reid,ccf10,ccf10+reid",
                              identities=12, config=str(config), json=True)  # fmt: skip
    out = main(args)
    cal = out["calibration"]
    assert 0.3 < cal["similarity_at_far_0.01"] < cal["similarity_at_far_0.001"] < 1.0
    reid = out["identifiers"]["reid"]
    assert reid["robot_crops"]["shipped_far"] == 0.0
    assert reid["robot_crops"]["shipped_tar"] >= 0.9
    assert reid["cuhk03_test"]["auc"] > 0.8 and reid["cuhk03_test"]["shipped_far"] < 0.05
    # With two cues each must agree: the default accepts no crop that either cue alone
    # rejects, so no stranger, and not more of the target than the weaker cue.
    both = out["identifiers"]["ccf10+reid"]
    for crops in ("robot_crops", "cuhk03_test"):
        alone = [out["identifiers"][n][crops] for n in ("reid", "ccf10")]
        assert both[crops]["shipped_far"] <= min(a["shipped_far"] for a in alone) + 1e-9
        assert both[crops]["shipped_tar"] <= min(a["shipped_tar"] for a in alone) + 1e-9
    assert both["robot_crops"]["shipped_far"] == 0.0 and both["robot_crops"]["shipped_tar"] >= 0.5


def test_missing_data_is_a_clear_error(tmp_path):
    with pytest.raises(ValueError, match="no CUHK03 crops"):
        load_cuhk03(tmp_path)


@pytest.mark.parametrize("stray", ["a_b_c.jpg", "0001_front.jpg"])
def test_a_stray_file_among_the_crops_is_named(tmp_path, stray):
    import cv2
    import numpy as np

    for name in ("0001_00.jpg", "0001_05.jpg", stray):
        cv2.imwrite(str(tmp_path / name), np.full((128, 48, 3), 90, np.uint8))
    with pytest.raises(ValueError, match=f"{stray}: not a CUHK03 crop name"):
        load_cuhk03(tmp_path)


def _args(root, **given) -> argparse.Namespace:
    options = dict(data_dir=str(root), identifiers="reid", identities=8, config=None,
                   json=True, perturb=False, variants=None, only_after_learning=False)  # fmt: skip
    return argparse.Namespace(**{**options, **given})


def test_a_data_folder_without_the_robot_crops_is_refused_before_the_work(tmp_path):
    from follow.eval.verification import main

    (tmp_path / "cuhk03_val").mkdir()
    with pytest.raises(ValueError, match="no ccf_crops/ folder"):
        main(_args(tmp_path))


def test_verification_under_perturbation_reports_each_variant_mean_and_worst(
    data_path, model_path
):
    model_path("reid/person-reidentification-retail-0248.onnx")
    root = data_path("cuhk03_val").parent
    plain = main(_args(root))["identifiers"]["reid"]
    suite = main(_args(root, variants="original,dark,blur"))
    assert list(suite["variants"]) == ["original", "dark", "blur"]
    original = suite["variants"]["original"]
    # The original variant is the plain run, figure for figure.
    assert original["reid cuhk03_test"] == plain["cuhk03_test"]
    assert original["reid robot_crops"] == plain["robot_crops"]
    blurred = suite["variants"]["blur"]["reid cuhk03_test"]
    assert blurred["auc"] != plain["cuhk03_test"]["auc"]  # the crops were changed
    worst = suite["worst"]["reid cuhk03_test"]
    lowest = min(r["reid cuhk03_test"]["auc"] for r in suite["variants"].values())
    assert worst["auc"] == pytest.approx(lowest, abs=1e-4)
    # Enrolled as they are, then seen blurred: another score than blurred throughout.
    after = main(_args(root, variants="blur", only_after_learning=True))
    assert after["only_after_learning"] is True
    assert after["variants"]["blur"]["reid cuhk03_test"] != blurred
    with pytest.raises(ValueError, match="offset50 starts later"):
        main(_args(root, variants="offset50"))


def test_mirrored_positives_accept_more_of_the_target_and_no_hard_negative(data_path, model_path):
    """Robot-camera crops, the default ccf10+reid: learnt with its mirrored crops as
    positives too (`mirrored_positives`), the classifier's veto holds back fewer of the
    target's later views than without, and still lets none of the 28 hard-negative crops
    through."""
    from follow.config import IdentifyConfig
    from follow.eval.verification import verify_robot_crops
    from follow.identify.factory import build_appearance_model

    model_path("ccf/ccf10")
    model_path("reid/person-reidentification-retail-0248.onnx")
    folder = data_path("ccf_crops")
    assert IdentifyConfig().mirrored_positives == "with_reid"
    figures = {}
    for mirrored in ("with_reid", "never"):
        config = IdentifyConfig(mirrored_positives=mirrored)
        figures[mirrored] = verify_robot_crops(build_appearance_model(config), folder, config)
    assert figures["with_reid"]["shipped_far"] == 0.0
    assert figures["with_reid"]["shipped_tar"] > figures["never"]["shipped_tar"]


def test_the_shipped_part_colour_bar_is_the_one_its_calibration_gives(data_path):
    """`reid_part_colour_distance` is the distance within which 99 % of a person's crops
    stay of their other crops from the same camera (also under the suite's pixel
    changes), on CUHK03's even identities; and at it the rule alone turns away many
    other people but keeps all but a few of one person's crops."""
    from follow.config import IdentifyConfig
    from follow.eval.verification import calibrate_part_colours

    config = IdentifyConfig()
    people = load_cuhk03(data_path("cuhk03_val"))
    cal = calibrate_part_colours([p for p in people if p.identity % 2 == 0], config)
    assert cal["part_colour_distance_at_tar_0.99"] == pytest.approx(
        config.reid_part_colour_distance, abs=0.005
    )
    assert cal["part_colour_others_turned_away"] > 0.3
