"""The target state machine, one small class per state.

initial -> initial training -> tracking -> re-identification -> probation -> tracking
                                                      ^-- stature disagrees --'

Each state's `update(context, frame)` returns the state for the next frame: itself, or
its successor. A state that hands over within a frame (a target chosen, a target lost)
returns its successor's `update` of the same frame. What the states share (the
appearance model, timers, the target's last whereabouts) lives in the
`IdentityContext`; docs/identification.md draws the states and the rules between them.
"""

from __future__ import annotations

import logging
import math

from follow.frames import odom_to_base
from follow.identify.context import FrameTracks, IdentityContext
from follow.types import Odometry, TargetStatus

log = logging.getLogger(__name__)


class State:
    """One state of the target state machine: its status and target track, if any."""

    status: TargetStatus
    target_id: int | None = None

    def update(self, context: IdentityContext, frame: FrameTracks) -> State:
        raise NotImplementedError


class Initial(State):
    """No target yet. The target is the track the user selected (seen now, and confirmed
    by the tracker), else the nearest confirmed track in front of the robot within
    `max_initial_distance_m` seen now and in `min_target_observations` frames so far."""

    status = TargetStatus.INITIAL

    def update(self, context: IdentityContext, frame: FrameTracks) -> State:
        target_id = self._choose(context, frame)
        if target_id is None:
            return self
        log.info("target: track %d chosen, initial training", target_id)
        return InitialTraining(target_id).update(context, frame)

    @staticmethod
    def _choose(context: IdentityContext, frame: FrameTracks) -> int | None:
        requested = context.requested_id
        if requested is not None:  # a real person, by the tracker's word: no ghost track
            track = frame.by_id.get(requested)
            seen = track is not None and track.confirmed and track.observation is not None
            return requested if seen else None
        robot = frame.robot if frame.robot is not None else Odometry.origin()
        best, best_distance = None, context.config.max_initial_distance_m
        for track in frame.tracks:
            if not (track.confirmed and context.established(track)):
                continue
            x, y = odom_to_base(track.position_m, robot)
            distance = math.hypot(x, y)
            if x > 0.0 and distance <= best_distance:
                best, best_distance = track.track_id, distance
        return best


class InitialTraining(State):
    """The target is learnt as positive and every other observed track as negative, in
    `initial_training_frames` frames in a row in which it is seen, its crop shows nobody
    else and nobody walks near it (the tracker could swap them there, and the model would
    learn the other person as the target from its first frames); someone coming near
    drops what was learnt before (the track may carry the other person after, and a model
    of two people takes either for the target) and learning starts again once they are
    gone; so does its track going unseen, or no frame coming, for longer than
    `identity_risk_unseen_s` (the tracker may have moved the track onto someone else);
    losing its track before then starts over, from the frame it is lost in."""

    status = TargetStatus.INITIAL_TRAINING

    def __init__(self, target_id: int):
        self.target_id = target_id
        self.frames_learnt = 0
        self.crowded = False  # someone walks near the target: learning waits
        self.waited = False  # the wait was logged
        self.slow_said = False  # frames too far apart to learn from: said once

    def update(self, context: IdentityContext, frame: FrameTracks) -> State:
        if self.target_id not in frame.by_id:
            if context.requested_id == self.target_id:  # never another: the user chose it
                log.warning("selected track %d lost before it was learnt: waiting for it; "
                            "select a track again to follow someone", self.target_id)  # fmt: skip
            else:
                log.info("target track %d lost during initial training", self.target_id)
            context.forget()
            return Initial().update(context, frame)
        # Since the frame the target was last seen in, a stall of perception included.
        unseen_s = frame.stamp_s - context.last_target_seen_s
        if unseen_s > context.config.identity_risk_unseen_s and self.frames_learnt:
            log.info("target track %d unseen for %.1f s: learning it starts again (%d "
                     "frame(s) learnt before are dropped)", self.target_id, unseen_s,
                     self.frames_learnt)  # fmt: skip
            self._drop_learnt(context)
            self._say_if_too_slow(context)
        context.look(frame, only=self.target_id)
        crowded = bool(context.swappable(self.target_id, frame))
        if crowded and not self.crowded:  # said once; again (someone at the limit) quietly
            log.log(logging.DEBUG if self.waited else logging.INFO,
                    "target track %d has someone beside it: learning it waits until nobody "
                    "is within %.1f m of it or overlaps it in the image%s", self.target_id,
                    context.config.identity_risk_distance_m,
                    f", and starts again ({self.frames_learnt} frame(s) learnt before are "
                    "dropped)" if self.frames_learnt else "")  # fmt: skip
            self.waited = True
        if crowded and self.frames_learnt:
            self._drop_learnt(context)
        self.crowded = crowded
        learnt = (
            self.target_id in frame.appearances
            and not crowded
            and context.learn(self.target_id, frame)
        )
        context.note_target(self.target_id, frame)
        context.note_stature(self.target_id, frame)
        if learnt:
            context.note_vouched(frame)
            context.note_seen_apart(self.target_id, frame)
            self.frames_learnt += 1
            if self.frames_learnt >= context.config.initial_training_frames:
                log.info("target track %d learnt: tracking", self.target_id)
                return Tracking(self.target_id)
        return self

    def _say_if_too_slow(self, context: IdentityContext) -> None:
        """Frames further apart than `identity_risk_unseen_s` each count as a stall, so a
        perception that slow never learns a target: the robot stays stopped, and the
        user is told why (once), not left waiting."""
        if self.slow_said or context.frame_gap_s <= context.config.identity_risk_unseen_s:
            return
        self.slow_said = True
        log.warning("frames come %.1f s apart, more than identity_risk_unseen_s (%.1f s): "
                    "the target cannot be learnt from frames this far apart (a slow or "
                    "overloaded host?); nothing is followed", context.frame_gap_s,
                    context.config.identity_risk_unseen_s)  # fmt: skip

    def _drop_learnt(self, context: IdentityContext) -> None:
        """Forget the frames learnt so far: the track may carry someone else now."""
        context.forget()  # the model, the stature and who was seen beside it
        self.frames_learnt = 0


class Tracking(State):
    """Following the target's track, learning while its confidence stays at or above
    `id_switch_confidence`. Below it the identity is no longer trusted, unless nobody
    came near the target for `identity_trust_s` and a learnt frame confirmed it since
    (it turned round) or another person covers its crop (judged once the crop is
    clear); losing the track also ends it.

    The target's stature is taken from the track learnt in initial training only
    (`reidentified` False): a re-identified track may be a stranger who passed every
    test (the twin in the target's clothes), and its height must not become the bar
    that the real target, coming back, is then refused by."""

    status = TargetStatus.TRACKING

    def __init__(self, target_id: int, reidentified: bool = False):
        self.target_id = target_id
        self.reidentified = reidentified

    @property
    def notes_stature(self) -> bool:
        """Whether the track's height is the target's."""
        return not self.reidentified

    def update(self, context: IdentityContext, frame: FrameTracks) -> State:
        if self._keeps(context, frame):
            return self
        return Reidentification().update(context, frame)

    def _keeps(self, context: IdentityContext, frame: FrameTracks) -> bool:
        """Whether the track stays the target after this frame (learnt where confirmed)."""
        if self.target_id not in frame.by_id:
            log.info("target track %d lost: re-identification", self.target_id)
            return False
        context.look(frame, only=self.target_id)
        confidence = frame.confidences.get(self.target_id)
        threshold = context.config.id_switch_confidence
        context.note_target(self.target_id, frame)
        if confidence is None:  # not observed this frame: nothing to judge or learn
            # (a frame without a crop, at the image's edge, gives a height where nobody
            # could have swapped the track)
            if self.notes_stature and context.identity_trusted(frame.stamp_s):
                context.note_stature(self.target_id, frame)
            return True
        if confidence >= threshold:
            self._confirmed(context, frame, confidence)
            return True
        if self._excused_as_turn(context, frame.stamp_s):
            log.debug(
                "target track %d confidence %.2f is low, but nobody came near it: not learnt",
                self.target_id, confidence,
            )  # fmt: skip
            return True
        if context.crop_shows_another(self.target_id, frame):
            log.debug(
                "target track %d confidence %.2f is low while another person covers it: "
                "judged once it is clear", self.target_id, confidence,
            )  # fmt: skip
            return True
        log.info(
            "target track %d confidence %.2f below %.2f: re-identification",
            self.target_id, confidence, threshold,
        )  # fmt: skip
        return False

    def _confirmed(self, context: IdentityContext, frame: FrameTracks, confidence: float) -> None:
        """A frame whose confidence keeps the target. Only one that vouches for who the
        track is (`IdentityContext.vouches`) gives its stature and marks those seen
        beside it: after a crossing, one in which someone else scores higher may carry a
        stranger the tracker swapped in, whose height must not become the bar, nor may
        the target (on another track) be taken for someone seen beside it. Learning it
        is `may_learn`'s to decide (without re-id such a frame is still learnt)."""
        vouched = context.vouches(self.target_id, frame, confidence)
        if vouched:
            if self.notes_stature:
                context.note_stature(self.target_id, frame)
            context.note_seen_apart(self.target_id, frame)
        if context.may_learn(vouched) and context.learn(self.target_id, frame):
            context.note_vouched(frame)

    def _excused_as_turn(self, context: IdentityContext, stamp_s: float) -> bool:
        """Whether a low confidence is taken for the target turning round: nobody could
        have swapped its track for `identity_trust_s`."""
        return context.identity_trusted(stamp_s)


class Reidentification(State):
    """The target is unknown and nothing is learnt. A track becomes the target again
    after `reid_frames` consecutive frames in which it passes every test of `_placed`,
    `_classifier_agrees` and `_passes`, or, for a track in view in the frame the target
    was lost in, of `_placed` and `_reid_decisive`; the evidence needed rises the longer
    the target is gone.
    A frame in which a track is unseen ends its run, and so does a gap between frames
    longer than `identity_risk_unseen_s` for every track (`IdentityContext.note_frame`);
    such a gap also ends every track's being in view at the loss."""

    status = TargetStatus.REIDENTIFICATION

    def __init__(self, present_at_loss: set[int] | None = None):
        self.streaks: dict[int, int] = {}  # track id -> consecutive frames passed
        # The tracks seen in the frame the target was lost in (None: those of the first
        # frame; a track coasting unseen then may be carried onto anyone later), none
        # after a stall (`_still_present`); a failed probation hands them back, so a
        # newcomer never becomes one.
        self.present_at_loss = present_at_loss

    def update(self, context: IdentityContext, frame: FrameTracks) -> State:
        if self.present_at_loss is None:
            self.present_at_loss = _seen(frame)
        self.present_at_loss = _still_present(context, frame, self.present_at_loss)
        self.streaks = {k: v for k, v in self.streaks.items() if k in frame.by_id}
        if context.frame_gap_s > context.config.identity_risk_unseen_s:
            # No frame for as long (perception stalled): every track went unseen, and
            # the tracker may have moved one onto someone else. Every streak ends.
            self.streaks = {}
        # The re-id network runs only on a frame where some track passes every test that
        # needs no embedding (or where re-id alone may decide, below): on any other frame
        # no track can pass, whatever re-id says.
        context.look(frame, embed=False)
        classifier = context.classifier_confidences(frame)
        parts = context.part_distances(frame)
        placed = {i for i in frame.confidences if self._placed(context, frame, i, parts)}
        eligible = {i for i in placed if self._classifier_agrees(context, frame, i, classifier)}
        # Where re-id alone may decide (for a track in view since the target was lost), it
        # needs its embedding, and so does everyone it is compared with (a lone person
        # has no one to be decisive against).
        may_decide = (
            classifier is not None and context.config.reid_decisive_margin > 0.0
            and len(frame.confidences) > 1
        )  # fmt: skip
        decidable = placed & self.present_at_loss if may_decide else set()
        if eligible or decidable:
            context.look(frame)
        confidences = frame.confidences
        similarities = context.similarities(frame)
        for track_id in frame.by_id:  # unseen this frame: no evidence, the streak ends
            passed = (
                track_id in eligible and self._passes(context, frame, track_id, similarities)
            ) or (
                track_id in decidable
                and self._reid_decisive(context, frame, track_id, similarities)
            )
            self.streaks[track_id] = self.streaks.get(track_id, 0) + 1 if passed else 0
        ready = [
            i for i, n in self.streaks.items()
            if n >= context.config.reid_frames and i in confidences
        ]  # fmt: skip
        if not ready:
            return self
        target_id = max(ready, key=lambda i: confidences[i])
        log.info("target re-identified as track %d: on probation", target_id)
        return Probation(target_id, frame.stamp_s, self.present_at_loss)

    @staticmethod
    def _placed(
        context: IdentityContext,
        frame: FrameTracks,
        track_id: int,
        parts: dict[int, float] | None,
    ) -> bool:
        """The tests that ask where and who the track is, not how much it looks like the
        target: confirmed by the tracker and seen in `min_target_observations` frames,
        did not fail probation and was never beside the confirmed target
        (`reid_excludes_seen_beside`); it stands where the target could have walked
        (`reid_reach_m` + `reid_reach_speed_mps`); its neck height agrees with the
        target's (`reid_height_tolerance_m`); and its torso and legs are each of the
        target's colours (`reid_part_colour_distance`)."""
        track = frame.by_id[track_id]
        return (
            context.established(track)
            and track_id not in context.rejected
            and not context.seen_beside_target(track_id)
            and context.reachable(track, frame.stamp_s)
            and context.same_height(track)
            and context.parts_match(parts, track_id)
        )

    @staticmethod
    def _classifier_agrees(
        context: IdentityContext,
        frame: FrameTracks,
        track_id: int,
        classifier: dict[int, float] | None,
    ) -> bool:
        """With two cues, the boosted classifier's own confidence reaches the required
        one (`reid_confidence` rising to `reid_strict_confidence`); the last test that
        needs no re-id embedding."""
        return classifier is None or classifier[track_id] >= context.required_confidence(
            frame.stamp_s
        )

    @staticmethod
    def _reid_decisive(
        context: IdentityContext,
        frame: FrameTracks,
        track_id: int,
        similarities: dict[int, float] | None,
    ) -> bool:
        """Whether re-id alone tells the track from everyone in view: its similarity
        to the gallery reaches the required one and exceeds every other seen track's by
        `reid_decisive_margin`. Such a frame passes without the classifier's vote, for a
        track that was in view when the target was lost (the target's own track, doubted
        at a crossing, or the one it may have been swapped onto): telling a handful of
        people present apart is what re-id does well, while a newcomer may be anyone
        (a look-alike coming in where the target left) and needs both cues."""
        if similarities is None:
            return False
        # Everyone else seen in the frame, a person without a crop (too small, cut by the
        # image's edge) included: re-id cannot lead someone it did not embed.
        others = [similarities.get(i, math.nan) for i in _seen(frame) if i != track_id]
        if not others or not all(math.isfinite(v) for v in others):
            return False  # nobody to compare with, or someone not embedded: undecided
        similarity = similarities[track_id]
        return (
            similarity >= context.required_similarity(frame.stamp_s)
            and similarity - max(others) >= context.config.reid_decisive_margin
        )

    @staticmethod
    def _passes(
        context: IdentityContext,
        frame: FrameTracks,
        track_id: int,
        similarities: dict[int, float] | None,
    ) -> bool:
        """The rest, for a track placed where the classifier agrees: its fused
        confidence reaches the required one and leads every other seen track's by
        `reid_margin` (a lead over nobody is no evidence, nor over a person seen without
        a crop, who was compared with nobody); with a re-id cue its
        similarity to the gallery reaches the required one (`reid_accept_similarity`
        rising to `reid_strict_similarity` at `reid_strict_after_s`)."""
        if frame.unscored_beside(track_id):
            return False
        confidences = frame.confidences
        confidence = confidences[track_id]
        runner_up = max((c for i, c in confidences.items() if i != track_id), default=-1.0)
        lead = confidence - runner_up
        return (
            confidence >= context.required_confidence(frame.stamp_s)
            and lead > 0.0  # a tie is no lead, whatever the margin
            and lead >= context.config.reid_margin
            and (
                similarities is None
                or similarities[track_id] >= context.required_similarity(frame.stamp_s)
            )
        )


class Probation(Tracking):
    """A re-identified target, tracked as any target but not yet trusted: a new track's
    stature estimate starts wide and settles over its first second, so a stranger in the
    target's clothes can pass the stature test for the few frames re-identification
    needs. For `reid_probation_s`, and at least `min_target_observations` frames in which
    the candidate is seen clear of others, the stature test runs again every frame on
    the settling estimate (against the target's height from before, which the candidate
    does not replace), and a failure sends the track back to re-identification, never to
    be named again; a low confidence ends it too (a handover counts as an identity risk).
    A frame in which another person covers the candidate judges no stature either way
    (as tracking takes none from it): its skeleton may carry that person's feet, and one
    such frame must not reject the real target for good. A gap between frames longer
    than `identity_risk_unseen_s` starts its time and its count again: the tracker may
    have moved the track onto someone else in it. Whatever ends the probation
    early (that, a lost track, a doubted identity) also undoes what the candidate taught
    the model and where it walked, so a wrong pick leaves nothing behind. Then it is the
    target: tracking."""

    def __init__(self, target_id: int, since_s: float, present_at_loss: set[int] | None = None):
        super().__init__(target_id, reidentified=True)
        self.since_s = since_s
        self.present_at_loss = present_at_loss  # handed back to re-identification on undo
        self.observed = 0  # frames of probation in which the candidate's stature was judged
        self.before: tuple | None = None  # the model and the target's whereabouts when named

    def update(self, context: IdentityContext, frame: FrameTracks) -> State:
        if self.before is None:
            self.before = (context.model.snapshot(), context.whereabouts())
            # A handover is itself a moment the identity may be wrong: learning needs a
            # lead as after a crossing (and `_excused_as_turn` never excuses it).
            context.identity_risk_s = self.since_s
        if context.frame_gap_s > context.config.identity_risk_unseen_s:
            self.observed, self.since_s = 0, frame.stamp_s  # what came before proves nothing
        if self.present_at_loss is not None:
            self.present_at_loss = _still_present(context, frame, self.present_at_loss)
        track = frame.by_id.get(self.target_id)
        judged = track is not None and self._stature_judged(context, frame)
        if judged and not context.same_height(track):
            log.info("re-identified track %d is not the target's stature: re-identification",
                     self.target_id)  # fmt: skip
            context.rejected.add(self.target_id)
            return self._undo(context, frame)
        if not self._keeps(context, frame):
            return self._undo(context, frame)
        if judged and track.observation is not None:
            self.observed += 1
        long_enough = frame.stamp_s - self.since_s >= context.config.reid_probation_s
        if long_enough and self.observed >= context.config.min_target_observations:
            log.info("re-identified track %d kept its stature: tracking", self.target_id)
            return Tracking(self.target_id, reidentified=True)
        return self

    def _stature_judged(self, context: IdentityContext, frame: FrameTracks) -> bool:
        """Whether this frame judges the candidate's stature: not while another person
        covers its crop."""
        context.look(frame, only=self.target_id)  # the boxes (done once a frame)
        return not context.crop_shows_another(self.target_id, frame)

    def _excused_as_turn(self, context: IdentityContext, stamp_s: float) -> bool:
        """Never: the handover is an identity risk for the whole probation, which lasts
        longer than `identity_trust_s` (and longer still while the candidate is unseen)."""
        return False

    def _undo(self, context: IdentityContext, frame: FrameTracks) -> State:
        model, whereabouts = self.before
        context.model.restore(model)
        context.restore(whereabouts)
        context.rescore(frame)  # this frame was scored by the model the candidate taught
        return Reidentification(self.present_at_loss).update(context, frame)


def _seen(frame: FrameTracks) -> set[int]:
    """The tracks observed in the frame (not coasting on the tracker's prediction)."""
    return {i for i, track in frame.by_id.items() if track.observation is not None}


def _still_present(context: IdentityContext, frame: FrameTracks, present: set[int]) -> set[int]:
    """`present`, or nobody after a gap between frames longer than `identity_risk_unseen_s`
    (perception stalled): every track went unseen at once, and the tracker may have
    carried any of them onto anyone. A track that coasts unseen on its own keeps its
    place: the tracker retires it after `max_unseen_s` (ids are never reused), and the
    occlusions it bridges are what the re-id-decisive path is for (cut at 0.5 s unseen,
    PETS blur lost its target 1 for good after an occlusion of 0.86 s: CT 0.87 -> 0.22)."""
    return set() if context.frame_gap_s > context.config.identity_risk_unseen_s else present
