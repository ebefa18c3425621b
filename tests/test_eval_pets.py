"""The PETS 2009 evaluations on a short stretch (60 frames, one pose run shared through
the detection cache)."""

import json

import pytest

from follow import cli

FRAMES = "60"


def _run(capsys, *args) -> dict:
    capsys.readouterr()
    assert cli.main(list(args)) == 0
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])


@pytest.fixture
def pets(data_path, model_path):
    data_path("pets2009_s2l1/View_001.avi")
    model_path("pose/human-pose-estimation-0001.onnx")


def test_tracking_evaluation_ranks_our_tracker_first(pets, capsys, tmp_path):
    r = _run(capsys, "eval", "tracking", "--frames", FRAMES, "--plot",
             str(tmp_path / "t.png"), "--json")  # fmt: skip
    assert set(r) >= {"ours", "direct", "norfair", "bytetrack"}
    ours = r["ours"]
    assert ours["gt_objects"] > 250  # about 4.7 annotated people per frame
    assert ours["mota"] > 0.6 and ours["idf1"] > 0.6
    for other in ("direct", "norfair", "bytetrack"):
        assert ours["mota"] > r[other]["mota"], (other, r)
    assert (tmp_path / "t.png").stat().st_size > 10_000


def test_scoring_can_leave_out_the_first_frames(pets, capsys):
    whole = _run(capsys, "eval", "tracking", "--frames", FRAMES, "--json")
    later = _run(capsys, "eval", "tracking", "--frames", FRAMES, "--score-from-frame", "30",
                 "--json")  # fmt: skip
    assert 0 < later["ours"]["gt_objects"] < whole["ours"]["gt_objects"]
    assert cli.main(["eval", "tracking", "--frames", FRAMES, "--score-from-frame", "60"]) != 0
    assert "--score-from-frame 60 is outside 0..59" in capsys.readouterr().err


def test_the_shipped_pets_ankle_height_matches_a_fit_on_the_data(pets, capsys, tmp_path):
    from follow.config import Config
    from follow.eval.pets_setup import PETS_SETTINGS

    r = _run(capsys, "eval", "ankle-height", "--frames", FRAMES, "--plot",
             str(tmp_path / "a.png"), "--json")  # fmt: skip
    assert r["samples"] > 150
    # The detector's ankle points lie well over the annotated ground point (box bottom).
    assert 0.15 < r["median_m"] < 0.35
    assert r["ankle_height_m"] == pytest.approx(
        Config.load(PETS_SETTINGS).tracker.ankle_height_m, abs=0.03
    )
    assert (tmp_path / "a.png").stat().st_size > 5_000


def test_identification_evaluation_accounts_for_every_frame(pets, capsys, tmp_path):
    # The default identifier. (CCF10 alone follows these two targets 0.48 of these 60
    # frames with the PETS settings' median filter, 0.65 without: docs/identification.md.)
    r = _run(capsys, "eval", "identification", "--frames", FRAMES, "--identifiers",
             "ccf10+reid", "--min-visible-s", "5", "--max-targets", "2", "--plot",
             str(tmp_path / "i.png"), "--json")  # fmt: skip
    assert len(r["targets"]) == 2
    fractions = r["ccf10+reid"]
    assert sum(fractions[k] for k in ("ct", "cl", "wt", "wl")) == pytest.approx(1.0, abs=1e-3)
    assert fractions["ct"] > 0.5  # the selected person is followed most of the time
    assert (tmp_path / "i.png").stat().st_size > 5_000


def test_whole_sequence_scoring_counts_undecided_wrong_time_within_wrong_time(pets, capsys):
    args = ["eval", "identification", "--frames", FRAMES, "--identifiers", "ccf10+reid",
            "--min-visible-s", "5", "--max-targets", "2", "--json"]  # fmt: skip
    usual = _run(capsys, *args)["ccf10+reid"]
    whole = _run(capsys, *args, "--whole-sequence")["ccf10+reid"]
    assert "wt_undecided" not in usual
    assert 0.0 <= whole["wt_undecided_s"] <= whole["seconds"]["wt"]
    assert whole["wt_undecided"] == pytest.approx(
        whole["wt_undecided_s"] / sum(whole["seconds"].values()), abs=1e-3
    )
    # to the end of the run, never less than to each target's last annotated frame
    assert sum(whole["seconds"].values()) >= sum(usual["seconds"].values())


def test_bench_times_every_stage_and_the_runner_against_bare_inference(pets, capsys):
    # no warm-up: a slow runner takes 2-3 of the 4 frames, and none of the warm-up's is timed
    r = _run(capsys, "bench", "--frames", "4", "--warmup", "0", "--json")
    assert r["frames"] == 4
    for key in ("pose_ms", "inference_ms", "decode_ms", "tracker_ms", "identify_ms",
                "control_ms", "in_turn_ms", "bare_inference_ms"):  # fmt: skip
        assert r[key] is not None and r[key] >= 0.0, key
    assert r["pose_ms"] >= r["inference_ms"] > 0.0
    assert r["in_turn_ms"] >= r["pose_ms"]
    # fps is printed to two decimals
    assert r["in_turn_fps"] == pytest.approx(1000.0 / r["in_turn_ms"], rel=0.01, abs=0.006)
    # the runner drove the frames through the threads and commanded from them
    # the pose network runs on the CPU here: "auto" runs the stages in turn
    assert r["runner_frames"] >= 2 and r["overlap_stages"] is False
    assert r["runner_frame_ms"] == pytest.approx(1000.0 / r["runner_fps"], rel=0.01)
    assert r["end_to_end_over_inference"] == pytest.approx(
        r["runner_frame_ms"] / r["bare_inference_ms"], rel=0.01
    )
    assert 0 < r["capture_to_command_median_ms"] <= r["capture_to_command_p95_ms"]
    # 4 frames: a p95 of so few latencies is said to be about their largest
    assert 1 <= r["capture_to_command_samples"] <= 4
    assert any(f"p95 comes from {r['capture_to_command_samples']} latencies" in n
               for n in r["notes"])  # fmt: skip
    # and the same runner with the stages overlapped beside it, its latency too
    assert r["runner_fps_stages_overlapped"] > 0.0
    assert 0 < r["capture_to_command_median_ms_stages_overlapped"] <= (
        r["capture_to_command_p95_ms_stages_overlapped"])  # fmt: skip
    assert 50.0 < r["peak_rss_mb"] < 4000.0
    # The robot default runs the whole network (no stage cut); without the INT8 model it
    # says FP32 ran.
    assert r["settings"] == "robot" and r["network_stages"] == 2
    assert r["pose_model"].startswith("human-pose-estimation-0001")
    assert "initial-stage" not in r["pose_model"]
    assert ("int8" in r["pose_model"]) != any("INT8" in n for n in r["notes"])


def test_bench_pets_settings_run_the_initial_stage_at_576_px(pets, capsys):
    r = _run(capsys, "bench", "--settings", "pets", "--provider", "cpu", "--frames", "2",
             "--warmup", "0", "--json")  # fmt: skip
    assert r["input_height_px"] == 576 and r["network_stages"] == 1
    assert r["pose_backend"] == "onnxruntime:CPUExecutionProvider"
    assert r["reid_backend"] == "onnxruntime:CPUExecutionProvider"  # a CPU cell: all on it
    assert "initial-stage" in r["pose_model"]


def test_bench_tracker_times_the_tracker_alone_on_the_cached_detections(pets, capsys):
    r = _run(capsys, "bench", "tracker", "--frames", FRAMES, "--repeats", "1", "--json")
    assert r["frames"] == 60 and r["repeats"] == 1
    assert 2 <= r["tracks_per_frame"] <= 10  # about 4.7 annotated people per frame
    assert 0.0 < r["tracker_ms_per_track"] <= r["tracker_ms_per_frame"]
    assert r["reference_filterpy_step_ms"] > 0.0
    assert r["per_track_over_reference"] == pytest.approx(
        r["tracker_ms_per_track"] / r["reference_filterpy_step_ms"], rel=0.01
    )
