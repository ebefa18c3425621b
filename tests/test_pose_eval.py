"""Scoring rules of `follow eval pose` on hand-made frames."""

from __future__ import annotations

import numpy as np
import pytest

from follow.eval.perturb import Variant
from follow.eval.pets import GtBox
from follow.eval.pose import frame_range, score_frame, variant_frames
from follow.types import Observation


def box(pid, xc, yc, w=20.0, h=60.0, hidden=0.0):
    return GtBox(pid, xc, yc, w, h, hidden)


def test_one_neck_counts_for_one_person_only():
    # Two overlapping boxes, one neck inside both: one hit, not two.
    boxes = [box(1, 100, 100), box(2, 105, 102)]
    obs = [Observation(np.array([102.0, 80.0]))]
    c = score_frame(obs, boxes)
    assert (c.people, c.neck_hits, c.detections, c.detections_in_boxes) == (2, 1, 1, 1)


def test_ankle_must_be_in_the_lower_fifth_of_the_box():
    boxes = [box(1, 100, 100), box(2, 200, 100)]  # bottoms at 130, lower fifth from 118
    obs = [
        Observation(np.array([100.0, 80.0]), ankle_px=np.array([101.0, 125.0])),
        Observation(np.array([200.0, 80.0]), ankle_px=np.array([200.0, 110.0])),
    ]
    c = score_frame(obs, boxes)
    assert (c.neck_hits, c.ankle_hits) == (2, 1)


def test_hidden_people_are_neither_missed_nor_false():
    boxes = [box(1, 100, 100, hidden=0.8), box(2, 300, 100)]
    hidden_found = [Observation(np.array([100.0, 80.0]))]
    c = score_frame(hidden_found, boxes)
    assert (c.people, c.neck_hits, c.detections_in_boxes) == (1, 0, 1)
    c = score_frame([], boxes)
    assert (c.people, c.neck_hits) == (1, 0)


def test_necks_outside_every_box_lower_precision():
    boxes = [box(1, 100, 100)]
    obs = [Observation(np.array([100.0, 80.0])), Observation(np.array([400.0, 80.0]))]
    s = score_frame(obs, boxes)
    assert (s.detections, s.detections_in_boxes) == (2, 1)
    assert s.summary()["precision"] == 0.5 and s.summary()["neck_recall"] == 1.0


def test_eval_pose_command_prints_json(model_path, data_path, monkeypatch, capsys):
    import json

    from follow import cli

    model_path("pose/human-pose-estimation-0001.onnx")
    data_path("pets2009_s2l1/View_001.avi")
    args = ["eval", "pose", "--frames", "2", "--sizes", "480", "--provider", "cpu", "--json"]
    assert cli.main(args) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    (row,) = result["sizes"]
    assert row["input"] == [640, 480] and result["frames"] == 2
    assert 0.5 <= row["neck_recall"] <= 1.0 and 0.5 <= row["precision"] <= 1.0
    assert row["ms"] > 0 and row["people"] >= 3


def test_near_people_evaluation_finds_large_real_people(data_path, model_path, capsys):
    import json

    from follow import cli

    data_path("ccf_crops/p01.jpg")
    model_path("pose/human-pose-estimation-0001.onnx")
    capsys.readouterr()
    assert cli.main(["eval", "pose-near", "--person-heights", "320", "--sizes", "256",
                     "--stages", "1", "2", "--json"]) == 0  # fmt: skip
    r = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert r["crops"] == 42 and len(r["rows"]) == 2
    for row in r["rows"]:
        assert row["neck"] >= 0.9 and row["ankle"] >= 0.8, row
    assert cli.main(["eval", "pose-near", "--person-heights", "470", "--sizes", "256"]) != 0
    assert "does not fit" in capsys.readouterr().err


def test_far_people_need_their_size_in_the_input(data_path, model_path, capsys, tmp_path):
    """The measurement behind [pose] min_person_input_px: the same crops, 96 px tall in the
    frame, are found less often at a 256 px input (51 px in it) than at 368 px (74 px)."""
    import json

    from follow import cli

    data_path("ccf_crops/p01.jpg")
    model_path("pose/human-pose-estimation-0001.onnx")
    fp32 = tmp_path / "fp32.toml"
    fp32.write_text('[pose]\nprecision = "fp32"\n')
    capsys.readouterr()
    assert cli.main(["eval", "pose-near", "--person-heights", "96", "--sizes", "256", "368",
                     "--stages", "2", "--max-crops", "12", "--config", str(fp32),
                     "--json"]) == 0  # fmt: skip
    r = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert r["crops"] == 12
    small, large = sorted(r["rows"], key=lambda row: row["input_height_px"])
    assert (small["person_input_px"], large["person_input_px"]) == (51.2, 73.6)
    assert large["neck"] >= 0.9 and small["neck"] < large["neck"], r["rows"]


def test_max_crops_takes_evenly_spaced_crops(tmp_path):
    from follow.eval.pose_near import crop_files

    for i in range(10):
        (tmp_path / f"c{i}.jpg").write_bytes(b"")
    picked = [p.name for p in crop_files(str(tmp_path), 4)]
    assert picked == ["c0.jpg", "c3.jpg", "c6.jpg", "c9.jpg"]
    assert len(crop_files(str(tmp_path), 0)) == 10 == len(crop_files(str(tmp_path), 50))
    with pytest.raises(ValueError, match="max-crops"):
        crop_files(str(tmp_path), -1)


def test_frames_are_taken_from_the_half_asked_for():
    """Settings are chosen on frames 0-399 and checked on 400-794: the two never share a
    frame, and a later-starting variant starts where it starts."""
    first = frame_range(795, 100, 0, 400)
    second = frame_range(795, 100, 400)
    assert first[0] == 0 and first[-1] == 399 and len(first) == 100
    assert second[0] == 400 and second[-1] == 794 and len(second) == 100
    assert not set(first) & set(second)
    assert variant_frames(795, 10, Variant("offset100", "", first_frame=100), 0, 400)[0] == 100
    with pytest.raises(ValueError, match="no frames from 400 until 400"):
        frame_range(795, 10, 400, 400)
    with pytest.raises(ValueError, match="variant offset100: no frames from 100 until 50"):
        variant_frames(795, 10, Variant("offset100", "", first_frame=100), 0, 50)
    with pytest.raises(ValueError, match="--frames must be at least 1"):
        frame_range(795, 0)


def test_near_people_under_sensor_noise(data_path, model_path, capsys):
    """`--variants` applies the suite's pixel changes to the pasted frames: noise hides
    small people from the robot's default detector; a later start is refused."""
    import json

    from follow import cli

    data_path("ccf_crops/p01.jpg")
    model_path("pose/human-pose-estimation-0001.onnx")
    capsys.readouterr()
    assert cli.main(["eval", "pose-near", "--person-heights", "96", "--sizes", "368",
                     "--stages", "2", "--variants", "original,noise", "--json"]) == 0  # fmt: skip
    r = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    by_variant = {row["variant"]: row for row in r["rows"]}
    assert set(by_variant) == {"original", "noise"}
    assert by_variant["noise"]["neck"] + 0.2 < by_variant["original"]["neck"], by_variant
    assert cli.main(["eval", "pose-near", "--variants", "offset50"]) != 0
    assert "pose-near has no sequence" in capsys.readouterr().err


def test_a_person_is_found_by_a_neck_in_the_upper_part_and_an_ankle_in_the_lower():
    """The rule `follow eval pose-near` and `pose-scene` share: box (100, 50, 60, 200)."""
    import numpy as np

    from follow.eval.pose_near import ankle_found, observations_on_person
    from follow.types import Observation

    box = (100, 50, 60, 200)
    on = Observation(np.array([130.0, 90.0]), np.array([130.0, 240.0]))
    neck_too_low = Observation(np.array([130.0, 140.0]), np.array([130.0, 240.0]))  # 0.45 h
    beside = Observation(np.array([170.0, 90.0]))
    ankle_too_high = Observation(np.array([120.0, 80.0]), np.array([120.0, 190.0]))  # 0.7 h
    found = observations_on_person([on, neck_too_low, beside, ankle_too_high], box)
    assert found == [on, ankle_too_high]
    assert ankle_found(found, box)
    assert not ankle_found([ankle_too_high], box)


def test_a_later_start_before_the_frames_asked_for_is_counted_once(monkeypatch):
    """From frame 400 on, offset50 takes the original's very frames and pixels: the same
    run, which must not count twice in the mean over the variants."""
    from types import SimpleNamespace

    from follow.config import PoseConfig
    from follow.eval import pose
    from follow.eval.perturb import variant

    runs = []

    def fake_evaluate(sequence, frames, config, model_path=None):
        noisy = getattr(sequence, "variant", None) is not None
        runs.append((noisy, tuple(frames)))
        recall = 0.5 if noisy else 0.9
        return {"neck_recall": recall, "ankle_recall": recall, "precision": 1.0, "model": "m"}

    monkeypatch.setattr(pose, "evaluate_size", fake_evaluate)
    args = SimpleNamespace(frames=10, from_frame=400, until_frame=None, sizes=[256],
                           model_file=None, json=True, plot=None)  # fmt: skip
    chosen = [variant("original"), variant("noise"), variant("offset50")]
    r = pose.main_perturbed(args, PoseConfig(), SimpleNamespace(frame_count=795), chosen)
    assert len(runs) == 2 and list(r["variants"]) == ["original", "noise"]
    assert r["same_as"] == {"offset50": "original"}
    assert r["mean"]["256"]["neck_recall"] == pytest.approx(0.7)
    # Where a later start takes frames of its own, it is a run of its own.
    runs.clear()
    args.from_frame = 0
    r = pose.main_perturbed(args, PoseConfig(), SimpleNamespace(frame_count=795), chosen)
    assert len(runs) == 3 and r["same_as"] == {}


def test_feet_beyond_the_frame_give_no_ankle_on_its_edge(data_path, model_path, capsys,
                                                         tmp_path):  # fmt: skip
    """Real crops with a fifth of the person below the frame (the feet 2-5 heatmap cells
    beyond it): the network still reports ankles, on the frame's last rows; the decoder
    drops them, and keeps the neck."""
    import json

    from follow import cli

    data_path("ccf_crops/p01.jpg")
    model_path("pose/human-pose-estimation-0001.onnx")
    keep = tmp_path / "keep.toml"
    keep.write_text("[pose]\nbottom_edge_margin_cells = 0\n")
    argv = ["eval", "pose-near", "--person-heights", "432", "--sizes", "368", "--stages", "2",
            "--cut-bottom", "0.2", "--max-crops", "14", "--json"]  # fmt: skip
    capsys.readouterr()
    rows = {}
    for name, extra in (("dropped", []), ("kept", ["--config", str(keep)])):
        assert cli.main(argv + extra) == 0
        [rows[name]] = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["rows"]
    assert rows["kept"]["cut_bottom"] == 0.2
    assert rows["kept"]["ankle"] >= 0.5 and rows["dropped"]["ankle"] <= 0.1, rows
    # the kept ones lie on the last heatmap row, whose centre is half a cell over the edge
    assert rows["kept"]["ankle_over_bottom_edge_cells"] < 0.6, rows
    assert rows["kept"]["neck"] >= 0.9 and rows["dropped"]["neck"] >= 0.9, rows


def test_a_cut_is_a_share_under_one_half_at_one_edge():
    import argparse

    from follow.eval.pose_near import cut_share, frames_with_people

    assert cut_share("0.15") == 0.15
    for bad in ("0.5", "-0.1", "x"):
        with pytest.raises(argparse.ArgumentTypeError):
            cut_share(bad)
    with pytest.raises(ValueError, match="not both"):
        frames_with_people([], 320, cut_bottom=0.1, cut_top=0.1)
