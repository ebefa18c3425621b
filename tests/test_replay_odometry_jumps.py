"""A bag's replay gives the tracker the bag's odometry jumps, as its run does: without
them a reset of the odom frame (an estimator's yaw reset) passed for motion in the
replay, and its targets disagreed with the run's although nothing had changed."""

from __future__ import annotations

import json
import math

import numpy as np

from follow import cli
from follow import run as run_module
from follow.bag_writer import BagWriter
from follow.camera import CameraModel, CameraPose
from follow.types import Odometry

FIRST_IMAGE_S, IMAGE_PERIOD_S, IMAGES = 1000.0, 0.1, 6
ODOM_PERIOD_S = 0.02  # a base's rate: a reset is told from motion between its samples
RESET_S = 1000.251  # the odom frame turns by RESET_YAW_RAD and shifts by RESET_SHIFT_M
RESET_YAW_RAD, RESET_SHIFT_M = 0.3, 0.3


def reported_pose(stamp_s: float) -> Odometry:
    """A robot driving at 0.5 m/s, as its odometry reports it across the reset."""
    x_m = 0.5 * (stamp_s - FIRST_IMAGE_S)
    if stamp_s < RESET_S:
        return Odometry(x_m, 0.0, 0.0, stamp_s)
    c, s = math.cos(RESET_YAW_RAD), math.sin(RESET_YAW_RAD)
    return Odometry(c * x_m + RESET_SHIFT_M, s * x_m, RESET_YAW_RAD, stamp_s)


def write_reset_bag(path) -> None:
    rng = np.random.default_rng(0)
    odometry_s = FIRST_IMAGE_S - 0.1 + ODOM_PERIOD_S * np.arange(35)
    with BagWriter(path) as bag:
        for k in range(IMAGES):
            stamp_s = FIRST_IMAGE_S + IMAGE_PERIOD_S * k
            for t in odometry_s[(odometry_s >= stamp_s - IMAGE_PERIOD_S) & (odometry_s < stamp_s)]:
                bag.write_odometry("/odom", reported_pose(float(t)))
            bag.write_string("/skeletons", stamp_s, "[]")
            image = rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)
            bag.write_image("/camera/image_raw", stamp_s, image, "camera")
        for t in odometry_s[odometry_s >= stamp_s]:
            bag.write_odometry("/odom", reported_pose(float(t)))


def jumps_past_each_frame(monkeypatch) -> list:
    """For every frame processed, how many odometry jumps the tracker is told the
    frame's pose is past (None: the tracker is told of none and guesses)."""
    seen = []
    build_perception = run_module.build_perception

    def recording(*args, **kwargs):
        perception = build_perception(*args, **kwargs)
        process = perception.process

        def processing(frame, robot, index):
            jumps = perception.odometry_jumps
            seen.append(None if jumps is None else len(jumps.between(0.0, frame.stamp_s)))
            return process(frame, robot, index)

        perception.process = processing
        return perception

    monkeypatch.setattr(run_module, "build_perception", recording)
    return seen


def _run(args, capsys) -> dict:
    assert cli.main(args) == 0
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])


def test_a_bag_replay_tells_the_tracker_of_the_odometry_jumps_its_run_was_told(
    tmp_path, capsys, monkeypatch
):
    bag = tmp_path / "reset.mcap"
    write_reset_bag(bag)
    CameraModel.from_fov((64, 48), 70.0, CameraPose(height_m=1.2)).save(tmp_path / "cam.yaml")
    (tmp_path / "follow.toml").write_text('[identify]\nidentifier = "channels"\n')
    common = [str(bag), "--camera", str(tmp_path / "cam.yaml"), "--json"]
    seen = jumps_past_each_frame(monkeypatch)
    _run(["run", *common, "--config", str(tmp_path / "follow.toml"), "--image-topic",
          "/camera/image_raw", "--odom-topic", "/odom", "--skeletons-topic", "/skeletons",
          "--log", str(tmp_path / "run.jsonl")], capsys)  # fmt: skip
    ran, seen[:] = list(seen), []
    replayed = _run(["run", *common, "--replay", str(tmp_path / "run.jsonl")], capsys)
    assert ran == [0, 0, 0, 1, 1, 1]
    assert seen == ran and replayed["frames"] == IMAGES
