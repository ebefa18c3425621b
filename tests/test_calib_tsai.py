import json
import math

import numpy as np
import pytest

from calib import cli
from calib.camera_file import write_camera_file
from calib.gt_boxes import BoxFileError, motion_figures, read_boxes
from calib.tsai import TsaiCamera, TsaiFileError
from follow.camera import CameraModel, CameraPose, read_calibration_notes

PETS = "pets2009_s2l1"

VALID_XML = """<?xml version="1.0"?>
<Camera name="test">
  <Geometry width="640" height="480" ncx="640" nfx="640" dx="0.005" dy="0.005"
            dpx="0.005" dpy="0.005"/>
  <Intrinsic focal="4.0" kappa1="{kappa1}" cx="321.5" cy="238.0" sx="1.02"/>
  <Extrinsic tx="-300" ty="400" tz="9000" rx="{rx}" ry="0.05" rz="0.3"/>
</Camera>
"""


def write(tmp_path, text, name="cam.xml"):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.fixture
def synthetic_tsai(tmp_path):
    # rx ~ -110 deg: the optical axis points down at the floor, like a mast camera.
    return TsaiCamera.from_xml(write(tmp_path, VALID_XML.format(kappa1=0.01, rx=-1.95)))


def test_project_and_back_project_are_inverse(synthetic_tsai):
    cam = synthetic_tsai
    grid = cam.image_grid(20.0)
    ground = cam.back_project_to_plane(grid, 0.0)
    below = np.isfinite(ground[:, 0])
    assert below.sum() > 100
    assert np.allclose(ground[below, 2], 0.0)
    assert np.abs(cam.project(ground[below]) - grid[below]).max() < 1e-6
    xy = cam.back_project_to_ground(grid[below])
    assert np.allclose(xy, ground[below, :2])


def test_distortion_is_applied_to_projection(tmp_path):
    with_k = TsaiCamera.from_xml(write(tmp_path, VALID_XML.format(kappa1=0.02, rx=-1.95)))
    without = TsaiCamera.from_xml(write(tmp_path, VALID_XML.format(kappa1=0.0, rx=-1.95), "b.xml"))
    corner = np.array([[0.0, 0.0]])
    point = without.back_project_to_plane(corner, 0.0)
    assert np.isfinite(point).all()
    # Positive kappa1 pulls image points towards the centre (barrel distortion).
    pix = with_k.project(point)[0]
    centre = np.array([with_k.cx_px, with_k.cy_px])
    assert np.linalg.norm(pix - centre) < np.linalg.norm(corner[0] - centre) - 5.0


def test_converted_model_agrees_with_tsai(synthetic_tsai):
    model, discrepancy_px = synthetic_tsai.to_camera_model()
    assert discrepancy_px < 0.5
    grid = synthetic_tsai.image_grid(16.0)
    world = synthetic_tsai.back_project_to_plane(grid, 0.0)
    ok = np.isfinite(world[:, 0])
    assert np.abs(model.project(world[ok]) - grid[ok]).max() < 0.5
    centre = synthetic_tsai.position_world_m
    assert model.position_base == pytest.approx(centre)
    # The converted camera looks down: positive pitch in `follow`'s convention.
    assert model.pose.pitch_rad > 0


def test_discrepancy_grows_when_the_model_is_wrong(synthetic_tsai):
    model, good_px = synthetic_tsai.to_camera_model()
    K = model.K.copy()
    K[0, 2] += 2.0
    bad_px = synthetic_tsai.max_discrepancy_px(
        CameraModel(K, model.dist, model.image_size, model.pose)
    )
    assert bad_px > 1.9 > good_px


@pytest.mark.parametrize(
    "text, expected",
    [
        ("<Camera><Geometry", "not valid XML"),
        (VALID_XML.format(kappa1=0.0, rx=0.0).replace("<Intrinsic", "<Other"), "<Intrinsic>"),
        (VALID_XML.format(kappa1=0.0, rx=0.0).replace('cy="238.0"', ""), "'cy'"),
        (VALID_XML.format(kappa1="abc", rx=0.0), "'kappa1' is not a number"),
        (VALID_XML.format(kappa1=0.0, rx=0.0).replace('focal="4.0"', 'focal="-4"'), "focal"),
        # a fractional size was rounded, a huge one asked the conversion for a vast grid
        (
            VALID_XML.format(kappa1=0.0, rx=0.0).replace('width="640"', 'width="640.4"'),
            "'width' must be a whole number of pixels",
        ),
        (
            VALID_XML.format(kappa1=0.0, rx=0.0).replace('height="480"', 'height="1e6"'),
            "'height' must be a whole number of pixels, 1 to 16384",
        ),
    ],
)
def test_malformed_xml_names_the_problem(tmp_path, text, expected):
    with pytest.raises(TsaiFileError, match=expected):
        TsaiCamera.from_xml(write(tmp_path, text))


def test_missing_file_is_named(tmp_path):
    with pytest.raises(TsaiFileError, match="cannot read"):
        TsaiCamera.from_xml(tmp_path / "absent.xml")


def test_pets_import_agrees_and_gives_plausible_people(data_path):
    tsai = TsaiCamera.from_xml(data_path(f"{PETS}/View_001.xml"))
    model, discrepancy_px = tsai.to_camera_model()
    assert discrepancy_px < 0.5
    assert model.image_size == (768, 576)
    boxes = read_boxes(data_path(f"{PETS}/PETS2009-S2L1.xml"))
    figures = motion_figures(model, boxes, fps=7.0)
    assert 0.8 <= figures["median_walking_speed_mps"] <= 1.2
    assert 1.6 <= figures["median_stature_m"] <= 1.9
    # The exact Tsai model gives the same figures.
    exact = motion_figures(tsai, boxes, fps=7.0)
    assert figures["median_stature_m"] == pytest.approx(exact["median_stature_m"], abs=0.01)


def test_import_tsai_command_writes_a_loadable_camera(data_path, tmp_path, capsys):
    out = tmp_path / "pets.yaml"
    rc = cli.main(["import-tsai", str(data_path(f"{PETS}/View_001.xml")), "-o", str(out), "--json"])
    assert rc == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["max_discrepancy_px"] < 0.5
    model = CameraModel.load(out)
    assert model.pose.height_m == pytest.approx(result["height_m"])
    assert 2.0 < model.pose.height_m < 20.0
    assert math.degrees(model.pose.pitch_rad) == pytest.approx(result["pitch_deg"])


def test_import_tsai_command_reports_malformed_xml(tmp_path, capsys):
    bad = write(tmp_path, "<Camera><Geometry width='1'/></Camera>")
    rc = cli.main(["import-tsai", str(bad), "-o", str(tmp_path / "c.yaml"), "--json"])
    assert rc == 2
    captured = capsys.readouterr()
    assert "lacks attribute" in captured.err
    assert "error" in json.loads(captured.out.strip().splitlines()[-1])
    assert not (tmp_path / "c.yaml").exists()


def test_box_file_errors_name_the_place(tmp_path):
    bad = write(tmp_path, '<dataset><frame number="3"><objectlist><object id="1">'
                          '<box xc="1" yc="x" w="1" h="1"/></object></objectlist></frame></dataset>')  # fmt: skip
    with pytest.raises(BoxFileError, match="frame 3"):
        read_boxes(bad)


@pytest.mark.parametrize(
    "frame, box, match",
    [("100000000", 'xc="1" yc="1" w="1" h="1"', "frame number 100000000 is outside"),
     ("-5", 'xc="1" yc="1" w="1" h="1"', "frame number -5 is outside"),
     ("3", 'xc="1" yc="1" w="1" h="nan"', "frame 3, object 1: the box needs finite"),
     ("3", 'xc="1" yc="1" w="0" h="5"', "positive w, h")],
)  # fmt: skip
def test_a_box_file_with_impossible_frames_or_boxes_is_refused(tmp_path, frame, box, match):
    """A frame number of 10^8 made every evaluation read 10^8 frames (it hung); a
    negative one or a NaN box was taken in silence."""
    bad = write(tmp_path, f'<dataset><frame number="{frame}"><objectlist><object id="1">'
                          f"<box {box}/></object></objectlist></frame></dataset>")  # fmt: skip
    with pytest.raises(BoxFileError, match=match):
        read_boxes(bad)


@pytest.mark.parametrize("step", ["0", "-8", "nan"])
def test_a_grid_step_that_is_not_positive_is_refused_before_anything_is_written(
    tmp_path, capsys, step
):
    # A step of 0 ended in a traceback; a negative one fitted the distortion to one pixel
    # and reported a discrepancy of 0 px over that one pixel.
    xml = write(tmp_path, VALID_XML.format(kappa1=0.01, rx=-1.95))
    out = tmp_path / "c.yaml"
    with pytest.raises(SystemExit) as exit_:
        cli.main(["import-tsai", str(xml), "-o", str(out), "--grid-step-px", step])
    assert exit_.value.code == 2
    assert "argument --grid-step-px" in capsys.readouterr().err
    assert not out.exists()
    with pytest.raises(ValueError, match="grid step"):
        TsaiCamera.from_xml(xml).to_camera_model(step_px=-8.0)


def test_a_bad_box_file_or_frame_rate_leaves_the_camera_file_alone(tmp_path, capsys):
    # The camera file was written before the boxes were read: the command failed, yet
    # the file at -o had been replaced.
    xml = write(tmp_path, VALID_XML.format(kappa1=0.01, rx=-1.95))
    boxes = write(tmp_path, '<dataset><frame number="1"><objectlist><object id="1">'
                            '<box xc="300" yc="300" w="20" h="60"/></object></objectlist>'
                            "</frame></dataset>", "boxes.xml")  # fmt: skip
    out = tmp_path / "c.yaml"
    out.write_text("the camera of yesterday")
    argv = ["import-tsai", str(xml), "-o", str(out)]
    assert cli.main([*argv, "--boxes", str(tmp_path / "absent.xml")]) == 2
    assert "absent.xml: cannot read" in capsys.readouterr().err
    for fps in ("0", "nan"):
        with pytest.raises(SystemExit):
            cli.main([*argv, "--boxes", str(boxes), "--fps", fps])
        assert "argument --fps" in capsys.readouterr().err
    assert out.read_text() == "the camera of yesterday"
    assert cli.main([*argv, "--fps", "25"]) == 2  # a rate for boxes not given: refused
    assert "--fps is the frame rate of the --boxes annotation" in capsys.readouterr().err
    assert out.read_text() == "the camera of yesterday"
    assert cli.main([*argv, "--boxes", str(boxes)]) == 0
    assert CameraModel.load(out).image_size == (640, 480)


def test_a_conversion_far_off_the_tsai_model_is_refused_not_written(tmp_path, capsys):
    # kappa1 = 0.1: OpenCV's k1, k2, k3 cannot follow it over the image; the converted
    # camera, tens of pixels off, was written with exit status 0.
    xml = write(tmp_path, VALID_XML.format(kappa1=0.1, rx=-1.95))
    _, discrepancy_px = TsaiCamera.from_xml(xml).to_camera_model()
    assert discrepancy_px > 10.0
    out = tmp_path / "c.yaml"
    assert cli.main(["import-tsai", str(xml), "-o", str(out), "--json"]) == 2
    captured = capsys.readouterr()
    assert "px off the Tsai model" in captured.err
    assert "px off the Tsai model" in json.loads(captured.out.strip().splitlines()[-1])["error"]
    assert not out.exists()


@pytest.mark.parametrize(
    "extrinsic", ['tx="-0.3" ty="0.4" tz="9.0"', 'tx="-300" ty="400" tz="-9000"']
)
def test_a_world_in_metres_or_upside_down_is_refused_by_name(tmp_path, extrinsic):
    # In metres the camera came out 3 mm over the floor, and was written.
    text = VALID_XML.format(kappa1=0.01, rx=-1.95).replace(
        'tx="-300" ty="400" tz="9000"', extrinsic
    )
    with pytest.raises(TsaiFileError, match="world units must be mm"):
        TsaiCamera.from_xml(write(tmp_path, text))


def test_an_import_over_a_calibrated_file_keeps_none_of_its_notes(tmp_path, capsys):
    # The notes of the chessboard calibration the file held (its RMS, views, coverage)
    # were kept beside the import's, as if they described the imported intrinsics.
    xml = write(tmp_path, VALID_XML.format(kappa1=0.01, rx=-1.95))
    out = tmp_path / "c.yaml"
    old = CameraModel.from_fov((640, 480), 70.0, CameraPose(1.0))
    write_camera_file(out, old, {"intrinsics": "follow-calib intrinsics",
                                 "intrinsics_rms_px": 0.15, "pose_board_rms_px": 0.2})  # fmt: skip
    assert cli.main(["import-tsai", str(xml), "-o", str(out)]) == 0
    notes = read_calibration_notes(out)
    assert notes["intrinsics"] == notes["pose"] == "follow-calib import-tsai cam.xml"
    assert "intrinsics_rms_px" not in notes and "pose_board_rms_px" not in notes


def test_a_grid_step_finer_than_a_pixel_is_refused_by_the_option(tmp_path, capsys):
    """--grid-step-px 0.01 asked numpy for terabytes: a MemoryError traceback."""
    import argparse

    from calib.tsai_cmd import MIN_GRID_STEP_PX, grid_step_px

    xml = write(tmp_path, VALID_XML.format(kappa1=0.01, rx=-1.95))
    out = tmp_path / "c.yaml"
    with pytest.raises(SystemExit) as exit_:
        cli.main(["import-tsai", str(xml), "-o", str(out), "--grid-step-px", "0.5"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "argument --grid-step-px: expected a number of pixels >= 1" in err
    assert "Traceback" not in err and not out.exists()
    with pytest.raises(argparse.ArgumentTypeError, match="got '0.01'"):
        grid_step_px("0.01")
    assert grid_step_px("1") == MIN_GRID_STEP_PX == 1.0


def test_a_grid_too_large_for_the_image_is_refused_before_it_is_made(tmp_path, capsys, monkeypatch):
    """The bound on the step leaves a fine grid over a large image (16384 px a side is a
    valid Tsai file) too large for memory: refused naming the option, before any array."""
    import calib.tsai
    import calib.tsai_cmd

    xml = write(tmp_path, VALID_XML.format(kappa1=0.01, rx=-1.95))
    tsai = TsaiCamera.from_xml(xml)
    # 640x480 every 4 px (the check of the default 8 px step): 161 x 121 pixels.
    assert tsai.grid_point_count(4.0) == 161 * 121 == len(tsai.image_grid(4.0))
    monkeypatch.setattr(calib.tsai, "MAX_GRID_POINTS", 10_000)
    monkeypatch.setattr(calib.tsai_cmd, "MAX_GRID_POINTS", 10_000)
    with pytest.raises(ValueError, match=r"makes 1\.95e\+04 pixels of the 640x480 image"):
        tsai.image_grid(4.0)
    out = tmp_path / "c.yaml"
    assert cli.main(["import-tsai", str(xml), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    assert f"--grid-step-px 8 is too fine for the 640x480 image of {xml}" in err
    assert not out.exists()
    assert cli.main(["import-tsai", str(xml), "-o", str(out), "--grid-step-px", "12"]) == 0


@pytest.mark.parametrize(
    "attributes, reason, fields",
    [
        ('focal="0.004"', "179.7 deg field of view", "<Intrinsic> focal"),
        ('sx="3.0"', "differ by more than 2x", "<Intrinsic> focal"),
    ],
)
def test_values_that_make_no_camera_name_the_tsai_file_not_a_camera_matrix(
    tmp_path, capsys, attributes, reason, fields
):
    """The camera's own refusal came through bare: no file named, and advice to check a
    camera_matrix the user never wrote."""
    name = attributes.split("=")[0]
    text = VALID_XML.format(kappa1=0.01, rx=-1.95)
    text = text.replace(f'{name}="4.0"' if name == "focal" else f'{name}="1.02"', attributes)
    xml = write(tmp_path, text)
    out = tmp_path / "c.yaml"
    assert cli.main(["import-tsai", str(xml), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    assert f"error: Tsai file {xml}: its values make a camera follow cannot use" in err
    assert reason in err and fields in err and "camera_matrix" not in err
    assert not out.exists()
    with pytest.raises(TsaiFileError):
        from calib.tsai_cmd import _convert

        _convert(TsaiCamera.from_xml(xml), xml, 8.0)
