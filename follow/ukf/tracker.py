"""Multi-person tracker on the ground plane.

Every frame: predict each person's UKF to the frame's time with the real time step,
work out where each track expects the neck and ankle in the image (unscented transform),
gate and associate the observations (global nearest neighbour on the negative
log-likelihood), update, start tracks from unclaimed neck+ankle observations, and
retire tracks that are lost. Tracks live in `odom`; the robot's pose at the frame's time
maps them into the camera, so the robot's own motion does not move them.
"""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from follow.camera import CameraModel
from follow.config import TrackerConfig
from follow.frames import base_to_odom, odom_jump_transform, odom_to_base, rotation_2d
from follow.odometry_buffer import OdometryJumps, pose_jumped
from follow.types import L_ANKLE, R_ANKLE, Observation, Odometry, TrackState
from follow.ukf.association import InnovationGate, gate_mahalanobis_sq, global_nearest_neighbour
from follow.ukf.models import MeasurementModel, process_noise
from follow.ukf.person import PersonFilter, initial_state_base, project_sigma_points

log = logging.getLogger(__name__)


@dataclass
class _Track:
    track_id: int
    filter: PersonFilter
    created_s: float
    last_seen_s: float
    updates: int = 1
    confirmed: bool = False


def measurement_sigmas_px(camera: CameraModel, config: TrackerConfig) -> tuple[float, float]:
    """Neck and ankle pixel noise at the camera's resolution."""
    scale = camera.image_size[1] / float(config.detection_height_px)
    return config.neck_noise_px * scale, config.ankle_noise_px * scale


def check_observation(
    obs: object, camera: CameraModel, max_outside_px: float
) -> Observation | None:
    """The observation as the tracker may use it: None (with a warning) when it is not an
    Observation or its neck lies outside the image; its ankle is dropped (with a warning)
    when that lies outside the image or on or above the horizon."""
    if not isinstance(obs, Observation):
        log.warning("dropping an observation of type %s", type(obs).__name__)
        return None
    if not np.isfinite(obs.neck_px).all() or not camera.in_image(obs.neck_px, -max_outside_px)[0]:
        log.warning("dropping an observation whose neck %s is outside the image", obs.neck_px)
        return None
    if obs.ankle_px is not None and not camera.in_image(obs.ankle_px, -max_outside_px)[0]:
        log.warning("ignoring an ankle %s outside the image", obs.ankle_px)
        return without_ankle(obs)
    if obs.ankle_px is not None and not camera.is_below_horizon(obs.ankle_px)[0]:
        log.warning("ignoring an ankle %s on or above the horizon (on no floor)", obs.ankle_px)
        return without_ankle(obs)
    return obs


def without_ankle(obs: Observation) -> Observation:
    """The observation with its ankle refused and all else kept (border flag, skeleton).
    A track reports this form, not the caller's, so that no reader (the identifier's
    crop) takes feet the tracker ruled out: without an ankle, they use the track's
    expected ankle pixel instead."""
    return replace(obs, ankle_px=None)


def _position_std_m(track: _Track) -> float:
    """The track's position std along its most uncertain direction on the floor."""
    return math.sqrt(max(np.linalg.eigvalsh(track.filter.cov[:2, :2])[-1], 0.0))


def _single_ankle(obs: Observation) -> bool:
    """Whether the observation's ankle point is one ankle alone (known only when the
    observation carries its skeleton): the skeleton's only ankle, or one of its two
    ankles itself where the other was too faint for the observation (found over the
    detector's peak threshold, under `keypoint_min_confidence`)."""
    sk = obs.skeleton
    if sk is None or not obs.has_ankle:
        return False
    ankles = [sk.keypoints_px[k] for k in (R_ANKLE, L_ANKLE) if sk.has(k)]
    if len(ankles) != 2:
        return len(ankles) == 1
    apart = not np.array_equal(ankles[0], ankles[1])
    return apart and any(np.array_equal(obs.ankle_px, a) for a in ankles)


class PeopleTracker:
    """Tracks people from per-frame neck/ankle observations."""

    def __init__(self, camera: CameraModel, config: TrackerConfig | None = None):
        self.camera = camera
        self.config = config if config is not None else TrackerConfig()
        self._ids = itertools.count(1)
        self._tracks: list[_Track] = []
        self._states: list[TrackState] = []
        self._last_stamp_s: float | None = None
        self._last_robot: Odometry | None = None
        neck_px, ankle_px = measurement_sigmas_px(camera, self.config)
        self._neck_sigma_px, self._ankle_sigma_px = neck_px, ankle_px
        self._focal_px = float(np.sqrt(camera.K[0, 0] * camera.K[1, 1]))

    def _measurement_cov(self, depth_m: float, single_ankle: bool = False) -> np.ndarray:
        """R for a person at `depth_m` from the camera: the detector's pixel noise plus the
        keypoints' own wander around the modelled points (gait, posture), which spans
        more pixels the nearer the person is. One ankle alone strays farther from the
        body than the midpoint of both."""
        cfg = self.config
        z = max(depth_m, cfg.min_projection_depth_m, 1e-3)
        ankle_m = cfg.single_ankle_position_noise_m if single_ankle else cfg.ankle_position_noise_m
        neck = self._neck_sigma_px**2 + (self._focal_px * cfg.neck_position_noise_m / z) ** 2
        ankle = self._ankle_sigma_px**2 + (self._focal_px * ankle_m / z) ** 2
        return np.diag([neck, neck, ankle, ankle])

    def _depth_m(self, mean: np.ndarray, robot: Odometry) -> float:
        """Depth in the camera of a state's ground point."""
        ground = odom_to_base(mean[:2], robot)
        return float(self.camera.base_to_camera(np.array([[ground[0], ground[1], 0.0]]))[0, 2])

    @property
    def tracks(self) -> list[TrackState]:
        """The live tracks as of the last update."""
        return list(self._states)

    # ------------------------------------------------------------------ one frame
    def update(
        self,
        observations: Sequence[Observation],
        stamp_s: float,
        robot: Odometry | None = None,
        odometry_jumps: OdometryJumps | None = None,
    ) -> list[TrackState]:
        """Fold one frame's observations in; returns every live track (tentative and
        confirmed) for this frame.

        `observations` are in pixels of this tracker's camera; `robot` is the robot's pose
        in `odom` at `stamp_s` (None: at the origin); `odometry_jumps` is the log of jumps
        between consecutive odometry samples that `robot` came from (`OdometryJumps`), by
        which the tracks are moved into a new odom frame (`_follow_odometry`). Each
        returned track carries the observation it took this frame as the tracker used it
        (or None): the caller's object where it was used whole, else a copy without the
        ankle it refused (outside the image, on or above the horizon, or another person's
        feet taken by the neck alone), so that readers fall back to the expected ankle;
        and the neck/ankle pixels its updated state projects to, with their covariance
        from the state's uncertainty alone (no measurement noise), e.g. to cut an image
        region.
        """
        if not math.isfinite(stamp_s):
            log.warning("ignoring a frame with a non-finite timestamp %r", stamp_s)
            return self.tracks
        if self._last_stamp_s is not None and stamp_s <= self._last_stamp_s:
            # A frame at the same time as the last one is that frame again (a repeated
            # message): fusing it twice would count one sighting as two.
            same = stamp_s == self._last_stamp_s
            log.warning(
                "ignoring a frame whose timestamp %.3f s %s %.3f s",
                stamp_s,
                "is the same as the last frame's," if same else "goes back from",
                self._last_stamp_s,
            )
            return self.tracks
        previous_stamp_s = self._last_stamp_s
        dt = 0.0 if previous_stamp_s is None else stamp_s - previous_stamp_s
        self._last_stamp_s = stamp_s
        robot = robot if robot is not None else Odometry.origin(stamp_s)
        self._follow_odometry(robot, dt, odometry_jumps)
        self._last_robot = robot
        cfg = self.config
        model = MeasurementModel(
            self.camera,
            robot,
            cfg.ankle_height_m,
            cfg.walking_ankle_lift_m,
            cfg.full_gait_speed_mps,
            cfg.min_projection_depth_m,
            cfg.ankle_height_per_neck_height,
        )

        # The usable form of each observation: the caller's own object where it is
        # usable whole, which is what a track then reports having taken.
        checked = (
            check_observation(o, self.camera, cfg.max_outside_image_px) for o in observations
        )
        obs = [o for o in checked if o is not None]

        # Tracks past their unseen time go before they can take anything: after a long
        # gap (a frozen camera) their spread would let them take anyone, anywhere. A
        # tentative track seen in the last frame has missed none yet: it gets this frame
        # within the confirmed tracks' time, so that frames slower than its own shorter
        # time (a slow CPU) still let a person be confirmed.
        self._tracks = [
            t for t in self._tracks
            if stamp_s - t.last_seen_s <= (
                cfg.max_unseen_s if t.last_seen_s == previous_stamp_s
                else self._max_unseen_s(t))
        ]  # fmt: skip
        Q = process_noise(dt, cfg.accel_noise_mps2, cfg.height_noise_mps)
        for track in self._tracks:
            track.filter.predict(dt, Q)
        project_sigma_points([t.filter for t in self._tracks], model)

        depths = [self._depth_m(t.filter.mean, robot) for t in self._tracks]
        no_noise = np.zeros((4, 4))
        expected = [t.filter.expected_measurement(model, no_noise, True) for t in self._tracks]
        # each track's predicted place and its spread, for both gates on the floor
        positions = np.array([t.filter.mean[:2] for t in self._tracks]).reshape(-1, 2)
        spreads = np.array([_position_std_m(t) for t in self._tracks])
        floor_ok = self._floor_gate(obs, robot, positions, spreads)
        placed = self._placed_for_a_neck(robot, positions, spreads)
        for i, o in enumerate(obs):
            if not o.has_ankle:
                floor_ok[i] &= placed
        pairs, in_some_gate = self._associate(obs, expected, depths, floor_ok)
        used = pairs + self._associate_necks(obs, expected, depths, pairs, in_some_gate,
                                             floor_ok, placed)  # fmt: skip
        by_ankle = self._associate_ankles(obs, expected, depths, used, in_some_gate, floor_ok,
                                          stamp_s)  # fmt: skip

        associated: dict[int, Observation] = {}
        claimed = set()
        for i, j in used + by_ankle:
            track, o = self._tracks[j], obs[i]
            if (i, j) in by_ankle:  # the ankle fallback: the neck is off the height state
                R = self._measurement_cov(depths[j], _single_ankle(o))[2:4, 2:4]
                z, ankle_only = o.ankle_px, True
            else:
                if (i, j) not in pairs:
                    o = without_ankle(o)  # the neck fallback: the feet were someone else's
                R = self._measurement_cov(depths[j], _single_ankle(o))
                z, R = (
                    (np.concatenate([o.neck_px, o.ankle_px]), R)
                    if o.has_ankle
                    else (o.neck_px, R[:2, :2])
                )
                ankle_only = False
            claimed.add(i)
            if track.filter.update(z, R, model, ankle_only):
                track.updates += 1
                track.last_seen_s = stamp_s
                track.confirmed = track.confirmed or track.updates >= cfg.min_updates_to_confirm
                associated[track.track_id] = o

        # An observation inside some track's gate (including tracks started just now) is
        # that track's duplicate or a neighbour's, not a new person.
        born: list[InnovationGate] = []
        gate4 = gate_mahalanobis_sq(4, cfg.gate_chi2_quantile)
        for i, o in enumerate(obs):
            if i in claimed or in_some_gate[i] or not o.has_ankle:
                continue
            z = np.concatenate([o.neck_px, o.ankle_px])
            if any(g.cost(z)[0] <= gate4 for g in born):
                continue
            track = self._start_track(o, stamp_s, robot)
            if track is not None:
                associated[track.track_id] = o
                R4 = self._measurement_cov(self._depth_m(track.filter.mean, robot))
                e = track.filter.expected_measurement(model, R4, True)
                if e is not None:
                    born.append(InnovationGate(*e))

        self._retire(stamp_s, robot, self._unseen_outside_view(expected, stamp_s))
        project_sigma_points([t.filter for t in self._tracks], model)  # the updated ones
        self._states = [self._state(t, model, associated.get(t.track_id)) for t in self._tracks]
        return self.tracks

    # ------------------------------------------------------------------ steps
    def _follow_odometry(self, robot: Odometry, dt: float, jumps: OdometryJumps | None) -> None:
        """Move the tracks by every odometry jump between the last frame's pose and
        `robot`, oldest first. The log's jumps were told between samples tens of ms apart
        (4 rad/s and 3 m/s over that, plus 0.1 rad / 0.2 m): over the frame interval the
        same reset can pass for motion (0.37 rad at 15 fps), and the tracks be left in a
        frame that no longer exists. The frame-interval test (`_robot_jumped`) is for a
        jump the log did not see (no log, or none logged between samples that reach into
        the frame interval); where the log has one the test is not asked as well, so no
        jump is applied twice (also where a frame's pose was taken before the sample after
        a jump came, and the log places that jump a frame early)."""
        last = self._last_robot
        if last is None:
            return
        logged = [] if jumps is None else jumps.between(last.stamp_s, robot.stamp_s)
        for before, after in logged:
            log.warning("odometry jumped from (%.2f, %.2f, %.2f rad) to (%.2f, %.2f, "
                        "%.2f rad) at %.3f s (a reset?): tracks kept where they stood "
                        "relative to the robot", before.x_m, before.y_m, before.yaw_rad,
                        after.x_m, after.y_m, after.yaw_rad, after.stamp_s)  # fmt: skip
            self._follow_odometry_jump(before, after)
        seen = jumps is not None and jumps.seen_near(last.stamp_s, robot.stamp_s)
        if not seen and self._robot_jumped(robot, dt):
            self._follow_odometry_jump(last, robot)

    def _robot_jumped(self, robot: Odometry, dt: float) -> bool:
        """Whether the robot's pose moved farther than it can drive in `dt`: odometry
        reset to the origin, or an estimator's yaw reset. Every track's position is then
        in a frame that no longer exists: left there, each would leap, and the robot be
        sent after a phantom."""
        last = self._last_robot
        if last is None or not pose_jumped(last, robot, dt):
            return False
        log.warning("robot pose jumped from (%.2f, %.2f, %.2f rad) to (%.2f, %.2f, %.2f rad) "
                    "in %.2f s (odometry reset?): tracks kept where they stood relative to "
                    "the robot", last.x_m, last.y_m, last.yaw_rad, robot.x_m, robot.y_m,
                    robot.yaw_rad, dt)  # fmt: skip
        return True

    def _follow_odometry_jump(self, before: Odometry, after: Odometry) -> None:
        """Move every track into the new odom frame, where it stood relative to the
        robot (which cannot have moved far in one frame)."""
        rotation, offset = odom_jump_transform(before, after)
        for track in self._tracks:
            track.filter.move_frame(rotation, offset)

    def _floor_gate(self, obs: list[Observation], robot: Odometry, positions: np.ndarray,
                    spreads: np.ndarray) -> np.ndarray:  # fmt: skip
        """(observations, tracks): False where an observation's ground point (from its
        ankles) lies too far from a track's predicted position (`positions`, with their
        position std `spreads`) for that track to take
        it (`floor_gate_m`, `floor_gate_per_range`, 3 x the track's position std up to
        `floor_gate_max_spread_m`: an unseen track's std grows to over a metre before it
        is retired, and a gate that grew with it took a person 7 m off). The
        pixel gate is no bound for an unseen track near the camera: its sigma points,
        projected as if at `min_projection_depth_m`, spread over the whole image. A
        neck-only observation is not gated here: its ground point depends on the height
        the track assumes, and is ill-conditioned where the camera is near neck height."""
        cfg = self.config
        ok = np.ones((len(obs), len(self._tracks)), dtype=bool)
        if not self._tracks or not any(o.has_ankle for o in obs):
            return ok
        for i, o in enumerate(obs):
            if not o.has_ankle:
                continue
            ground = self.camera.back_project_to_plane(o.ankle_px, cfg.ankle_height_m)
            if not np.isfinite(ground).all():
                continue
            range_m = math.hypot(ground[0], ground[1])
            limit = (cfg.floor_gate_m + cfg.floor_gate_per_range * range_m
                     + np.minimum(3.0 * spreads, cfg.floor_gate_max_spread_m))  # fmt: skip
            distance = np.linalg.norm(positions - base_to_odom(ground[:2], robot), axis=1)
            ok[i] = distance <= limit
        return ok

    def _placed_for_a_neck(self, robot: Odometry, positions: np.ndarray,
                           spreads: np.ndarray) -> np.ndarray:  # fmt: skip
        """Per track: whether its position (`positions`) is known well enough for a neck
        alone to update it (its std, `spreads`, within `neck_only_max_position_std_m` +
        `max_position_std_per_range` x its range). A neck gives a bearing, and a range only
        where the camera looks down on it steeply: a track unseen long enough to have lost
        its place would be drawn along the bearing toward whoever shows a neck there."""
        cfg = self.config
        ranges = np.hypot(positions[:, 0] - robot.x_m, positions[:, 1] - robot.y_m)
        return spreads <= cfg.neck_only_max_position_std_m + cfg.max_position_std_per_range * ranges

    def _associate(
        self,
        obs: list[Observation],
        expected: list[tuple[np.ndarray, np.ndarray] | None],
        depths_m: list[float],
        allowed: np.ndarray | None = None,
    ) -> tuple[list[tuple[int, int]], np.ndarray]:
        """GNN pairs (observation, track), and for each observation whether it fell in
        any track's gate. `expected` holds each track's predicted measurement and its
        covariance without measurement noise; `allowed` (observations, tracks), where
        given, rules pairs out beforehand (`_floor_gate`)."""
        cost = np.full((len(obs), len(expected)), np.inf)
        q = self.config.gate_chi2_quantile
        # Observations by kind: each track's gate for a kind scores them all at once.
        by_kind: dict[str, tuple[list[int], list[np.ndarray]]] = {}
        for i, o in enumerate(obs):
            if o.has_ankle:
                z, kind = (
                    np.concatenate([o.neck_px, o.ankle_px]),
                    "single" if _single_ankle(o) else "both",
                )
            else:
                z, kind = o.neck_px, "neck"
            rows, zs = by_kind.setdefault(kind, ([], []))
            rows.append(i)
            zs.append(z)
        for kind, (rows, zs) in by_kind.items():
            Z = np.array(zs)
            k = Z.shape[1]
            limit = gate_mahalanobis_sq(k, q)
            for j, e in enumerate(expected):
                if e is None:
                    continue
                zp, S0 = e
                R = self._measurement_cov(depths_m[j], kind == "single")
                d2, nll = InnovationGate(zp[:k], S0[:k, :k] + R[:k, :k]).costs(Z)
                cost[rows, j] = np.where(d2 <= limit, nll, np.inf)
        if allowed is not None:
            cost[~allowed] = np.inf
        return global_nearest_neighbour(cost), np.isfinite(cost).any(axis=1)

    def _associate_necks(self, obs, expected, depths_m, pairs, in_some_gate, floor_ok, placed):
        """(observation, track) pairs by the neck alone, for a person whose feet were
        given to someone else (`neck_fallback_association`). A person half hidden behind
        a nearer one is often handed the nearer one's feet by the skeleton assembly: the
        ankle then fits no track, and the observation would start a second track with a
        neck height read from the wrong feet. Such an observation (in no track's gate,
        its ankle in the ankle gate of another track that was given no feet of its own
        this frame) is paired with a track left without an observation whose neck gate
        holds its neck. A whole person of their own (a stranger stepping in front of a
        hidden target) has feet no footless track expects, and starts a track as before;
        so does one whose feet stand outside the floor gate (`floor_ok`, observations x
        tracks) of every footless track whose ankle gate holds them: an unseen track near
        the camera has an ankle gate over the whole image."""
        if not self.config.neck_fallback_association:
            return []
        taken = {j for _, j in pairs}
        footed = {j for i, j in pairs if obs[i].has_ankle}
        footless = [j for j in range(len(expected)) if j not in footed]
        rows = [i for i, o in enumerate(obs) if o.has_ankle and not in_some_gate[i]]
        cols = [j for j in range(len(expected))
                if j not in taken and expected[j] is not None and placed[j]]  # fmt: skip
        if not rows or not cols or len(footless) < 2:
            return []
        necks = [Observation(obs[i].neck_px) for i in rows]
        found, _ = self._associate(necks, [expected[j] for j in cols], [depths_m[j] for j in cols])
        out = []
        for a, b in found:
            i, j = rows[a], cols[b]
            owners = [k for k in footless if k != j and floor_ok[i, k]]
            if self._feet_expected_by(obs[i], owners, expected, depths_m):
                out.append((i, j))
        return out

    def _associate_ankles(self, obs, expected, depths_m, used, in_some_gate, floor_ok, stamp_s):
        """(observation, track) pairs by the ankle alone, for a person whose neck moved
        faster than the height state follows (`ankle_fallback_association`). A person
        who crouches lowers the neck 0.5 m in half a second, and raises it as fast: the
        neck+ankle observation then falls out of their track's gate and started a new
        track (1 -> 5 ids over one crouch, simulated), which the identifier had to
        re-identify. Such an observation (in no track's gate) is paired with a confirmed
        track seen within `tentative_max_unseen_s` and left without an observation this
        frame, whose ankle gate holds its ankle, within that track's floor gate, and whose
        neck gate across the image holds its neck (above the same feet); the neck's
        height is not asked, since it is what changed."""
        if not self.config.ankle_fallback_association:
            return []
        cfg = self.config
        taken = {j for _, j in used}
        claimed = {i for i, _ in used}
        rows = [i for i, o in enumerate(obs)
                if o.has_ankle and i not in claimed and not in_some_gate[i]]  # fmt: skip
        cols = [j for j, e in enumerate(expected)
                if j not in taken and e is not None and self._tracks[j].confirmed
                and stamp_s - self._tracks[j].last_seen_s <= cfg.tentative_max_unseen_s]  # fmt: skip
        if not rows or not cols:
            return []
        ankle_limit = gate_mahalanobis_sq(2, cfg.gate_chi2_quantile)
        across_limit = gate_mahalanobis_sq(1, cfg.gate_chi2_quantile)
        cost = np.full((len(rows), len(cols)), np.inf)
        for b, j in enumerate(cols):
            zp, S0 = expected[j]
            for a, i in enumerate(rows):
                o = obs[i]
                if not floor_ok[i, j]:
                    continue
                R = self._measurement_cov(depths_m[j], _single_ankle(o))
                across = (o.neck_px[0] - zp[0]) ** 2 / (S0[0, 0] + R[0, 0])
                d2, nll = self._ankle_gate(o, expected[j], depths_m[j]).cost(o.ankle_px)
                if d2 <= ankle_limit and across <= across_limit:
                    cost[a, b] = nll
        return [(rows[a], cols[b]) for a, b in global_nearest_neighbour(cost)]

    def _feet_expected_by(self, o: Observation, tracks: list[int], expected, depths_m) -> bool:
        """Whether the observation's ankle lies in the ankle gate of one of `tracks`."""
        limit = gate_mahalanobis_sq(2, self.config.gate_chi2_quantile)
        for k in tracks:
            e = expected[k]
            if e is None or len(e[0]) < 4:
                continue
            if self._ankle_gate(o, e, depths_m[k]).cost(o.ankle_px)[0] <= limit:
                return True
        return False

    def _ankle_gate(self, o: Observation, expected, depth_m: float) -> InnovationGate:
        """The ankle gate of a track (its expected neck+ankle measurement and covariance,
        without measurement noise) for the observation `o`: its ankle noise added."""
        zp, S0 = expected
        R = self._measurement_cov(depth_m, _single_ankle(o))
        return InnovationGate(zp[2:4], S0[2:4, 2:4] + R[2:4, 2:4])

    def _start_track(self, o: Observation, stamp_s: float, robot: Odometry) -> _Track | None:
        cfg = self.config
        ground = self.camera.ground_point(o.ankle_px)
        depth_m = float("inf") if ground is None else self._depth_m(ground, Odometry.origin())
        R = self._measurement_cov(depth_m, _single_ankle(o))
        init = initial_state_base(
            self.camera, o.neck_px, o.ankle_px, math.sqrt(R[0, 0]), math.sqrt(R[2, 2]), cfg
        )
        if init is None:
            log.warning(
                "no track from an impossible observation (neck %s, ankle %s)",
                o.neck_px,
                o.ankle_px,
            )
            return None
        xyh, P3 = init
        range_m = math.hypot(xyh[0], xyh[1])
        std_m = math.sqrt(max(np.linalg.eigvalsh(P3[:2, :2])[-1], 0.0))
        if std_m > self._max_position_std_m(range_m):
            # `_retire` would delete it in this very update; started, its gate (wide as
            # its spread) would keep a nearer person in the same image column from
            # starting a track, frame after frame.
            log.debug("no track for a person %.1f m off: position std %.1f m", range_m, std_m)
            return None
        mean = np.zeros(5)
        mean[:2] = base_to_odom(xyh[:2], robot)
        mean[4] = xyh[2]
        cov = np.zeros((5, 5))
        T = np.zeros((3, 3))
        T[:2, :2] = rotation_2d(robot.yaw_rad)
        T[2, 2] = 1.0
        P3 = T @ P3 @ T.T
        idx = [0, 1, 4]
        cov[np.ix_(idx, idx)] = P3
        cov[2, 2] = cov[3, 3] = cfg.init_velocity_std_mps**2
        track = _Track(next(self._ids), PersonFilter(mean, cov, cfg), stamp_s, stamp_s)
        track.confirmed = track.updates >= cfg.min_updates_to_confirm
        self._tracks.append(track)
        return track

    def _unseen_outside_view(self, expected, stamp_s: float) -> set[int]:
        """Ids of the tracks not seen at `stamp_s` whose predicted neck (`expected`, one
        per track that existed before this frame's births) lies outside the image, or in
        no pixel (behind the camera); none looked for where `max_unseen_outside_view_s`
        could not shorten a track's life."""
        if self.config.max_unseen_outside_view_s >= self.config.max_unseen_s:
            return set()
        return {
            t.track_id for t, e in zip(self._tracks[: len(expected)], expected, strict=True)
            if t.last_seen_s < stamp_s and (e is None or not self.camera.in_image(e[0][:2])[0])
        }  # fmt: skip

    def _max_unseen_s(self, track: _Track) -> float:
        cfg = self.config
        return cfg.max_unseen_s if track.confirmed else cfg.tentative_max_unseen_s

    def _max_position_std_m(self, range_m: float) -> float:
        """The position std past which a track at `range_m` is too uncertain to keep (far
        people are always uncertain along the viewing ray)."""
        cfg = self.config
        return cfg.max_position_std_m + cfg.max_position_std_per_range * range_m

    def _retire(self, stamp_s: float, robot: Odometry, outside_view: set[int]) -> None:
        """Delete the tracks unseen for too long (shorter while predicted outside the
        image, `outside_view`), too uncertain, or broken."""
        cfg = self.config
        keep = []
        for t in self._tracks:
            unseen_s = stamp_s - t.last_seen_s
            limit_s = self._max_unseen_s(t)
            if t.track_id in outside_view:
                limit_s = min(limit_s, cfg.max_unseen_outside_view_s)
            mean = t.filter.mean
            range_m = math.hypot(mean[0] - robot.x_m, mean[1] - robot.y_m)
            pos_std = _position_std_m(t)
            if (unseen_s > limit_s or pos_std > self._max_position_std_m(range_m)
                    or not np.isfinite(mean).all()):  # fmt: skip
                log.debug(
                    "track %d retired (unseen %.2f s, std %.2f m)", t.track_id, unseen_s, pos_std
                )
                continue
            keep.append(t)
        self._tracks = keep

    def _state(self, t: _Track, model: MeasurementModel, obs: Observation | None) -> TrackState:
        zero = np.zeros((4, 4))
        e = t.filter.expected_measurement(model, zero, True)
        neck = neck_cov = ankle = ankle_cov = None
        if e is not None:
            zp, S = e
            neck, neck_cov, ankle, ankle_cov = zp[:2], S[:2, :2], zp[2:], S[2:, 2:]
        return TrackState(
            track_id=t.track_id,
            mean=t.filter.mean.copy(),
            cov=t.filter.cov.copy(),
            confirmed=t.confirmed,
            last_seen_s=t.last_seen_s,
            expected_neck_px=neck,
            expected_neck_cov=neck_cov,
            expected_ankle_px=ankle,
            expected_ankle_cov=ankle_cov,
            observation=obs,
        )
