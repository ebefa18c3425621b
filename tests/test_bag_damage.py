"""A bag's faults named rather than hidden: a damaged record ends the bag naming it (no
traceback), odometry whose clock stepped back is not merged across the step, and the
images skipped are counted by reason, in the refusal of a bag whose images are all
skipped and in `follow run`'s summary."""

from __future__ import annotations

import struct
from types import SimpleNamespace

import numpy as np
import pytest
from nobody_seen import NobodySeen

from follow import cli
from follow import run as run_module
from follow.bag import BagSource
from follow.bag_writer import BagWriter
from follow.camera import CameraModel, CameraPose
from follow.types import Odometry

TOPIC = "/camera/image_raw"
CAMERA = CameraModel.from_fov((64, 48), 70.0, CameraPose(height_m=1.2, pitch_rad=0.1))
MARKED_X_M = 0.873456789  # the x of one odometry sample: found in the bag's bytes


def _image(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 255, (48, 64, 3), dtype=np.uint8)


def write_small_bag(path, images=6, marked: int | None = None) -> None:
    """`images` 10 Hz images with odometry beside each (the `marked` one at MARKED_X_M)."""
    with BagWriter(path) as bag:
        for i in range(images):
            t = 1000.0 + 0.1 * i
            x = MARKED_X_M if i == marked else 0.1 * i
            bag.write_odometry("/odom", Odometry(x, 0.0, 0.0, t - 0.01))
            bag.write_odometry("/odom", Odometry(x, 0.0, 0.0, t + 0.01))
            bag.write_image(TOPIC, t, _image(i), "camera")


def damage_record(path) -> None:
    """Damage the storage record of the marked odometry sample (not its message bytes):
    an MCAP record's length made huge, a ROS 1 record's `time` field renamed."""
    data = bytearray(path.read_bytes())
    at = data.find(struct.pack("<d", MARKED_X_M))
    assert at > 0
    if path.suffix == ".bag":
        field = data.rfind(b"time=", 0, at)
        data[field : field + 5] = b"tine="
    else:  # the Message record (opcode 5, then its length) holding the sample
        for start in range(at, at - 200, -1):
            length = struct.unpack_from("<Q", data, start + 1)[0]
            if data[start] == 5 and at < start + 9 + length < len(data):
                break
        struct.pack_into("<Q", data, start + 1, 2**40)
    path.write_bytes(data)


@pytest.mark.parametrize("name", ["damaged.mcap", "damaged.bag"])
def test_a_damaged_record_ends_the_bag_naming_it_not_with_a_traceback(tmp_path, capsys, name):
    path = tmp_path / name
    write_small_bag(path, marked=3)
    damage_record(path)
    with pytest.raises(Exception, match=r"/odom: damaged record \(ReaderError") as raised:
        BagSource(str(path), TOPIC, "/odom")
    assert type(raised.value).__name__ == "SourceError" and str(path) in str(raised.value)
    CAMERA.save(tmp_path / "camera.yaml")
    args = ["run", str(path), "--camera", str(tmp_path / "camera.yaml"),
            "--image-topic", TOPIC, "--odom-topic", "/odom"]  # fmt: skip
    assert cli.main(args) == 1
    assert "/odom: damaged record" in capsys.readouterr().err


def test_a_record_damaged_mid_run_keeps_the_frames_read_before_it(tmp_path):
    from rosbags.rosbag2.errors import ReaderError

    write_small_bag(tmp_path / "robot.mcap")
    source = BagSource(str(tmp_path / "robot.mcap"), TOPIC, "/odom")
    read = source._reader.messages

    def messages(connections):
        for index, message in enumerate(read(connections)):
            if index == 3:
                raise ReaderError("Truncated record at offset 1234")
            yield message

    source._reader.messages = messages
    frames = []
    with pytest.raises(Exception, match=rf"{TOPIC}: damaged record \(ReaderError: Trunc") as e:
        frames.extend(source)
    assert type(e.value).__name__ == "SourceError"
    assert [f.stamp_s for f in frames] == pytest.approx([1000.0, 1000.1, 1000.2])
    source.close()


def _recorded_at(bag: BagWriter, record_s: float, pose: Odometry) -> None:
    """Odometry stamped on the robot's clock, recorded at `record_s` on the recorder's."""
    write = bag.write
    bag.write = lambda topic, _stamp, msg: write(topic, record_s, msg)
    try:
        bag.write_odometry("/odom", pose)
    finally:
        del bag.write


def test_odometry_whose_clock_steps_back_is_not_merged_across_the_step(tmp_path, caplog):
    """The robot drives +x at 1 m/s; its clock steps back 0.5 s at 1 s (an NTP step),
    the bag's record time does not. Samples after the step stamped at or before the last
    one kept are dropped, as images are: each image gets the pose of its own side."""

    def robot_stamp(k: int) -> float:  # 50 Hz ticks, on the robot's clock
        return 1000.0 + 0.02 * (k if k < 50 else k - 25)

    path = tmp_path / "clockstep.mcap"
    with BagWriter(path) as bag:
        for k in range(100):
            _recorded_at(bag, 1000.0 + 0.02 * k, Odometry(0.02 * k, 0.0, 0.0, robot_stamp(k)))
        for i in range(20):  # 10 Hz images, 5 ms after an odometry tick
            t = 0.1 * i + 0.005
            image = bag._types("sensor_msgs/msg/Image")
            stamp = 1000.0 + t - (0.5 if t >= 1.0 else 0.0)
            bag.write(TOPIC, 1000.0 + t, image(header=bag._header(stamp, "camera"),
                                               **image_fields(_image(i))))  # fmt: skip
    source = BagSource(str(path), TOPIC, "/odom")
    frames = list(source)
    assert "25 odometry message(s) on /odom skipped: stamped at or before" in caplog.text
    assert len(frames) == 15  # images 10..14 are stamped at or before image 9
    for frame in frames:
        true_x = frame.stamp_s - 1000.0 + (0.5 if frame.stamp_s > 1000.95 else 0.0)
        assert abs(source.odometry_at(frame.stamp_s).x_m - true_x) < 0.05, frame.stamp_s
    assert source.skipped_images == {"stamp not after the previous": 5}
    source.close()


def image_fields(image: np.ndarray) -> dict:
    from follow.rosmsg import image_fields as fields

    return fields(image)


def _mono16(bag: BagWriter, stamp_s: float, seed: int):
    grey = _image(seed)[:, :, 0].astype(np.uint16) * 256
    return bag._types("sensor_msgs/msg/Image")(
        header=bag._header(stamp_s, "camera"), height=48, width=64, encoding="mono16",
        is_bigendian=0, step=128, data=grey.view(np.uint8).reshape(-1),
    )  # fmt: skip


def test_a_bag_whose_images_are_all_skipped_is_refused_with_the_counts(tmp_path, capsys):
    path = tmp_path / "mono16.mcap"
    with BagWriter(path) as bag:
        for i in range(6):
            bag.write(TOPIC, 1000.0 + 0.1 * i, _mono16(bag, 1000.0 + 0.1 * i, i))
    message = f"6 images on {TOPIC}, all skipped: 6 in unsupported encoding 'mono16'"
    with pytest.raises(Exception, match=message) as raised:
        list(BagSource(str(path), TOPIC))
    assert type(raised.value).__name__ == "SourceError"
    CAMERA.save(tmp_path / "camera.yaml")
    assert cli.main(["run", str(path), "--camera", str(tmp_path / "camera.yaml"),
                     "--image-topic", TOPIC]) == 1  # fmt: skip
    err = capsys.readouterr().err
    assert message in err and "no frames" not in err


def write_mixed_bag(path) -> None:
    """10 images: 2 in mono16, 1 repeating its predecessor's stamp, 2 with no odometry
    near them (odometry covers 1000.0..1000.7 s only), 5 usable."""
    with BagWriter(path) as bag:
        for k in range(36):
            bag.write_odometry("/odom", Odometry(0.0, 0.0, 0.0, 1000.0 + 0.02 * k))
        for i in range(10):
            t = 1000.0 + 0.1 * i
            if i in (2, 5):
                bag.write(TOPIC, t, _mono16(bag, t, i))
            else:
                stamp = t - 0.1 if i == 4 else t  # image 4 stamped as image 3
                bag.write(TOPIC, t, bag._types("sensor_msgs/msg/Image")(
                    header=bag._header(stamp, "camera"), **image_fields(_image(i))))  # fmt: skip


MIXED_SKIPS = {"unsupported encoding 'mono16'": 2, "stamp not after the previous": 1,
               "no odometry": 2}  # fmt: skip


def test_the_images_a_bag_skips_are_counted_by_reason(tmp_path):
    write_mixed_bag(tmp_path / "mixed.mcap")
    source = BagSource(str(tmp_path / "mixed.mcap"), TOPIC, "/odom", max_odometry_gap_s=0.05)
    assert len(list(source)) == 5
    assert source.skipped_images == MIXED_SKIPS
    source.close()


def test_follow_runs_summary_reports_the_bags_skipped_images(tmp_path, monkeypatch):
    write_mixed_bag(tmp_path / "mixed.mcap")
    CAMERA.save(tmp_path / "camera.yaml")
    (tmp_path / "config.toml").write_text("[ros]\nmax_odometry_age_s = 0.05\n")
    monkeypatch.setattr(run_module, "build_perception", lambda *a, **k: NobodySeen())
    args = SimpleNamespace(
        max_frames=None, config=str(tmp_path / "config.toml"), mavlink=None, replay=None,
        source=str(tmp_path / "mixed.mcap"), image_topic=TOPIC, odom_topic="/odom",
        camera_info_topic=None, skeletons_topic=None, realtime=False,
        camera=str(tmp_path / "camera.yaml"), output_video=None, log=None, frames_dir=None,
        target_id=None, json=True, folder_fps=None, no_base=True,
    )  # fmt: skip
    result = run_module.main(args)
    assert result["frames"] == 5 and result["frames_without_odometry"] == 2
    assert result["skipped_images"] == MIXED_SKIPS
