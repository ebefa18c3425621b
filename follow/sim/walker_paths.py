"""Scripted walkers for closed-loop following runs: a person walking straight, along
arcs, and stopping, as piecewise constant speed and turn rate, in the `odom` frame."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Segment:
    duration_s: float
    speed_mps: float = 0.0
    turn_rate_radps: float = 0.0  # counter-clockwise positive


class WalkerPath:
    """Position and velocity of a walker at any time, integrated once on a fine grid."""

    def __init__(
        self,
        segments: list[Segment],
        start_xy_m: tuple[float, float] = (0.0, 0.0),
        start_heading_rad: float = 0.0,
        step_s: float = 0.005,
    ):
        if not segments:
            raise ValueError("walker path: no segments")
        self.segments = tuple(segments)
        self.duration_s = sum(s.duration_s for s in segments)
        n = int(math.ceil(self.duration_s / step_s)) + 1
        self._t = np.arange(n) * step_s
        self._xy = np.zeros((n, 2))
        self._v = np.zeros((n, 2))
        x, y, heading = start_xy_m[0], start_xy_m[1], start_heading_rad
        for i, t in enumerate(self._t):
            seg = self.segment_at(t)
            vx, vy = seg.speed_mps * math.cos(heading), seg.speed_mps * math.sin(heading)
            self._xy[i], self._v[i] = (x, y), (vx, vy)
            x, y = x + vx * step_s, y + vy * step_s
            heading += seg.turn_rate_radps * step_s

    def segment_at(self, t_s: float) -> Segment:
        end = 0.0
        for seg in self.segments:
            end += seg.duration_s
            if t_s < end:
                return seg
        return Segment(0.0)  # after the script the walker stands still

    def time_in_segment(self, t_s: float) -> float:
        """Seconds since the walker last changed speed or turn rate."""
        start = 0.0
        for seg in self.segments:
            if t_s < start + seg.duration_s:
                return t_s - start
            start += seg.duration_s
        return t_s - self.duration_s

    def state(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """(position (2,), velocity (2,)) at time t_s (clamped to the script)."""
        i = int(np.clip(round(t_s / (self._t[1] - self._t[0])), 0, len(self._t) - 1))
        return self._xy[i].copy(), self._v[i].copy()


def scenario(name: str, speed_mps: float = 1.0, start_distance_m: float = 1.8) -> WalkerPath:
    """A named script; the walker starts `start_distance_m` ahead of a robot at the origin."""
    turn = 0.25  # rad/s: a 4 m radius arc at 1 m/s
    scripts = {
        "straight": [Segment(1.0), Segment(11.0, speed_mps), Segment(3.0)],
        "turning": [
            Segment(1.0), Segment(3.0, speed_mps), Segment(5.0, speed_mps, turn),
            Segment(5.0, speed_mps, -turn), Segment(2.0, speed_mps), Segment(3.0),
        ],
        "stopping": [
            Segment(1.0), Segment(4.0, speed_mps), Segment(3.0), Segment(4.0, speed_mps),
            Segment(3.0),
        ],
        "short": [Segment(0.5), Segment(4.0, speed_mps), Segment(1.0)],
    }  # fmt: skip
    if name not in scripts:
        raise ValueError(f"unknown walker scenario {name!r}; known: {sorted(scripts)}")
    return WalkerPath(scripts[name], start_xy_m=(start_distance_m, 0.0))


SCENARIOS = ("straight", "turning", "stopping")
