"""After a long gap (a frozen camera, a robot left idle with the node running, a clock
jump) no track past its unseen time takes anyone, the person in view gets a track of
their own in that frame, and the filter never raises on the huge spread."""

from __future__ import annotations

import numpy as np
import pytest

from follow.camera import CameraModel, CameraPose
from follow.config import TrackerConfig
from follow.frames import odom_to_base
from follow.types import Observation, Odometry
from follow.ukf.models import MeasurementModel, process_noise
from follow.ukf.person import PersonFilter
from follow.ukf.tracker import PeopleTracker

FPS = 15.0


def _camera() -> CameraModel:
    return CameraModel.from_fov((640, 360), 70.0, CameraPose(height_m=0.6, pitch_rad=0.02))


def _observe(camera, xy, neck_height_m, rng) -> Observation:
    base_xy = odom_to_base(np.asarray(xy, dtype=float), Odometry.origin())
    cfg = TrackerConfig()
    ankle_z = cfg.ankle_height_m + cfg.ankle_height_per_neck_height * neck_height_m
    uv = camera.project(np.array([[*base_xy, neck_height_m], [*base_xy, ankle_z]]))
    uv = uv + rng.normal(0.0, 1.0, uv.shape)
    return Observation(uv[0], uv[1])


@pytest.mark.parametrize("gap_s", [3.0, 6.0, 30.0])
def test_after_a_gap_the_person_in_view_gets_a_new_track_where_they_stand(gap_s):
    camera = _camera()
    tracker = PeopleTracker(camera, TrackerConfig())
    rng = np.random.default_rng(0)
    for k in range(30):  # person A, 4 m ahead, 1 m to the left
        tracks = tracker.update([_observe(camera, (4.0, 1.0), 1.45, rng)], k / FPS)
    assert [t.confirmed for t in tracks] == [True]
    after = tracker.update([_observe(camera, (6.0, -1.5), 1.30, rng)], 29 / FPS + gap_s)
    assert [t.track_id for t in after] != [1]  # A's track took nobody
    assert len(after) == 1 and np.linalg.norm(after[0].mean[:2] - [6.0, -1.5]) < 1.0


def test_a_filter_with_a_huge_spread_refuses_an_update_instead_of_raising():
    """A state the tracker reached itself in a fuzz run, then 5000 s unseen."""
    cfg = TrackerConfig()
    cov = np.array([
        [7.6011e00, -4.5078e-01, 1.3024e-01, -3.6449e-01, 1.4085e-01],
        [-4.5078e-01, 3.6976e-02, -5.7727e-03, 6.1908e-02, -8.4263e-03],
        [1.3024e-01, -5.7727e-03, 1.2601e00, -4.0161e-02, -2.6564e-04],
        [-3.6449e-01, 6.1908e-02, -4.0161e-02, 5.5670e-01, -6.9157e-03],
        [1.4085e-01, -8.4263e-03, -2.6564e-04, -6.9157e-03, 5.9611e-03]])  # fmt: skip
    person = PersonFilter(np.array([21.81, -1.34, -0.03, -0.64, 1.29]), cov, cfg)
    person.predict(5000.0, process_noise(5000.0, cfg.accel_noise_mps2, cfg.height_noise_mps))
    camera = _camera()
    model = MeasurementModel(camera, Odometry.origin(), cfg.ankle_height_m,
                             cfg.walking_ankle_lift_m, cfg.full_gait_speed_mps,
                             cfg.min_projection_depth_m, cfg.ankle_height_per_neck_height)  # fmt: skip
    tracker = PeopleTracker(camera, cfg)
    R = tracker._measurement_cov(tracker._depth_m(person.mean, Odometry.origin()))
    z = np.array([347.49, 159.81, 344.73, 188.57])
    person.update(z, R, model)  # may refuse (False); must not raise
    assert np.isfinite(person.mean).all() and np.isfinite(person.cov).all()
