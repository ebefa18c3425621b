"""ROS 2 messages the node publishes, built from one FrameResult."""

from __future__ import annotations

import json
import math

import numpy as np
from builtin_interfaces.msg import Duration, Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, Pose, PoseArray, PoseStamped, Quaternion, Twist
from std_msgs.msg import ColorRGBA, Header, String
from visualization_msgs.msg import Marker, MarkerArray

from follow.freshness import is_fresh
from follow.pipeline import FrameResult
from follow.rosmsg import quaternion_of_yaw, stamp_fields
from follow.types import TargetStatus, TrackState, VelocityCommand

TARGET_RGBA = (0.9, 0.1, 0.1, 0.9)
CONFIRMED_RGBA = (0.1, 0.4, 0.9, 0.7)
TENTATIVE_RGBA = (0.6, 0.6, 0.6, 0.5)
ELLIPSE_SIGMAS = 2.0  # the covariance ellipse drawn at 2 standard deviations
MIN_HEADING_SPEED_MPS = 0.1  # slower tracks carry no heading (identity orientation)
MARKER_LIFETIME_S = 1.0  # markers of a node that stopped publishing fade out


def header(stamp: float | Time, frame_id: str) -> Header:
    """A Header at `stamp`: seconds, or the input message's own Time, passed through so
    that outputs carry their image's stamp to the nanosecond (float seconds are ~0.2 us
    apart at today's epoch, too coarse for exact-time matching)."""
    if isinstance(stamp, Time):
        return Header(stamp=Time(sec=stamp.sec, nanosec=stamp.nanosec), frame_id=frame_id)
    return Header(stamp=Time(**stamp_fields(stamp)), frame_id=frame_id)


def _result_header(result: FrameResult, frame_id: str, stamp: Time | None) -> Header:
    """A Header for what is published about a result: at `stamp` (its image's own), else
    at the result's stamp."""
    return header(result.stamp_s if stamp is None else stamp, frame_id)


def track_pose(track: TrackState, z_m: float = 0.0) -> Pose:
    """A track's ground position, facing where it walks."""
    vx, vy = track.velocity_mps
    yaw = math.atan2(vy, vx) if math.hypot(vx, vy) >= MIN_HEADING_SPEED_MPS else 0.0
    x, y = (float(v) for v in track.position_m)
    return Pose(position=Point(x=x, y=y, z=z_m), orientation=Quaternion(**quaternion_of_yaw(yaw)))


def target_track(result: FrameResult) -> TrackState | None:
    """The target's track when the identifier is tracking it, else None."""
    if result.target.status != TargetStatus.TRACKING:
        return None
    return result.target_track


def target_pose(result: FrameResult, frame_id: str, stamp: Time | None = None,
                max_unseen_s: float = math.inf) -> PoseStamped | None:  # fmt: skip
    """The target's pose, or None when not tracked or last observed more than
    `max_unseen_s` before the frame: lost, as the controller takes it (the tracker
    predicts a hidden track on, and each new stamp would make that pose look fresh)."""
    track = target_track(result)
    if track is None or not is_fresh(result.stamp_s, track.last_seen_s, max_unseen_s):
        return None
    return PoseStamped(header=_result_header(result, frame_id, stamp), pose=track_pose(track))


def tracks_pose_array(result: FrameResult, frame_id: str, stamp: Time | None = None) -> PoseArray:
    return PoseArray(header=_result_header(result, frame_id, stamp),
                     poses=[track_pose(t) for t in result.tracks])  # fmt: skip


def _colour(track: TrackState, target_id: int | None) -> ColorRGBA:
    rgba = (TARGET_RGBA if track.track_id == target_id
            else CONFIRMED_RGBA if track.confirmed else TENTATIVE_RGBA)  # fmt: skip
    return ColorRGBA(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def _ellipse(track: TrackState) -> tuple[float, float, float]:
    """Axis lengths (diameters) and heading of the position covariance's ellipse."""
    values, vectors = np.linalg.eigh(track.cov[:2, :2])
    values = np.clip(values, 1e-6, None)
    major = vectors[:, 1]
    return (2 * ELLIPSE_SIGMAS * math.sqrt(values[1]), 2 * ELLIPSE_SIGMAS * math.sqrt(values[0]),
            math.atan2(major[1], major[0]))  # fmt: skip


def track_markers(result: FrameResult, frame_id: str, stamp: Time | None = None) -> MarkerArray:
    """Per track: a body (its height), its 2-sigma ground ellipse and a label; the
    target in red. Marker ids are the track ids."""
    head = _result_header(result, frame_id, stamp)
    lifetime = Duration(sec=int(MARKER_LIFETIME_S), nanosec=int(MARKER_LIFETIME_S % 1 * 1e9))
    target_id = target_track(result).track_id if target_track(result) is not None else None
    markers = [Marker(header=head, action=Marker.DELETEALL)]
    for t in result.tracks:
        colour, height = _colour(t, target_id), max(t.neck_height_m, 0.1)
        body = Marker(header=head, ns="people", id=t.track_id, type=Marker.CYLINDER,
                      pose=track_pose(t, height / 2), color=colour, lifetime=lifetime)  # fmt: skip
        body.scale.x = body.scale.y = 0.4
        body.scale.z = height
        major, minor, heading = _ellipse(t)
        ellipse = Marker(header=head, ns="covariance", id=t.track_id, type=Marker.CYLINDER,
                         color=colour, lifetime=lifetime)  # fmt: skip
        ellipse.pose.position = Point(x=float(t.position_m[0]), y=float(t.position_m[1]), z=0.01)
        ellipse.pose.orientation = Quaternion(**quaternion_of_yaw(heading))
        ellipse.scale.x, ellipse.scale.y, ellipse.scale.z = major, minor, 0.02
        label = Marker(header=head, ns="labels", id=t.track_id, type=Marker.TEXT_VIEW_FACING,
                       pose=track_pose(t, height + 0.3), color=colour, lifetime=lifetime,
                       text=f"{t.track_id}  {height:.2f} m")  # fmt: skip
        label.scale.z = 0.3
        markers += [body, ellipse, label]
    return MarkerArray(markers=markers)


def target_state(result: FrameResult, identifier: str, following: bool) -> String:
    """The identifier's state as JSON (status, target id, per-track confidences) and the
    frame's stage latencies."""
    return String(data=json.dumps({
        "stamp_s": result.stamp_s, "frame": result.frame_index,
        "status": result.target.status.value, "target_id": result.target.target_id,
        "confidences": {str(k): round(float(v), 4) for k, v in result.target.confidences.items()},
        "identifier": identifier, "following": following,
        "timing_ms": {k: round(float(v), 3) for k, v in result.timing_ms.items()},
    }))  # fmt: skip


def twist(command: VelocityCommand) -> Twist:
    msg = Twist()
    msg.linear.x = float(command.forward_mps)
    msg.angular.z = float(command.yaw_rate_radps)
    return msg


def diagnostics(stamp_s: float, name: str, values: dict[str, str], ok: bool, message: str,
                failed: bool = False):  # fmt: skip
    """One DiagnosticStatus: OK, WARN where not `ok`, ERROR where something `failed`."""
    level = DiagnosticStatus.ERROR if failed else (
        DiagnosticStatus.OK if ok else DiagnosticStatus.WARN)  # fmt: skip
    status = DiagnosticStatus(
        level=level, name=name,
        message=message, hardware_id="follow",
        values=[KeyValue(key=k, value=v) for k, v in values.items()],
    )  # fmt: skip
    return DiagnosticArray(header=header(stamp_s, ""), status=[status])
