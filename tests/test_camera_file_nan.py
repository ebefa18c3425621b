"""A camera file whose matrix holds NaN or an infinity is refused as not finite, whichever
entry it is: a NaN principal point was said to lie outside the image, which sent the
reader looking for a matrix of another image size."""

from __future__ import annotations

import json

import pytest
import yaml

from follow.camera import CameraFileError, CameraModel, CameraPose


def _camera_file(tmp_path, row: int, column: int, value: float, name: str):
    data = CameraModel.from_fov((480, 360), 60.0, CameraPose(height_m=1.0, pitch_rad=0.1)).to_dict()
    data["camera_matrix"][row][column] = value
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data) if name.endswith(".yaml") else json.dumps(data))
    return path


@pytest.mark.parametrize("name", ["cam.yaml", "cam.json"])
@pytest.mark.parametrize(
    "row, column, value",
    [(0, 0, float("nan")), (0, 2, float("nan")), (1, 2, float("nan")), (1, 2, float("inf"))],
    ids=["f_x nan", "c_x nan", "c_y nan", "c_y inf"],
)
def test_a_matrix_entry_that_is_not_finite_is_named_so(tmp_path, name, row, column, value):
    path = _camera_file(tmp_path, row, column, value, name)
    with pytest.raises(CameraFileError, match="camera K must be a finite 3x3 matrix") as err:
        CameraModel.load(path)
    assert str(path) in str(err.value)
    assert "principal point" not in str(err.value)
