"""Bad runner input gets one clear line naming what is wrong, never a raw traceback: one
test per row of the table in docs/system.md."""

import json
import logging

import cv2
import numpy as np
import pytest

from follow import cli
from follow.camera import CameraModel, CameraPose
from follow.capture import FrameSource
from follow.config import MavlinkConfig
from follow.run import checked_frames
from follow.types import Frame


def _video(path, frames=30, size=(64, 48)):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 15.0, size)
    rng = np.random.default_rng(1)
    for _ in range(frames):
        writer.write(rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8))
    writer.release()
    return path


def _camera(tmp_path, size=(64, 48)):
    path = tmp_path / "cam.yaml"
    CameraModel.from_fov(size, 70.0, CameraPose(height_m=1.0)).save(path)
    return path


def _error(capsys, argv) -> str:
    assert cli.main(argv) == 1
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    return err


def _log(path, header, records):
    lines = [json.dumps({"log_version": 1, **header})] + records
    path.write_text("\n".join(lines) + "\n")
    return path


def test_max_frames_below_one(tmp_path, capsys):
    err = _error(capsys, ["run", "x.avi", "--camera", "c.yaml", "--max-frames", "0"])
    assert "--max-frames must be >= 1, got 0" in err


def test_frame_size_change_mid_stream():
    small = Frame(np.zeros((24, 32, 3), np.uint8), 0.0)
    large = Frame(np.zeros((48, 64, 3), np.uint8), 0.1)
    frames = checked_frames(small, iter([small, large]), "cam.avi")
    with pytest.raises(ValueError, match="frame 2 is 64x48, but the stream started at 32x24"):
        list(frames)


def test_replay_of_another_source(tmp_path, capsys):
    video = _video(tmp_path / "b.avi")
    log = _log(tmp_path / "run.jsonl", {"source": str(tmp_path / "a.avi"),
                                         "image_size": [64, 48]}, [])  # fmt: skip
    err = _error(capsys, ["run", str(video), "--camera", str(_camera(tmp_path)),
                          "--replay", str(log)])  # fmt: skip
    assert f"the log is of source {tmp_path / 'a.avi'}, not {video}" in err


def test_replay_of_the_same_file_from_another_folder_is_allowed(tmp_path, capsys, caplog):
    """The log names its source as it was typed where the run started: the same file
    from another folder, or moved, replays (with a warning), and what a replay does not
    write is refused rather than silently ignored."""
    (tmp_path / "moved").mkdir()
    video = _video(tmp_path / "moved" / "a.avi")
    log = _log(tmp_path / "run.jsonl", {"source": "recorded/a.avi", "image_size": [64, 48]}, [])
    argv = ["run", str(video), "--camera", str(_camera(tmp_path)), "--replay", str(log)]
    err = _error(capsys, argv)
    assert "the log is of source" not in err  # it got past the source: no frame matches
    assert "the log was recorded from recorded/a.avi" in caplog.text
    err = _error(capsys, [*argv, "--log", str(tmp_path / "again.jsonl"), "--max-frames", "5"])
    assert "--replay takes no --log, --max-frames" in err


def test_replay_of_another_image_size(tmp_path, capsys):
    video = _video(tmp_path / "a.avi")
    record = json.dumps({"frame": 0, "stamp_s": 0.0, "skeletons": []})
    log = _log(tmp_path / "run.jsonl", {"source": str(video), "image_size": [640, 480]},
               [record])  # fmt: skip
    err = _error(capsys, ["run", str(video), "--camera", str(_camera(tmp_path)),
                          "--replay", str(log)])  # fmt: skip
    assert "the log is of 640x480 frames" in err and "has 64x48 frames" in err


@pytest.mark.parametrize(
    "record, message",
    [(json.dumps({"frame": 0, "skeletons": []}), "line 2: frame record without the key 'stamp_s'"),
     ('{"frame": 0, "stamp_s": ', "line 2 is not JSON"),
     ("[1, 2]", "line 2: malformed frame record (a frame record must be a JSON object")],
)  # fmt: skip
def test_malformed_replay_log(tmp_path, capsys, record, message):
    video = _video(tmp_path / "a.avi")
    good = json.dumps({"frame": 1, "stamp_s": 0.1, "skeletons": []})
    log = _log(tmp_path / "run.jsonl", {"source": str(video), "image_size": [64, 48]},
               [record, good])  # fmt: skip
    err = _error(capsys, ["run", str(video), "--camera", str(_camera(tmp_path)),
                          "--replay", str(log)])  # fmt: skip
    assert f"run log {log}: {message}" in err


@pytest.mark.parametrize(
    "frames, message",
    [((1, 0), "frame 0 is out of order (after frame 1)"),
     ((2, 2), "frame 2 is out of order (after frame 2)"),
     ((-1, 0), "frame -1 is out of order (below 0)")],
)  # fmt: skip
def test_replay_log_out_of_order(tmp_path, capsys, monkeypatch, frames, message):
    """The replay reads the log as it goes, pairing each record with its frame: records
    must come in the order of their frames, as a run writes them."""
    from types import SimpleNamespace

    from follow import run as run_module

    class Perception:
        identifier = None

        def process(self, frame, robot, index):
            return SimpleNamespace(target=SimpleNamespace(target_id=None))

    monkeypatch.setattr(run_module, "build_perception", lambda *a, **k: Perception())
    video = _video(tmp_path / "a.avi")
    # stamped as the video's frames are (15 fps), so that only their order is wrong
    records = [json.dumps({"frame": k, "stamp_s": max(k, 0) / 15.0, "skeletons": []})
               for k in frames]  # fmt: skip
    log = _log(tmp_path / "run.jsonl", {"source": str(video), "image_size": [64, 48]}, records)
    err = _error(capsys, ["run", str(video), "--camera", str(_camera(tmp_path)),
                          "--replay", str(log)])  # fmt: skip
    assert f"--replay {log}: the log's {message}" in err


def test_a_target_id_never_seen_is_warned_of_after_the_configured_wait(tmp_path, caplog,
                                                                        model_path):  # fmt: skip
    """`follow run --target-id` leaves the watch to the identifier (one warning, not two),
    after `[control] missing_target_warn_s` of the video's frames."""
    model_path("pose/human-pose-estimation-0001.onnx")
    config = tmp_path / "f.toml"
    config.write_text("[control]\nmissing_target_warn_s = 1.0\n")
    video = _video(tmp_path / "a.avi", frames=40)  # 4 s at 10 fps, nobody in it
    argv = ["run", str(video), "--camera", str(_camera(tmp_path)), "--config", str(config),
            "--no-base", "--target-id", "999", "--json"]  # fmt: skip
    with caplog.at_level(logging.WARNING, logger="follow"):
        assert cli.main(argv) == 0
    said = [r.getMessage() for r in caplog.records if "999" in r.getMessage()]
    assert len(said) == 1
    assert "selected track 999: not among the tracks 1.0 s after its selection" in said[0]


def test_stream_ending_early_warns(tmp_path, caplog):
    whole = _video(tmp_path / "whole.avi")
    data = whole.read_bytes()
    (tmp_path / "cut.avi").write_bytes(data[: len(data) // 2])
    with caplog.at_level(logging.WARNING, logger="follow.capture"):
        assert len(list(FrameSource(str(whole)))) == 30
        assert not caplog.records
        read = len(list(FrameSource(str(tmp_path / "cut.avi"))))
    assert read < 30
    assert f"ended after {read} of the 30 frames" in caplog.records[0].getMessage()


def test_serial_link_needs_no_missing_module():
    from follow.control.mavlink_base import MavlinkBase, MavlinkError

    with pytest.raises(MavlinkError, match="'/dev/ttyNONE0,115200'.*could not open port"):
        MavlinkBase(MavlinkConfig(connection="/dev/ttyNONE0,115200"))


def test_a_replay_takes_the_runs_target_id_and_refuses_another_or_a_malformed_one():
    from follow.run import replay_target_id

    assert replay_target_id({"target_id": 3}, "run.jsonl", None) == 3
    assert replay_target_id({"target_id": 3}, "run.jsonl", 3) == 3
    assert replay_target_id({}, "run.jsonl", 4) == 4  # a log from before the header had it
    assert replay_target_id({"target_id": None}, "run.jsonl", None) is None
    with pytest.raises(ValueError, match="the run selected track 3, not --target-id 4"):
        replay_target_id({"target_id": 3}, "run.jsonl", 4)
    for bad in ("3", 2.5, True):
        with pytest.raises(ValueError, match="run.jsonl: the header's target_id .* is no track"):
            replay_target_id({"target_id": bad}, "run.jsonl", None)


@pytest.mark.parametrize("option", ["--mavlink", "--config", "--log"])
def test_an_empty_option_is_refused_by_the_command_line(tmp_path, capsys, option):
    """`--mavlink ""` used to run on the configuration's connection (the base driven by a
    command line that looks as if it drives none), `--config ""` on the defaults."""
    video = _video(tmp_path / "a.avi")
    with pytest.raises(SystemExit) as exit_:
        cli.main(["run", str(video), "--camera", str(_camera(tmp_path)), option, " "])
    assert exit_.value.code == 2
    assert f"argument {option}: empty" in capsys.readouterr().err


def test_no_base_and_mavlink_together_are_refused(tmp_path, capsys):
    video = _video(tmp_path / "a.avi")
    err = _error(capsys, ["run", str(video), "--camera", str(_camera(tmp_path)), "--no-base",
                          "--mavlink", "udpin:127.0.0.1:14550"])  # fmt: skip
    assert "--no-base and --mavlink contradict" in err


def test_no_base_drives_no_base_though_the_configuration_names_one(tmp_path, monkeypatch,
                                                                   model_path):  # fmt: skip
    """The README's first look at the view passes the robot's configuration, which names
    its base: `--no-base` must keep the run from connecting to it."""
    from follow import run as run_module

    model_path("pose/human-pose-estimation-0001.onnx")
    config = tmp_path / "robot.toml"
    config.write_text('[mavlink]\nconnection = "udpin:127.0.0.1:1"\n')
    opened = []
    real_open_base = run_module.open_base
    monkeypatch.setattr(run_module, "open_base",
                        lambda c: opened.append(c.mavlink.connection) or real_open_base(c))  # fmt: skip
    video = _video(tmp_path / "a.avi")
    argv = ["run", str(video), "--camera", str(_camera(tmp_path)), "--config", str(config),
            "--no-base", "--max-frames", "2", "--json"]  # fmt: skip
    assert cli.main(argv) == 0
    assert opened == [""]  # asked for no connection: a NullBase


def test_a_base_that_cannot_be_reached_leaves_an_earlier_log_as_it_was(tmp_path, capsys,
                                                                        model_path):  # fmt: skip
    model_path("pose/human-pose-estimation-0001.onnx")
    video = _video(tmp_path / "a.avi")
    log = tmp_path / "run.jsonl"
    log.write_text("an earlier run's log\n")
    err = _error(capsys, ["run", str(video), "--camera", str(_camera(tmp_path)), "--mavlink",
                          "not a connection string", "--log", str(log)])  # fmt: skip
    assert "MAVLink" in err or "mavlink" in err
    assert log.read_text() == "an earlier run's log\n"


@pytest.mark.parametrize(
    "extra",
    [["--mavlink", "udpin:127.0.0.1:14550"], ["--realtime"], ["--odom-topic", "/odom"],
     ["--skeletons-topic", "/people"]],
)  # fmt: skip
def test_a_replay_refuses_what_it_would_ignore(tmp_path, capsys, extra):
    video = _video(tmp_path / "a.avi")
    record = json.dumps({"frame": 0, "stamp_s": 0.0, "skeletons": []})
    log = _log(tmp_path / "run.jsonl", {"source": str(video), "image_size": [64, 48]}, [record])
    err = _error(capsys, ["run", str(video), "--camera", str(_camera(tmp_path)), "--replay",
                          str(log), *extra])  # fmt: skip
    assert f"--replay takes no {extra[0]}" in err
