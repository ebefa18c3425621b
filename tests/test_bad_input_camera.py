"""A camera file with an unknown key, a fractional image size or a matrix whose last
row is not [0, 0, 1] is refused, naming the file and the key; follow-calib's own files
(with their `calibration` record) still load."""

from __future__ import annotations

import json
import re

import pytest
import yaml

from calib.camera_file import write_camera_file
from follow.camera import CameraFileError, CameraModel, CameraPose


def _data() -> dict:
    pose = CameraPose(height_m=0.9, pitch_rad=0.2)
    return CameraModel.from_fov((640, 480), 70.0, pose).to_dict()


def _write(tmp_path, data: dict, name: str = "cam.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data) if name.endswith(".yaml") else json.dumps(data))
    return path


@pytest.mark.parametrize("name", ["cam.yaml", "cam.json"])
def test_a_misspelt_pose_key_is_refused_not_left_at_its_default(tmp_path, name):
    data = _data()
    data["pose"]["rol_rad"] = data["pose"].pop("roll_rad")
    path = _write(tmp_path, data, name)
    with pytest.raises(CameraFileError) as err:
        CameraModel.load(path)
    message = str(err.value)
    assert str(path) in message and "unknown key 'pose.rol_rad'" in message
    assert "'roll_rad'" in message  # the known keys are listed


def test_unknown_top_level_keys_are_all_named(tmp_path):
    data = {**_data(), "bogus": 1, "image_widht": 640}
    path = _write(tmp_path, data)
    with pytest.raises(CameraFileError, match="unknown keys 'bogus', 'image_widht'; known: "):
        CameraModel.load(path)


def test_the_calibration_record_of_follow_calib_is_accepted(tmp_path):
    path = tmp_path / "cam.yaml"
    model = CameraModel.from_dict(_data())
    write_camera_file(path, model, {"intrinsics": "follow-calib intrinsics", "rms_px": 0.2})
    assert "calibration" in yaml.safe_load(path.read_text())
    assert CameraModel.load(path).pose == model.pose


@pytest.mark.parametrize("value", [768.5, "768", True, None])
@pytest.mark.parametrize("key", ["image_width", "image_height"])
def test_an_image_size_that_is_not_whole_pixels_is_refused(tmp_path, key, value):
    data = {**_data(), key: value}
    path = _write(tmp_path, data)
    expected = re.escape(f"{path}: field '{key}' must be a whole number of pixels, got {value!r}")
    with pytest.raises(CameraFileError, match=expected):
        CameraModel.load(path)


def test_a_whole_float_image_size_is_read_as_pixels(tmp_path):
    data = {**_data(), "image_width": 640.0}
    assert CameraModel.load(_write(tmp_path, data)).image_size == (640, 480)


def test_a_camera_matrix_whose_last_row_is_not_0_0_1_is_refused(tmp_path):
    data = _data()
    data["camera_matrix"][2] = [0.1, 0.0, 5.0]
    path = _write(tmp_path, data)
    with pytest.raises(CameraFileError, match=r"camera_matrix last row must be \[0, 0, 1\]") as err:
        CameraModel.load(path)
    assert str(path) in str(err.value)


def test_a_camera_matrix_with_vertical_skew_is_refused(tmp_path):
    """Projection reads K as upper triangular (as OpenCV writes it): a K[1][0] it would
    ignore must not give silently wrong positions."""
    data = _data()
    data["camera_matrix"][1][0] = 3.0
    path = _write(tmp_path, data)
    with pytest.raises(CameraFileError, match=r"camera_matrix\[1\]\[0\] must be 0") as err:
        CameraModel.load(path)
    assert str(path) in str(err.value)


def test_a_missing_camera_matrix_is_named_missing(tmp_path):
    data = _data()
    del data["camera_matrix"]
    with pytest.raises(CameraFileError, match="missing field 'camera_matrix'"):
        CameraModel.load(_write(tmp_path, data))


@pytest.mark.parametrize("field", ["pose.height_m", "camera_matrix", "distortion"])
def test_a_number_too_large_for_a_float_is_refused_by_name(tmp_path, field):
    data = _data()
    huge = 10**400  # a whole number JSON and YAML read exactly, beyond any float
    if field == "pose.height_m":
        data["pose"]["height_m"] = huge
    elif field == "camera_matrix":
        data["camera_matrix"][0][0] = huge
    else:
        data["distortion"] = [huge, 0.0, 0.0, 0.0]
    path = tmp_path / "cam.json"
    path.write_text(json.dumps(data))
    with pytest.raises(CameraFileError, match=re.escape(f"camera file {path}: field '{field}'")):
        CameraModel.load(path)


@pytest.mark.parametrize("name", ["cam.yaml", "cam.json"])
def test_a_key_given_twice_is_refused_not_left_to_the_last_one(tmp_path, name):
    # YAML and JSON readers keep the last of two equal keys: a pitch added below the
    # measured one replaced it without a word.
    data = _data()
    measured = data["pose"]["pitch_rad"]
    if name.endswith(".yaml"):
        text = yaml.safe_dump(data, sort_keys=False)
        text = text.replace(
            f"  pitch_rad: {measured}\n", f"  pitch_rad: {measured}\n  pitch_rad: 0.0\n"
        )
    else:
        text = json.dumps(data).replace(
            f'"pitch_rad": {measured}', f'"pitch_rad": {measured}, "pitch_rad": 0.0'
        )
    assert text.count("pitch_rad") == 2
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(CameraFileError, match="duplicate key 'pitch_rad'") as err:
        CameraModel.load(path)
    assert str(path) in str(err.value)


def test_a_camera_matrix_for_another_image_size_is_refused(tmp_path):
    """A matrix calibrated on 1920x1080 frames in a file for 640x360 ones puts the
    principal point outside the image: every distance would be wrong, without a word."""
    data = CameraModel.from_fov((1920, 1080), 70.0, CameraPose(height_m=0.9)).to_dict()
    data["image_width"], data["image_height"] = 640, 360
    path = _write(tmp_path, data)
    with pytest.raises(CameraFileError, match="principal point .* outside the 640x360 image"):
        CameraModel.load(path)


@pytest.mark.parametrize("name", ["camera.yaml.bak", "camera.conf"])
def test_a_yaml_file_under_another_suffix_is_said_to_be_read_as_json(tmp_path, name):
    # It was called "not valid YAML/JSON" though it was valid YAML, only named otherwise.
    path = tmp_path / name
    path.write_text(yaml.safe_dump(_data()))
    with pytest.raises(CameraFileError) as err:
        CameraModel.load(path)
    message = str(err.value)
    assert f"camera file {path}: not valid JSON" in message
    assert "YAML" not in message.split("(")[0]
    assert "name a YAML camera file .yaml or .yml" in message


def test_a_malformed_yaml_file_is_said_to_be_yaml(tmp_path):
    path = tmp_path / "cam.yaml"
    path.write_text("pose: [1, 2\n")
    with pytest.raises(CameraFileError, match=re.escape(f"camera file {path}: not valid YAML (")):
        CameraModel.load(path)


@pytest.mark.parametrize("name", ["cam.yaml", "cam.json"])
def test_a_file_saved_with_a_utf8_byte_order_mark_loads(tmp_path, name):
    # Windows editors may start UTF-8 text with a byte order mark: the JSON reader
    # refused such a file ("Unexpected UTF-8 BOM").
    path = tmp_path / name
    text = yaml.safe_dump(_data()) if name.endswith(".yaml") else json.dumps(_data())
    path.write_text(text, encoding="utf-8-sig")
    assert CameraModel.load(path).to_dict() == CameraModel.from_dict(_data()).to_dict()


@pytest.mark.parametrize(
    "fx, fy, match",
    [
        (500.0, 5.0, "differ by more than 2x"),  # a digit lost
        (500.0, 1500.0, "differ by more than 2x"),
        (1e6, 1e6, "field of view"),  # 0.04 deg across 640 px
        (1e308, 1e308, "field of view"),
    ],
)
def test_focal_lengths_no_camera_has_are_refused(tmp_path, fx, fy, match):
    """A typing error in camera_matrix used to load, and then placed every person at a
    wrong distance (or at infinity) without a word."""
    data = _data()
    data["camera_matrix"][0][0], data["camera_matrix"][1][1] = fx, fy
    path = _write(tmp_path, data)
    with pytest.raises(CameraFileError, match=match) as err:
        CameraModel.load(path)
    assert str(path) in str(err.value)


def test_real_lenses_from_telephoto_to_wide_load(tmp_path):
    for fov_deg in (6.0, 40.0, 70.0, 120.0, 155.0):
        model = CameraModel.from_fov((640, 480), fov_deg, CameraPose(height_m=0.9))
        assert CameraModel.from_dict(model.to_dict()).image_size == (640, 480)
    # real distortion: a wide lens's barrel (PETS's converted Tsai lens), a pincushion
    for dist in ([-0.158, 0.074, 0.0, 0.0, -0.037], [-0.28, 0.07, 0.001, -0.0005, 0.0],
                 [0.12, -0.3, 0.0, 0.0, 0.2], [-0.18, 0.04, 0.001, -0.0005, 40.0]):  # fmt: skip
        data = _data()
        data["distortion"] = dist
        assert CameraModel.load(_write(tmp_path, data)).dist.tolist() == dist


@pytest.mark.parametrize(
    "edit, match",
    [
        ({"skew": 5000.0}, r"camera_matrix\[0\]\[1\] \(skew\) 5000 is over 0.1 of f_x"),
        ({"fx": 1.0, "fy": 1.0}, "179.6 deg field of view, over the 160 deg"),
        ({"distortion": [-1.8, 0.04, 0.001, -0.0005, 0.0]}, "turns back 0.287 focal lengths"),
        ({"distortion": [-0.5, 0.2, 0, 0, 0, 50.0, -100.0, 1e6]}, "turns back .* inside the image"),
        ({"distortion": [1e9, 0.0, 0.0, 0.0, 0.0]}, "squeezes the image into 0.0"),
    ],
)  # fmt: skip
def test_intrinsics_no_lens_has_are_refused_naming_what_to_check(tmp_path, edit, match):
    """Typing errors that loaded and then moved where every person is in view (a sign
    dropped from k1 = -0.18 put a standing person's neck at 1.37 m instead of 2.25 m)."""
    data = _data()
    if "skew" in edit:
        data["camera_matrix"][0][1] = edit["skew"]
    if "fx" in edit:
        data["camera_matrix"][0][0], data["camera_matrix"][1][1] = edit["fx"], edit["fy"]
    if "distortion" in edit:
        data["distortion"] = edit["distortion"]
    path = _write(tmp_path, data)
    with pytest.raises(CameraFileError, match=match) as err:
        CameraModel.load(path)
    assert str(path) in str(err.value)


def test_quoted_numbers_and_a_grid_of_coefficients_are_refused(tmp_path):
    data = _data()
    data["camera_matrix"][0][0] = "500"
    with pytest.raises(CameraFileError, match="'camera_matrix' is not numeric"):
        CameraModel.load(_write(tmp_path, data))
    data = _data()
    data["distortion"] = [[0.1, 0.0], [0.0, 0.0]]
    with pytest.raises(CameraFileError, match=r"one list of coefficients, got shape \(2, 2\)"):
        CameraModel.load(_write(tmp_path, data))


def test_numbers_written_as_yaml_1_2_writes_them_are_numbers(tmp_path):
    """YAML 1.1 reads `5.6e2` as a number but `56e1`, `-.5` and `.5e3` as text; all are
    numbers here, as in YAML 1.2 (a hand-edited `distortion: [-.28, .07]` is common)."""
    model = CameraModel.from_dict(_data())
    text = yaml.safe_dump(model.to_dict()).replace("height_m: 0.9", "height_m: 9e-1")
    text = text.replace("pitch_rad: 0.2", "pitch_rad: .2e0").replace(
        "distortion: []", "distortion: [-.28, .07, 0, 0, -.5e-3]"
    )
    assert "9e-1" in text and ".2e0" in text and "-.28" in text
    path = tmp_path / "cam.yaml"
    path.write_text(text)
    loaded = CameraModel.load(path)
    assert loaded.pose.height_m == pytest.approx(0.9)
    assert loaded.pose.pitch_rad == pytest.approx(0.2)
    assert loaded.dist.tolist() == pytest.approx([-0.28, 0.07, 0.0, 0.0, -0.0005])


def test_an_empty_camera_path_is_named_as_such():
    with pytest.raises(CameraFileError, match="no path given"):
        CameraModel.load("")
