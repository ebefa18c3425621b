"""`follow-calib check --frame N` past a video's end names the frame asked for and how
many frames the video has."""

from __future__ import annotations

from test_capture import damaged_mjpeg
from test_run_bad_input import _video

from calib import cli
from follow.camera import CameraModel, CameraPose


def _camera(tmp_path):
    """A camera file for the tiny test videos, 1 m up, pitched down 0.2 rad."""
    camera = tmp_path / "cam.yaml"
    CameraModel.from_fov((64, 48), 70.0, CameraPose(height_m=1.0, pitch_rad=0.2)).save(camera)
    return camera


def test_a_frame_past_the_end_names_the_frame_and_the_count(tmp_path, capsys):
    video = _video(tmp_path / "clip.avi", frames=7)
    argv = ["check", str(video), "--camera", str(_camera(tmp_path)), "-o", str(tmp_path / "c.png")]
    assert cli.main([*argv, "--frame", "999999"]) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    assert f"video {video}: has no frame 999999 (--frame); it has 7 frames, 0..6" in err
    assert cli.main([*argv, "--frame", "6"]) == 0  # the last one is there


def test_an_output_that_cannot_be_written_is_refused_before_the_work(tmp_path, capsys):
    video = _video(tmp_path / "clip.avi", frames=2)
    camera = _camera(tmp_path)
    for output, option in (("c.xyz", "--output"), ("missing/c.png", "--output")):
        try:
            cli.main(["check", str(video), "--camera", str(camera), "-o", str(tmp_path / output)])
        except SystemExit as exit_:
            assert exit_.code == 2
        else:
            raise AssertionError(f"{output} was accepted")
        assert f"argument -o/{option}" in capsys.readouterr().err
    try:
        cli.main(["check", str(video), "--camera", str(camera), "--max-range-m", "-1"])
    except SystemExit as exit_:
        assert exit_.code == 2 and "argument --max-range-m" in capsys.readouterr().err
    else:
        raise AssertionError("--max-range-m -1 was accepted")


def test_a_grid_too_fine_to_draw_is_refused_by_name(tmp_path, capsys):
    # A 1 nm grid asked numpy for a 139 GiB array: a MemoryError traceback.
    video = _video(tmp_path / "clip.avi", frames=1)
    argv = ["check", str(video), "--camera", str(_camera(tmp_path)), "-o", str(tmp_path / "c.png")]
    assert cli.main([*argv, "--grid-step-m", "1e-9"]) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and "grid step of 1e-09 m draws" in err, err
    assert not (tmp_path / "c.png").exists()
    assert cli.main([*argv, "--grid-step-m", "0.05"]) == 0


def test_a_camera_index_that_cannot_be_opened_is_named_as_one(tmp_path, capsys, monkeypatch):
    """As `follow run` says it: too large for OpenCV, or no device behind it."""
    import cv2

    argv = ["check", "--camera", str(_camera(tmp_path)), "-o", str(tmp_path / "c.png")]
    assert cli.main(["check", "99999999999", *argv[1:]]) == 2
    assert "no camera index is that large" in capsys.readouterr().err

    class NoDevice:
        def __init__(self, index):
            pass

        def isOpened(self):
            return False

    monkeypatch.setattr(cv2, "VideoCapture", NoDevice)
    assert cli.main(["check", "7", *argv[1:]]) == 2
    err = capsys.readouterr().err
    assert "no camera at index 7 can be opened" in err and "Traceback" not in err


def test_a_damaged_frame_of_a_video_is_skipped_not_taken_for_its_end(tmp_path, caplog):
    """As `follow run` reads past a frame that cannot be decoded, so do the calibration
    commands: the frames after it are there, and the skip is said."""
    from calib.chessboard import iter_video_frames

    video = damaged_mjpeg(tmp_path / "clip.avi", frames=30, damaged=15)
    names = [name for name, _ in iter_video_frames(video)]
    assert len(names) == 29 and "frame 15" not in names and names[-1] == "frame 29"
    assert "1 damaged frame(s) skipped" in caplog.text
    argv = ["check", str(video), "--camera", str(_camera(tmp_path)), "-o", str(tmp_path / "c.png")]
    assert cli.main([*argv, "--frame", "28"]) == 0  # the 29th frame that decodes


def test_a_damaged_stretch_longer_than_the_run_bound_does_not_end_a_calibration_video(tmp_path):
    """It ended after MAX_UNDECODABLE_RUN failed reads, losing the frames after the stretch;
    `follow run` reads on to a frame count that fits the file, and so does the calibration."""
    from test_capture_damaged_video import mjpeg_video

    from calib.chessboard import iter_video_frames
    from follow.cli_args import MAX_UNDECODABLE_RUN

    damaged = range(30, 70)
    assert len(damaged) > MAX_UNDECODABLE_RUN
    video = mjpeg_video(tmp_path / "clip.avi", 100, damaged)
    names = [name for name, _ in iter_video_frames(video)]
    assert len(names) == 60 and names[-1] == "frame 99"


def test_options_for_videos_only_are_refused_with_an_image(tmp_path, capsys):
    """`--frame` with an image, `--every` with image files: they used to be ignored."""
    import cv2
    import numpy as np

    image = tmp_path / "floor.png"
    cv2.imwrite(str(image), np.full((48, 64, 3), 120, np.uint8))
    argv = ["check", str(image), "--camera", str(_camera(tmp_path)), "-o", str(tmp_path / "c.png")]
    assert cli.main([*argv, "--frame", "5"]) == 2
    assert "--frame picks a frame of a video or camera" in capsys.readouterr().err
    assert not (tmp_path / "c.png").exists()
    argv = ["intrinsics", str(image), "--pattern", "9x6", "--square-size-m", "0.03",
            "--every", "3", "-o", str(tmp_path / "cam.yaml")]  # fmt: skip
    assert cli.main(argv) == 2
    assert "--every picks frames of a video or camera" in capsys.readouterr().err


def test_an_image_size_that_is_not_positive_is_named_not_taken_for_a_principal_point(
    tmp_path, capsys
):
    """`image_width: 0` was reported as a principal point outside a 0x48 image."""
    good = _camera(tmp_path).read_text()
    video = _video(tmp_path / "clip.avi", frames=1)
    for key, value in (("image_width", 0), ("image_width", -64), ("image_height", 0)):
        bad = tmp_path / "bad.yaml"
        original = 64 if key == "image_width" else 48
        bad.write_text(good.replace(f"{key}: {original}", f"{key}: {value}"))
        argv = ["check", str(video), "--camera", str(bad), "-o", str(tmp_path / "c.png")]
        assert cli.main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert err.endswith(
            f"camera file {bad}: field '{key}' must be a positive number of pixels, got {value}"
        ), err
        assert "principal point" not in err
