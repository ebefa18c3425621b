"""Motion and measurement models of one person on the floor.

State `[x, y, vx, vy, h]`: ground position and velocity in `odom`, neck height. People
move at constant velocity disturbed by white acceleration noise; the neck height drifts
by a small random walk. The camera sees the neck at `(x, y, h)` and the ankle point at
`(x, y, a)`, where `a` is the ankle keypoint's mean height over the floor: its height
when standing, plus, for a walking person, the mean lift of the feet over a gait cycle
(each foot rises in its swing phase, so the midpoint of the ankles is on average above
the floor, which would otherwise read as a person farther away).
"""

from __future__ import annotations

import numpy as np

from follow.camera import CameraModel
from follow.frames import odom_to_base
from follow.types import Odometry

STATE_DIM = 5
X, Y, VX, VY, H = range(STATE_DIM)


def constant_velocity(state: np.ndarray, dt: float) -> np.ndarray:
    """Move state(s) (..., 5) forward by `dt` seconds at constant velocity."""
    out = np.array(state, dtype=np.float64, copy=True)
    out[..., X] += dt * out[..., VX]
    out[..., Y] += dt * out[..., VY]
    return out


def process_noise(dt_s: float, accel_noise_mps2: float, height_noise_mps: float) -> np.ndarray:
    """Q for a time step: white acceleration on (x, y) integrated over `dt_s`, plus a
    height random walk. A long gap therefore adds much more uncertainty than a short one."""
    dt = max(float(dt_s), 0.0)
    q = accel_noise_mps2**2
    Q = np.zeros((STATE_DIM, STATE_DIM))
    for p, v in ((X, VX), (Y, VY)):
        Q[p, p] = q * dt**3 / 3.0
        Q[p, v] = Q[v, p] = q * dt**2 / 2.0
        Q[v, v] = q * dt
    Q[H, H] = height_noise_mps**2 * dt
    return Q


def population_ankle_height_m(config) -> float:
    """The standing ankle keypoint height of a person of the default neck height: what
    a single observation, without a height estimate, is back-projected with."""
    return (
        config.ankle_height_m + config.ankle_height_per_neck_height * config.default_neck_height_m
    )


class MeasurementModel:
    """Projects states to the neck and ankle pixels for one camera pose and robot pose."""

    def __init__(
        self,
        camera: CameraModel,
        robot: Odometry,
        ankle_height_m: float = 0.0,
        walking_ankle_lift_m: float = 0.0,
        full_gait_speed_mps: float = 0.6,
        min_depth_m: float = 0.3,
        ankle_height_per_neck_height: float = 0.0,
    ):
        """`min_depth_m`: points nearer to (or behind) the camera plane are projected as if
        at this depth, so that the sigma points of an uncertain track near the robot still
        give finite (if far-flung) pixels instead of none."""
        self.camera = camera
        self.min_depth_m = float(min_depth_m)
        self.robot = robot
        self.ankle_height_m = float(ankle_height_m)
        self.ankle_height_per_neck_height = float(ankle_height_per_neck_height)
        self.walking_ankle_lift_m = float(walking_ankle_lift_m)
        self.full_gait_speed_mps = max(float(full_gait_speed_mps), 1e-6)

    def ankle_heights_m(self, states: np.ndarray, gait_speeds_mps: np.ndarray | None = None
                        ) -> np.ndarray:  # fmt: skip
        """Expected ankle keypoint height (N,) of states (N, 5): the standing height (a
        constant plus a fraction of the neck height) plus the gait's mean lift, in
        proportion to the speed up to a full walking gait: each state's own speed, or
        `gait_speeds_mps` (N,) where given (`PersonFilter`: the mean's, so that the
        spread of a standing person's velocity does not lift their feet)."""
        speed = (np.hypot(states[:, VX], states[:, VY]) if gait_speeds_mps is None
                 else np.asarray(gait_speeds_mps, dtype=np.float64))  # fmt: skip
        gait = np.minimum(speed / self.full_gait_speed_mps, 1.0)
        standing = self.ankle_height_m + self.ankle_height_per_neck_height * states[:, H]
        return standing + self.walking_ankle_lift_m * gait

    def _points_base(self, states: np.ndarray, gait_speeds_mps: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        s = np.atleast_2d(states)
        ground = odom_to_base(s[:, :2], self.robot)
        neck = np.column_stack([ground, s[:, H]])
        ankle = np.column_stack([ground, self.ankle_heights_m(s, gait_speeds_mps)])
        return neck, ankle

    def _project(self, points_base: np.ndarray) -> np.ndarray:
        if self.min_depth_m > 0:
            cam = self.camera
            pc = cam.base_to_camera(points_base)
            near = pc[:, 2] < self.min_depth_m
            if near.any():  # move only those points, so that each projects on its own
                pc[near, 2] = self.min_depth_m
                points_base = np.array(points_base, dtype=np.float64)
                points_base[near] = pc[near] @ cam.rotation_base_from_cam.T + cam.position_base
        return self.camera.project(points_base)

    def in_front(self, state: np.ndarray) -> bool:
        """Whether the state's neck lies in front of the camera plane. One behind it is in
        no pixel: the near clamp of `_project` would put a point straight behind the
        camera on the principal point, where a person ahead is seen."""
        neck, _ = self._points_base(state)
        return bool(self.camera.base_to_camera(neck)[0, 2] > 0.0)

    def neck_ankle(self, states: np.ndarray, gait_speeds_mps: np.ndarray | None = None
                   ) -> np.ndarray:  # fmt: skip
        """(N, 4) pixels [neck_u, neck_v, ankle_u, ankle_v] for states (N, 5); the gait
        lift at each state's speed, or at `gait_speeds_mps` (N,) where given."""
        neck, ankle = self._points_base(states, gait_speeds_mps)
        uv = self._project(np.vstack([neck, ankle]))
        n = len(neck)
        return np.hstack([uv[:n], uv[n:]])

    def neck_only(self, states: np.ndarray) -> np.ndarray:
        """(N, 2) neck pixels for states (N, 5)."""
        neck, _ = self._points_base(states)
        return self._project(neck)

    # Single-state versions, in the form filterpy's update calls them.
    def hx_neck_ankle(self, state: np.ndarray) -> np.ndarray:
        return self.neck_ankle(state[None])[0]

    def hx_neck(self, state: np.ndarray) -> np.ndarray:
        return self.neck_only(state[None])[0]
