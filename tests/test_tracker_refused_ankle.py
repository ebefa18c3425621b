"""An ankle the tracker refuses is not handed on: a track reports the observation as the
tracker used it, so the identifier's crop comes from the track's expected ankle, not from
feet that were on no floor or someone else's."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from follow.camera import CameraModel, CameraPose
from follow.ccf.roi import hip_of, person_boxes, roi_from_keypoints, track_rois
from follow.config import IdentifyConfig, TrackerConfig
from follow.types import L_ANKLE, NECK, R_ANKLE, Observation, Skeleton
from follow.ukf.tracker import PeopleTracker

FPS = 15.0
SIZE = (640, 360)
ICFG = IdentifyConfig()


@pytest.fixture
def camera() -> CameraModel:
    # The detector's resolution (1/3 of 1920x1080), HFOV 70 deg, 0.6 m over the floor.
    return CameraModel.from_fov(SIZE, 70.0, CameraPose(height_m=0.6, pitch_rad=0.02))


@pytest.fixture(autouse=True)
def _quiet():
    """The refused ankles are warned of; the warnings are not what is tested here."""
    logging.disable(logging.WARNING)
    yield
    logging.disable(logging.NOTSET)


def point(camera, xy, z) -> np.ndarray:
    return camera.project(np.array([[xy[0], xy[1], z]]))[0]


def observe(camera, xy, neck_h, ankle_z=None) -> Observation:
    """A person at `xy` (base = odom, the robot at the origin): neck at `neck_h`, the
    ankle point at the modelled ankle height unless `ankle_z` is given."""
    if ankle_z is None:
        cfg = TrackerConfig()
        ankle_z = cfg.ankle_height_m + cfg.ankle_height_per_neck_height * neck_h
    return Observation(point(camera, xy, neck_h), point(camera, xy, ankle_z))


def crop_from_expected_ankle(track) -> tuple[int, int, int, int]:
    """The crop the identifier should cut for a track seen without a usable ankle."""
    obs = track.observation
    return roi_from_keypoints(obs.neck_px, track.expected_ankle_px, SIZE, ICFG,
                              hip_px=hip_of(obs), whole=True)  # fmt: skip


def test_a_crop_above_the_horizon_comes_from_the_expected_ankle(camera):
    """A skeleton whose 'ankle' is its hip (0.9 m, over the 0.6 m camera's horizon): the
    track is updated by the neck, and the crop spans the whole body from the tracker's
    expected ankle, not the chest above the hip that was learnt as the target."""
    xy, h = (3.0, 0.4), 1.45
    tracker = PeopleTracker(camera)
    for k in range(10):
        tracker.update([observe(camera, xy, h)], k / FPS)
    bad = observe(camera, xy, h, ankle_z=0.9)
    kps, conf = np.full((18, 2), np.nan), np.zeros(18)
    kps[NECK], kps[R_ANKLE], kps[L_ANKLE] = bad.neck_px, bad.ankle_px, bad.ankle_px
    conf[[NECK, R_ANKLE, L_ANKLE]] = 0.8
    bad = Observation(bad.neck_px, bad.ankle_px, True, Skeleton(kps, conf))
    assert not camera.is_below_horizon(bad.ankle_px)[0]
    (track,) = tracker.update([bad], 10 / FPS)
    assert track.last_seen_s == 10 / FPS
    taken = track.observation
    assert taken.ankle_px is None and taken.skeleton is bad.skeleton and taken.touches_border
    np.testing.assert_array_equal(taken.neck_px, bad.neck_px)
    crop = track_rois([track], SIZE, ICFG)[track.track_id]
    refused = roi_from_keypoints(bad.neck_px, bad.ankle_px, SIZE, ICFG, whole=True)
    assert crop == crop_from_expected_ankle(track)
    assert crop[3] - crop[1] > 2 * (refused[3] - refused[1])


def test_an_observation_used_whole_is_the_callers_object(camera):
    """Callers (the evaluations) match a track to the person it saw by the observation's
    identity: the tracker hands back the caller's own object when it used all of it."""
    tracker = PeopleTracker(camera)
    for k in range(5):
        given = observe(camera, (5.0, 0.0), 1.5)
        (track,) = tracker.update([given], k / FPS)
        assert track.observation is given


def test_a_half_hidden_persons_crop_is_not_cut_down_to_anothers_feet(camera):
    """A (8 m) half hidden behind B (4 m) is handed B's feet and kept by the neck alone:
    A's crop and box come from A's expected ankle, not from B's feet."""
    a, b = (8.0, 0.3), (4.0, 0.15)
    tracker = PeopleTracker(camera)
    t = 0.0
    for _ in range(int(2 * FPS)):
        t += 1 / FPS
        tracks = tracker.update([observe(camera, a, 1.45), observe(camera, b, 1.5)], t)
    a_id = min(tracks, key=lambda s: np.linalg.norm(s.position_m - a)).track_id
    feet_of_b = observe(camera, b, 1.5).ankle_px
    for _ in range(5):
        t += 1 / FPS
        a_seen = Observation(observe(camera, a, 1.45).neck_px, feet_of_b)
        b_seen = Observation(observe(camera, b, 1.5).neck_px)
        tracks = tracker.update([a_seen, b_seen], t)
    track = {s.track_id: s for s in tracks}[a_id]
    assert track.last_seen_s == t and track.observation.ankle_px is None
    rois = track_rois(tracks, SIZE, ICFG)
    assert rois[a_id] == crop_from_expected_ankle(track)
    own_ankle_v = observe(camera, a, 1.45).ankle_px[1]
    assert abs(rois[a_id][3] - own_ankle_v) < abs(rois[a_id][3] - feet_of_b[1])
    assert person_boxes(tracks, rois, SIZE, ICFG)[a_id][3] < feet_of_b[1]
