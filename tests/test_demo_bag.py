"""`follow demo --bag`: the demo's run as a robot bag, which `follow run` replays to the
same tracks and targets, and whose ground truth matches what was followed."""

import json

import numpy as np
from rosbags.highlevel import AnyReader

from follow import cli
from follow.runlog import read_run_log
from follow.sim.demo import TARGET_ID, run_demo
from follow.sim.demo_bag import (
    CAMERA_INFO_TOPIC,
    IMAGE_TOPIC,
    ODOM_TOPIC,
    SKELETONS_TOPIC,
    TRUE_PEOPLE_TOPIC,
    companion_paths,
)


def test_follow_run_replays_the_demo_bag_to_the_same_targets(tmp_path, capsys):
    bag = tmp_path / "demo.mcap"
    run_demo(seconds=6.0, seed=0, identifier="channels", output=tmp_path / "demo",
             write_video=False, bag_path=bag)  # fmt: skip
    camera_file, config_file = companion_paths(bag)
    capsys.readouterr()
    args = ["run", str(bag), "--camera", str(camera_file), "--config", str(config_file),
            "--image-topic", IMAGE_TOPIC, "--odom-topic", ODOM_TOPIC,
            "--camera-info-topic", CAMERA_INFO_TOPIC, "--skeletons-topic", SKELETONS_TOPIC,
            "--log", str(tmp_path / "replay.jsonl"), "--json"]  # fmt: skip
    assert cli.main(args) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    demo = list(read_run_log(tmp_path / "demo" / "demo.jsonl")[1])
    replay = list(read_run_log(tmp_path / "replay.jsonl")[1])
    # The demo runs in real time: a loaded machine may drop a few frames, and the bag
    # holds exactly the frames the demo processed.
    assert summary["frames"] == len(demo) and summary["frames_without_odometry"] == 0
    assert len(demo) >= 60, len(demo)  # of 90
    for d, r in zip(demo, replay, strict=True):
        assert r.stamp_s == d.stamp_s and r.robot == d.robot
        assert (r.target_status, r.target_id) == (d.target_status, d.target_id)
        # The bag holds the skeletons as the run log rounds them (1e-4 px): the same
        # tracks to within a millimetre.
        assert [t["id"] for t in r.tracks] == [t["id"] for t in d.tracks]
        for a, b in zip(r.tracks, d.tracks, strict=True):
            np.testing.assert_allclose(a["mean"], b["mean"], atol=2e-3)
    assert sum(r.target_status == "tracking" for r in replay) > 30

    # The bag run's own log replays on the bag (`--replay` opened only video files).
    capsys.readouterr()
    again = ["run", str(bag), "--camera", str(camera_file), "--config", str(config_file),
             "--image-topic", IMAGE_TOPIC, "--camera-info-topic", CAMERA_INFO_TOPIC,
             "--replay", str(tmp_path / "replay.jsonl"), "--json"]  # fmt: skip
    assert cli.main(again) == 0
    replayed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert replayed == {"frames": len(replay), "target_agreement": 1.0, "not_replayed": 0}

    # The ground truth in the bag: the followed track lies on the true target.
    with AnyReader([bag]) as reader:
        (people,) = [c for c in reader.connections if c.topic == TRUE_PEOPLE_TOPIC]
        truth = [json.loads(reader.deserialize(raw, c.msgtype).data)
                 for c, _, raw in reader.messages([people])]  # fmt: skip
    assert len(truth) == len(replay)
    last = replay[-1]
    track = next(t for t in last.tracks if t["id"] == last.target_id)
    error_m = np.linalg.norm(np.array(track["mean"][:2]) - truth[-1][str(TARGET_ID)])
    assert last.target_status == "tracking" and error_m < 0.5


def test_a_demo_that_fails_before_it_runs_leaves_no_bag(tmp_path, monkeypatch):
    """A simulated rover that cannot start (its port taken) ends the demo before its first
    frame: no unfinished bag is left, which a second try would refuse to overwrite."""
    import pytest

    from follow.sim import rover

    def no_rover(*args, **kwargs):
        raise RuntimeError("address already in use")

    monkeypatch.setattr(rover, "SimRover", no_rover)
    for name in ("demo.bag", "demo.mcap", "demo_ros2"):
        with pytest.raises(RuntimeError, match="already in use"):
            run_demo(seconds=1.0, seed=0, identifier="channels", write_video=False,
                     bag_path=tmp_path / name)  # fmt: skip
        assert not (tmp_path / name).exists()


def _small_camera():
    from follow.camera import CameraModel, CameraPose

    return CameraModel.from_fov((64, 48), 70.0, CameraPose(height_m=1.0))


def test_the_files_beside_a_demo_bag_are_named_after_its_whole_name(tmp_path):
    """`with_suffix` named them robot.toml and robot.camera.yaml beside robot.mcap (the
    robot's own files, replaced), and gave two dated bag folders the same pair."""
    from follow.sim.demo_bag import DemoBag

    robot_toml, robot_camera = tmp_path / "robot.toml", tmp_path / "robot.camera.yaml"
    robot_toml.write_text("# the robot's own config\n")
    robot_camera.write_text("# the robot's measured calibration\n")
    bag = DemoBag(tmp_path / "robot.mcap", _small_camera(), "channels", 1)
    bag.close()
    assert robot_toml.read_text() == "# the robot's own config\n"
    assert robot_camera.read_text() == "# the robot's measured calibration\n"
    camera_file, config_file = companion_paths(tmp_path / "robot.mcap")
    assert (camera_file.name, config_file.name) == ("robot.mcap.camera.yaml", "robot.mcap.toml")
    assert 'identifier = "channels"' in config_file.read_text()
    assert set(companion_paths("runs/2024.05.01")).isdisjoint(companion_paths("runs/2024.05.02"))


def test_a_file_beside_the_bag_that_exists_is_refused_by_name_and_kept(tmp_path):
    import pytest

    from follow.sim.demo_bag import DemoBag

    camera_file, config_file = companion_paths(tmp_path / "demo.mcap")
    config_file.write_text("# mine\n")
    with pytest.raises(FileExistsError, match=rf"{config_file.name} exists already"):
        DemoBag(tmp_path / "demo.mcap", _small_camera(), "channels", 1)
    assert config_file.read_text() == "# mine\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == [config_file.name]  # nothing else


def test_an_aborted_demo_bag_takes_the_files_beside_it_along(tmp_path):
    """Left behind, they would name a bag that does not exist, and refuse the next try."""
    from follow.sim.demo_bag import DemoBag

    bag = DemoBag(tmp_path / "demo.mcap", _small_camera(), "channels", 1)
    assert all(p.is_file() for p in companion_paths(tmp_path / "demo.mcap"))
    bag.abort()
    assert not list(tmp_path.iterdir())
