import dataclasses
import json

import cv2
import numpy as np
import pytest

from calib import cli
from calib.camera_file import write_camera_file
from calib.chessboard import detect_chessboard
from calib.intrinsics import (
    CalibrationError,
    IntrinsicsResult,
    calibrate_intrinsics,
    check_tilts,
    coverage,
)
from calib.synthetic import (
    BoardSpec,
    board_fully_visible,
    calibration_views,
    render_board,
    rotation_from_euler_deg,
)
from follow.camera import (
    CameraModel,
    CameraPose,
    PlaceholderPoseError,
    check_pose_measured,
    has_placeholder_pose,
    read_calibration_notes,
)

BOARD = BoardSpec((9, 6), 0.03)
TRUE_CAMERA = CameraModel.from_fov(
    (640, 480), 70.0, CameraPose(1.0), dist=np.array([-0.2, 0.06, 0.0005, -0.0008, 0.0])
)


@pytest.fixture(scope="module")
def views():
    return calibration_views(TRUE_CAMERA, BOARD, 12, seed=1)


def test_focal_length_within_half_a_percent_from_twelve_views(views):
    result = calibrate_intrinsics(views, BOARD.pattern_size, BOARD.square_size_m, progress=False)
    assert result.K[0, 0] == pytest.approx(TRUE_CAMERA.K[0, 0], rel=0.005)
    assert result.K[1, 1] == pytest.approx(TRUE_CAMERA.K[1, 1], rel=0.005)
    assert result.K[:2, 2] == pytest.approx(TRUE_CAMERA.K[:2, 2], abs=3.0)
    assert result.dist[0] == pytest.approx(-0.2, abs=0.03)
    assert result.views_used == 12 and not result.rejected
    assert set(result.per_view_rms_px) == {name for name, _ in views}
    assert result.rms_px < 0.3
    # The recovered model maps image points like the true one over the image.
    grid = np.array([[u, v] for u in (10, 320, 630) for v in (10, 240, 470)], float)
    rays_true = TRUE_CAMERA.pixel_rays_base(grid)
    rays_est = TRUE_CAMERA.__class__(result.K, result.dist, (640, 480), CameraPose(1.0))
    angle = np.degrees(
        np.arccos(np.clip((rays_true * rays_est.pixel_rays_base(grid)).sum(1), -1, 1))
    )
    assert angle.max() < 0.3


@pytest.mark.parametrize("model, coefficients", [("radial", 5), ("standard", 5), ("rational", 8)])
def test_every_distortion_model_gives_a_camera_file(views, tmp_path, model, coefficients):
    result = calibrate_intrinsics(
        views, BOARD.pattern_size, BOARD.square_size_m, distortion_model=model, progress=False
    )
    assert result.dist.size == coefficients
    if model == "radial":
        assert result.dist[2:4].tolist() == [0.0, 0.0]
    # The file `follow` reads holds it (OpenCV's rational model returns 14 coefficients).
    CameraModel(result.K, result.dist, result.image_size, CameraPose(1.0)).save(tmp_path / "c.yaml")
    saved = CameraModel.load(tmp_path / "c.yaml")
    assert saved.K[0, 0] == pytest.approx(TRUE_CAMERA.K[0, 0], rel=0.005)
    # Inside the image, away from its corners, it maps pixels to rays like the true camera.
    grid = np.array([[u, v] for u in (80, 320, 560) for v in (60, 240, 420)], float)
    cosines = (TRUE_CAMERA.pixel_rays_base(grid) * saved.pixel_rays_base(grid)).sum(1)
    assert np.degrees(np.arccos(np.clip(cosines, -1, 1))).max() < 0.3


def turned_views(tilts_deg, depths_m=(0.4, 0.55)):
    """The board at each distance and five places in the image, turned by each of
    `tilts_deg` ((about x, about y) in degrees), where it fits in the image."""
    out = []
    for depth_m in depths_m:
        for u, v in [(0.3, 0.3), (0.7, 0.3), (0.3, 0.7), (0.7, 0.7), (0.5, 0.5)]:
            for about_x, about_y in tilts_deg:
                R = rotation_from_euler_deg(about_x, about_y, 0.0)
                aim = np.linalg.inv(TRUE_CAMERA.K) @ [u * 640, v * 480, 1.0] * depth_m
                t = aim - R @ [*BOARD.centre_m, 0.0]
                if board_fully_visible(TRUE_CAMERA, BOARD, R, t):
                    name = f"{tilts_deg} {len(out)}"
                    out.append((name, render_board(TRUE_CAMERA, BOARD, R, t)))
    return out


@pytest.mark.parametrize(
    "tilts_deg, problem",
    [
        ([(0, 0)], "nearly parallel to the image in every view"),
        ([(0, -30), (0, 30)], "tilted left/right only"),
        ([(-30, 0), (30, 0)], "tilted up/down only"),
    ],
)
def test_views_that_cannot_fix_the_focal_length_are_refused(tilts_deg, problem):
    # These fit with a low RMS a focal length 2.5-35 % off: the board's distance absorbs it.
    with pytest.raises(
        CalibrationError, match=problem + ".*tilted left/right and 2 tilted up/down"
    ):
        calibrate_intrinsics(
            turned_views(tilts_deg), BOARD.pattern_size, BOARD.square_size_m, progress=False
        )


def test_two_views_tilted_each_way_fix_the_focal_length():
    # Flat views at 0.4 m, and at 0.55 m views turned left/right, up/down, ... in turn.
    turned = turned_views([(0, 30), (30, 0)], depths_m=(0.55,))
    views = turned_views([(0, 0)], depths_m=(0.4,)) + turned[::3]  # 2 each way
    result = calibrate_intrinsics(views, BOARD.pattern_size, BOARD.square_size_m, progress=False)
    assert not result.rejected
    assert result.K[0, 0] == pytest.approx(TRUE_CAMERA.K[0, 0], rel=0.01)
    one_way = np.array([[0.0, 0.0, 1.0], [0.0, 0.3, 0.95], [0.0, -0.3, 0.95], [0.3, 0.0, 0.95]])
    with pytest.raises(CalibrationError, match=r"too few views tilt the board \(1 left/right, 2"):
        check_tilts(one_way)


def test_rejects_blurred_duplicate_and_boardless_views(views):
    blurred = cv2.GaussianBlur(views[3][1], (0, 0), 3.0)
    duplicate = np.clip(views[5][1].astype(int) + 2, 0, 255).astype(np.uint8)
    blank = np.full((480, 640), 128, np.uint8)
    extra = [("blurred", blurred), ("again", duplicate), ("blank", blank)]
    result = calibrate_intrinsics(
        views[:6] + extra, BOARD.pattern_size, BOARD.square_size_m, progress=False
    )
    reasons = dict(result.rejected)
    assert reasons["blurred"].startswith("blurred")
    assert reasons["again"] == f"near-duplicate of {views[5][0]}"
    assert reasons["blank"] == "no 9x6 board found"
    assert result.views_used == 6
    assert any("10 or more" in w for w in result.warnings)


def test_too_few_views_is_a_clear_error(views):
    with pytest.raises(CalibrationError, match="only 2 usable view"):
        calibrate_intrinsics(views[:2], BOARD.pattern_size, BOARD.square_size_m, progress=False)


def test_coverage_names_the_uncovered_parts():
    cols, rows = 9, 6
    jj, ii = np.mgrid[0:rows, 0:cols]
    small = np.column_stack([20 + 12 * ii.ravel(), 20 + 12 * jj.ravel()]).astype(float)
    fraction, uncovered = coverage([small], (640, 480), (cols, rows))
    assert fraction < 0.1
    assert "bottom-right" in uncovered and "top-left" not in uncovered
    full = np.column_stack([10 + 77 * ii.ravel(), 10 + 92 * jj.ravel()]).astype(float)
    fraction, uncovered = coverage([full], (640, 480), (cols, rows))
    assert fraction > 0.9 and uncovered == []


def test_intrinsics_command_on_a_folder(views, tmp_path, capsys):
    folder = tmp_path / "views"
    folder.mkdir()
    for name, image in views[:6]:
        cv2.imwrite(str(folder / f"{name.replace(' ', '_')}.png"), image)
    (folder / "zz_corrupt.png").write_bytes(b"not an image")
    out = tmp_path / "cam.yaml"
    argv = ["intrinsics", str(folder), "--pattern", "9x6", "--square-size-m", "0.03"]
    assert cli.main(argv + ["-o", str(out), "--json"]) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["views_used"] == 6
    assert {"view": "zz_corrupt.png", "reason": result["rejected"][0]["reason"]} in result[
        "rejected"
    ]
    assert "not a readable image" in result["rejected"][0]["reason"]
    model = CameraModel.load(out)
    assert model.K[0, 0] == pytest.approx(TRUE_CAMERA.K[0, 0], rel=0.01)
    assert result["per_view_rms_px"].keys() == {f"synthetic_{i:02d}.png" for i in range(6)}
    assert result["pose_kept"] is False
    assert has_placeholder_pose(out)  # `follow run` drives no base on it
    # Running again keeps a pose measured in between.
    model.with_pose(CameraPose(0.7, 0.2)).save(out)
    assert cli.main(argv + ["-o", str(out), "--json"]) == 0
    assert CameraModel.load(out).pose.height_m == pytest.approx(0.7)
    assert not has_placeholder_pose(out)
    # A camera file that cannot be read is refused, not replaced: its pose would be lost.
    broken = out.read_text().replace("height_m: 0.7", "height_m: -0.7")
    out.write_text(broken)
    assert cli.main(argv + ["-o", str(out), "--json"]) != 0
    assert "would lose its pose" in capsys.readouterr().err
    assert out.read_text() == broken


def test_intrinsics_command_names_unreadable_files_when_too_few_views_remain(
    views, tmp_path, capsys
):
    for name, image in views[:2]:
        cv2.imwrite(str(tmp_path / f"{name.replace(' ', '_')}.png"), image)
    (tmp_path / "corrupt.png").write_bytes(b"not an image")
    out = tmp_path / "cam.yaml"
    argv = ["intrinsics", "--pattern", "9x6", "--square-size-m", "0.03", "-o", str(out), "--json"]

    def error(*inputs):
        assert cli.main(argv + [str(tmp_path / name) for name in inputs]) == 2
        return json.loads(capsys.readouterr().out.strip().splitlines()[-1])["error"]

    message = error(".")
    assert message.startswith("only 2 usable view(s)")
    assert message.endswith("; 1 unreadable file(s): image " + str(tmp_path / "corrupt.png") +
                            ": not a readable image (corrupt or unknown format)")  # fmt: skip
    assert error("corrupt.png").startswith("no images to calibrate from; 1 unreadable file(s)")
    # A video among images is refused, as by `ground`, not taken for a corrupt image.
    (tmp_path / "board.avi").write_bytes(b"")
    assert error("synthetic_00.png", "board.avi").endswith(
        "board.avi: give a video on its own, not among images"
    )
    assert not out.exists()


def test_intrinsics_command_names_a_missing_folder(tmp_path, capsys):
    argv = ["intrinsics", str(tmp_path / "nowhere"), "--pattern", "9x6", "--square-size-m", "0.03"]
    assert cli.main(argv) == 2
    assert "nowhere: no such file or folder" in capsys.readouterr().err


def test_intrinsics_command_rejects_a_bad_pattern(capsys):
    with pytest.raises(SystemExit):
        cli.main(["intrinsics", "x", "--pattern", "9by6", "--square-size-m", "0.03"])
    assert "must look like 9x6" in capsys.readouterr().err


def test_intrinsics_command_on_a_video_drops_repeated_frames(views, tmp_path, capsys):
    video = tmp_path / "board.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, (640, 480))
    assert writer.isOpened()
    for _, image in views[:5]:
        for _ in range(2):  # the camera lingers: each pose twice
            writer.write(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
    writer.release()
    argv = ["intrinsics", str(video), "--every", "1", "--pattern", "9x6", "--square-size-m",
            "0.03", "-o", str(tmp_path / "cam.json"), "--json"]  # fmt: skip
    assert cli.main(argv) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["views_used"] == 5
    duplicates = [r for r in result["rejected"] if r["reason"].startswith("near-duplicate")]
    assert [r["view"] for r in duplicates] == [f"frame {i}" for i in (1, 3, 5, 7, 9)]
    assert CameraModel.load(tmp_path / "cam.json").K[0, 0] == pytest.approx(
        TRUE_CAMERA.K[0, 0], rel=0.02
    )


def test_a_view_tilted_where_a_flat_one_was_is_no_duplicate():
    """Tilting the board in place, as the tilt rule asks, changes its shape in the image,
    not its place: the view is new, however small the board looks."""
    flat = turned_views([(0, 0)], depths_m=(0.9,))
    tilted = turned_views([(0, 30), (30, 0)], depths_m=(0.9,))
    result = calibrate_intrinsics(flat + tilted, BOARD.pattern_size, BOARD.square_size_m,
                                  progress=False)  # fmt: skip
    assert not [r for r in result.rejected if "duplicate" in r[1]]
    still = np.clip(flat[0][1].astype(int) + 2, 0, 255).astype(np.uint8)  # held still: a copy
    again = calibrate_intrinsics([*flat, *tilted, ("still", still)], BOARD.pattern_size,
                                 BOARD.square_size_m, progress=False)  # fmt: skip
    assert dict(again.rejected)["still"] == f"near-duplicate of {flat[0][0]}"


@pytest.mark.parametrize(
    "option, value",
    [
        ("--max-edge-width-px", "nan"),
        ("--max-edge-width-px", "-1"),
        ("--duplicate-fraction", "nan"),
        ("--duplicate-fraction", "-0.1"),
        ("--duplicate-fraction", "inf"),
    ],
)
def test_screening_limits_that_are_not_numbers_in_range_are_refused(
    tmp_path, capsys, option, value
):
    # A NaN or negative duplicate limit silently turned the screening off; a NaN or
    # negative edge width rejected every view as "blurred (... > nan)".
    argv = ["intrinsics", str(tmp_path), "--pattern", "9x6", "--square-size-m", "0.03"]
    with pytest.raises(SystemExit) as exit_:
        cli.main([*argv, "-o", str(tmp_path / "cam.yaml"), option, value])
    assert exit_.value.code == 2
    assert f"argument {option}" in capsys.readouterr().err


def test_a_calibration_that_reprojects_poorly_is_warned_about(views, monkeypatch):
    # Corners 1 px off everywhere (a board that is not flat, motion blur) gave a camera
    # file with no word about its RMS.
    plain = calibrate_intrinsics(views, BOARD.pattern_size, BOARD.square_size_m, progress=False)
    assert not [w for w in plain.warnings if "RMS" in w]
    rng = np.random.default_rng(3)

    def shaky(*args, **kwargs):
        found = detect_chessboard(*args, **kwargs)
        corners = found.corners_px + rng.normal(0.0, 1.0, found.corners_px.shape)
        return dataclasses.replace(found, corners_px=corners)

    monkeypatch.setattr("calib.intrinsics.detect_chessboard", shaky)
    poor = calibrate_intrinsics(views, BOARD.pattern_size, BOARD.square_size_m, progress=False)
    assert poor.rms_px > 0.5
    assert [w for w in poor.warnings if w.startswith(f"corners reproject with {poor.rms_px:.2f}")]


def test_a_camera_is_read_until_enough_views_are_kept(views, tmp_path, monkeypatch, capsys):
    # A camera never runs out of frames: the command read it for ever.
    read = []

    def endless_camera(source, every=1, limit=None):
        assert source == "0"
        for index in range(10_000):
            if len(read) > 40:
                raise AssertionError("still reading the camera")
            read.append(index)
            yield f"frame {index}", views[index % len(views)][1]

    monkeypatch.setattr("calib.intrinsics_cmd.iter_video_frames", endless_camera)
    argv = ["intrinsics", "0", "--pattern", "9x6", "--square-size-m", "0.03", "--max-views",
            "8", "-o", str(tmp_path / "cam.yaml"), "--json"]  # fmt: skip
    assert cli.main(argv) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["views_used"] == 8 and len(read) == 8


def test_an_output_that_cannot_be_written_is_refused_before_the_work(tmp_path, monkeypatch, capsys):
    # It was found out only when the file was written, the views screened and the
    # camera calibrated for nothing.
    (tmp_path / "shot.png").write_bytes(b"")
    ran = []
    monkeypatch.setattr("calib.intrinsics.calibrate_intrinsics", lambda *a, **k: ran.append(1))
    for output in ("shot.png/camera.yaml", "shot.png/new/camera.yaml"):
        argv = ["intrinsics", str(tmp_path / "shot.png"), "--pattern", "9x6",
                "--square-size-m", "0.03", "-o", str(tmp_path / output)]  # fmt: skip
        assert cli.main(argv) == 2
        assert f"cannot write {tmp_path / output}" in capsys.readouterr().err
    assert not ran


def test_views_of_the_same_file_name_in_two_folders_are_each_counted(views, tmp_path, capsys):
    """Views were reported by file name only: two folders of shots named alike collapsed
    into one entry each, so views_used (written into the camera file) was too low."""
    for k, folder in enumerate(("left", "right")):
        (tmp_path / folder).mkdir()
        for i, (_, image) in enumerate(views[3 * k : 3 * k + 3]):
            cv2.imwrite(str(tmp_path / folder / f"shot_{i}.png"), image)
    out = tmp_path / "cam.yaml"
    argv = ["intrinsics", str(tmp_path / "left"), str(tmp_path / "right"),
            "--pattern", "9x6", "--square-size-m", "0.03", "-o", str(out), "--json"]  # fmt: skip
    assert cli.main(argv) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["views_used"] == 6
    assert len(result["per_view_rms_px"]) == 6
    assert str(tmp_path / "right" / "shot_0.png") in result["per_view_rms_px"]


def test_a_file_that_cannot_be_read_is_skipped_like_a_corrupt_one(
    views, tmp_path, monkeypatch, capsys
):
    # A file without read permission stopped the whole calibration with a bare
    # "[Errno 13] Permission denied", where a corrupt one is skipped and listed.
    for name, image in views[:6]:
        cv2.imwrite(str(tmp_path / f"{name.replace(' ', '_')}.png"), image)
    (tmp_path / "locked.png").write_bytes(b"")
    fromfile = np.fromfile

    def refuse_locked(file, *args, **kwargs):
        if str(file).endswith("locked.png"):
            raise PermissionError(13, "Permission denied", str(file))
        return fromfile(file, *args, **kwargs)

    monkeypatch.setattr(np, "fromfile", refuse_locked)
    out = tmp_path / "cam.yaml"
    argv = ["intrinsics", str(tmp_path), "--pattern", "9x6", "--square-size-m", "0.03"]
    assert cli.main(argv + ["-o", str(out), "--json"]) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["views_used"] == 6
    assert result["rejected"] == [
        {"view": "locked.png", "reason": f"image {tmp_path / 'locked.png'}: cannot read "
                                         "(Permission denied)"}
    ]  # fmt: skip


@pytest.mark.parametrize(
    "pose_note, new_focal_px, stale",
    [
        ("follow-calib ground", 420.0, True),
        ("follow-calib import-tsai View_001.xml", 420.0, True),
        ("follow-calib ground", None, False),  # the same intrinsics: still measured
        (None, 420.0, False),  # set by hand: no K in it
    ],
)
def test_a_pose_measured_through_earlier_intrinsics_is_marked_a_placeholder(
    tmp_path, monkeypatch, capsys, pose_note, new_focal_px, stale
):
    """Re-running intrinsics kept a pose `ground` solved through the old K, and its note
    `pose: follow-calib ground`, so follow drove a base on distances 15 % off."""
    out = tmp_path / "cam.yaml"
    notes = {"intrinsics": "follow-calib intrinsics"}
    if pose_note is not None:
        notes["pose"] = pose_note
    measured = TRUE_CAMERA.with_pose(CameraPose(0.815, 0.236))
    write_camera_file(out, measured, notes)
    K = TRUE_CAMERA.K.copy()
    if new_focal_px is not None:
        K[0, 0] = K[1, 1] = new_focal_px
    result = IntrinsicsResult(K, TRUE_CAMERA.dist, (640, 480), 0.15, {"a.png": 0.15}, [], 0.8, [])
    monkeypatch.setattr("calib.intrinsics.calibrate_intrinsics", lambda *a, **k: result)
    (tmp_path / "a.png").write_bytes(b"")
    argv = ["intrinsics", str(tmp_path / "a.png"), "--pattern", "9x6", "--square-size-m",
            "0.03", "-o", str(out)]  # fmt: skip
    assert cli.main(argv + ["--json"]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert CameraModel.load(out).pose == measured.pose  # kept, whatever its note
    assert report["pose_kept"] and report["pose_placeholder"] is stale
    assert has_placeholder_pose(out) is stale
    warned = [w for w in report["warnings"] if "earlier camera matrix" in w]
    if stale:
        assert warned == [
            f"{out}: its pose ({pose_note}) was measured through the earlier camera matrix and "
            "distortion: it is kept, marked a placeholder (no base is driven on it); re-run "
            "`follow-calib ground`"
        ]
        note = read_calibration_notes(out)["pose"]
        assert note.startswith("placeholder") and "follow-calib ground" in note
        with pytest.raises(PlaceholderPoseError):
            check_pose_measured(out, True, print)
        assert cli.main(argv) == 0  # and said without --json
        assert "(pose is a placeholder)" in capsys.readouterr().out
    else:
        assert not warned
        assert read_calibration_notes(out).get("pose") == pose_note
