"""Image-space trackers that users would otherwise pick, run on the same skeletons as
ours: norfair tracking the keypoints, and ByteTrack (supervision) on skeleton boxes.
Each track's foot point (bottom centre of its box, i.e. at the ankle keypoints) is
back-projected to the plane of the ankles, as our own tracker's are, so that all methods
are scored on the ground plane alike."""

from __future__ import annotations

import warnings

import numpy as np

from follow.camera import CameraModel
from follow.types import Skeleton


def skeleton_box(s: Skeleton, min_confidence: float) -> np.ndarray | None:
    """(x0, y0, x1, y1) around the keypoints found with at least `min_confidence`."""
    ok = np.isfinite(s.keypoints_px).all(axis=1) & (s.confidences >= min_confidence)
    if ok.sum() < 2:
        return None
    pts = s.keypoints_px[ok]
    x0, y0 = pts.min(axis=0)
    x1, y1 = pts.max(axis=0)
    pad = 0.1 * max(y1 - y0, 1.0)
    return np.array([x0 - pad, y0 - pad, x1 + pad, y1])


def foot_point_px(box: np.ndarray) -> np.ndarray:
    return np.array([(box[0] + box[2]) / 2.0, box[3]])


def _to_ground(camera: CameraModel, feet_px: list[np.ndarray], ankle_height_m: float) -> np.ndarray:
    if not feet_px:
        return np.empty((0, 2))
    return camera.back_project_to_plane(np.array(feet_px), ankle_height_m)[:, :2]


class NorfairKeypointTracker:
    """norfair on all 18 keypoints, matched by the number of nearby confident keypoints
    (the pose-tracking recipe from norfair's own OpenPose example)."""

    def __init__(self, camera: CameraModel, min_confidence: float = 0.1,
                 keypoint_match_px: float | None = None, hit_counter_max: int = 15,
                 ankle_height_m: float = 0.0):  # fmt: skip
        import norfair

        self._norfair = norfair
        self.camera = camera
        self.ankle_height_m = ankle_height_m
        self.min_confidence = min_confidence
        match_px = keypoint_match_px or camera.image_size[1] / 18.0

        def keypoints_distance(detection, tracked) -> float:
            d = np.linalg.norm(detection.points - tracked.estimate, axis=1)
            matches = np.count_nonzero(
                (d < match_px)
                & (detection.scores > min_confidence)
                & (tracked.last_detection.scores > min_confidence)
            )
            return 1.0 / (1.0 + matches)

        self._tracker = norfair.Tracker(
            distance_function=keypoints_distance,
            distance_threshold=0.34,  # at least two keypoints agree
            detection_threshold=min_confidence,
            hit_counter_max=hit_counter_max,
            initialization_delay=2,
        )

    def update(self, skeletons: list[Skeleton]) -> tuple[list[int], np.ndarray]:
        detections = []
        for s in skeletons:
            ok = np.isfinite(s.keypoints_px).all(axis=1)
            if ok.sum() < 2:
                continue
            pts = np.where(ok[:, None], s.keypoints_px, s.keypoints_px[ok].mean(axis=0))
            detections.append(
                self._norfair.Detection(points=pts, scores=np.where(ok, s.confidences, 0.0))
            )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            objects = self._tracker.update(detections)
        ids, feet = [], []
        for obj in objects:
            live = obj.last_detection.scores > self.min_confidence
            if live.sum() < 2:
                continue
            pts = obj.estimate[live]
            box = np.array([*pts.min(axis=0), *pts.max(axis=0)])
            ids.append(int(obj.id))
            feet.append(foot_point_px(box))
        return ids, _to_ground(self.camera, feet, self.ankle_height_m)


class ByteTrackBoxTracker:
    """ByteTrack (supervision) on the boxes around each skeleton's keypoints."""

    def __init__(self, camera: CameraModel, frame_rate_hz: float, min_confidence: float = 0.1,
                 ankle_height_m: float = 0.0):  # fmt: skip
        import supervision as sv

        self._sv = sv
        self.camera = camera
        self.ankle_height_m = ankle_height_m
        self.min_confidence = min_confidence
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            self._tracker = sv.ByteTrack(frame_rate=frame_rate_hz, track_activation_threshold=0.2)

    def update(self, skeletons: list[Skeleton]) -> tuple[list[int], np.ndarray]:
        boxes, scores = [], []
        for s in skeletons:
            box = skeleton_box(s, self.min_confidence)
            if box is not None:
                boxes.append(box)
                ok = s.confidences >= self.min_confidence
                scores.append(float(s.confidences[ok].mean()))
        sv = self._sv
        if boxes:
            dets = sv.Detections(
                xyxy=np.array(boxes, np.float32),
                confidence=np.array(scores, np.float32),
                class_id=np.zeros(len(boxes), int),
            )
        else:
            dets = sv.Detections.empty()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            tracked = self._tracker.update_with_detections(dets)
        ids = [int(i) for i in (tracked.tracker_id if tracked.tracker_id is not None else [])]
        feet = [foot_point_px(b) for b in tracked.xyxy]
        return ids, _to_ground(self.camera, feet, self.ankle_height_m)
