"""Recorded bags as input: writing and reading ROS 1, ROS 2 and MCAP bags, odometry
matched to image stamps, and `follow run BAG` giving the same results as the video."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
from pets_robot import CONFIG_TOML, pets_camera, pets_frames, robot_pose

from follow import cli
from follow.bag import BagSource
from follow.bag_writer import BagWriter
from follow.camera import CameraModel, CameraPose
from follow.capture import SourceError
from follow.runlog import read_run_log
from follow.types import Odometry

ODOM_PERIOD_S = 0.02
ODOM_OFFSET_S = 0.007  # odometry is never stamped at the images' instants


def odometry_track(first_s: float, last_s: float) -> list[Odometry]:
    n = int((last_s - first_s + 0.2) / ODOM_PERIOD_S) + 1
    return [robot_pose(first_s - 0.1 + ODOM_OFFSET_S + k * ODOM_PERIOD_S) for k in range(n)]


def write_robot_bag(path, frames, camera, odometry=True):
    with BagWriter(path) as bag:
        poses = odometry_track(frames[0].stamp_s, frames[-1].stamp_s) if odometry else []
        for frame in frames:
            for pose in [p for p in poses if p.stamp_s < frame.stamp_s]:
                bag.write_odometry("/odom", pose)
            poses = [p for p in poses if p.stamp_s >= frame.stamp_s]
            bag.write_camera_info("/camera/camera_info", frame.stamp_s, camera, "camera")
            bag.write_image("/camera/image_raw", frame.stamp_s, frame.image, "camera")
        for pose in poses:
            bag.write_odometry("/odom", pose)


@pytest.fixture
def small_frames():
    from follow.types import Frame

    rng = np.random.default_rng(3)
    return [Frame(rng.integers(0, 255, (48, 64, 3), dtype=np.uint8), 1000.0 + 0.1 * i)
            for i in range(6)]  # fmt: skip


@pytest.fixture
def small_camera():
    pose = CameraPose(height_m=1.2, pitch_rad=0.1)
    return CameraModel.from_fov((64, 48), 70.0, pose, dist=np.array([0.1, -0.02, 0, 0, 0.01]))


@pytest.mark.parametrize("name", ["robot.bag", "robot.mcap", "robot_ros2"])
def test_every_bag_format_gives_back_the_frames_odometry_and_intrinsics(
    tmp_path, small_frames, small_camera, name
):
    write_robot_bag(tmp_path / name, small_frames, small_camera)
    source = BagSource(str(tmp_path / name), "/camera/image_raw", "/odom", "/camera/camera_info")
    frames = list(source)
    source.close()
    assert [f.stamp_s for f in frames] == pytest.approx([f.stamp_s for f in small_frames], abs=1e-9)
    assert all(np.array_equal(a.image, b.image) for a, b in zip(frames, small_frames, strict=True))
    assert source.fps == pytest.approx(10.0)
    for frame in frames:  # the pose at each image's instant, between 50 Hz samples
        pose, truth = source.odometry_at(frame.stamp_s), robot_pose(frame.stamp_s)
        assert (pose.x_m, pose.y_m, pose.yaw_rad) == pytest.approx(
            (truth.x_m, truth.y_m, truth.yaw_rad), abs=1e-6
        )
    from follow.rosmsg import camera_from_info

    camera = camera_from_info(source.camera_info, small_camera)
    np.testing.assert_allclose(camera.K, small_camera.K)
    np.testing.assert_allclose(camera.dist, small_camera.dist)
    assert camera.image_size == (64, 48)


def test_images_without_odometry_nearby_are_skipped(tmp_path, small_frames, small_camera):
    path = tmp_path / "gap.mcap"
    with BagWriter(path) as bag:
        for frame in small_frames:
            bag.write_image("/camera/image_raw", frame.stamp_s, frame.image, "camera")
        bag.write_odometry("/odom", robot_pose(small_frames[0].stamp_s + 0.05))
    source = BagSource(str(path), "/camera/image_raw", "/odom", max_odometry_gap_s=0.1)
    stamps = [f.stamp_s for f in source]
    # Frames 0 and 1 lie 0.05 s from the one odometry sample; the rest are too far.
    assert stamps == pytest.approx([small_frames[0].stamp_s, small_frames[1].stamp_s])
    assert source.frames_without_odometry == 4


def test_a_repeated_image_is_skipped_not_tracked_twice(tmp_path, small_frames, small_camera):
    path = tmp_path / "repeated.mcap"
    with BagWriter(path) as bag:
        for frame in [*small_frames[:3], small_frames[2], *small_frames[3:]]:  # one twice
            bag.write_image("/camera/image_raw", frame.stamp_s, frame.image, "camera")
    source = BagSource(str(path), "/camera/image_raw")
    assert [f.stamp_s for f in source] == pytest.approx([f.stamp_s for f in small_frames])
    assert source.repeated_frames == 1


def test_unstamped_odometry_is_placed_at_its_record_time_as_unstamped_images_are(
    tmp_path, small_frames
):
    path = tmp_path / "unstamped.mcap"
    poses = odometry_track(small_frames[0].stamp_s, small_frames[-1].stamp_s)
    with BagWriter(path) as bag:
        stamped_header = bag._header
        bag._header = lambda stamp, frame_id: stamped_header(0.0, frame_id)  # header left 0
        for pose in poses:
            bag.write_odometry("/odom", pose)  # recorded at the pose's time
        bag._header = stamped_header
        for frame in small_frames:
            bag.write_image("/camera/image_raw", frame.stamp_s, frame.image, "camera")
    source = BagSource(str(path), "/camera/image_raw", "/odom")
    frames = list(source)
    assert len(frames) == len(small_frames) and source.frames_without_odometry == 0
    for frame in frames:
        expected = robot_pose(frame.stamp_s)
        pose = source.odometry_at(frame.stamp_s)
        assert (pose.x_m, pose.y_m, pose.yaw_rad) == pytest.approx(
            (expected.x_m, expected.y_m, expected.yaw_rad), abs=1e-6
        )


def test_one_unusable_odometry_sample_is_a_gap_not_an_unreadable_bag(
    tmp_path, small_frames, small_camera, caplog
):
    path = tmp_path / "nan.mcap"
    poses = odometry_track(small_frames[0].stamp_s, small_frames[-1].stamp_s)
    object.__setattr__(poses[7], "x_m", float("nan"))  # a driver's glitch, as recorded
    with BagWriter(path) as bag:
        for pose in poses:
            bag.write_odometry("/odom", pose)
        for frame in small_frames:
            bag.write_image("/camera/image_raw", frame.stamp_s, frame.image, "camera")
    source = BagSource(str(path), "/camera/image_raw", "/odom")
    assert len(list(source)) == len(small_frames)
    assert "1 odometry message(s) on /odom skipped" in caplog.text


def test_an_empty_image_in_a_bag_is_skipped_not_fatal(tmp_path, small_frames):
    path = tmp_path / "empty.mcap"
    with BagWriter(path) as bag:
        for k, frame in enumerate(small_frames):
            if k == 2:
                image_type = bag._types("sensor_msgs/msg/Image")
                bag.write("/camera/image_raw", frame.stamp_s, image_type(
                    header=bag._header(frame.stamp_s, "camera"), height=0, width=64,
                    encoding="mono8", is_bigendian=0, step=64, data=np.zeros(0, np.uint8),
                ))  # fmt: skip
            else:
                bag.write_image("/camera/image_raw", frame.stamp_s, frame.image, "camera")
    assert len(list(BagSource(str(path), "/camera/image_raw"))) == len(small_frames) - 1


def test_a_missing_topic_is_named_with_the_topics_the_bag_holds(
    tmp_path, small_frames, small_camera
):
    write_robot_bag(tmp_path / "robot.mcap", small_frames, small_camera)
    with pytest.raises(SourceError, match=r"no topic /image.*/camera/image_raw \(sensor_msgs"):
        BagSource(str(tmp_path / "robot.mcap"), "/image")
    with pytest.raises(SourceError, match="topic /odom is nav_msgs/msg/Odometry, expected"):
        BagSource(str(tmp_path / "robot.mcap"), "/odom")


@pytest.mark.parametrize("name", ["robot.bag", "robot.mcap", "robot_ros2"])
def test_a_bag_refused_when_opened_is_closed_again(tmp_path, small_frames, small_camera, name):
    import os

    def open_in_bag() -> list[str]:
        fds = "/proc/self/fd"
        return [t for t in (os.path.realpath(f"{fds}/{fd}") for fd in os.listdir(fds))
                if t.startswith(str(tmp_path.resolve() / name))]  # fmt: skip

    write_robot_bag(tmp_path / name, small_frames, small_camera)
    for topics in (("/image",), ("/camera/image_raw", "/camera/image_raw")):
        with pytest.raises(SourceError):
            BagSource(str(tmp_path / name), *topics)  # no such topic; images as odometry
    assert open_in_bag() == []


def test_follow_run_on_a_bag_needs_the_image_topic(tmp_path, small_frames, small_camera, capsys):
    write_robot_bag(tmp_path / "robot.mcap", small_frames, small_camera)
    small_camera.save(tmp_path / "cam.yaml")
    code = cli.main(["run", str(tmp_path / "robot.mcap"), "--camera", str(tmp_path / "cam.yaml")])
    assert code == 1
    assert "--image-topic" in capsys.readouterr().err


@pytest.mark.parametrize("drive", ["--realtime", "--mavlink", "config"])
def test_a_bags_odometry_is_never_replayed_beside_a_live_base(
    tmp_path, small_frames, small_camera, capsys, drive
):
    """The bag's odometry is the recorded robot's: a connection from the configuration
    file is refused like --mavlink, before any frame is read."""
    write_robot_bag(tmp_path / "robot.mcap", small_frames, small_camera)
    small_camera.save(tmp_path / "cam.yaml")
    args = ["run", str(tmp_path / "robot.mcap"), "--camera", str(tmp_path / "cam.yaml"),
            "--image-topic", "/camera/image_raw", "--odom-topic", "/odom"]  # fmt: skip
    if drive == "config":
        (tmp_path / "base.toml").write_text('[mavlink]\nconnection = "udpin:127.0.0.1:14599"\n')
        args += ["--config", str(tmp_path / "base.toml")]
    else:
        args += [drive] if drive == "--realtime" else [drive, "udpin:127.0.0.1:14599"]
    assert cli.main(args) == 1
    err = capsys.readouterr().err
    assert "odometry is replayed frame by frame" in err and "[mavlink] connection" in err


FRAMES = 10


def _run(args, capsys) -> dict:
    capsys.readouterr()
    assert cli.main(args + ["--json"]) == 0
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])


@pytest.mark.slow
def test_follow_run_on_a_pets_bag_matches_the_video(tmp_path, data_path, model_path, capsys):
    """The same skeletons, tracks and targets from the bag as from the video; with the
    bag's odometry, the robot pose at every image and the tracks it implies."""
    from follow.config import Config
    from follow.run import build_perception

    model_path("pose/human-pose-estimation-0001.onnx")
    camera, camera_file = pets_camera(data_path, tmp_path)
    (tmp_path / "config.toml").write_text(CONFIG_TOML)
    frames = pets_frames(data_path, FRAMES)
    write_robot_bag(tmp_path / "robot.mcap", frames, camera)
    common = ["--camera", str(camera_file), "--config", str(tmp_path / "config.toml"),
              "--target-id", "1", "--max-frames", str(FRAMES)]  # fmt: skip
    video = str(data_path("pets2009_s2l1/View_001.avi"))
    _run(["run", video, *common, "--log", str(tmp_path / "video.jsonl")], capsys)
    topics = ["--image-topic", "/camera/image_raw", "--camera-info-topic", "/camera/camera_info"]
    _run(["run", str(tmp_path / "robot.mcap"), *common, *topics,
          "--log", str(tmp_path / "still.jsonl")], capsys)  # fmt: skip
    moving = _run(["run", str(tmp_path / "robot.mcap"), *common, *topics, "--odom-topic", "/odom",
                   "--log", str(tmp_path / "moving.jsonl")], capsys)  # fmt: skip
    assert moving["frames"] == FRAMES and moving["frames_without_odometry"] == 0

    video_log = list(read_run_log(tmp_path / "video.jsonl")[1])
    still_log = list(read_run_log(tmp_path / "still.jsonl")[1])
    moving_log = list(read_run_log(tmp_path / "moving.jsonl")[1])
    # Without odometry the bag is the video: the same tracks and targets, frame by frame.
    assert sum(len(r.tracks) for r in video_log) > 2 * FRAMES
    for v, s in zip(video_log, still_log, strict=True):
        assert s.tracks == v.tracks
        assert (s.target_status, s.target_id) == (v.target_status, v.target_id)
    assert any(r.target_id == 1 for r in video_log)

    # With odometry: the pose at each image's stamp, and the tracks that pose implies
    # (tracking and identification re-run here on the video's skeletons at that pose).
    config = Config.load(tmp_path / "config.toml")
    current = [[]]
    height, width = frames[0].image.shape[:2]
    perception = build_perception(
        config, camera.for_image_size(width, height), detect=lambda frame: current[0]
    )
    perception.identifier.select_target(1)
    for index, (v, m) in enumerate(zip(video_log, moving_log, strict=True)):
        truth = robot_pose(frames[index].stamp_s)
        assert m.stamp_s == pytest.approx(frames[index].stamp_s, abs=1e-6)
        assert (m.robot.x_m, m.robot.y_m, m.robot.yaw_rad) == pytest.approx(
            (truth.x_m, truth.y_m, truth.yaw_rad), abs=1e-4
        )
        current[0] = v.skeletons
        result = perception.process(frames[index], truth, index)
        expected = {t.track_id: t.mean[:2] for t in result.tracks}
        got = {t["id"]: np.array(t["mean"][:2]) for t in m.tracks}
        assert got.keys() == expected.keys()
        for track_id, position in expected.items():
            np.testing.assert_allclose(got[track_id], position, atol=2e-3)
        assert m.target_id == result.target.target_id
    # The robot turned by 0.05 rad/s: tracks in `odom` are not those of the still camera.
    last_v = {t["id"]: np.array(t["mean"][:2]) for t in video_log[-1].tracks}
    last_m = {t["id"]: np.array(t["mean"][:2]) for t in moving_log[-1].tracks}
    shared = last_v.keys() & last_m.keys()
    assert shared and max(np.linalg.norm(last_v[k] - last_m[k]) for k in shared) > 0.2
    assert math.isfinite(moving["fps"])


@pytest.mark.parametrize("name", ["robot.bag", "robot.mcap", "robot_ros2"])
def test_a_bag_whose_writing_fails_part_way_is_not_left_as_a_shorter_valid_bag(
    tmp_path, small_frames, name
):
    path = tmp_path / name
    with pytest.raises(RuntimeError, match="disk full"):
        with BagWriter(path) as bag:
            for i, frame in enumerate(small_frames):
                if i == 3:
                    raise RuntimeError("disk full")
                bag.write_image("/camera/image_raw", frame.stamp_s, frame.image, "camera")
    assert not path.exists()
    assert list(tmp_path.iterdir()) == []  # no temporary left either


@pytest.mark.parametrize("name", ["robot.bag", "robot.mcap", "robot_ros2"])
def test_a_bag_is_written_beside_its_destination_and_renamed_into_place(
    tmp_path, small_frames, monkeypatch, name
):
    """Written under its own name, a ROS 1 bag or a ROS 2 bag folder cut short by a
    killed run read back as a valid, shorter recording; written in a system temp folder,
    the last step was a copy whenever that folder is on another file system. The bag is
    written hidden in the destination's own folder, then renamed."""
    renamed = []
    replace = os.replace
    monkeypatch.setattr(os, "replace",
                        lambda src, dst: (renamed.append((src, dst)), replace(src, dst)))  # fmt: skip
    path = tmp_path / name
    with BagWriter(path) as bag:
        frame = small_frames[0]
        bag.write_image("/camera/image_raw", frame.stamp_s, frame.image, "camera")
        (hidden,) = tmp_path.iterdir()
        assert hidden.name.startswith(f".{name}.") and hidden.is_dir()
    (into_place,) = [Path(src) for src, dst in renamed if Path(dst) == path]
    assert hidden in into_place.parents
    assert list(tmp_path.iterdir()) == [path]
    source = BagSource(str(path), "/camera/image_raw")
    assert [f.stamp_s for f in source] == [frame.stamp_s]
    source.close()


@pytest.mark.parametrize("failing", ["writer", "rename"])
def test_a_single_mcap_whose_closing_fails_leaves_neither_bag_nor_temporary(
    tmp_path, small_frames, monkeypatch, failing
):
    def fail(*args):
        raise OSError("disk full")

    path = tmp_path / "robot.mcap"
    replace = os.replace
    bag = BagWriter(path)
    frame = small_frames[0]
    bag.write_image("/camera/image_raw", frame.stamp_s, frame.image, "camera")
    temporary = bag._tmp
    if failing == "writer":  # the writer finishes its file, then fails
        close = bag._writer.close
        monkeypatch.setattr(bag._writer, "close", lambda: (close(), fail()))
    else:
        monkeypatch.setattr(os, "replace",  # the bag's own rename only
                            lambda src, dst: fail() if Path(dst) == path else replace(src, dst))
    with pytest.raises(OSError, match="disk full"):
        bag.close()
    assert not path.exists() and not temporary.exists()
    assert list(tmp_path.iterdir()) == []


def _record_replayed_frames(monkeypatch) -> list:
    """The (stamp, image) of every frame a replay hands to perception, in order (the
    perception itself is replaced: what matters is which images the records meet)."""
    from types import SimpleNamespace

    from follow import run as run_module

    seen = []

    class Recorder:
        identifier = None

        def process(self, frame, robot, index):
            seen.append((frame.stamp_s, frame.image))
            return SimpleNamespace(target=SimpleNamespace(target_id=None))

    monkeypatch.setattr(run_module, "build_perception", lambda *a, **k: Recorder())
    return seen


def test_a_bag_run_replays_each_record_on_its_own_image(
    tmp_path, small_frames, small_camera, capsys, monkeypatch, model_path
):
    """Images without odometry are skipped in the run but not in the replay (which reads
    no odometry): each record must still meet the image it was made from, not the one
    at its position among all the bag's images."""
    model_path("ccf/ccf10")  # the run's identifier
    path = tmp_path / "late_odometry.mcap"
    with BagWriter(path) as bag:
        for frame in small_frames:
            bag.write_string("/skeletons", frame.stamp_s, "[]")
            bag.write_image("/camera/image_raw", frame.stamp_s, frame.image, "camera")
        for pose in odometry_track(small_frames[4].stamp_s, small_frames[-1].stamp_s):
            bag.write_odometry("/odom", pose)  # none near the first two images
    small_camera.save(tmp_path / "cam.yaml")
    common = [str(path), "--camera", str(tmp_path / "cam.yaml"),
              "--image-topic", "/camera/image_raw"]  # fmt: skip
    ran = _run(["run", *common, "--odom-topic", "/odom", "--skeletons-topic", "/skeletons",
                "--log", str(tmp_path / "run.jsonl")], capsys)  # fmt: skip
    assert ran["frames_without_odometry"] == 2

    seen = _record_replayed_frames(monkeypatch)
    replayed = _run(["run", *common, "--replay", str(tmp_path / "run.jsonl")], capsys)
    assert replayed["frames"] == ran["frames"] == len(seen)
    images = {round(f.stamp_s, 6): f.image for f in small_frames}
    for stamp, image in seen:
        assert np.array_equal(image, images[round(stamp, 6)])


def test_a_replay_reads_the_image_topic_the_run_read(
    tmp_path, small_frames, small_camera, capsys, monkeypatch, model_path
):
    """A bag with two cameras, run on the second: the replay, not told the topic again,
    must replay the second camera's images (the log names the topic), not refuse the
    bag or take the first."""
    model_path("ccf/ccf10")  # the run's identifier
    path = tmp_path / "two_cameras.mcap"
    with BagWriter(path) as bag:
        for frame in small_frames:
            bag.write_string("/skeletons", frame.stamp_s, "[]")
            bag.write_image("/front/image_raw", frame.stamp_s, 255 - frame.image, "front")
            bag.write_image("/rear/image_raw", frame.stamp_s, frame.image, "rear")
    small_camera.save(tmp_path / "cam.yaml")
    common = [str(path), "--camera", str(tmp_path / "cam.yaml")]
    ran = _run(["run", *common, "--image-topic", "/rear/image_raw", "--skeletons-topic",
                "/skeletons", "--log", str(tmp_path / "run.jsonl")], capsys)  # fmt: skip
    seen = _record_replayed_frames(monkeypatch)
    replayed = _run(["run", *common, "--replay", str(tmp_path / "run.jsonl")], capsys)
    assert replayed["frames"] == ran["frames"] == len(seen) > 0
    rear = {round(f.stamp_s, 6): f.image for f in small_frames}
    assert all(np.array_equal(image, rear[round(stamp, 6)]) for stamp, image in seen)


def test_a_bag_named_with_another_suffix_or_in_no_folder_is_refused_by_name(tmp_path):
    """`--bag run.txt` wrote a ROS 2 bag folder named run.txt; a bag in a folder that
    does not exist was reported with the name of a hidden temporary folder."""
    with pytest.raises(ValueError, match=r"run\.txt: name a \.mcap or \.bag file"):
        BagWriter(tmp_path / "run.txt")
    assert not list(tmp_path.iterdir())
    with pytest.raises(OSError, match=r"cannot write the bag .*missing/run\.mcap"):
        BagWriter(tmp_path / "missing" / "run.mcap")
    with BagWriter(tmp_path / "2024.05.01") as bag:  # a folder named with a date
        bag.write_string("/note", 0.0, "[]")
    assert (tmp_path / "2024.05.01" / "metadata.yaml").is_file()


@pytest.mark.parametrize("name", ["run.db3", "run.mp4", "run.v2"])
def test_a_bag_named_with_a_suffix_of_digits_and_letters_is_refused_too(tmp_path, name):
    """Only letters were refused: `--bag run.db3` wrote a ROS 2 bag folder (MCAP inside)
    under the name of an SQLite bag file; only a dated folder's digits pass."""
    with pytest.raises(ValueError, match=rf"{name}: name a \.mcap or \.bag file"):
        BagWriter(tmp_path / name)
    assert not list(tmp_path.iterdir())


def test_a_skeletons_topic_holding_other_json_is_named_as_such(tmp_path, small_frames):
    path = tmp_path / "other.mcap"
    with BagWriter(path) as bag:
        for frame in small_frames[:2]:
            bag.write_image("/camera/image_raw", frame.stamp_s, frame.image, "camera")
            bag.write_string("/people", frame.stamp_s, json.dumps({"7": [1.0, 2.0]}))
    with pytest.raises(SourceError, match="/people at .* is not a JSON list of skeletons"):
        BagSource(str(path), "/camera/image_raw", skeletons_topic="/people")


def test_a_message_whose_bytes_do_not_decode_is_skipped_not_fatal(
    tmp_path, small_frames, caplog, capsys
):
    """A damaged bag (a few bytes of one image, one odometry sample and one skeletons
    message): each is skipped with a warning naming its topic and time, the rest is run."""
    path = tmp_path / "damaged.mcap"
    poses = odometry_track(small_frames[0].stamp_s, small_frames[-1].stamp_s)
    damaged_image_s = small_frames[3].stamp_s
    with BagWriter(path) as bag:
        for pose in poses:
            bag.write_odometry("/odom", pose)
        for frame in small_frames:
            bag.write_string("/skeletons", frame.stamp_s, "[]")
            bag.write_image("/camera/image_raw", frame.stamp_s, frame.image, "camera")
        for topic, stamp_s in (("/camera/image_raw", damaged_image_s + 0.05),
                               ("/odom", poses[5].stamp_s + 0.001),
                               ("/skeletons", damaged_image_s + 0.05)):  # fmt: skip
            bag._writer.write(bag._connections[topic], int(stamp_s * 1e9), b"\xff\x01\x02")
    source = BagSource(str(path), "/camera/image_raw", "/odom", skeletons_topic="/skeletons")
    frames = list(source)
    assert [f.stamp_s for f in frames] == [f.stamp_s for f in small_frames]
    assert source.damaged_images == 1
    text = caplog.text
    assert "skipping an image: /camera/image_raw at" in text and "does not decode" in text
    assert "1 odometry message(s) on /odom skipped" in text
    assert "1 skeleton message(s) skipped (first: /skeletons at" in text
