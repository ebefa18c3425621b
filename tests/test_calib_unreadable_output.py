"""A camera that `follow` would refuse to read is never written over a camera file: the
writers build models through the constructor, which takes a principal point anywhere in
the image, while every reader refuses one more than 20 % off the centre."""

from __future__ import annotations

import json

import numpy as np
import pytest

from calib import cli
from calib.camera_file import write_camera_file
from calib.intrinsics import IntrinsicsResult
from follow.camera import CameraFileError, CameraModel, CameraPose

SIZE = (640, 480)
# A principal point 22 % of the width left of the centre: inside the image, so the
# constructor takes it; a camera file reader does not.
OFF_CENTRE_K = np.array([[457.0, 0.0, 180.0], [0.0, 457.0, 239.5], [0.0, 0.0, 1.0]])
MEASURED = CameraModel.from_fov(SIZE, 70.0, CameraPose(0.8, 0.3))


def measured_file(path):
    """A measured camera file at `path`; its text, to compare with afterwards."""
    write_camera_file(path, MEASURED, {"pose": "follow-calib ground"})
    return path.read_text()


def test_a_camera_no_reader_takes_is_not_written_and_the_old_file_stays(tmp_path):
    out = tmp_path / "cam.yaml"
    before = measured_file(out)
    off_centre = CameraModel(OFF_CENTRE_K, np.zeros(5), SIZE, CameraPose(1.0))
    with pytest.raises(CameraFileError) as refused:
        write_camera_file(out, off_centre, {"intrinsics": "follow-calib intrinsics"})
    message = str(refused.value)
    assert message.startswith(f"{out} not written") and "\n" not in message
    assert "principal point (180, 239.5) lies 22 % of the width" in message
    assert "camera_matrix" not in message  # the user typed no camera_matrix
    assert out.read_text() == before
    assert np.array_equal(CameraModel.load(out).K, MEASURED.K)
    assert [p.name for p in tmp_path.iterdir()] == ["cam.yaml"]  # no temporary file left


def test_intrinsics_refuses_to_write_a_camera_that_it_could_not_read_back(
    tmp_path, monkeypatch, capsys
):
    """It wrote the file and exited 0; `check`, and intrinsics itself run again with the
    same -o, then refused the file, and the measured one it replaced was lost."""
    out = tmp_path / "cam.yaml"
    before = measured_file(out)
    result = IntrinsicsResult(OFF_CENTRE_K, np.zeros(5), SIZE, 0.15, {"a.png": 0.15}, [], 0.8, [])
    monkeypatch.setattr("calib.intrinsics.calibrate_intrinsics", lambda *a, **k: result)
    (tmp_path / "a.png").write_bytes(b"")
    argv = ["intrinsics", str(tmp_path / "a.png"), "--pattern", "9x6", "--square-size-m",
            "0.03", "-o", str(out), "--json"]  # fmt: skip
    for _ in range(2):  # and the same again: the old file is still there to keep
        assert cli.main(argv) == 2
        captured = capsys.readouterr()
        err = captured.err.strip()
        assert "Traceback" not in err and len(err.splitlines()) == 1, err
        assert f"follow-calib intrinsics: error: {out} not written" in err
        assert "22 %" in err
        assert json.loads(captured.out.strip().splitlines()[-1])["error"].startswith(str(out))
        assert out.read_text() == before


def test_import_tsai_refuses_a_principal_point_no_reader_takes(tmp_path, capsys):
    from test_calib_tsai import VALID_XML

    xml = tmp_path / "cam.xml"
    xml.write_text(VALID_XML.format(kappa1=0.01, rx=-1.95).replace('cx="321.5"', 'cx="180"'))
    out = tmp_path / "cam.yaml"
    before = measured_file(out)
    assert cli.main(["import-tsai", str(xml), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    assert f"error: Tsai file {xml}: " in err and "principal point (180, 238)" in err
    assert "<Intrinsic>" in err and "camera_matrix" not in err
    assert out.read_text() == before
