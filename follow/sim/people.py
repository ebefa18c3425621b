"""Simulated people walking on the floor.

A walker follows a route of waypoints in `odom` (straight walks, turns at the waypoints,
stops of given lengths) and has a stature; its 18 OpenPose joints are placed in 3-D from
body proportions. While walking, a gait cycle swings the feet back and forth under the
body and lifts each ankle during its swing phase, so the ankle keypoint moves the way it
does for a real walker; standing people have both feet on the floor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from follow.types import NUM_KEYPOINTS

# Joint positions in the body frame (x forward, y left, z up), as fractions of stature,
# for a person standing upright: (forward, left, up). Feet and arms are moved by the gait.
_BODY_FRACTIONS = np.array([
    [0.030, 0.000, 0.930],   # nose
    [0.000, 0.000, 0.818],   # neck
    [0.000, -0.115, 0.818],  # r_shoulder
    [0.000, -0.130, 0.630],  # r_elbow
    [0.010, -0.130, 0.485],  # r_wrist
    [0.000, 0.115, 0.818],   # l_shoulder
    [0.000, 0.130, 0.630],   # l_elbow
    [0.010, 0.130, 0.485],   # l_wrist
    [0.000, -0.055, 0.530],  # r_hip
    [0.000, -0.055, 0.285],  # r_knee
    [0.000, -0.055, 0.039],  # r_ankle (malleolus; the shoe sole is added below)
    [0.000, 0.055, 0.530],   # l_hip
    [0.000, 0.055, 0.285],   # l_knee
    [0.000, 0.055, 0.039],   # l_ankle
    [0.025, -0.030, 0.945],  # r_eye
    [0.025, 0.030, 0.945],   # l_eye
    [0.000, -0.060, 0.935],  # r_ear
    [0.000, 0.060, 0.935],   # l_ear
])  # fmt: skip
NECK_HEIGHT_PER_STATURE = 0.818
# The ankle keypoint sits at the malleolus, 0.039 of stature over the sole on average
# (Drillis and Contini's segment proportions), which is itself lifted by the shoe.
SHOE_SOLE_M = 0.025


@dataclass(frozen=True)
class GaitConfig:
    """How a walker's feet and arms move."""

    stride_per_stature: float = 0.8  # one full cycle (two steps) as a fraction of stature
    stance_fraction: float = 0.6  # part of the cycle a foot is planted
    ankle_lift_m: float = 0.10  # peak height of the ankle keypoint in the swing phase
    arm_swing_per_stature: float = 0.08  # peak fore/aft wrist motion
    full_gait_speed_mps: float = 0.6  # below this the steps shorten towards standing


@dataclass(frozen=True)
class PersonPose:
    """A walker's ground-truth state at one time."""

    position_m: np.ndarray  # (2,) in odom
    velocity_mps: np.ndarray  # (2,)
    heading_rad: float
    distance_walked_m: float


def _foot_offsets(phase: float, stride_m: float, stance_fraction: float, lift_m: float):
    """(forward offset from the body, height) of one foot at a gait phase in [0, 1)."""
    half = 0.5 * stride_m * stance_fraction  # the body covers stance_fraction of a stride
    if phase < stance_fraction:  # planted: slides back under the moving body
        s = phase / stance_fraction
        return half * (1.0 - 2.0 * s), 0.0
    s = (phase - stance_fraction) / (1.0 - stance_fraction)  # swinging forward, lifted
    return -half + 2.0 * half * s, lift_m * math.sin(math.pi * s)


class Walker:
    """One person following a route: waypoints, walking speeds and stops."""

    def __init__(
        self,
        person_id: int,
        stature_m: float,
        waypoints_m: np.ndarray,
        speeds_mps: np.ndarray | float = 1.2,
        pauses_s: np.ndarray | float = 0.0,
        start_s: float = 0.0,
        gait: GaitConfig | None = None,
        gait_phase: float = 0.0,
        ankle_height_per_stature: float = 0.039,
        shoe_sole_m: float = SHOE_SOLE_M,
    ):
        """`waypoints_m` (N, 2) in odom; the walker stands at waypoint 0 until `start_s`,
        walks leg i (waypoint i to i+1) at `speeds_mps[i]`, stops `pauses_s[i]` at
        waypoint i+1, and stays at the last waypoint at the end."""
        if not 1.0 <= stature_m <= 2.5:
            raise ValueError(f"walker {person_id}: stature_m {stature_m} is not a person's")
        wp = np.asarray(waypoints_m, dtype=np.float64).reshape(-1, 2)
        if len(wp) < 1 or not np.isfinite(wp).all():
            raise ValueError(f"walker {person_id}: waypoints must be finite (N, 2)")
        legs = len(wp) - 1
        speeds = np.broadcast_to(np.asarray(speeds_mps, dtype=np.float64), (legs,))
        pauses = np.broadcast_to(np.asarray(pauses_s, dtype=np.float64), (legs,))
        if (speeds <= 0).any() or (pauses < 0).any():
            raise ValueError(f"walker {person_id}: speeds must be > 0 and pauses >= 0")
        self.person_id = int(person_id)
        self.stature_m = float(stature_m)
        self.gait = gait if gait is not None else GaitConfig()
        self._phase0 = float(gait_phase)
        # Standing height of the ankle keypoint: the malleolus over the shoe sole.
        self.ankle_height_m = ankle_height_per_stature * self.stature_m + shoe_sole_m
        # Timeline of pieces: (t0, t1, p0, velocity, walked_at_t0).
        self._t0, self._p0, self._v, self._d0 = [], [], [], []
        t, walked = float(start_s), 0.0
        heading = math.atan2(*(wp[1] - wp[0])[::-1]) if legs and np.any(wp[1] != wp[0]) else 0.0
        self._headings = []
        self._add(-math.inf, wp[0], np.zeros(2), 0.0, heading)
        for i in range(legs):
            delta = wp[i + 1] - wp[i]
            length = float(np.hypot(*delta))
            if length > 1e-9:
                heading = math.atan2(delta[1], delta[0])
                self._add(t, wp[i], delta / length * speeds[i], walked, heading)
                t += length / speeds[i]
                walked += length
            self._add(t, wp[i + 1], np.zeros(2), walked, heading)
            t += pauses[i]
        self.end_s = t
        self._t0_arr = np.array(self._t0)

    def _add(self, t0, p0, v, walked, heading):
        self._t0.append(t0)
        self._p0.append(np.asarray(p0, dtype=np.float64))
        self._v.append(np.asarray(v, dtype=np.float64))
        self._d0.append(walked)
        self._headings.append(heading)

    @property
    def neck_height_m(self) -> float:
        return NECK_HEIGHT_PER_STATURE * self.stature_m

    def pose(self, t_s: float) -> PersonPose:
        i = int(np.searchsorted(self._t0_arr, t_s, side="right")) - 1
        i = max(i, 0)
        dt = 0.0 if i == 0 else t_s - self._t0[i]
        v = self._v[i]
        speed = float(np.hypot(*v))
        return PersonPose(
            position_m=self._p0[i] + v * dt,
            velocity_mps=v.copy(),
            heading_rad=self._headings[i],
            distance_walked_m=self._d0[i] + speed * dt,
        )

    def keypoints_m(self, t_s: float) -> np.ndarray:
        """The 18 joints (18, 3) in odom at time `t_s`."""
        pose = self.pose(t_s)
        g, S = self.gait, self.stature_m
        speed = float(np.hypot(*pose.velocity_mps))
        amount = min(1.0, speed / g.full_gait_speed_mps) if g.full_gait_speed_mps > 0 else 1.0
        stride = g.stride_per_stature * S
        phase = (pose.distance_walked_m / stride + self._phase0) % 1.0
        local = _BODY_FRACTIONS * S
        local[[10, 13], 2] = self.ankle_height_m
        for ankle, knee, wrist, offset in ((10, 9, 7, 0.0), (13, 12, 4, 0.5)):
            fwd, lift = _foot_offsets(
                (phase + offset) % 1.0, stride, g.stance_fraction, g.ankle_lift_m
            )
            local[ankle, 0] += amount * fwd
            local[ankle, 2] += amount * lift
            local[knee, 0] += 0.5 * amount * fwd
            local[knee, 2] += 0.5 * amount * lift
            # The opposite arm swings with this leg.
            local[wrist, 0] += amount * g.arm_swing_per_stature * S * (fwd / max(stride, 1e-9))
        c, s = math.cos(pose.heading_rad), math.sin(pose.heading_rad)
        out = np.empty((NUM_KEYPOINTS, 3))
        out[:, 0] = pose.position_m[0] + c * local[:, 0] - s * local[:, 1]
        out[:, 1] = pose.position_m[1] + s * local[:, 0] + c * local[:, 1]
        out[:, 2] = local[:, 2]
        return out


def random_walker(
    person_id: int,
    rng: np.random.Generator,
    duration_s: float,
    range_m: tuple[float, float] = (2.0, 25.0),
    bearing_rad: tuple[float, float] = (-0.55, 0.55),
    speed_mps: tuple[float, float] = (0.6, 1.6),
    stature_m: tuple[float, float] = (1.5, 1.95),
    stop_probability: float = 0.25,
    stop_s: tuple[float, float] = (1.0, 4.0),
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0),
    gait: GaitConfig | None = None,
) -> Walker:
    """A person wandering between random points of an annular sector in front of a pose
    `origin` (x, y, yaw): straight walks, turns at the waypoints, occasional stops."""
    ox, oy, oyaw = origin

    def point():
        # Uniform over the sector's area would put most people far, and walks between
        # points uniform in range cross the middle most; log-uniform ranges give the near
        # distances a fair share of the time.
        r = math.exp(rng.uniform(math.log(range_m[0]), math.log(range_m[1])))
        b = oyaw + rng.uniform(*bearing_rad)
        return np.array([ox + r * math.cos(b), oy + r * math.sin(b)])

    waypoints, speeds, pauses = [point()], [], []
    t = 0.0
    while t < duration_s:
        nxt = point()
        speed = rng.uniform(*speed_mps)
        pause = rng.uniform(*stop_s) if rng.random() < stop_probability else 0.0
        t += float(np.hypot(*(nxt - waypoints[-1]))) / speed + pause
        waypoints.append(nxt)
        speeds.append(speed)
        pauses.append(pause)
    return Walker(
        person_id,
        rng.uniform(*stature_m),
        np.array(waypoints),
        np.array(speeds),
        np.array(pauses),
        gait=gait,
        gait_phase=rng.random(),
        # people differ in proportions and shoes: the filter knows only the mean
        ankle_height_per_stature=rng.uniform(0.035, 0.043),
        shoe_sole_m=rng.uniform(0.015, 0.035),
    )
