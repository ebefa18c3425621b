"""What the states of the target state machine share, and one frame as they see it.

The `IdentityContext` outlives the states: the learnt appearance model (boosted
classifier and/or re-id gallery), the track the user selected, how many frames each
track was seen in, and the timers and last whereabouts of the target that the
re-identification rules read. A `FrameTracks` is one frame's tracks; its appearances and
confidences are computed once, when a state first looks at them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from follow.ccf.roi import Roi, covered_fraction, person_boxes, track_rois
from follow.config import IdentifyConfig
from follow.frames import odom_jump_transform
from follow.identify.appearance import Appearance, AppearanceModel, reid_rule_applies
from follow.odometry_buffer import pose_jumped
from follow.types import Odometry, TrackState


@dataclass
class FrameTracks:
    """One frame: the image, the tracks by id, and (once looked at) their appearances."""

    image_bgr: np.ndarray
    tracks: list[TrackState]
    stamp_s: float
    robot: Odometry | None
    by_id: dict[int, TrackState]
    looked: bool = False
    rois: dict[int, Roi] = field(default_factory=dict)  # tracks observed this frame
    boxes: dict[int, Roi] = field(default_factory=dict)  # and those hidden behind others
    appearances: dict[int, Appearance] = field(default_factory=dict)
    confidences: dict[int, float] = field(default_factory=dict)  # empty until looked at

    def unscored_beside(self, track_id: int) -> bool:
        """Whether another track seen in the frame has no confidence (no crop: too small,
        cut by the image's edge): nobody can be said to lead a person not compared."""
        return any(
            i != track_id and t.observation is not None and i not in self.confidences
            for i, t in self.by_id.items()
        )


class IdentityContext:
    """The appearance model, the selected id, and what is known of the target's past."""

    def __init__(self, config: IdentifyConfig, model: AppearanceModel):
        self.config = config
        self.model = model
        self.requested_id: int | None = None
        self.observed_frames: dict[int, int] = {}  # track id -> frames it was seen in
        self.last_frame_s: float | None = None  # the stamp of the last frame handed over
        self.frame_gap_s = 0.0  # the time since the frame before this one, if any
        self.last_robot: Odometry | None = None  # the robot's pose in the last frame
        # how far odometry jumps have moved the odom frame so far (3x3, homogeneous)
        self.odom_moved = np.eye(3)
        self.forget()

    def forget(self) -> None:
        """Forget the target and everything learnt (the frame counts of tracks stay)."""
        self.model.reset()
        self.identity_risk_s = -math.inf  # when the tracker last could have swapped it
        self.vouched_s = -math.inf  # the last frame whose crop confirmed the identity
        self.last_target_position_m: np.ndarray | None = None  # odom frame
        self.last_target_s = -math.inf
        self.last_target_seen_s = -math.inf  # when the target was last observed
        self.target_height: tuple[float, float] | None = None  # neck height mean, var
        self.seen_apart: set[int] = set()  # tracks seen beside the target: other people
        self.rejected: set[int] = set()  # tracks whose stature failed probation

    def count_observations(self, by_id: dict[int, TrackState]) -> None:
        """One more frame for each track observed in it; tracks gone are dropped."""
        self.observed_frames = {
            i: self.observed_frames.get(i, 0) + int(t.observation is not None)
            for i, t in by_id.items()
        }

    def note_frame(self, stamp_s: float, robot: Odometry | None = None) -> None:
        """A new frame, once a frame whatever the state: the time since the frame before
        it (none for the first one, or the first after the identifier is reset). A stall
        of perception hands over no frame at all, and the target's track is matched again
        in the next one: `note_target` takes such a gap as the track unseen for as long,
        and re-identification ends every candidate's run of passing frames across it.

        An odometry jump (a reset to the origin, an estimator's yaw reset) moves the
        target's last position into the new odom frame, where it stood relative to the
        robot, as the tracker moves every track: left in the old frame, re-identification
        would look for the target where it never was."""
        first = self.last_frame_s is None
        self.frame_gap_s = 0.0 if first else stamp_s - self.last_frame_s
        self.last_frame_s = stamp_s
        robot = robot if robot is not None else Odometry.origin(stamp_s)
        before = self.last_robot
        self.last_robot = robot
        if first or before is None or not pose_jumped(before, robot, self.frame_gap_s):
            return
        move = np.eye(3)
        move[:2, :2], move[:2, 2] = odom_jump_transform(before, robot)
        self.odom_moved = move @ self.odom_moved
        if self.last_target_position_m is not None:
            self.last_target_position_m = _moved(move, self.last_target_position_m)

    # ------------------------------------------------------------------ the frame
    def look(self, frame: FrameTracks, only: int | None = None, embed: bool = True) -> None:
        """Cut and describe every observed track's crop, and score it (once a frame).
        Confidences are those of the model before this frame is learnt.

        The re-id network (~5-7 ms a person on a laptop core) runs only where it decides
        something: with `only`, on that track alone (the target, while it is learnt and
        checked); with `embed` false, on nobody (re-identification, until a track passes
        every test that needs no embedding); otherwise on everyone, completing what an
        earlier look this frame left out. A track without an embedding is scored by the
        classifier alone."""
        if frame.looked:
            if embed and only is None and any(self.model.lacks_embedding(a)
                                              for a in frame.appearances.values()):  # fmt: skip
                ids = list(frame.appearances)
                completed = self.model.complete(
                    frame.image_bgr, [frame.rois[i] for i in ids],
                    [frame.appearances[i] for i in ids],
                )  # fmt: skip
                frame.appearances = dict(zip(ids, completed, strict=True))
                self._score(frame)
            return
        frame.looked = True
        h, w = frame.image_bgr.shape[:2]
        frame.rois = track_rois(frame.tracks, (w, h), self.config)
        ids = list(frame.rois)
        wanted = [embed and (only is None or i == only) for i in ids]
        described = self.model.describe(frame.image_bgr, [frame.rois[i] for i in ids], wanted)
        frame.appearances = dict(zip(ids, described, strict=True))
        frame.boxes = person_boxes(frame.tracks, frame.rois, (w, h), self.config)
        self._score(frame)

    def rescore(self, frame: FrameTracks) -> None:
        """Score the frame's appearances again: the model changed since it was looked at
        (a candidate's teaching undone)."""
        if frame.looked:
            self._score(frame)

    def _score(self, frame: FrameTracks) -> None:
        scores = self._by_track(frame, self.model.confidence) if self.model.ready else None
        frame.confidences = scores or dict.fromkeys(frame.appearances, 0.0)

    @staticmethod
    def _by_track(frame: FrameTracks, score) -> dict[int, float] | None:
        """track id -> `score` (a model method over appearances) of each described
        track; None where the model has no such score."""
        ids = list(frame.appearances)
        scores = score([frame.appearances[i] for i in ids])
        if scores is None:
            return None
        return {i: float(s) for i, s in zip(ids, scores, strict=True)}

    def classifier_confidences(self, frame: FrameTracks) -> dict[int, float] | None:
        """Each described track's confidence by the boosted classifier alone, where it
        is one of two cues that must agree (None otherwise)."""
        return self._by_track(frame, self.model.classifier_confidence)

    def part_distances(self, frame: FrameTracks) -> dict[int, float] | None:
        """Each described track's distance from the target's colours in its least alike
        part, torso or legs (None before any was learnt)."""
        return self._by_track(frame, self.model.part_distances)

    def parts_match(self, distances: dict[int, float] | None, track_id: int) -> bool:
        """Whether the track's torso and legs are each within `reid_part_colour_distance`
        of the target's colours (`part_distances` of this frame; True before any were
        learnt)."""
        if distances is None:
            return True
        return bool(distances[track_id] <= self.config.reid_part_colour_distance)

    def similarities(self, frame: FrameTracks) -> dict[int, float] | None:
        """Each described track's re-id similarity to the target's gallery (None
        without a re-id cue or an empty gallery)."""
        return self._by_track(frame, self.model.similarity)

    # ------------------------------------------------------------------ the target
    def note_target(self, target_id: int, frame: FrameTracks) -> None:
        """Remember where the target is, when it was seen, and whether the tracker could
        be swapping it with someone this frame (another track near it on the floor or
        touching its box in the image, or its track unseen, or no frame handed over, for
        `identity_risk_unseen_s`: `note_frame`; a target first named this frame was
        chosen from it, past any gap). What a frame that vouches for the identity adds
        is `note_stature` and `note_seen_apart` (`vouches`); one that is learnt,
        `note_vouched`."""
        track = frame.by_id[target_id]
        named_before = math.isfinite(self.last_target_s)
        self.last_target_position_m = track.position_m.copy()
        self.last_target_s = frame.stamp_s
        if track.observation is not None:
            self.last_target_seen_s = frame.stamp_s
        unseen_s = frame.stamp_s - track.last_seen_s
        if named_before:  # no frame in the gap: the target was unseen all along it
            unseen_s = max(unseen_s, self.frame_gap_s)
        swappable = self.swappable(target_id, frame)
        if swappable or unseen_s > self.config.identity_risk_unseen_s:
            self.identity_risk_s = frame.stamp_s
        self.seen_apart -= swappable

    def note_vouched(self, frame: FrameTracks) -> None:
        """This frame's crop confirmed the target's identity (it is learnt): trust can
        come back once the risk is `identity_trust_s` old (`identity_trusted`)."""
        self.vouched_s = frame.stamp_s

    def forget_departed(self, frame: FrameTracks) -> None:
        """Drop the marks of tracks the tracker no longer has (its ids are never reused):
        over an hour of passers-by they would only grow."""
        self.seen_apart &= frame.by_id.keys()
        self.rejected &= frame.by_id.keys()

    def note_stature(self, target_id: int, frame: FrameTracks) -> None:
        """Take the target's height from this frame, unless its track is unseen or another
        person covers its crop (`crop_shows_another`: its skeleton may then have been
        given that person's feet, and nothing is learnt of its appearance either)."""
        track = frame.by_id[target_id]
        if track.observation is not None and not self.crop_shows_another(target_id, frame):
            self.target_height = (track.neck_height_m, float(track.cov[4, 4]))

    def note_seen_apart(self, target_id: int, frame: FrameTracks) -> None:
        """On a frame that confirmed the target's identity: two people seen at once are
        two people, where the tracker cannot be confusing them, so each other track seen
        and scored is never the target come back (`seen_apart`). One seen without a crop
        was compared with nobody: after a swap it may carry the target."""
        if frame.by_id[target_id].observation is None:
            return
        swappable = self.swappable(target_id, frame)
        self.seen_apart |= {i for i in frame.confidences if i != target_id} - swappable

    def swappable(self, target_id: int, frame: FrameTracks) -> set[int]:
        """The tracks the tracker could be confusing with the target this frame: within
        `identity_risk_distance_m` of it on the floor, or their boxes touching its."""
        return self._near_target(target_id, frame) | self._touching_target(target_id, frame)

    def whereabouts(self) -> tuple:
        """Where and when the target was last named and seen, when its identity was last
        at risk, and who was seen beside it: what `note_target` moves, besides its
        height, to be put back with `restore`."""
        return (self.last_target_position_m, self.last_target_s, self.last_target_seen_s,
                self.identity_risk_s, self.vouched_s, set(self.seen_apart),
                self.odom_moved.copy())  # fmt: skip

    def restore(self, whereabouts: tuple) -> None:
        """Put back `whereabouts`, the position moved by any odometry jump since."""
        (position, self.last_target_s, self.last_target_seen_s, self.identity_risk_s,
         self.vouched_s, seen_apart, odom_moved) = whereabouts  # fmt: skip
        self.seen_apart = set(seen_apart)
        since = self.odom_moved @ np.linalg.inv(odom_moved)
        self.last_target_position_m = None if position is None else _moved(since, position)

    def _near_target(self, target_id: int, frame: FrameTracks) -> set[int]:
        """The other tracks within `identity_risk_distance_m` of the target on the floor."""
        target = frame.by_id[target_id]
        limit = self.config.identity_risk_distance_m
        return {i for i, t in frame.by_id.items()
                if i != target_id and float(np.linalg.norm(t.position_m - target.position_m))
                <= limit}  # fmt: skip

    @staticmethod
    def _touching_target(target_id: int, frame: FrameTracks) -> set[int]:
        """The other tracks whose box overlaps the target's in the image (a person
        passing in front): the tracker could swap them too."""
        target_box = frame.boxes.get(target_id)
        if target_box is None:
            return set()
        return {i for i, box in frame.boxes.items()
                if i != target_id and covered_fraction(target_box, box) > 0.0}  # fmt: skip

    def seen_beside_target(self, track_id: int) -> bool:
        """Whether the track was seen at once with the confirmed target, apart from it
        (`reid_excludes_seen_beside`)."""
        return self.config.reid_excludes_seen_beside and track_id in self.seen_apart

    def identity_trusted(self, stamp_s: float) -> bool:
        """Whether nobody could have swapped the target's track for `identity_trust_s`,
        and a crop has confirmed who it is since the last moment somebody could: time
        alone judges nothing (a target seen without a crop, too small or covered, for as
        long may have been swapped unexamined)."""
        return (stamp_s - self.identity_risk_s > self.config.identity_trust_s
                and self.vouched_s > self.identity_risk_s)  # fmt: skip

    def vouches(self, target_id: int, frame: FrameTracks, confidence: float) -> bool:
        """Whether a frame that keeps the target confirms who its track carries: any
        frame while its identity is trusted (`identity_trusted`); while at risk only one
        where no other track seen in it scores higher than the target's, nor goes
        unscored (`FrameTracks.unscored_beside`). After a crossing or a gap the tracker
        may carry a stranger on the target's track, the target on another (or on a new
        one): such a frame must give neither the target's stature (the stranger's height
        would become the bar the real target is refused by) nor marks of people seen
        beside it (the real target among them), whatever the identifier. Whether it is
        learnt is `may_learn`. The others are scored as the target is, re-id included: a
        look that embedded the target alone left them scored by the classifier, which is
        not the target's scale (`confidence`, the target's score when the frame was first
        looked at, is that of the same model)."""
        if self.identity_trusted(frame.stamp_s):
            return True
        self.look(frame)  # embeds those left out, and scores everyone again alike
        if frame.unscored_beside(target_id):
            return False
        confidence = frame.confidences.get(target_id, confidence)
        return all(c < confidence for i, c in frame.confidences.items() if i != target_id)

    def may_learn(self, vouched: bool) -> bool:
        """Whether a frame that keeps the target is learnt, given whether it `vouches`
        for the target: a frame at risk that does not is learnt only where
        `learn_needs_lead_at_risk` does not apply ("with_reid", the default, applies
        beside a re-id cue only; "always"; "never"). Learning a swapped-in stranger
        teaches the model the stranger, and the next frames trust it; but the boosted
        classifier alone scores others too unsteadily to be outscored by them as
        evidence (docs/identification.md), so without re-id it learns on."""
        if vouched:
            return True
        return not reid_rule_applies(self.config.learn_needs_lead_at_risk, self.model.has_reid)

    def crop_shows_another(self, target_id: int, frame: FrameTracks) -> bool:
        """Whether another person's box covers more than `max_learning_overlap` of the
        target's: its crop then shows (part of) someone else. (False for a target
        without a box this frame: nothing to judge.)"""
        target_box = frame.boxes.get(target_id)
        if target_box is None:
            return False
        limit = self.config.max_learning_overlap
        return any(
            covered_fraction(target_box, box) > limit
            for i, box in frame.boxes.items()
            if i != target_id
        )

    def learn(self, target_id: int, frame: FrameTracks) -> bool:
        """Learn the frame unless the target's crop shows someone else; whether it did.
        Too few other people are topped up with recoloured copies of the target; its
        mirrored crop is learnt as a positive too (`mirrored_positives`)."""
        if self.crop_shows_another(target_id, frame):
            return False
        positives = [frame.appearances[target_id]]
        negatives = [a for i, a in frame.appearances.items()
                     if i != target_id and not self._behind_target(i, target_id, frame)]  # fmt: skip
        missing = self.config.min_negatives_per_update - len(negatives)
        crop = self.model.crop(frame.image_bgr, frame.rois[target_id])
        synthetic = self.model.synthetic_negatives(crop, missing) if missing > 0 else []
        self.model.learn(positives, negatives, synthetic, self.model.mirrored_positives(crop))
        return True

    def _behind_target(self, track_id: int, target_id: int, frame: FrameTracks) -> bool:
        """Whether the track stands behind the target (its feet higher in the image) with
        more than `max_learning_overlap` of its box covered by the target's: its crop then
        shows the target, which must not be learnt as another person. (One standing in
        front hides the target instead, and its crop shows itself.)"""
        box, target_box = frame.boxes[track_id], frame.boxes[target_id]  # boxes hold every ROI
        return (box[3] < target_box[3]
                and covered_fraction(box, target_box) > self.config.max_learning_overlap)  # fmt: skip

    # ------------------------------------------------------------ who may be it
    def established(self, track: TrackState) -> bool:
        """Whether a track may become the target: confirmed by the tracker, seen now, and
        in enough frames."""
        return (
            track.confirmed
            and track.observation is not None
            and self.observed_frames.get(track.track_id, 0) >= self.config.min_target_observations
        )

    def reachable(self, track: TrackState, stamp_s: float) -> bool:
        """Whether the target could have walked to `track` since it was last named."""
        if self.last_target_position_m is None:
            return True
        reach_m = self.config.reid_reach_m + self.config.reid_reach_speed_mps * max(
            0.0, stamp_s - self.last_target_s
        )
        return float(np.linalg.norm(track.position_m - self.last_target_position_m)) <= reach_m

    def same_height(self, track: TrackState) -> bool:
        """Whether the track's estimated neck height could be the target's: within the
        tolerance for posture and calibration and the two estimates' spread, independent
        errors, so added in quadrature."""
        if self.target_height is None:
            return True
        height, var = self.target_height
        combined_std = math.sqrt(max(0.0, var) + max(0.0, float(track.cov[4, 4])))
        spread = self.config.reid_height_tolerance_stds * combined_std
        limit = math.hypot(self.config.reid_height_tolerance_m, spread)
        return abs(track.neck_height_m - height) <= limit

    def _strictness(self, stamp_s: float) -> float:
        """0 just after the target was last seen, rising to 1 at `reid_strict_after_s`."""
        if not math.isfinite(self.last_target_seen_s):
            return 1.0
        gone_s = max(0.0, stamp_s - self.last_target_seen_s)
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


def _moved(move: np.ndarray, position_m: np.ndarray) -> np.ndarray:
    """A floor position moved by a 3x3 homogeneous transform."""
    return move[:2, :2] @ position_m + move[:2, 2]
