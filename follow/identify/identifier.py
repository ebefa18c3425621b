"""The target state machine: which track is the person to follow.

initial -> initial training -> tracking <-> re-identification

- initial: the target is the track the user selected, else the nearest confirmed track
  in front of the robot within `max_initial_distance_m`.
- initial training: the target's appearance is learnt as positive and every other
  observed track's as negative for `initial_training_frames` frames in which it is seen.
- tracking: learning goes on while the target's confidence stays at or above
  `id_switch_confidence`; below it, or when the target's track is lost, the identity is
  no longer trusted and the state becomes re-identification. A low confidence is not
  acted on while another person covers the target's crop (it then describes them, not
  the target): the tracker's identity is kept until the crop is clear again.
- re-identification: nothing is learnt; a track whose confidence is at least
  `reid_confidence` and ahead of every other seen track's by `reid_margin`, in
  `reid_frames` consecutive frames in which it is seen, and that stands where the target
  could have walked since it was last the target (`reid_reach_m` + `reid_reach_speed_mps`
  per second from its track's last position), becomes the target again. With a re-id
  cue the evidence must also be absolute: the candidate's similarity to the target's
  gallery reaches `reid_accept_similarity` in each of those frames. Both bars rise the
  longer the target is gone (to `reid_strict_similarity` and `reid_strict_confidence`
  at `reid_strict_after_s`): the more strangers have passed by, the more evidence.
  Clothes can match where stature does not: the candidate's estimated neck height must
  agree with the target's last estimate (`reid_height_tolerance_m` plus twice their
  combined std). A lead over nobody (a stranger
  alone in view) is no evidence.

Only a track seen in the current frame, and in `min_target_observations` frames so far,
can become the target. Online boosting never learns from the target alone: a frame with
too few other people is topped up with recoloured copies of the target's crop.

A track's appearance is cut from the observation associated with it in this frame; a
track without one (occluded, missed) has no appearance and no confidence this frame.
Nothing is learnt from a crop that shows two people: while another person's box (seen,
or predicted by the tracker) covers more than `max_learning_overlap` of the target's
box the frame is not learnt (neither the target nor the others). Learning during a crossing would teach the target's appearance as the other
person's and the other way round, which later makes the wrong person look like the target.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

import numpy as np

from follow.ccf.features import FeatureExtractor, check_image
from follow.ccf.roi import roi_from_keypoints
from follow.config import IdentifyConfig
from follow.frames import odom_to_base
from follow.identify.appearance import Appearance, AppearanceModel
from follow.identify.reid import ReidEmbedder
from follow.types import InvalidInput, Odometry, TargetEstimate, TargetStatus, TrackState

log = logging.getLogger(__name__)

R_HIP, L_HIP = 8, 11
HIP_MIN_CONFIDENCE = 0.0


class TargetIdentifier:
    """Learns the target's appearance online and says, per frame, which track it is."""

    def __init__(
        self,
        config: IdentifyConfig,
        extractor: FeatureExtractor | None,
        reid: ReidEmbedder | None = None,
    ):
        if config.initial_training_frames < 1 or config.reid_frames < 1:
            raise ValueError("initial_training_frames and reid_frames must be >= 1")
        if config.reid_confidence < config.id_switch_confidence:
            raise ValueError(
                f"reid_confidence ({config.reid_confidence}) must not be below "
                f"id_switch_confidence ({config.id_switch_confidence})"
            )
        if config.min_target_observations < 1 or config.min_negatives_per_update < 0:
            raise ValueError("min_target_observations must be >= 1, min_negatives_per_update >= 0")
        if not (
            -1.0 <= config.reid_accept_similarity <= config.reid_strict_similarity <= 1.0
            and config.reid_confidence <= config.reid_strict_confidence <= 1.0
            and config.reid_strict_after_s > 0.0
        ):
            raise ValueError(
                "need -1 <= reid_accept_similarity <= reid_strict_similarity <= 1, "
                "reid_confidence <= reid_strict_confidence <= 1 and reid_strict_after_s > 0, "
                f"got {config.reid_accept_similarity}, {config.reid_strict_similarity}, "
                f"{config.reid_strict_confidence}, {config.reid_strict_after_s}"
            )
        if config.reid_reach_m < 0.0 or config.reid_reach_speed_mps < 0.0:
            raise ValueError("reid_reach_m and reid_reach_speed_mps must be >= 0")
        if config.reid_margin < 0.0 or not 0.0 <= config.max_learning_overlap <= 1.0:
            raise ValueError(
                f"reid_margin ({config.reid_margin}) must be >= 0 and max_learning_overlap "
                f"({config.max_learning_overlap}) in [0, 1]"
            )
        self.config = config
        self.model = AppearanceModel(config, extractor, reid)
        self._requested_id: int | None = None
        self.reset()

    @property
    def name(self) -> str:
        return self.model.name

    def reset(self) -> None:
        """Forget the target and everything learnt; a selected id stays requested."""
        self.model.reset()
        self.status = TargetStatus.INITIAL
        self.target_id: int | None = None
        self._identity_risk_s = -math.inf  # when the tracker last could have swapped it
        self._training_frames = 0
        self._reid_streaks: dict[int, int] = {}
        self._last_target_position_m: np.ndarray | None = None  # odom frame
        self._last_target_s = -math.inf
        self._last_target_seen_s = -math.inf  # when the target was last observed
        self._target_height: tuple[float, float] | None = None  # neck height mean, var
        self._observed_frames: dict[int, int] = {}  # track id -> frames it was seen in
        self._rois: dict = {}  # this frame's ROIs by track id

    def select_target(self, track_id: int) -> None:
        """Follow this track id: learning starts afresh on the next frame it is present."""
        self._requested_id = int(track_id)
        self.reset()

    # ------------------------------------------------------------------ appearance
    def rois(self, tracks: Sequence[TrackState], image_size: tuple[int, int]) -> dict:
        """track id -> ROI for the tracks with an observation this frame and a usable box."""
        out = {}
        for track in tracks:
            obs = track.observation
            if obs is None:
                continue
            ankle = obs.ankle_px if obs.ankle_px is not None else track.expected_ankle_px
            roi = roi_from_keypoints(
                obs.neck_px, ankle, image_size, self.config, hip_px=_hip_of(obs)
            )
            if roi is not None:
                out[track.track_id] = roi
        return out

    def person_boxes(
        self, tracks: Sequence[TrackState], rois: dict, image_size: tuple[int, int]
    ) -> dict:
        """track id -> the box a person occupies: its ROI when seen, else the box of the
        tracker's expected neck and ankle pixels (a person hidden behind another)."""
        out = dict(rois)
        for track in tracks:
            if track.track_id in out or track.expected_neck_px is None:
                continue
            if track.expected_ankle_px is None:
                continue
            roi = roi_from_keypoints(
                track.expected_neck_px, track.expected_ankle_px, image_size, self.config
            )
            if roi is not None:
                out[track.track_id] = roi
        return out

    def _appearances(self, image_bgr, tracks) -> tuple[dict[int, Appearance], dict]:
        h, w = image_bgr.shape[:2]
        rois = self.rois(tracks, (w, h))
        self._rois = rois
        ids = list(rois)
        described = self.model.describe(image_bgr, [rois[i] for i in ids])
        return dict(zip(ids, described, strict=True)), self.person_boxes(tracks, rois, (w, h))

    # -------------------------------------------------------------------- per frame
    def update(
        self,
        image_bgr: np.ndarray,
        tracks: Sequence[TrackState],
        stamp_s: float,
        robot: Odometry | None = None,
    ) -> TargetEstimate:
        """One frame: the tracks of the tracker (with this frame's observations)."""
        check_image(image_bgr, "identifier image")
        if not math.isfinite(stamp_s):
            raise InvalidInput(f"identifier stamp_s is not finite: {stamp_s}")
        by_id = {t.track_id: t for t in tracks}
        if len(by_id) != len(tracks):
            raise InvalidInput("identifier: duplicate track ids in one frame")
        self._reid_streaks = {k: v for k, v in self._reid_streaks.items() if k in by_id}
        self._observed_frames = {
            i: self._observed_frames.get(i, 0) + int(t.observation is not None)
            for i, t in by_id.items()
        }

        if self.status == TargetStatus.INITIAL:
            self.target_id = self._choose_initial(tracks, robot)
            if self.target_id is None:
                return TargetEstimate(self.status, None, {}, stamp_s)
            log.info("target: track %d chosen, initial training", self.target_id)
            self.status = TargetStatus.INITIAL_TRAINING
            self._training_frames = 0

        if self.target_id is not None and self.target_id not in by_id:
            if self.status == TargetStatus.INITIAL_TRAINING:
                log.info("target track %d lost during initial training", self.target_id)
                observed = self._observed_frames
                self.reset()
                self._observed_frames = observed
                return TargetEstimate(self.status, None, {}, stamp_s)
            log.info("target track %d lost: re-identification", self.target_id)
            self._enter_reidentification()

        if self.target_id is not None:
            self._last_target_position_m = by_id[self.target_id].position_m.copy()
            self._last_target_s = stamp_s
            if by_id[self.target_id].observation is not None:
                self._last_target_seen_s = stamp_s
                track = by_id[self.target_id]
                self._target_height = (track.neck_height_m, float(track.cov[4, 4]))
        appearances, boxes = self._appearances(image_bgr, tracks)
        if self.target_id is not None and self._identity_at_risk(by_id, stamp_s):
            self._identity_risk_s = stamp_s
        ids = list(appearances)
        scores = (
            self.model.confidence([appearances[i] for i in ids])
            if self.model.ready
            else np.zeros(len(ids))
        )
        confidences = {i: float(c) for i, c in zip(ids, scores, strict=True)}

        if self.status == TargetStatus.INITIAL_TRAINING:
            if self.target_id in appearances and self._learn(image_bgr, appearances, boxes):
                self._training_frames += 1
                if self._training_frames >= self.config.initial_training_frames:
                    log.info("target track %d learnt: tracking", self.target_id)
                    self.status = TargetStatus.TRACKING
        elif self.status == TargetStatus.TRACKING:
            if self.target_id in confidences:
                low = confidences[self.target_id] < self.config.id_switch_confidence
                trusted = stamp_s - self._identity_risk_s > self.config.identity_trust_s
                if low and trusted:
                    log.debug(
                        "target track %d confidence %.2f is low, but nobody came near it: "
                        "not learnt", self.target_id, confidences[self.target_id],
                    )  # fmt: skip
                elif low and self._crop_shows_another(boxes):
                    log.debug(
                        "target track %d confidence %.2f is low while another person "
                        "covers it: judged once it is clear", self.target_id,
                        confidences[self.target_id],
                    )  # fmt: skip
                elif low:
                    log.info(
                        "target track %d confidence %.2f below %.2f: re-identification",
                        self.target_id, confidences[self.target_id],
                        self.config.id_switch_confidence,
                    )  # fmt: skip
                    self._enter_reidentification()
                else:
                    self._learn(image_bgr, appearances, boxes)
        if self.status == TargetStatus.REIDENTIFICATION:
            similarities = self.model.similarity([appearances[i] for i in ids])
            if similarities is not None:
                similarities = dict(zip(ids, similarities.tolist(), strict=True))
            self._reidentify(confidences, similarities, by_id, stamp_s)
        seen = self.target_id in by_id and by_id[self.target_id].observation is not None
        return TargetEstimate(self.status, self.target_id, confidences, stamp_s, seen)

    # ----------------------------------------------------------------------- states
    def _choose_initial(self, tracks: Sequence[TrackState], robot: Odometry | None) -> int | None:
        if self._requested_id is not None:
            present = any(
                t.track_id == self._requested_id and t.observation is not None for t in tracks
            )
            return self._requested_id if present else None
        robot = robot if robot is not None else Odometry.origin()
        best, best_distance = None, self.config.max_initial_distance_m
        for track in tracks:
            if not (track.confirmed and self._established(track)):
                continue
            x, y = odom_to_base(track.position_m, robot)
            distance = math.hypot(x, y)
            if x > 0.0 and distance <= best_distance:
                best, best_distance = track.track_id, distance
        return best

    def _identity_at_risk(self, by_id: dict, stamp_s: float) -> bool:
        """Whether the tracker could be swapping the target with someone this frame: its
        track has gone unseen for a while, or another track stands near it on the floor."""
        target = by_id[self.target_id]
        if stamp_s - target.last_seen_s > self.config.identity_risk_unseen_s:
            return True
        limit = self.config.identity_risk_distance_m
        return any(float(np.linalg.norm(t.position_m - target.position_m)) <= limit
                   for i, t in by_id.items() if i != self.target_id)  # fmt: skip

    def _crop_shows_another(self, boxes: dict) -> bool:
        """Whether another person's box covers more than `max_learning_overlap` of the
        target's: its crop then shows (part of) someone else."""
        target_box = boxes[self.target_id]
        limit = self.config.max_learning_overlap
        return any(
            covered_fraction(target_box, box) > limit
            for i, box in boxes.items()
            if i != self.target_id
        )

    def _established(self, track: TrackState) -> bool:
        """Whether a track may become the target: seen now, and in enough frames."""
        return (
            track.observation is not None
            and self._observed_frames.get(track.track_id, 0) >= self.config.min_target_observations
        )

    def _learn(self, image_bgr, appearances: dict[int, Appearance], boxes: dict) -> bool:
        """Learn the frame unless the target's crop shows someone else; whether it did.
        Too few other people are topped up with recoloured copies of the target."""
        if self._crop_shows_another(boxes):
            return False
        positives = [appearances[self.target_id]]
        negatives = [a for i, a in appearances.items() if i != self.target_id]
        missing = self.config.min_negatives_per_update - len(negatives)
        synthetic = (
            self.model.synthetic_negatives(
                self.model.crop(image_bgr, self._rois[self.target_id]), missing
            )
            if missing > 0
            else []
        )
        self.model.learn(positives, negatives, synthetic)
        return True

    def _enter_reidentification(self) -> None:
        self.status = TargetStatus.REIDENTIFICATION
        self.target_id = None
        self._reid_streaks = {}

    def _reachable(self, track: TrackState, stamp_s: float) -> bool:
        """Whether the target could have walked to `track` since it was last named."""
        if self._last_target_position_m is None:
            return True
        reach_m = self.config.reid_reach_m + self.config.reid_reach_speed_mps * max(
            0.0, stamp_s - self._last_target_s
        )
        return float(np.linalg.norm(track.position_m - self._last_target_position_m)) <= reach_m

    def _strictness(self, stamp_s: float) -> float:
        """0 just after the target was last seen, rising to 1 at `reid_strict_after_s`."""
        if not math.isfinite(self._last_target_seen_s):
            return 1.0
        gone_s = max(0.0, stamp_s - self._last_target_seen_s)
        return min(1.0, gone_s / self.config.reid_strict_after_s)

    def required_similarity(self, stamp_s: float) -> float:
        """The re-id similarity a candidate needs, rising with the time the target has
        been unseen."""
        cfg = self.config
        span = cfg.reid_strict_similarity - cfg.reid_accept_similarity
        return cfg.reid_accept_similarity + self._strictness(stamp_s) * span

    def required_confidence(self, stamp_s: float) -> float:
        """The confidence a candidate needs, rising the same way."""
        cfg = self.config
        span = cfg.reid_strict_confidence - cfg.reid_confidence
        return cfg.reid_confidence + self._strictness(stamp_s) * span

    def _same_height(self, track: TrackState) -> bool:
        """Whether the track's estimated neck height could be the target's."""
        if self._target_height is None:
            return True
        height, var = self._target_height
        spread = 2.0 * math.sqrt(max(0.0, var) + max(0.0, float(track.cov[4, 4])))
        limit = self.config.reid_height_tolerance_m + spread
        return abs(track.neck_height_m - height) <= limit

    def _reidentify(
        self,
        confidences: dict[int, float],
        similarities: dict[int, float] | None,
        by_id: dict,
        stamp_s: float,
    ) -> None:
        bar = self.required_similarity(stamp_s)
        needed = self.required_confidence(stamp_s)
        for track_id, confidence in confidences.items():
            runner_up = max((c for i, c in confidences.items() if i != track_id), default=-1.0)
            if (
                confidence >= needed
                and confidence - runner_up >= self.config.reid_margin
                and (similarities is None or similarities[track_id] >= bar)
                and self._established(by_id[track_id])
                and self._reachable(by_id[track_id], stamp_s)
                and self._same_height(by_id[track_id])
            ):
                self._reid_streaks[track_id] = self._reid_streaks.get(track_id, 0) + 1
            else:
                self._reid_streaks[track_id] = 0
        ready = [
            i for i, n in self._reid_streaks.items()
            if n >= self.config.reid_frames and i in confidences
        ]  # fmt: skip
        if ready:
            self.target_id = max(ready, key=lambda i: confidences[i])
            self.status = TargetStatus.TRACKING
            self._reid_streaks = {}
            log.info("target re-identified as track %d", self.target_id)


def covered_fraction(box, other) -> float:
    """Fraction of `box`'s area (x0, y0, x1, y1) that `other` covers."""
    w = min(box[2], other[2]) - max(box[0], other[0])
    h = min(box[3], other[3]) - max(box[1], other[1])
    area = (box[2] - box[0]) * (box[3] - box[1])
    return max(0, w) * max(0, h) / area if area > 0 else 0.0


def _hip_of(observation) -> np.ndarray | None:
    """Mean of the detected hips of the observation's skeleton, if any."""
    skeleton = observation.skeleton
    if skeleton is None:
        return None
    hips = [skeleton.keypoints_px[k] for k in (R_HIP, L_HIP) if skeleton.has(k, HIP_MIN_CONFIDENCE)]
    return np.mean(hips, axis=0) if hips else None
