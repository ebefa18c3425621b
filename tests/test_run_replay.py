"""`follow run --replay` reads its log as it replays: each record just before its frame,
never the whole log first (an hour's log at 30 fps is some 100 000 records)."""

import json
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

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


def test_a_replay_whose_source_gives_other_frames_than_the_runs_is_refused(
    tmp_path, capsys, model_path
):
    """A bag replayed with a tighter `[ros] max_odometry_age_s` skips one image more
    than the run did: every later record used to be replayed on the next image, with
    full agreement and a false "past the end" warning."""
    from follow.bag_writer import BagWriter
    from follow.types import Odometry

    model_path("ccf/ccf10")  # the run's identifier
    bag = tmp_path / "gap.mcap"
    rng = np.random.default_rng(5)
    with BagWriter(bag) as writer:
        for i in range(6):
            stamp = 1000.0 + 0.5 * i
            for dt in (-0.15, 0.15) if i == 3 else (-0.01, 0.01):  # image 3: odometry 0.15 s off
                writer.write_odometry("/odom", Odometry(0.0, 0.0, 0.0, stamp + dt))
            writer.write_string("/skeletons", stamp, "[]")
            image = rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)
            writer.write_image("/camera/image_raw", stamp, image, "camera")
    camera = tmp_path / "cam.yaml"
    CameraModel.from_fov((64, 48), 70.0, CameraPose(height_m=1.0)).save(camera)
    common = ["run", str(bag), "--camera", str(camera), "--json"]
    log = tmp_path / "run.jsonl"
    assert cli.main([*common, "--image-topic", "/camera/image_raw", "--odom-topic", "/odom",
                     "--skeletons-topic", "/skeletons", "--log", str(log)]) == 0  # fmt: skip
    capsys.readouterr()
    assert cli.main([*common, "--replay", str(log)]) == 0  # the run's settings: all 6 frames
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["frames"] == 6

    tight = tmp_path / "tight.toml"
    tight.write_text("[ros]\nmax_odometry_age_s = 0.1\n")
    assert cli.main([*common, "--replay", str(log), "--config", str(tight)]) == 1
    err = capsys.readouterr().err
    assert (f"--replay {log}: the log's frame 3 is stamped 1001.500000 s, but frame 3 of "
            f"{bag} is stamped 1002.000000 s" in err)  # fmt: skip
    assert "max_odometry_age_s" in err and "Traceback" not in err


def test_a_replay_of_a_folder_at_another_frame_rate_is_refused(tmp_path, capsys, monkeypatch):
    """The same images stamped at another `--folder-fps` are not the frames the run saw
    (its tracker ran at their stamps)."""
    folder = tmp_path / "frames"
    folder.mkdir()
    for k in range(3):
        cv2.imwrite(str(folder / f"{k:04d}.png"), np.full((48, 64, 3), 20 * k, np.uint8))
    camera = tmp_path / "cam.yaml"
    CameraModel.from_fov((64, 48), 70.0, CameraPose(height_m=1.0)).save(camera)
    log = tmp_path / "run.jsonl"
    lines = [{"log_version": 1, "source": str(folder), "image_size": [64, 48]}]
    lines += [{"frame": k, "stamp_s": k / 10.0, "skeletons": []} for k in range(3)]
    log.write_text("".join(json.dumps(line) + "\n" for line in lines))
    _configs_replayed_with(monkeypatch)
    argv = ["run", str(folder), "--camera", str(camera), "--replay", str(log), "--json"]
    assert cli.main([*argv, "--folder-fps", "10"]) == 0
    assert cli.main([*argv, "--folder-fps", "5"]) == 1
    err = capsys.readouterr().err
    assert "the log's frame 1 is stamped 0.100000 s, but frame 1 of" in err
    assert "is stamped 0.200000 s" in err


@pytest.mark.parametrize("tail", ["", '{"frame": 0, "stamp_s": 0.0, "skel'])
def test_a_log_without_frame_records_is_named_not_its_source(tmp_path, capsys, monkeypatch, tail):
    """A header alone, or with a first frame line cut short (a run killed at once), was
    reported as "no frame of it found in SOURCE", as if the source were at fault."""
    argv = _logged_run(tmp_path, 3, {}, logged=())
    log = tmp_path / "run.jsonl"
    log.write_text(log.read_text() + tail)
    configs = _configs_replayed_with(monkeypatch)
    assert cli.main(argv) == 1
    err = capsys.readouterr().err
    assert f"the log {log} holds no frame records" in err and "found in" not in err
    assert configs == []


def test_a_live_camera_is_not_replayed(tmp_path, capsys, monkeypatch):
    """A camera's frames are new ones, never those the log was made from."""
    argv = _logged_run(tmp_path, 3, {"source": "0"})
    argv[1] = "0"
    closed = []

    class Camera:
        live = True

        def __iter__(self):
            return iter([run_module.Frame(np.zeros((48, 64, 3), np.uint8), 5.0)])

        def close(self):
            closed.append(True)

    monkeypatch.setattr(run_module, "open_source", lambda *a, **k: Camera())
    configs = _configs_replayed_with(monkeypatch)
    assert cli.main(argv) == 1
    assert "0 is a live camera; a replay needs the recorded frames" in capsys.readouterr().err
    assert closed == [True] and configs == []
