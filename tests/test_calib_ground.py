import json
import math

import cv2
import numpy as np
import pytest

from calib import cli
from calib.camera_file import read_calibration_notes, write_camera_file
from calib.chessboard import BoardNotFoundError, ImageInputError, detect_chessboard
from calib.ground import GroundPoseError, average_frames, estimate_ground_pose, pitch_roll_from_up
from calib.synthetic import BoardSpec, render_floor_board
from follow.camera import PLACEHOLDER_POSE_NOTE, CameraModel, CameraPose, has_placeholder_pose

# A 75 deg wide camera with noticeable barrel distortion, as on small robots.
DIST = np.array([-0.18, 0.04, 0.001, -0.0005, 0.0])
SIZE = (640, 480)


def camera(height_m, pitch_deg, roll_deg=0.0):
    pose = CameraPose(height_m, math.radians(pitch_deg), math.radians(roll_deg))
    return CameraModel.from_fov(SIZE, 75.0, pose, dist=DIST)


def place_board(cam, board, yaw_rad, extra_m):
    """Board origin so that its centre lies just beyond the nearest floor in view."""
    half_vfov = math.atan((SIZE[1] / 2) / cam.K[1, 1])
    near = cam.pose.height_m / math.tan(cam.pose.pitch_rad + 0.85 * half_vfov)
    centre = np.array([near + extra_m, 0.1])
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    origin = centre - np.array([[c, -s], [s, c]]) @ board.centre_m
    return origin, centre


# (height m, pitch deg, roll deg, board yaw deg, inner corners, square m): boards from A2
# size for a low camera to a floor mat for a 1.5 m camera that looks straight ahead, laid
# in every orientation (a diagonal one only where the view is steep enough to see it).
CASES = [
    (0.4, 0.0, 1.0, 0.0, (7, 5), 0.08),
    (0.4, 30.0, -2.0, 135.0, (7, 5), 0.08),
    (0.8, 15.0, 0.0, 90.0, (7, 5), 0.1),
    (1.0, 20.0, -1.0, 40.0, (7, 5), 0.1),
    (1.5, 0.0, 2.0, 180.0, (9, 7), 0.2),
    (1.5, 30.0, 1.0, 270.0, (7, 5), 0.1),
]


@pytest.mark.parametrize("height_m, pitch_deg, roll_deg, yaw_deg, pattern, square_m", CASES)
def test_recovers_height_pitch_roll_and_board(
    height_m, pitch_deg, roll_deg, yaw_deg, pattern, square_m
):
    cam = camera(height_m, pitch_deg, roll_deg)
    board = BoardSpec(pattern, square_m)
    yaw = math.radians(yaw_deg)
    origin, centre = place_board(cam, board, yaw, extra_m=0.4 + max(pattern) * square_m / 2)
    image = render_floor_board(cam, board, origin[0], origin[1], yaw, seed=int(yaw_deg))
    result = estimate_ground_pose(image, cam.K, cam.dist, pattern, square_m)
    assert result.height_m == pytest.approx(height_m, abs=0.01)
    assert math.degrees(result.pitch_rad) == pytest.approx(pitch_deg, abs=0.2)
    assert math.degrees(result.roll_rad) == pytest.approx(roll_deg, abs=0.2)
    assert result.board_centre_level_m == pytest.approx(centre, abs=0.03)
    assert result.reprojection_rms_px < 0.5


def board_under(cam, board):
    """A view of `board` lying where the camera's optical axis meets the floor."""
    ahead_m = cam.pose.height_m / math.tan(cam.pose.pitch_rad)
    return render_floor_board(cam, board, ahead_m - board.centre_m[0], -board.centre_m[1])


@pytest.mark.parametrize("pitch_deg", [85.0, 90.0])
def test_a_camera_looking_straight_down_is_refused(pitch_deg, tmp_path, capsys):
    # Its roll is unobservable: at 90 deg the estimate was any angle, at 85 deg 3 deg off.
    cam = camera(1.0, pitch_deg, 2.0)
    image = board_under(cam, BoardSpec((7, 5), 0.1))
    with pytest.raises(GroundPoseError, match="roll cannot be measured"):
        estimate_ground_pose(image, cam.K, cam.dist, (7, 5), 0.1)
    cv2.imwrite(str(tmp_path / "down.png"), image)
    cam.with_pose(CameraPose(1.0)).save(tmp_path / "cam.yaml")
    before = (tmp_path / "cam.yaml").read_text()
    for extra in ([], ["--board-in-base", "0.5", "0", "0"]):
        assert ground_command(tmp_path / "down.png", tmp_path, *extra) == 2
        assert f"looks {pitch_deg:.0f}" in capsys.readouterr().err
    assert (tmp_path / "cam.yaml").read_text() == before
    assert not list(tmp_path.glob("*_ground.png"))


def test_a_steep_camera_below_the_limit_keeps_its_roll():
    cam = camera(1.0, 78.0, 2.0)
    result = estimate_ground_pose(
        board_under(cam, BoardSpec((7, 5), 0.1)), cam.K, cam.dist, (7, 5), 0.1
    )
    assert math.degrees(result.pitch_rad) == pytest.approx(78.0, abs=0.2)
    assert math.degrees(result.roll_rad) == pytest.approx(2.0, abs=0.3)


def test_pitch_roll_from_up_inverts_the_camera_convention():
    for pitch, roll in [(0.0, 0.0), (0.3, -0.1), (-0.2, 0.25), (1.2, 0.0)]:
        R = CameraPose(1.0, pitch, roll).rotation_base_from_cam()
        up_cam = R.T @ np.array([0.0, 0.0, 1.0])
        assert pitch_roll_from_up(up_cam) == pytest.approx((pitch, roll), abs=1e-12)


def test_board_in_base_gives_yaw_and_offsets():
    cam = camera(0.8, 15.0).with_pose(
        CameraPose(0.8, math.radians(15.0), 0.0, math.radians(10.0), 0.2, -0.1)
    )
    board = BoardSpec((7, 5), 0.1)
    image = render_floor_board(cam, board, 1.6, 0.2, math.radians(30.0))
    result = estimate_ground_pose(image, cam.K, cam.dist, (7, 5), 0.1)
    c, s = math.cos(math.radians(30.0)), math.sin(math.radians(30.0))
    centre_base = np.array([1.6, 0.2]) + np.array([[c, -s], [s, c]]) @ board.centre_m
    # The rows' direction is given either way along them; the yaw nearest the prior wins.
    for row_yaw_deg in (30.0, 210.0):
        pose = result.pose_from_board_in_base(tuple(centre_base), math.radians(row_yaw_deg))
        assert math.degrees(pose.yaw_rad) == pytest.approx(10.0, abs=0.3)
        assert (pose.x_m, pose.y_m) == pytest.approx((0.2, -0.1), abs=0.02)
    pose = result.pose_from_board_in_base(tuple(centre_base), math.radians(30.0), math.pi)
    assert abs(math.degrees(pose.yaw_rad)) == pytest.approx(170.0, abs=0.3)


def test_no_board_is_a_clear_error():
    cam = camera(0.8, 15.0)
    empty = np.full((120, 160), 120, np.uint8)
    assert detect_chessboard(empty, (7, 5)) is None
    with pytest.raises(BoardNotFoundError, match="no 7x5 chessboard"):
        estimate_ground_pose(empty, cam.K, cam.dist, (7, 5), 0.1)


def test_average_frames_checks_sizes():
    a = np.full((4, 6), 10, np.uint8)
    assert average_frames([a, a + 10]).tolist() == np.full((4, 6), 15).tolist()
    with pytest.raises(ValueError, match="frame 1 is 5x4"):
        average_frames([a, np.zeros((4, 5), np.uint8)])


@pytest.fixture
def board_scene(tmp_path):
    cam = camera(0.8, 15.0, 1.0)
    board = BoardSpec((7, 5), 0.1)
    for i in range(2):
        image = render_floor_board(cam, board, 1.2, 0.5, -1.0, seed=i, noise_sigma=4.0)
        cv2.imwrite(str(tmp_path / f"board{i}.png"), image)
    cam.with_pose(CameraPose(1.0, 0.0, 0.0, 0.1, 0.3, 0.0)).save(tmp_path / "cam.yaml")
    return cam, tmp_path


def test_ground_command_updates_the_camera_file_and_draws_an_overlay(board_scene, capsys):
    cam, folder = board_scene
    rc = cli.main(
        [
            "ground",
            str(folder / "board0.png"),
            str(folder / "board1.png"),
            "--camera",
            str(folder / "cam.yaml"),
            "--pattern",
            "7x5",
            "--square-size-m",
            "0.1",
            "--json",
        ]  # fmt: skip
    )
    assert rc == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["frames_averaged"] == 2
    saved = CameraModel.load(folder / "cam.yaml")
    assert saved.pose.height_m == pytest.approx(0.8, abs=0.01)
    assert math.degrees(saved.pose.pitch_rad) == pytest.approx(15.0, abs=0.2)
    assert saved.pose.yaw_rad == pytest.approx(0.1)  # kept from the file
    assert saved.pose.x_m == pytest.approx(0.3)
    assert np.allclose(saved.K, cam.K)
    overlay = cv2.imread(out["overlay"])
    assert overlay.shape == (480, 640, 3)
    # The overlay differs from the input: grid, horizon and corners are drawn on it.
    plain = cv2.cvtColor(cv2.imread(str(folder / "board0.png")), cv2.COLOR_BGR2GRAY)
    drawn = np.any(overlay != cv2.cvtColor(plain, cv2.COLOR_GRAY2BGR), axis=2)
    assert drawn.mean() > 0.02
    # The horizon (blue-ish, B high, R low) is drawn above the floor, where the sky is.
    horizon_v = cam.project(np.array([1e5, 0.0, 0.0]))[1]
    column = overlay[:, 320].astype(int)
    bluish = np.nonzero((column[:, 0] > 200) & (column[:, 2] < 80))[0]
    assert np.min(np.abs(bluish - horizon_v)) < 3


def test_ground_command_to_another_file_keeps_the_intrinsics_notes(board_scene):
    cam, folder = board_scene
    measured = {"intrinsics": "follow-calib intrinsics", "intrinsics_rms_px": 0.15}
    write_camera_file(folder / "cam.yaml", CameraModel.load(folder / "cam.yaml"), measured)
    # Notes of an older file at -o described a camera no longer in it: they go.
    write_camera_file(folder / "old.yaml", cam, {"intrinsics": "elsewhere", "lens": "old"})
    for output in ("new.yaml", "old.yaml"):
        assert ground_command(folder / "board0.png", folder, "-o", str(folder / output)) == 0
        notes = read_calibration_notes(folder / output)
        assert notes.items() >= {**measured, "pose": "follow-calib ground"}.items()
        assert "lens" not in notes and notes["pose_board_rms_px"] < 0.5


def test_ground_command_measures_a_placeholder_pose(board_scene):
    """The placeholder pose of `follow-calib intrinsics`, which `follow run` drives no base
    on, is measured: in place, and into another file."""
    _, folder = board_scene
    notes = {"intrinsics": "follow-calib intrinsics", "pose": PLACEHOLDER_POSE_NOTE}
    write_camera_file(folder / "cam.yaml", CameraModel.load(folder / "cam.yaml"), notes)
    assert has_placeholder_pose(folder / "cam.yaml")
    assert ground_command(folder / "board0.png", folder, "-o", str(folder / "new.json")) == 0
    assert not has_placeholder_pose(folder / "new.json")
    assert has_placeholder_pose(folder / "cam.yaml")  # the input is left as it was
    assert ground_command(folder / "board0.png", folder) == 0
    assert not has_placeholder_pose(folder / "cam.yaml")
    assert read_calibration_notes(folder / "cam.yaml")["intrinsics"] == notes["intrinsics"]


def test_ground_command_without_board_fails_cleanly(board_scene, capsys):
    _, folder = board_scene
    blank = folder / "blank.png"
    cv2.imwrite(str(blank), np.full((120, 160), 100, np.uint8))
    rc = ground_command(blank, folder)
    assert rc == 2
    assert "no 7x5 chessboard" in capsys.readouterr().err


@pytest.mark.parametrize("overlay", ["overlay.xyz", "missing/overlay.png"])
def test_an_overlay_that_cannot_be_written_leaves_the_camera_file_alone(
    board_scene, capsys, overlay
):
    _, folder = board_scene
    before = (folder / "cam.yaml").read_text()
    with pytest.raises(SystemExit) as exit_:
        cli.main(["ground", str(folder / "board0.png"), "--camera", str(folder / "cam.yaml"),
                  "--pattern", "7x5", "--square-size-m", "0.1",
                  "--overlay", str(folder / overlay)])  # fmt: skip
    assert exit_.value.code == 2 and "argument --overlay" in capsys.readouterr().err
    assert (folder / "cam.yaml").read_text() == before


def ground_command(image, folder, *extra):
    """`follow-calib ground` on one image with the scene's camera and board."""
    return cli.main(["ground", str(image), "--camera", str(folder / "cam.yaml"),
                     "--pattern", "7x5", "--square-size-m", "0.1", *extra])  # fmt: skip


def test_ground_command_names_a_broken_image(board_scene, capsys):
    _, folder = board_scene
    broken = folder / "broken.png"
    broken.write_bytes(b"\x89PNG not really")
    rc = ground_command(broken, folder)
    assert rc == 2
    err = capsys.readouterr().err
    assert "broken.png" in err and "not a readable image" in err
    with pytest.raises(ImageInputError, match="no such file"):
        from calib.chessboard import read_image

        read_image(folder / "absent.png")


def test_check_command_draws_the_grid_on_a_pets_frame(data_path, tmp_path, capsys):
    video = data_path("pets2009_s2l1/View_001.avi")
    cam_file = tmp_path / "pets.yaml"
    assert cli.main(["import-tsai", str(data_path("pets2009_s2l1/View_001.xml")),
                     "-o", str(cam_file)]) == 0  # fmt: skip
    out_png = tmp_path / "check.png"
    rc = cli.main(
        [
            "check",
            str(video),
            "--camera",
            str(cam_file),
            "--frame",
            "3",
            "-o",
            str(out_png),
            "--max-range-m",
            "45",
            "--json",
        ]  # fmt: skip
    )
    assert rc == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["frame_size"] == [480, 360] and result["camera_scaled_from"] == [768, 576]
    overlay = cv2.imread(str(out_png))
    green = (overlay[:, :, 1] > 200) & (overlay[:, :, 0] < 60) & (overlay[:, :, 2] < 60)
    # Grid lines cover the floor (lower half) but not the sky-free top band of text.
    assert green[180:].mean() > 0.03
    # The camera looks down 16 deg with a 13.6 deg half field of view: no horizon in view.
    assert result["horizon_row_at_centre_px"] < 0
    # A grid point drawn where the model puts it: world origin (red axes cross).
    origin_px = CameraModel.load(cam_file).scaled(480, 360).project(np.zeros(3))
    u, v = np.round(origin_px).astype(int)
    patch = overlay[v - 2 : v + 3, u - 2 : u + 3].astype(int)
    assert ((patch[:, :, 2] > 200) & (patch[:, :, 1] < 80)).any()


def test_check_command_names_a_missing_frame(data_path, tmp_path, capsys):
    cam = camera(0.8, 15.0)
    cam.save(tmp_path / "cam.yaml")
    rc = cli.main(["check", str(tmp_path / "nothing.png"), "--camera", str(tmp_path / "cam.yaml")])
    assert rc == 2
    assert "nothing.png: no such file" in capsys.readouterr().err


def test_a_folder_given_for_the_one_image_is_named_a_folder(tmp_path, capsys):
    # `intrinsics` takes folders; `ground` and `check` take one image. A folder that
    # exists was reported as "no such file", which sent users looking for a typo.
    from calib.chessboard import read_image

    (tmp_path / "frames").mkdir()
    with pytest.raises(ImageInputError, match="a folder, not an image file"):
        read_image(tmp_path / "frames")
    cam = camera(0.8, 15.0)
    cam.save(tmp_path / "cam.yaml")
    rc = cli.main(["check", str(tmp_path / "frames"), "--camera", str(tmp_path / "cam.yaml")])
    assert rc == 2
    assert "frames: a folder, not an image file" in capsys.readouterr().err


def test_check_keeps_the_old_overlay_when_the_new_one_cannot_be_written(tmp_path, monkeypatch):
    """The overlay is replaced whole: a disk that fills up part-way leaves the last good
    overlay as it was, not a cut image, and no temporary file behind."""
    import calib.camera_file

    cam = camera(0.8, 15.0)
    cam.save(tmp_path / "cam.yaml")
    frame_path = tmp_path / "frame.png"
    cv2.imwrite(str(frame_path), np.full((480, 640, 3), 90, np.uint8))
    out_png = tmp_path / "check.png"
    out_png.write_bytes(b"the overlay of yesterday")

    def disk_full(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(calib.camera_file.os, "fsync", disk_full)
    args = ["check", str(frame_path), "--camera", str(tmp_path / "cam.yaml"), "-o", str(out_png)]
    assert cli.main(args) != 0
    assert out_png.read_bytes() == b"the overlay of yesterday"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cam.yaml", "check.png", "frame.png"]
    monkeypatch.undo()
    assert cli.main(args) == 0 and cv2.imread(str(out_png)).shape == (480, 640, 3)


@pytest.mark.parametrize("values", [("1", "0", "inf"), ("1", "0", "nan"), ("nan", "0", "0")])
def test_board_in_base_must_be_finite_numbers(board_scene, capsys, values):
    # An infinite yaw ended in an OverflowError traceback; a NaN one in "cannot convert
    # float NaN to integer", naming no option.
    _, folder = board_scene
    before = (folder / "cam.yaml").read_text()
    with pytest.raises(SystemExit) as exit_:
        ground_command(folder / "board0.png", folder, "--board-in-base", *values)
    assert exit_.value.code == 2
    assert "argument --board-in-base: expected a finite number" in capsys.readouterr().err
    assert (folder / "cam.yaml").read_text() == before


def test_an_image_too_small_for_a_board_is_no_board_not_a_traceback(board_scene, capsys):
    # OpenCV's classic detector asserts on images under about 15 px: cv2.error escaped.
    _, folder = board_scene
    for height, width in ((1, 1), (9, 12)):
        assert detect_chessboard(np.full((height, width), 100, np.uint8), (7, 5)) is None
    cv2.imwrite(str(folder / "thumb.png"), np.full((9, 12), 100, np.uint8))
    assert ground_command(folder / "thumb.png", folder) == 2
    assert "no 7x5 chessboard" in capsys.readouterr().err


def test_ground_command_to_a_new_folder_writes_the_file_and_its_overlay(board_scene, capsys):
    """The camera file's missing folders are made (as for `intrinsics`), the default
    overlay beside it included, rather than failing after the measurement."""
    _, folder = board_scene
    output = folder / "robot" / "cam.yaml"
    assert ground_command(folder / "board0.png", folder, "-o", str(output)) == 0
    assert CameraModel.load(output).pose.height_m == pytest.approx(0.8, abs=0.01)
    assert cv2.imread(str(folder / "robot" / "cam_ground.png")).shape == (480, 640, 3)


def test_a_board_size_in_the_wrong_unit_is_warned_of(board_scene, capsys):
    """A board size in the wrong unit scales every length: the 0.1 m board given as
    0.01 puts the camera 8 cm up, within the pose's bounds, and the warning names the
    option."""
    _, folder = board_scene
    argv = ["ground", str(folder / "board0.png"), "--camera", str(folder / "cam.yaml"),
            "--pattern", "7x5", "--json", "-o", str(folder / "out.yaml")]  # fmt: skip
    assert cli.main([*argv, "--square-size-m", "0.1"]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["warnings"] == []
    assert cli.main([*argv, "--square-size-m", "0.01"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["height_m"] == pytest.approx(0.08, abs=0.002)
    [warning] = out["warnings"]
    assert "outside 0.1-5 m" in warning and "--square-size-m (0.01)" in warning


@pytest.mark.parametrize(
    "extra, named",
    [([], "--overlay"),  # the camera file cam0.yaml's overlay would be cam0_ground.png
     (["-o", "{board}"], "-o"), (["--overlay", "{board}"], "--overlay")],
)  # fmt: skip
def test_no_output_of_the_ground_command_overwrites_its_photo(board_scene, capsys, extra, named):
    cam, folder = board_scene
    photo = folder / "cam0_ground.png"
    photo.write_bytes((folder / "board0.png").read_bytes())
    (folder / "cam0.yaml").write_bytes((folder / "cam.yaml").read_bytes())
    before = photo.read_bytes(), (folder / "cam0.yaml").read_bytes()
    argv = [str(photo), "--camera", str(folder / "cam0.yaml"), "--pattern", "7x5",
            "--square-size-m", "0.1", *[a.format(board=photo) for a in extra]]  # fmt: skip
    assert cli.main(["ground", *argv]) == 2
    err = capsys.readouterr().err
    assert f"{named} {photo} is also the input {photo}: it would be overwritten" in err
    assert (photo.read_bytes(), (folder / "cam0.yaml").read_bytes()) == before


def test_other_calibration_commands_refuse_to_overwrite_their_inputs(board_scene, capsys):
    cam, folder = board_scene
    board, camera = folder / "board0.png", folder / "cam.yaml"
    before = board.read_bytes(), camera.read_bytes()
    for argv, named in (
        (["check", str(board), "--camera", str(camera), "-o", str(board)], "source"),
        (
            [
                "intrinsics",
                str(board),
                str(folder / "board1.png"),
                "--pattern",
                "7x5",
                "--square-size-m",
                "0.1",
                "-o",
                str(board),
            ],
            "input",
        ),  # fmt: skip
    ):
        assert cli.main(argv) == 2
        assert f"-o {board} is also the {named} {board}" in capsys.readouterr().err
    assert (board.read_bytes(), camera.read_bytes()) == before
    (folder / "out").mkdir()
    assert cli.main(["ground", str(board), "--camera", str(camera), "--pattern", "7x5",
                     "--square-size-m", "0.1", "-o", str(folder / "out")]) == 2  # fmt: skip
    assert "is a folder: give a file name" in capsys.readouterr().err
    assert list((folder / "out").iterdir()) == [] and not (folder / "out_ground.png").exists()


def test_a_square_size_given_in_centimetres_is_named_as_the_likely_cause(board_scene, capsys):
    """A 10 cm square given as 10 puts the camera 80 m up: no possible mounting, and the
    message says which option most likely holds the mistake."""
    cam, folder = board_scene
    before = (folder / "cam.yaml").read_bytes()
    assert cli.main(["ground", str(folder / "board0.png"), "--camera", str(folder / "cam.yaml"),
                     "--pattern", "7x5", "--square-size-m", "10"]) == 2  # fmt: skip
    err = capsys.readouterr().err
    assert "is not a possible mounting" in err
    assert "is --square-size-m (10) the side of one square in metres?" in err
    assert (folder / "cam.yaml").read_bytes() == before


def test_no_board_names_the_image_or_the_images_averaged(board_scene, capsys):
    """It said 'found in the image' whatever the user gave: with several images, which
    one lacked the board was left to guess."""
    _, folder = board_scene
    blank = folder / "blank.png"
    cv2.imwrite(str(blank), np.full((480, 640), 100, np.uint8))
    assert ground_command(blank, folder) == 2
    assert f"no 7x5 chessboard (inner corners) found in {blank};" in capsys.readouterr().err
    argv = ["ground", str(folder / "board0.png"), str(blank), "--camera",
            str(folder / "cam.yaml"), "--pattern", "9x6", "--square-size-m", "0.1"]  # fmt: skip
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert f"found in the average of {folder / 'board0.png'}, {blank};" in err


def test_images_of_another_size_to_average_are_named(board_scene, capsys):
    """'frame 1 is 320x240, the first is 640x480' named no file."""
    _, folder = board_scene
    small = folder / "small.png"
    cv2.imwrite(str(small), np.full((240, 320), 100, np.uint8))
    before = (folder / "cam.yaml").read_text()
    argv = ["ground", str(folder / "board0.png"), str(small), "--camera",
            str(folder / "cam.yaml"), "--pattern", "7x5", "--square-size-m", "0.1"]  # fmt: skip
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith(
        f"error: {small} is 320x240, {folder / 'board0.png'} is 640x480: frames to average "
        "must have one size"
    ), err
    assert (folder / "cam.yaml").read_text() == before
    a = np.zeros((4, 6), np.uint8)
    with pytest.raises(ValueError, match="^b.png is 5x4, a.png is 6x4"):
        average_frames([a, a, np.zeros((4, 5), np.uint8)], ["a.png", "a2.png", "b.png"])


def test_a_height_past_any_camera_file_is_refused_as_the_docs_say(board_scene, capsys):
    """The docs said any implausible height was written with a warning; one past the
    camera file's bounds (a board in centimetres given as metres) is refused instead."""
    from pathlib import Path

    from calib.ground_cmd import PLAUSIBLE_HEIGHT_M
    from follow.camera import POSE_BOUNDS

    _, folder = board_scene
    before = (folder / "cam.yaml").read_text()
    argv = ["ground", str(folder / "board0.png"), "--camera", str(folder / "cam.yaml"),
            "--pattern", "7x5", "--square-size-m"]  # fmt: skip
    assert cli.main([*argv, "10"]) == 2  # 0.8 m becomes 80 m
    err = capsys.readouterr().err
    assert "is not a possible mounting" in err and "is --square-size-m (10) the side" in err
    assert (folder / "cam.yaml").read_text() == before
    assert not (folder / "cam_ground.png").exists()
    assert cli.main([*argv, "1"]) == 0  # 8 m: written, with a warning
    assert 7.5 < CameraModel.load(folder / "cam.yaml").pose.height_m < 8.5
    docs = " ".join((Path(__file__).parents[1] / "docs" / "calibration.md").read_text().split())
    low, high = PLAUSIBLE_HEIGHT_M
    lowest, highest = POSE_BOUNDS["height_m"]
    assert f"A camera height outside {low:g}-{high:g} m is written with a warning" in docs
    assert f"A height outside {lowest:g}-{highest:g} m" in docs
    assert "is refused with an error that asks the same, and nothing is written" in docs
