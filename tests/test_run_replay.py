"""`follow run --replay` reads its log as it replays: each record just before its frame,
never the whole log first (an hour's log at 30 fps is some 100 000 records)."""

import json
from types import SimpleNamespace

import cv2
import numpy as np

from follow import cli
from follow import run as run_module
from follow.camera import CameraModel, CameraPose


def test_a_replay_reads_each_record_of_its_log_as_its_frame_is_reached(
    tmp_path, capsys, monkeypatch
):
    argv = _logged_run(tmp_path, 10, {}, (0, 2, 3, 6))

    events = []
    read_run_log = run_module.read_run_log

    def reading(path):
        header, records = read_run_log(path)

        def taken():
            for record in records:
                events.append(("read", record.frame_index))
                yield record

        return header, taken()

    class Recorder:
        identifier = None

        def process(self, frame, robot, index):
            events.append(("replayed", index))
            return SimpleNamespace(target=SimpleNamespace(target_id=None))

    monkeypatch.setattr(run_module, "read_run_log", reading)
    monkeypatch.setattr(run_module, "build_perception", lambda *a, **k: Recorder())
    assert cli.main(argv) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary == {"frames": 4, "target_agreement": 1.0, "not_replayed": 0}
    assert events == [(step, k) for k in (0, 2, 3, 6) for step in ("read", "replayed")]


def test_a_replay_against_a_shorter_source_says_how_much_of_the_log_it_left(
    tmp_path, capsys, monkeypatch, caplog
):
    """A log of 10 frames against 3 (a cut video): full agreement over 3 frames used to
    read as a replay of the whole run."""
    argv = _logged_run(tmp_path, 3, {}, range(10))
    _configs_replayed_with(monkeypatch)
    assert cli.main(argv) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary == {"frames": 3, "target_agreement": 1.0, "not_replayed": 7}
    assert "7 logged frames, from frame 3 on, lie past the end of" in caplog.text


def _logged_run(tmp_path, frames: int, header: dict, logged=(0,)) -> list[str]:
    """A 15 fps video of `frames` frames, its camera file and the log of a run that
    processed the frames `logged` (no skeletons, `header` added to the log's header):
    the arguments that replay it."""
    video = tmp_path / "a.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 15.0, (64, 48))
    for k in range(frames):
        writer.write(np.full((48, 64, 3), 20 * k, np.uint8))
    writer.release()
    camera = tmp_path / "cam.yaml"
    CameraModel.from_fov((64, 48), 70.0, CameraPose(height_m=1.0)).save(camera)
    log = tmp_path / "run.jsonl"
    lines = [{"log_version": 1, "source": str(video), "image_size": [64, 48], **header}]
    lines += [{"frame": k, "stamp_s": k / 15.0, "skeletons": []} for k in logged]
    log.write_text("".join(json.dumps(line) + "\n" for line in lines))
    return ["run", str(video), "--camera", str(camera), "--replay", str(log), "--json"]


def _configs_replayed_with(monkeypatch) -> list:
    configs = []

    class Recorder:
        identifier = None

        def process(self, frame, robot, index):
            return SimpleNamespace(target=SimpleNamespace(target_id=None))

    def build(config, *args, **kwargs):
        configs.append(config)
        return Recorder()

    monkeypatch.setattr(run_module, "build_perception", build)
    return configs


def test_a_replay_without_config_uses_the_one_the_run_named(tmp_path, capsys, monkeypatch):
    """The run's --config is in the log's header: replayed with the defaults instead,
    a run made with other tracker or identifier settings disagreed with itself."""
    config = tmp_path / "robot.toml"
    config.write_text('[identify]\nidentifier = "channels"\nseed = 7\n')
    argv = _logged_run(tmp_path, 3, {"config": str(config)})
    configs = _configs_replayed_with(monkeypatch)
    assert cli.main(argv) == 0
    assert configs[-1].identify.identifier == "channels" and configs[-1].identify.seed == 7

    other = tmp_path / "other.toml"
    other.write_text("[identify]\nseed = 3\n")
    assert cli.main(argv + ["--config", str(other)]) == 0  # given again: that one
    assert configs[-1].identify.seed == 3 and configs[-1].identify.identifier == "ccf10+reid"


def test_a_replay_whose_runs_config_is_gone_says_so(tmp_path, capsys, monkeypatch):
    argv = _logged_run(tmp_path, 3, {"config": str(tmp_path / "moved.toml")})
    configs = _configs_replayed_with(monkeypatch)
    assert cli.main(argv) == 1
    err = capsys.readouterr().err
    assert "moved.toml" in err and "--config" in err and "Traceback" not in err
    assert configs == []


def test_a_replay_through_another_camera_file_is_warned_of(tmp_path, caplog):
    from follow.run import warn_if_other_camera

    run_camera, other = tmp_path / "cam.yaml", tmp_path / "new_cam.yaml"
    run_camera.write_text("x")
    other.write_text("x")
    with caplog.at_level("WARNING"):
        warn_if_other_camera({"camera": str(run_camera)}, run_camera)
        warn_if_other_camera({"camera": str(run_camera)}, tmp_path / "." / "cam.yaml")
        assert not caplog.records  # the same file, however named
        warn_if_other_camera({"camera": str(run_camera)}, other)
    assert "new_cam.yaml; the run used" in caplog.text
