"""A deterministic simulated world: walking people and a robot carrying a camera.

The robot either follows a scripted path (a function of time giving its pose) or is
moved from outside each step with `set_robot_pose`, so that a controller and a simulated
base can close the loop. Every frame carries the exact ground truth (people's positions,
velocities and neck heights, the robot's pose) and the odometry the robot reports.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np

from follow.camera import CameraModel, CameraPose
from follow.frames import wrap_angle
from follow.sim.people import Walker
from follow.types import Odometry

RobotPath = Callable[[float], tuple[float, float, float]]


@dataclass(frozen=True)
class SimCameraConfig:
    """The robot's camera; defaults are the localisation set-up of Koide et al."""

    height_m: float = 0.6
    pitch_rad: float = 0.0  # positive looks down
    horizontal_fov_deg: float = 70.0
    image_width_px: int = 1920
    image_height_px: int = 1080
    detection_scale: float = 1.0 / 3.0  # the detector runs on the image resized by this
    fps: float = 15.0

    def camera(self) -> CameraModel:
        """The camera at full image resolution."""
        pose = CameraPose(height_m=self.height_m, pitch_rad=self.pitch_rad)
        return CameraModel.from_fov(
            (self.image_width_px, self.image_height_px), self.horizontal_fov_deg, pose
        )

    def detection_camera(self) -> CameraModel:
        """The camera at the detector's resolution (where keypoints are reported)."""
        w = round(self.image_width_px * self.detection_scale)
        h = round(self.image_height_px * self.detection_scale)
        return self.camera().scaled(w, h)


@dataclass(frozen=True)
class PersonTruth:
    """One person's exact state in one frame."""

    person_id: int
    position_m: np.ndarray  # (2,) odom
    velocity_mps: np.ndarray  # (2,)
    neck_height_m: float
    stature_m: float
    keypoints_m: np.ndarray  # (18, 3) odom


@dataclass(frozen=True)
class WorldFrame:
    """Ground truth of one frame: time, the robot's true pose, its odometry, the people."""

    index: int
    stamp_s: float
    robot: Odometry  # the true pose
    odometry: Odometry  # what the robot's odometry reports
    people: list[PersonTruth] = field(default_factory=list)

    def person(self, person_id: int) -> PersonTruth | None:
        return next((p for p in self.people if p.person_id == person_id), None)


def static_robot(x_m: float = 0.0, y_m: float = 0.0, yaw_rad: float = 0.0) -> RobotPath:
    return lambda t: (x_m, y_m, yaw_rad)


def turning_robot(amplitude_rad: float, period_s: float) -> RobotPath:
    """A robot at the origin turning back and forth (yaw = A sin(2 pi t / T))."""
    return lambda t: (0.0, 0.0, amplitude_rad * math.sin(2.0 * math.pi * t / period_s))


class World:
    """People and a robot with a camera, stepped at the camera's frame rate."""

    def __init__(
        self,
        walkers: list[Walker] | None = None,
        camera: SimCameraConfig | None = None,
        robot_path: RobotPath | None = None,
        seed: int = 0,
        odometry_drift_m_per_m: float = 0.0,
        odometry_drift_rad_per_rad: float = 0.0,
    ):
        """`robot_path` maps time to the robot's (x, y, yaw); without it the robot stays
        where `set_robot_pose` last put it (the origin to begin with). Odometry drifts by
        Gaussian noise of the given std per metre travelled / radian turned."""
        self.camera_config = camera if camera is not None else SimCameraConfig()
        self.walkers: list[Walker] = []
        for w in walkers or []:
            self.add_walker(w)
        self.robot_path = robot_path
        self.rng = np.random.default_rng(seed)
        self.drift_m_per_m = odometry_drift_m_per_m
        self.drift_rad_per_rad = odometry_drift_rad_per_rad
        self.index = -1
        self._pose = robot_path(0.0) if robot_path else (0.0, 0.0, 0.0)
        self._odom = self._pose
        self._odom_pose_at = self._pose

    # ------------------------------------------------------------------ set-up
    def add_walker(self, walker: Walker) -> None:
        if any(w.person_id == walker.person_id for w in self.walkers):
            raise ValueError(f"a walker with id {walker.person_id} is already in the world")
        self.walkers.append(walker)

    def set_robot_pose(self, pose: Odometry | tuple[float, float, float]) -> None:
        """Put the robot at a true pose (x, y, yaw) for the next frames; odometry follows
        it with its drift. Only for worlds without a scripted path."""
        if self.robot_path is not None:
            raise RuntimeError("this world's robot follows a scripted path")
        if isinstance(pose, Odometry):
            pose = (pose.x_m, pose.y_m, pose.yaw_rad)
        if not all(math.isfinite(v) for v in pose):
            raise ValueError(f"robot pose must be finite, got {pose}")
        self._pose = tuple(float(v) for v in pose)

    @property
    def dt_s(self) -> float:
        return 1.0 / self.camera_config.fps

    @property
    def stamp_s(self) -> float:
        return max(self.index, 0) * self.dt_s

    # ------------------------------------------------------------------ stepping
    def step(self) -> WorldFrame:
        """Advance one frame and return its ground truth."""
        self.index += 1
        t = self.index * self.dt_s
        if self.robot_path is not None:
            self._pose = tuple(float(v) for v in self.robot_path(t))
        self._advance_odometry()
        people = []
        for w in self.walkers:
            p = w.pose(t)
            people.append(
                PersonTruth(
                    person_id=w.person_id,
                    position_m=p.position_m,
                    velocity_mps=p.velocity_mps,
                    neck_height_m=w.neck_height_m,
                    stature_m=w.stature_m,
                    keypoints_m=w.keypoints_m(t),
                )
            )
        return WorldFrame(
            index=self.index,
            stamp_s=t,
            robot=Odometry(*self._pose, stamp_s=t),
            odometry=Odometry(*self._odom, stamp_s=t),
            people=people,
        )

    def run(self, n_frames: int) -> Iterator[WorldFrame]:
        for _ in range(n_frames):
            yield self.step()

    def _advance_odometry(self) -> None:
        """Integrate the true motion since the last frame into the odometry, with drift."""
        x0, y0, yaw0 = self._odom_pose_at
        x1, y1, yaw1 = self._pose
        c, s = math.cos(yaw0), math.sin(yaw0)
        fwd = c * (x1 - x0) + s * (y1 - y0)
        left = -s * (x1 - x0) + c * (y1 - y0)
        dyaw = float(wrap_angle(yaw1 - yaw0))
        dist = math.hypot(fwd, left)
        # Independent errors per metre (radian): the variance grows with the distance
        # (angle), so a frame's share of it does not depend on the frame rate.
        if self.drift_m_per_m > 0 and dist > 0:
            fwd += self.rng.normal(0.0, self.drift_m_per_m * math.sqrt(dist))
            left += self.rng.normal(0.0, self.drift_m_per_m * math.sqrt(dist))
        if self.drift_rad_per_rad > 0 and dyaw != 0:
            dyaw += self.rng.normal(0.0, self.drift_rad_per_rad * math.sqrt(abs(dyaw)))
        ox, oy, oyaw = self._odom
        c, s = math.cos(oyaw), math.sin(oyaw)
        self._odom = (
            ox + c * fwd - s * left,
            oy + s * fwd + c * left,
            float(wrap_angle(oyaw + dyaw)),
        )
        self._odom_pose_at = self._pose
