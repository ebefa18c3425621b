import math

import numpy as np
import pytest

from follow.camera import CameraModel, CameraPose
from follow.eval.mot import GroundPlaneMot
from follow.eval.peers import ByteTrackBoxTracker, NorfairKeypointTracker
from follow.types import Skeleton


def test_perfect_hypothesis_scores_one_and_a_swap_is_an_id_switch():
    mot = GroundPlaneMot(1.0)
    for t in range(10):
        gt = np.array([[t * 0.1, 0.0], [t * 0.1, 3.0]])
        mot.add_frame([1, 2], gt, [7, 8], gt + 0.1)
    s = mot.summary()
    assert s["mota"] == pytest.approx(1.0) and s["idf1"] == pytest.approx(1.0)
    assert s["motp_m"] == pytest.approx(math.hypot(0.1, 0.1), abs=1e-4)
    assert s["id_switches"] == 0

    mot = GroundPlaneMot(1.0)
    for t in range(10):
        gt = np.array([[t * 0.1, 0.0], [t * 0.1, 3.0]])
        hyp_ids = [7, 8] if t < 5 else [8, 7]
        mot.add_frame([1, 2], gt, hyp_ids, gt)
    s = mot.summary()
    assert s["id_switches"] == 2 and s["idf1"] < 0.6


def test_far_hypothesis_is_a_miss_and_a_false_positive():
    mot = GroundPlaneMot(1.0)
    mot.add_frame([1], np.array([[0.0, 0.0]]), [5], np.array([[1.5, 0.0]]))
    s = mot.summary()
    assert s["misses"] == 1 and s["false_positives"] == 1


def _camera() -> CameraModel:
    return CameraModel.from_fov((640, 480), 70.0, CameraPose(height_m=3.0, pitch_rad=0.4))


def _skeleton(camera: CameraModel, x: float, y: float) -> Skeleton:
    kp = np.full((18, 2), np.nan)
    conf = np.zeros(18)
    joints = {
        0: 1.65,
        1: 1.45,
        2: 1.4,
        5: 1.4,
        8: 0.9,
        11: 0.9,
        9: 0.5,
        12: 0.5,
        10: 0.05,
        13: 0.05,
    }
    for k, z in joints.items():
        dy = -0.18 if k in (2, 8, 9, 10) else (0.18 if k in (5, 11, 12, 13) else 0.0)
        kp[k] = camera.project(np.array([x, y + dy, z]))
        conf[k] = 0.8
    return Skeleton(kp, conf, 1.0)


@pytest.mark.parametrize("tracker_cls", ["norfair", "bytetrack"])
def test_peer_trackers_keep_two_walkers_apart_on_the_floor(tracker_cls):
    cam = _camera()
    tracker = (NorfairKeypointTracker(cam) if tracker_cls == "norfair"
               else ByteTrackBoxTracker(cam, frame_rate_hz=7.0))  # fmt: skip
    seen: dict[int, list[np.ndarray]] = {}
    for t in range(20):
        people = [(6.0 + 0.1 * t, -1.5), (9.0 - 0.1 * t, 1.5)]
        ids, ground = tracker.update([_skeleton(cam, x, y) for x, y in people])
        for i, g in zip(ids, ground, strict=True):
            seen.setdefault(i, []).append(g)
    long_tracks = {i: np.array(p) for i, p in seen.items() if len(p) >= 15}
    assert len(long_tracks) == 2
    sides = sorted(float(np.median(p[:, 1])) for p in long_tracks.values())
    assert sides[0] == pytest.approx(-1.5, abs=0.4) and sides[1] == pytest.approx(1.5, abs=0.4)
