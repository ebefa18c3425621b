"""End to end on a short stretch of the PETS 2009 video: `follow run` with the imported
camera writes a log whose tracks lie on the annotated people, and replaying the log
reproduces the same targets."""

import json

import numpy as np
import pytest

from follow import cli
from follow.runlog import read_run_log

FRAMES = 24


@pytest.fixture(scope="module")
def pets_run(tmp_path_factory):
    from conftest import _asset  # the model_path/data_path fixtures, at module scope

    from calib.tsai import TsaiCamera

    _asset("FOLLOW_MODEL_DIR", "pose/human-pose-estimation-0001.onnx")
    root = _asset("FOLLOW_DATA_DIR", "pets2009_s2l1")
    out = tmp_path_factory.mktemp("pets_run")
    camera, _ = TsaiCamera.from_xml(root / "View_001.xml").to_camera_model()
    camera.save(out / "pets.yaml")
    # The PETS pose settings (follow/eval/pets2009.toml) at a smaller, faster input.
    (out / "config.toml").write_text(
        "[pose]\ninput_height_px = 368\nnetwork_stages = 1\nheatmap_peak_threshold = 0.03\n"
    )
    args = ["run", str(root / "View_001.avi"), "--camera", str(out / "pets.yaml"),
            "--config", str(out / "config.toml"), "--max-frames", str(FRAMES),
            "--target-id", "1", "--log", str(out / "run.jsonl"),
            "--output-video", str(out / "run.avi"), "--json"]  # fmt: skip
    assert cli.main(args) == 0
    return root, out, args


def test_run_logs_tracks_on_the_annotated_people(pets_run, capsys):
    from follow.eval.pets_setup import PetsSetup

    root, out, _ = pets_run
    header, records = read_run_log(out / "run.jsonl")
    records = list(records)
    assert header["image_size"] == [480, 360]
    assert [r.frame_index for r in records] == list(range(FRAMES))
    assert (out / "run.avi").stat().st_size > 10_000
    setup = PetsSetup.load(root)
    near = far = 0
    for r in records[8:]:  # tracks are confirmed after a few frames
        _, gt, _ = setup.ground_truth(r.frame_index)
        for t in r.tracks:
            if t["confirmed"]:
                d = np.linalg.norm(gt - np.array(t["mean"][:2]), axis=1).min()
                near += d < 1.0
                far += d >= 1.0
    assert near > 5 * far and near > 50
    assert any(r.target_id == 1 for r in records)  # the selected person was followed


def test_replay_reproduces_the_targets(pets_run, capsys):
    root, out, args = pets_run
    capsys.readouterr()
    replay = args[:4] + ["--config", str(out / "config.toml"), "--replay",
                         str(out / "run.jsonl"), "--target-id", "1", "--json"]  # fmt: skip
    assert cli.main(replay) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["frames"] == FRAMES
    assert summary["target_agreement"] == 1.0


def test_replay_selects_the_runs_target_without_being_told(pets_run, capsys):
    """The run's --target-id is in the log's header: a replay without it used to select
    nobody, and its targets disagreed with the run's."""
    root, out, args = pets_run
    header, _ = read_run_log(out / "run.jsonl")
    assert header["target_id"] == 1
    capsys.readouterr()
    replay = args[:4] + ["--config", str(out / "config.toml"), "--replay",
                         str(out / "run.jsonl"), "--json"]  # fmt: skip
    assert cli.main(replay) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["target_agreement"] == 1.0
    assert cli.main(replay[:-1] + ["--target-id", "2", "--json"]) != 0
    assert "the run selected track 1, not --target-id 2" in capsys.readouterr().err
