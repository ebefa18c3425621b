"""Where the camera sees a standing person straight ahead of the robot.

The tracker ranges a person from their neck and ankle pixels. Near the robot the ankles
leave the bottom of the image (then only the neck gives range), nearer still the neck
leaves the top (then the person is not seen at all); a camera pitched steeply down loses
far people's necks instead. This works out, from the camera file alone, the distances
along the robot's x axis at which a person of the tracker's default neck height has their
neck and their ankles in view, so that `follow run` and the ROS 2 node can say before
the robot moves whether the following distance and the farthest person lie where the
camera can range them.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from follow.pose.preprocess import NETWORK_STRIDE_PX

log = logging.getLogger(__name__)

NEAREST_M = 0.2  # nearer than this a person is in the robot's footprint
STEP_M = 0.01


@dataclass(frozen=True)
class InView:
    """Distances (m, along `base` x) over which a point is in view: `from_m` to
    `until_m`, or None for both when it is never in view from NEAREST_M to
    `checked_until_m`."""

    from_m: float | None
    until_m: float | None
    checked_until_m: float
    # Where the point is at `checked_until_m` when out of view there: "above" or "below"
    # the image (or beside it: ""), which way a tilt would bring it in.
    farthest_off: str = ""

    def covers(self, distance_m: float) -> bool:
        return self.from_m is not None and self.from_m <= distance_m <= self.until_m

    def describe(self) -> str:
        if self.from_m is None:
            return f"never (checked {NEAREST_M:g}-{self.checked_until_m:g} m)"
        if self.until_m >= self.checked_until_m - STEP_M / 2:
            return f"from {self.from_m:.2f} m"
        return f"from {self.from_m:.2f} m to {self.until_m:.2f} m"


def edge_margins_px(camera, pose_config) -> tuple[float, float]:
    """How near the image's top and bottom edges keypoints are dropped (`[pose]
    top_edge_margin_cells`, `bottom_edge_margin_cells`, in the camera's pixels) at the
    input height the detector runs for this camera (its full height: the people-sized
    input's smaller ones widen the margins while everyone in view is near)."""
    from follow.pose.input_size import camera_input_height_px

    cell_px = NETWORK_STRIDE_PX * camera.image_size[1] / camera_input_height_px(pose_config, camera)
    top, bottom = pose_config.top_edge_margin_cells, pose_config.bottom_edge_margin_cells
    return top * cell_px, bottom * cell_px


def in_view(camera, point_height_m: float, farthest_m: float, margins_px: tuple[float, float]
            ) -> InView:  # fmt: skip
    """The distances along `base` x at which a point `point_height_m` over the floor is in
    the image, at least `margins_px` (top, bottom) from its top and bottom edges (the
    nearest stretch when the camera sees it over more than one)."""
    distances = np.arange(NEAREST_M, farthest_m + STEP_M / 2, STEP_M)
    points = np.column_stack(
        [distances, np.zeros_like(distances), np.full_like(distances, point_height_m)]
    )
    uv = camera.project(points)
    _, height = camera.image_size
    seen = (
        camera.in_image(uv)
        & (uv[:, 1] >= -0.5 + margins_px[0])
        & (uv[:, 1] <= height - 0.5 - margins_px[1])
    )
    off = ""
    if not seen[-1] and np.isfinite(uv[-1]).all():
        off = "above" if uv[-1, 1] < -0.5 + margins_px[0] else (
            "below" if uv[-1, 1] > height - 0.5 - margins_px[1] else "")  # fmt: skip
    if not seen.any():
        return InView(None, None, farthest_m, off)
    first = int(np.argmax(seen))
    unseen_after = np.flatnonzero(~seen[first:])
    last = first + (int(unseen_after[0]) - 1 if unseen_after.size else len(seen) - 1 - first)
    return InView(round(float(distances[first]), 2), round(float(distances[last]), 2),
                  farthest_m, off)  # fmt: skip


def person_in_view(camera, config) -> dict[str, InView]:
    """Where a standing person of the tracker's default neck height, straight ahead, has
    their neck and their ankles in view (`config` a Config)."""
    from follow.ukf.models import population_ankle_height_m

    margins = edge_margins_px(camera, config.pose)
    farthest = max(config.pose.far_person_distance_m, config.control.following_distance_m)
    return {
        "neck": in_view(camera, config.tracker.default_neck_height_m, farthest, margins),
        "ankles": in_view(camera, population_ankle_height_m(config.tracker), farthest, margins),
    }


def view_warnings(views: dict[str, InView], config) -> list[str]:
    """What `person_in_view`'s `views` mean for following, one sentence per problem: the
    target unseen or ranged by the neck alone at the following distance, the farthest
    person out of view."""
    neck, ankles = views["neck"], views["ankles"]
    follow_m = config.control.following_distance_m
    far_m = config.pose.far_person_distance_m
    if neck.from_m is None and ankles.from_m is None:  # no tilt would fix what follows
        return [
            f"a standing person straight ahead is never in view ({NEAREST_M:g}-"
            f"{neck.checked_until_m:g} m): check the camera file's pose (yaw_rad turned "
            "away from the robot's forward direction, pitch_rad far too steep, or height_m "
            "or x_m far off)"
        ]
    out = []
    if not neck.covers(follow_m):
        out.append(
            f"at the following distance ({follow_m:g} m) a standing person's neck is out of "
            f"view (in view {neck.describe()}): the target is lost there and the "
            "robot stops; raise [control] following_distance_m or tilt the camera"
        )
    elif not ankles.covers(follow_m):
        out.append(
            f"at the following distance ({follow_m:g} m) a standing person's ankles are out "
            f"of view (in view {ankles.describe()}): the target is ranged from the "
            "neck alone there, less surely; raise [control] following_distance_m or pitch "
            "the camera down"
        )
    if not neck.covers(far_m):
        tilt = {"below": ": pitch the camera down", "above": ": pitch the camera up"}
        out.append(
            f"a standing person {far_m:g} m away ([pose] far_person_distance_m) has their "
            f"neck out of view (in view {neck.describe()})"
            + tilt.get(neck.farthest_off, "")
        )
    return out


def log_person_in_view(camera, config) -> None:
    """Logs where a standing person straight ahead is in view, and warns about what
    `view_warnings` finds."""
    views = person_in_view(camera, config)
    log.info(
        "a standing person straight ahead has the neck in view %s, the ankles %s",
        views["neck"].describe(), views["ankles"].describe(),
    )  # fmt: skip
    for warning in view_warnings(views, config):
        log.warning("%s", warning)
