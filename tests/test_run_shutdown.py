"""`follow run` as a real process driving the simulated rover: SIGTERM and SIGHUP take
the Ctrl-C path (a zero command reaches the base, the log is flushed, the mp4 is
finalised and readable)."""

import json
import os
import signal
import subprocess
import sys
import time

import cv2
import numpy as np
import pytest
from waiting import wait_for

from follow.camera import CameraModel, CameraPose
from follow.sim.rover import SimRover


def write_video(path, frames=300, size=(320, 240), fps=15.0):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
    rng = np.random.default_rng(0)
    for i in range(frames):
        image = np.full((size[1], size[0], 3), 90, np.uint8)
        cv2.rectangle(image, (40 + i % 200, 60), (80 + i % 200, 200), (30, 60, 200), -1)
        image += rng.integers(0, 20, image.shape, dtype=np.uint8)
        writer.write(image)
    writer.release()


def _log_lines(path):
    return len(path.read_text().splitlines()) if path.exists() else 0


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_signal_stops_the_rover_and_finalises_the_outputs(tmp_path, model_path, signum):
    model_path("pose/human-pose-estimation-0001.onnx")
    write_video(tmp_path / "in.mp4")
    CameraModel.from_fov((320, 240), 70.0, CameraPose(height_m=1.0)).save(tmp_path / "cam.yaml")
    (tmp_path / "c.toml").write_text('[pose]\ninput_height_px = 128\nprecision = "fp32"\n')
    with SimRover(seed=3) as rover:
        command = [sys.executable, "-m", "follow.cli", "run", str(tmp_path / "in.mp4"),
                   "--camera", str(tmp_path / "cam.yaml"), "--config", str(tmp_path / "c.toml"),
                   "--mavlink", rover.connection, "--output-video", str(tmp_path / "out.mp4"),
                   "--log", str(tmp_path / "run.jsonl"), "--json"]  # fmt: skip
        process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                   text=True, env=os.environ.copy())  # fmt: skip
        try:
            assert wait_for(lambda: _log_lines(tmp_path / "run.jsonl") > 5, timeout_s=25.0)
            signalled = time.monotonic()
            process.send_signal(signum)
            out, err = process.communicate(timeout=15.0)
        finally:
            if process.poll() is None:
                process.kill()
        assert process.returncode == 0, err[-3000:]
        assert signal.Signals(signum).name in err, err[-3000:]  # the shutdown names it
        stamp, vx, yaw_rate = rover.last_setpoint
        stop_sent = stamp > signalled and vx == 0.0 and yaw_rate == 0.0
        assert stop_sent, (rover.last_setpoint, signalled, err[-3000:])  # follow sent it
        assert abs(rover.true_velocity()[0]) < 0.05
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["stopped_by"] == signal.Signals(signum).name
    assert summary["frames"] >= 5
    video = cv2.VideoCapture(str(tmp_path / "out.mp4"))
    ok, frame = video.read()
    assert ok and frame.shape[0] == 240
    lines = (tmp_path / "run.jsonl").read_text().splitlines()
    assert all(json.loads(line) for line in lines)  # every line complete: flushed
    # Every logged frame is in the video, but for the one the signal may have cut short.
    assert video.get(cv2.CAP_PROP_FRAME_COUNT) >= len(lines) - 2 >= 4
