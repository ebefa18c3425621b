"""`follow run` on a camera file whose pose `follow-calib intrinsics` left as a placeholder
(a level camera 1 m high) and `follow-calib ground` never measured: every distance to a
person would be wrong, so a run that drives a base is refused with one line naming the
file and the command that measures it; a run without a base only warns. A measured pose
and a file without calibration notes drive as before."""

import logging

import cv2
import numpy as np
import pytest
from nobody_seen import NobodySeen
from recording_base import RecordingBase

from calib.camera_file import write_camera_file
from follow import cli
from follow import run as run_module
from follow.camera import CameraModel, CameraPose
from follow.control.base import NullBase

CAMERA = CameraModel.from_fov((64, 48), 70.0, CameraPose(height_m=1.0))
# what `follow-calib intrinsics` writes into a new camera file, and `ground` over it
INTRINSICS_NOTES = {"intrinsics": "follow-calib intrinsics", "intrinsics_rms_px": 0.2,
                    "pose": "placeholder: measure it with `follow-calib ground`"}  # fmt: skip
GROUND_NOTES = {"pose": "follow-calib ground", "pose_board_rms_px": 0.1}


@pytest.fixture
def scene(tmp_path, monkeypatch):
    """A short video; `follow run` with a stand-in perception, and a stand-in base for
    what a MAVLink connection would open."""
    video = tmp_path / "walk.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 15.0, (64, 48))
    for _ in range(5):
        writer.write(np.zeros((48, 64, 3), np.uint8))
    writer.release()
    base = RecordingBase()
    monkeypatch.setattr(run_module, "build_perception", lambda *a, **k: NobodySeen())
    monkeypatch.setattr(run_module, "open_base",
                        lambda config: base if config.mavlink.connection else NullBase())  # fmt: skip
    return video, base


def _camera_file(path, notes=None):
    if notes is None:
        CAMERA.save(path)  # no calibration notes: written by hand or by `CameraModel.save`
    else:
        write_camera_file(path, CAMERA, notes)
    return path


@pytest.mark.parametrize("connection", ["option", "config"])
def test_a_placeholder_pose_drives_no_base(scene, tmp_path, capsys, connection):
    video, base = scene
    camera = _camera_file(tmp_path / "cam.yaml", INTRINSICS_NOTES)
    argv = ["run", str(video), "--camera", str(camera)]
    if connection == "option":
        argv += ["--mavlink", "udpin:127.0.0.1:14550"]
    else:
        (tmp_path / "robot.toml").write_text('[mavlink]\nconnection = "udpin:127.0.0.1:14550"\n')
        argv += ["--config", str(tmp_path / "robot.toml")]
    assert cli.main(argv) == 1
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    assert err.startswith(f"follow run: error: camera file {camera}: ")
    assert "placeholder" in err and "`follow-calib ground`" in err
    assert base.commands == []


def test_a_placeholder_pose_without_a_base_runs_with_a_warning(scene, tmp_path, caplog):
    video, _ = scene
    camera = _camera_file(tmp_path / "cam.json", INTRINSICS_NOTES)  # JSON is read alike
    with caplog.at_level(logging.WARNING, logger="follow.run"):
        assert cli.main(["run", str(video), "--camera", str(camera)]) == 0
    warnings = [r.getMessage() for r in caplog.records
                if r.levelno == logging.WARNING and r.name == "follow.run"]  # fmt: skip
    assert len(warnings) == 1, warnings
    assert f"camera file {camera}" in warnings[0]
    assert "placeholder" in warnings[0] and "distances to people are not measured" in warnings[0]


def test_the_pose_measured_by_ground_drives_the_base(scene, tmp_path, capsys, caplog):
    """The same file is refused until `follow-calib ground` replaces the placeholder note
    (it keeps the intrinsics' notes)."""
    video, base = scene
    camera = _camera_file(tmp_path / "cam.yaml", INTRINSICS_NOTES)
    argv = ["run", str(video), "--camera", str(camera), "--mavlink", "udpin:127.0.0.1:14550"]
    assert cli.main(argv) == 1 and base.commands == []
    assert "`follow-calib ground`" in capsys.readouterr().err
    write_camera_file(camera, CAMERA.with_pose(CameraPose(0.8, 0.2)), GROUND_NOTES)
    with caplog.at_level(logging.WARNING):
        assert cli.main(argv) == 0
    assert base.commands and base.commands[-1].is_stop
    assert not [r for r in caplog.records if "placeholder" in r.getMessage()]


def test_a_camera_file_without_notes_drives_the_base(scene, tmp_path, capsys, caplog):
    """Hand-written files, PETS imports and `CameraModel.save` carry no placeholder note;
    only a file that has one is refused."""
    video, base = scene
    for name, notes, rc in [("placeholder.yaml", INTRINSICS_NOTES, 1), ("plain.yaml", None, 0)]:
        camera = _camera_file(tmp_path / name, notes)
        argv = ["run", str(video), "--camera", str(camera), "--mavlink", "udpin:127.0.0.1:1"]
        with caplog.at_level(logging.WARNING):
            assert cli.main(argv) == rc, capsys.readouterr().err
    assert base.commands and base.commands[-1].is_stop
    assert not [r for r in caplog.records if "placeholder" in r.getMessage()]


def test_a_camera_that_cannot_see_the_target_at_the_following_distance_is_named(
        scene, tmp_path, caplog):  # fmt: skip
    """A camera 0.5 m up and level loses a standing person's neck nearer than about
    1.85 m: at the default following distance (1.8 m) the target would be lost."""
    video, _ = scene
    low = CameraModel.from_fov((64, 48), 70.0, CameraPose(height_m=0.5))
    low.save(tmp_path / "low.yaml")
    with caplog.at_level(logging.INFO, logger="follow.person_in_view"):
        assert cli.main(["run", str(video), "--camera", str(tmp_path / "low.yaml")]) == 0
    said = {r.levelno: r.getMessage() for r in caplog.records if r.name == "follow.person_in_view"}
    assert "neck in view from" in said[logging.INFO]
    assert "following distance (1.8 m)" in said[logging.WARNING]
    assert "neck is out of view" in said[logging.WARNING]
    caplog.clear()
    (tmp_path / "far.toml").write_text("[control]\nfollowing_distance_m = 3.0\n")
    with caplog.at_level(logging.WARNING, logger="follow.person_in_view"):
        assert cli.main(["run", str(video), "--camera", str(tmp_path / "low.yaml"),
                         "--config", str(tmp_path / "far.toml")]) == 0  # fmt: skip
    assert not [r for r in caplog.records if r.name == "follow.person_in_view"]
