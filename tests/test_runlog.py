import json

import numpy as np
import pytest

from follow.render import annotate, top_down
from follow.runlog import RunLogWriter, read_run_log
from follow.types import (
    Odometry,
    Skeleton,
    TargetEstimate,
    TargetStatus,
    TrackState,
    VelocityCommand,
)


def _skeleton(u0: float) -> Skeleton:
    kp = np.full((18, 2), np.nan)
    conf = np.zeros(18)
    kp[1], conf[1] = (u0, 50.0), 0.9
    kp[10], conf[10] = (u0, 150.0), 0.7
    return Skeleton(kp, conf, 1.5)


def _track(track_id: int, neck_px) -> TrackState:
    return TrackState(
        track_id, np.array([3.0, 0.2 * track_id, 0.5, 0.0, 1.5]), np.eye(5) * 0.1, True, 1.0,
        expected_neck_px=np.array(neck_px, float), expected_neck_cov=np.eye(2) * 16,
    )  # fmt: skip


def test_log_round_trip_and_truncated_last_line(tmp_path):
    path = tmp_path / "run.jsonl"
    with RunLogWriter(path, {"source": "video.avi"}) as log:
        for i in range(3):
            log.write_frame(
                i, i / 7.0, Odometry(0.1 * i, 0.0, 0.05, i / 7.0), [_skeleton(100 + i)],
                [_track(1, (100, 50)), _track(2, (200, 60))],
                TargetEstimate(TargetStatus.TRACKING, 1, {1: 0.8, 2: -0.6}),
                VelocityCommand(0.5, -0.1, i / 7.0), {"pose": 12.0},
            )  # fmt: skip
    with open(path, "a") as fh:
        fh.write('{"frame": 3, "stamp')  # a run killed mid-line
    header, records = read_run_log(path)
    records = list(records)
    assert header["source"] == "video.avi"
    assert [r.frame_index for r in records] == [0, 1, 2]
    r = records[2]
    assert r.target_id == 1 and r.confidences == {1: 0.8, 2: -0.6}
    assert r.command.forward_mps == pytest.approx(0.5)
    assert r.robot.x_m == pytest.approx(0.2)
    np.testing.assert_allclose(r.skeletons[0].keypoints_px[1], [102, 50])
    assert np.isnan(r.skeletons[0].keypoints_px[0]).all()


def test_malformed_log_line_is_named(tmp_path):
    path = tmp_path / "run.jsonl"
    with RunLogWriter(path, {}) as log:
        log.write_frame(0, 0.0, None, [], [], None, None)
    text = path.read_text()
    path.write_text(text + "{broken\n" + text.splitlines()[1] + "\n")
    _, records = read_run_log(path)
    with pytest.raises(ValueError, match="line 3"):
        list(records)


@pytest.mark.parametrize("size", [640, "640x480", [640], [640, -480], [640.5, 480]])
def test_a_header_image_size_that_is_no_width_and_height_is_named(tmp_path, size):
    path = tmp_path / "run.jsonl"
    with RunLogWriter(path, {"image_size": size}) as log:
        log.write_frame(0, 0.0, None, [], [], None, None)
    with pytest.raises(ValueError, match="header image_size .* is not \\[width, height\\]"):
        read_run_log(path)


def test_annotation_highlights_the_target():
    image = np.zeros((240, 320, 3), np.uint8)
    tracks = [_track(1, (100, 50)), _track(2, (200, 60))]
    out = annotate(image, [_skeleton(100)], tracks,
                   TargetEstimate(TargetStatus.TRACKING, 2, {1: -0.5, 2: 0.9}),
                   VelocityCommand(0.3, 0.0, 0.0))  # fmt: skip
    red = (out[..., 2] > 200) & (out[..., 0] < 50) & (out[..., 1] < 50)
    ys, xs = np.nonzero(red)
    assert red.sum() > 20 and abs(np.median(xs) - 200) < 25  # ellipse around track 2
    assert image.sum() == 0  # the input frame is not drawn on
    view = top_down(tracks, 2, Odometry.origin())
    assert view.shape == (360, 360, 3) and (view != 255).any()


@pytest.mark.parametrize(
    "record",
    ['{"frame": 0, "stamp_s": 0.0, "skeletons": [], "target": "tracking"}',
     '{"frame": 0, "stamp_s": 0.0, "skeletons": [], "target": {"id": 1, "confidences": [0.5]}}',
     '{"frame": 1e400, "stamp_s": 0.0, "skeletons": []}'],
)  # fmt: skip
def test_a_frame_record_of_the_wrong_shape_is_named_not_a_crash(tmp_path, record):
    path = tmp_path / "run.jsonl"
    path.write_text('{"log_version": 1}\n' + record + '\n{"frame": 1, "stamp_s": 0.1}\n')
    _, records = read_run_log(path)
    with pytest.raises(ValueError, match=rf"run log {path}: line 2: malformed frame record"):
        list(records)


_POINTS = json.dumps([[1.0, 2.0]] * 17 + [[1.0, "a"]])


@pytest.mark.parametrize(
    "fields, named",
    [('"stamp_s": "abc", "skeletons": []', 'stamp_s is "abc", not a finite number'),
     ('"stamp_s": 0, "skeletons": [], "robot": [1, 2]', "robot is [1, 2], not a list of 3"),
     ('"stamp_s": 0, "skeletons": 5', "skeletons is 5, not a list"),
     ('"stamp_s": 0, "skeletons": [{"keypoints_px": [[1, 2]], "confidences": [1]}]',
      "skeletons[0] keypoints_px is [[1, 2]], not a list of 18"),
     ('"stamp_s": 0, "skeletons": [{"keypoints_px": ' + _POINTS + ', "confidences": []}]',
      'skeletons[0] keypoints_px[17][1] is "a", not a finite number'),
     ('"stamp_s": 0, "skeletons": [], "target": {"confidences": {"x": 0.5}}',
      "target confidences key 'x' is no track id"),
     ('"stamp_s": 0, "skeletons": [], "command": [1, null]', "command[1] is null"),
     ('"stamp_s": 0, "skeletons": [], "target": {"id": "7"}', 'target id is "7", not a whole')],
)  # fmt: skip
def test_a_malformed_frame_record_names_the_field_and_its_value(tmp_path, fields, named):
    path = tmp_path / "run.jsonl"
    path.write_text('{"log_version": 1}\n{"frame": 0, ' + fields + "}\n"
                    '{"frame": 1, "stamp_s": 0.1, "skeletons": []}\n')  # fmt: skip
    _, records = read_run_log(path)
    with pytest.raises(ValueError) as caught:
        list(records)
    assert f"run log {path}: line 2: malformed frame record ({named}" in str(caught.value)


def test_a_frame_record_without_its_skeletons_is_refused_not_replayed_as_nobody(tmp_path):
    path = tmp_path / "run.jsonl"
    path.write_text('{"log_version": 1}\n{"frame": 0, "stamp_s": 0.0}\n')
    _, records = read_run_log(path)
    with pytest.raises(ValueError, match="line 2: frame record without the key 'skeletons'"):
        list(records)


def test_the_log_is_read_a_line_at_a_time_as_the_records_are_taken(tmp_path):
    """Lines written after the first records were taken are read too (the file is read
    as it is iterated, not whole at the start), and bytes that are not UTF-8 far down are
    named, with their offset in the file, only when reached."""
    path = tmp_path / "run.jsonl"
    log = RunLogWriter(path, {"source": "video.avi"})
    for i in range(2):
        log.write_frame(i, i / 15.0, None, [_skeleton(100 + i)], [], None, None)
    header, records = read_run_log(path)
    assert header["source"] == "video.avi" and next(records).frame_index == 0
    for i in range(2, 4):  # the run goes on
        log.write_frame(i, i / 15.0, None, [_skeleton(100 + i)], [], None, None)
    log.close()
    assert [r.frame_index for r in records] == [1, 2, 3]

    good = path.read_bytes()
    path.write_bytes(good + b'{"frame": 4, "stamp_s": \xff}\n' + good.splitlines(True)[1])
    _, records = read_run_log(path)
    assert [next(records).frame_index for _ in range(4)] == [0, 1, 2, 3]
    offset = len(good) + len(b'{"frame": 4, "stamp_s": ')
    with pytest.raises(ValueError, match=rf"run log {path}: not a text run log .* byte {offset}\)"):
        next(records)


@pytest.mark.parametrize("stamp", [1e300, 1e11, -0.5])
def test_a_stamp_no_clock_gives_is_refused_with_its_line(tmp_path, stamp):
    """A hand-edited 1e300 is a finite number: it passed, and the replay's tracker then
    failed with a raw OverflowError (its motion model takes dt ** 3)."""
    path = tmp_path / "run.jsonl"
    with RunLogWriter(path, {"source": "video.avi"}) as log:
        for i in range(3):
            log.write_frame(i, i / 15.0, None, [_skeleton(100 + i)], [], None, None)
    lines = path.read_text().splitlines(True)
    edited = json.loads(lines[2])
    edited["stamp_s"] = stamp
    path.write_text("".join([*lines[:2], json.dumps(edited) + "\n", *lines[3:]]))
    _, records = read_run_log(path)
    assert next(records).stamp_s == 0.0
    with pytest.raises(ValueError) as caught:
        next(records)
    assert f"run log {path}: line 3: malformed frame record (stamp_s is {json.dumps(stamp)}, " \
        "not a time from 0 to 1e+11 s)" in str(caught.value)  # fmt: skip
