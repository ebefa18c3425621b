import math
import os
import subprocess
import sys
from pathlib import Path

import cv2
import pytest

from calib.camera_file import write_camera_file, write_file_atomic
from calib.synthetic import BoardSpec, render_floor_board
from follow.camera import CameraModel, CameraPose, read_calibration_notes

REPO = Path(__file__).resolve().parents[1]
CAMERA = CameraModel.from_fov((640, 480), 70.0, CameraPose(0.83, 0.2, 0.01))

# Runs argv[2:] as Python with files limited to argv[1] bytes: a write past it fails with
# EFBIG, as one on a full disk fails with ENOSPC.
LIMITED_FILE_SIZE = """
import resource, signal, sys
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (int(sys.argv[1]), int(sys.argv[1])))
exec(sys.argv[2])
"""


def run_with_file_size_limit(code, limit_bytes, folder):
    env = dict(
        os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])
    )
    return subprocess.run([sys.executable, "-c", LIMITED_FILE_SIZE, str(limit_bytes), code],
                          cwd=folder, env=env, capture_output=True, text=True, timeout=60)  # fmt: skip


def test_a_camera_file_write_that_fails_part_way_leaves_the_old_file_whole(tmp_path):
    path = tmp_path / "cam.yaml"
    write_camera_file(path, CAMERA, {"pose": "follow-calib ground"})
    before = path.read_text()
    code = (
        "from calib.camera_file import write_camera_file\n"
        "from follow.camera import CameraModel\n"
        "model = CameraModel.load('cam.yaml')\n"
        "write_camera_file('cam.yaml', model, {'intrinsics': 'x' * 2000})\n"
    )
    done = run_with_file_size_limit(code, len(before) + 100, tmp_path)
    assert done.returncode != 0 and "cannot write" in done.stderr
    assert path.read_text() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cam.yaml"]  # no partial file left


def test_a_ground_overlay_that_fails_part_way_leaves_the_old_one_whole(tmp_path):
    cam = CAMERA.with_pose(CameraPose(0.8, math.radians(15.0)))
    cv2.imwrite(
        str(tmp_path / "board.png"), render_floor_board(cam, BoardSpec((7, 5), 0.1), 1.2, 0.0)
    )
    cam.save(tmp_path / "cam.yaml")
    camera_before = (tmp_path / "cam.yaml").read_text()
    old_overlay = bytes(range(256)) * 1000  # bigger than the limit
    (tmp_path / "cam_ground.png").write_bytes(old_overlay)
    code = (
        "from calib import cli\n"
        "sys.exit(cli.main(['ground', 'board.png', '--camera', 'cam.yaml', '--pattern', '7x5',"
        " '--square-size-m', '0.1']))\n"
    )
    done = run_with_file_size_limit(code, 20_000, tmp_path)
    assert done.returncode == 2 and "cannot write" in done.stderr
    assert (tmp_path / "cam_ground.png").read_bytes() == old_overlay
    assert (tmp_path / "cam.yaml").read_text() == camera_before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["board.png", "cam.yaml", "cam_ground.png"]


def test_a_replaced_file_keeps_its_permissions(tmp_path):
    path = tmp_path / "cam.yaml"
    path.write_text("old")
    path.chmod(0o640)
    write_file_atomic(path, b"new")
    assert path.read_bytes() == b"new" and path.stat().st_mode & 0o777 == 0o640
    (tmp_path / "link.yaml").symlink_to(path)
    write_file_atomic(tmp_path / "link.yaml", b"newer")
    assert (tmp_path / "link.yaml").is_symlink() and path.read_bytes() == b"newer"
    with pytest.raises(OSError, match="cannot write .*missing"):
        write_file_atomic(tmp_path / "missing" / "cam.yaml", b"new")


@pytest.mark.parametrize("name", ["cam.yaml", "cam.json"])
def test_notes_with_dates_are_kept_as_their_text(tmp_path, name):
    # The calibration section is free-form: YAML reads a date there as a date object.
    (tmp_path / "old.yaml").write_text(
        "calibration:\n  checked: 2024-05-01\n  2024-06-02: camera remounted\n"
    )
    path = tmp_path / name
    write_camera_file(
        path, CAMERA, {"pose": "follow-calib ground"}, notes_from=tmp_path / "old.yaml"
    )
    notes = read_calibration_notes(path)
    assert notes == {
        "checked": "2024-05-01",
        "2024-06-02": "camera remounted",
        "pose": "follow-calib ground",
    }
    assert CameraModel.load(path).to_dict() == CAMERA.to_dict()


@pytest.mark.parametrize("text", ["calibration: measured by hand\n",
                                  "calibration:\n  - tape measure\n  - level\n"])  # fmt: skip
def test_calibration_notes_that_are_not_a_table_are_kept_under_note(tmp_path, text):
    # Written by hand as one line or a list, they were read as no notes at all and the
    # next `intrinsics` or `ground` write dropped them without a word.
    (tmp_path / "old.yaml").write_text(text)
    kept = read_calibration_notes(tmp_path / "old.yaml")["note"]
    assert kept in ("measured by hand", ["tape measure", "level"])
    path = tmp_path / "cam.yaml"
    write_camera_file(
        path, CAMERA, {"pose": "follow-calib ground"}, notes_from=tmp_path / "old.yaml"
    )
    assert read_calibration_notes(path) == {"note": kept, "pose": "follow-calib ground"}
