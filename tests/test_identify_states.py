"""Each state object of the target state machine on scripted frames: what it returns.

The frames are given already looked at (their confidences and re-id similarities are
set by the test), and the appearance model only records what it is taught, so that each
state's rules are tested apart from what a classifier would learn.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from follow.config import IdentifyConfig
from follow.identify.appearance import Appearance
from follow.identify.context import FrameTracks, IdentityContext
from follow.identify.states import (
    Initial,
    InitialTraining,
    Probation,
    Reidentification,
    Tracking,
)
from follow.types import Observation, Odometry, TargetStatus, TrackState

CFG = IdentifyConfig(
    initial_training_frames=3, reid_frames=2, min_target_observations=2, min_negatives_per_update=0
)
IMAGE = np.zeros((480, 640, 3), np.uint8)


SCRIPTED_CONFIDENCES: dict[int, float] = {}  # id(appearance) -> the confidence `frame` gave
# id(appearance without an embedding) -> its confidence once `complete` embeds it
SCRIPTED_WITH_REID: dict[int, float] = {}


class RecordingModel:
    """Stands in for the AppearanceModel: re-id similarities and part-colour distances
    are each appearance's scripted values (None without a re-id cue, or where a frame
    scripts no part colours); learning and forgetting are counted."""

    def __init__(self, reid: bool = True, config: IdentifyConfig = CFG):
        self.reid = reid
        self.config = config
        self.learnt: list[tuple[int, int]] = []  # (positives, negatives) per frame
        self.resets = 0

    ready = True

    def reset(self) -> None:
        self.resets += 1

    def confidence(self, appearances):
        """The confidences the frame scripted for these appearances (`frame`): what they
        are scored again with after a candidate's teaching is undone."""
        return np.array([SCRIPTED_CONFIDENCES[id(a)] for a in appearances])

    def similarity(self, appearances):
        if not self.reid or not appearances:
            return None
        return np.array([float(a.embedding[0]) for a in appearances])

    def part_distances(self, appearances):
        if not appearances or any(a.parts is None for a in appearances):
            return None
        return np.array([float(a.parts[0]) for a in appearances])

    def classifier_confidence(self, appearances):
        """The classifier's own score where a frame scripts one (in `maps`) and the
        cues must agree, else None (AppearanceModel's contract)."""
        if not self.config.reid_cues_must_agree:
            return None
        if not appearances or any(a.maps is None for a in appearances):
            return None
        return np.array([float(a.maps[0]) for a in appearances])

    def learn(self, positives, negatives, synthetic=(), mirrored=()) -> None:
        self.learnt.append((len(positives), len(negatives)))

    def crop(self, image_bgr, roi):
        return None

    def mirrored_positives(self, crop_bgr) -> list:
        return []

    def snapshot(self):
        return list(self.learnt)

    def restore(self, snapshot) -> None:
        self.learnt = list(snapshot)

    @property
    def has_reid(self) -> bool:
        return self.reid

    def lacks_embedding(self, appearance) -> bool:
        return self.reid and appearance.embedding is None

    def complete(self, image_bgr, rois, appearances):
        """The appearances with an embedding each, scored as SCRIPTED_WITH_REID says."""
        out = []
        for a in appearances:
            if self.lacks_embedding(a):
                embedded = dataclasses.replace(a, embedding=np.array([0.0]))
                SCRIPTED_CONFIDENCES[id(embedded)] = SCRIPTED_WITH_REID[id(a)]
                a = embedded
            out.append(a)
        return out


def person(track_id, x_m, y_m=0.0, neck_height_m=1.45, observed=True, last_seen_s=0.0,
           height_std_m=0.01):  # fmt: skip
    cov = np.eye(5) * 1e-4
    cov[4, 4] = height_std_m**2
    return TrackState(
        track_id, np.array([x_m, y_m, 0.0, 0.0, neck_height_m]), cov, True, last_seen_s,
        observation=Observation(np.array([0.0, 0.0]), np.array([0.0, 1.0])) if observed else None,
    )  # fmt: skip


def frame(tracks, stamp_s, confidences, similarities=None, boxes=None, robot=None,
          classifier=None, parts=None):  # fmt: skip
    """A frame whose observed tracks have the given confidences (and similarities, the
    classifier's own confidences, part-colour distances); boxes default to ones that do
    not overlap."""
    seen = [t.track_id for t in tracks if t.observation is not None]
    boxes = boxes or {i: (100 * k, 0, 100 * k + 50, 200) for k, i in enumerate(seen)}
    similarities = similarities or {}
    appearances = {
        i: Appearance(
            maps=None if classifier is None else np.array([classifier[i]]),
            embedding=np.array([similarities.get(i, 0.0)]),
            parts=None if parts is None else np.array([parts[i]]),
        )
        for i in seen
    }
    SCRIPTED_CONFIDENCES.update({id(a): confidences[i] for i, a in appearances.items()})
    return FrameTracks(
        IMAGE, list(tracks), stamp_s, robot, {t.track_id: t for t in tracks}, looked=True,
        rois=dict(boxes), boxes=dict(boxes), appearances=appearances,
        confidences={i: confidences[i] for i in seen},
    )  # fmt: skip


def uncropped(seen, *track_ids):
    """`seen` with these tracks observed but not described (too small, cut by the
    image's edge): no box, appearance or confidence."""
    for track_id in track_ids:
        for described in (seen.rois, seen.boxes, seen.appearances, seen.confidences):
            described.pop(track_id, None)
    return seen


def step(state, ctx, seen):
    """`state.update` of a frame handed over as the identifier does: its gap noted first."""
    ctx.note_frame(seen.stamp_s)
    return state.update(ctx, seen)


def context(config=CFG, reid=True, observed=None):
    ctx = IdentityContext(config, RecordingModel(reid))
    ctx.observed_frames = dict(observed or {})
    return ctx


def tracked_context(target_position_m=(2.0, 0.0), stamp_s=10.0, **kwargs):
    """A context in which track 1 was last tracked, seen and trusted at `stamp_s`."""
    ctx = context(**kwargs)
    seen = frame([person(1, *target_position_m, last_seen_s=stamp_s)], stamp_s, {1: 0.9})
    ctx.note_target(1, seen)
    ctx.note_vouched(seen)
    ctx.note_stature(1, seen)
    return ctx


# ----------------------------------------------------------------------------- initial
def test_initial_chooses_the_nearest_established_track_in_front_and_starts_training():
    ctx = context(observed={1: 2, 2: 2, 3: 1, 4: 2})
    tracks = [person(1, 4.0), person(2, 2.5), person(3, 1.0), person(4, -1.0)]
    state = Initial().update(ctx, frame(tracks, 0.0, {1: 0.0, 2: 0.0, 3: 0.0, 4: 0.0}))
    # 3 is nearer but seen in one frame only; 4 stands behind the robot
    assert isinstance(state, InitialTraining) and state.target_id == 2
    assert state.status == TargetStatus.INITIAL_TRAINING
    assert state.frames_learnt == 1 and ctx.model.learnt == [(1, 3)]  # trained this frame


def test_initial_stays_without_an_eligible_track():
    ctx = context(observed={1: 2, 2: 1})
    far, new = person(1, CFG.max_initial_distance_m + 1.0), person(2, 2.0)
    initial = Initial()
    assert initial.update(ctx, frame([far, new], 0.0, {1: 0.0, 2: 0.0})) is initial
    turned = Odometry(0.0, 0.0, np.pi, 0.0)  # the robot faces the other way: both behind
    ctx.observed_frames[2] = 2
    assert initial.update(ctx, frame([new], 0.0, {2: 0.0}, robot=turned)) is initial
    assert initial.update(ctx, frame([new], 0.0, {2: 0.0})).target_id == 2


def test_initial_takes_only_the_selected_track_once_it_is_seen():
    ctx = context(observed={1: 2, 2: 2})
    ctx.requested_id = 2
    initial = Initial()
    assert initial.update(ctx, frame([person(1, 2.0)], 0.0, {1: 0.0})) is initial
    hidden = person(2, 3.0, observed=False)
    assert initial.update(ctx, frame([person(1, 2.0), hidden], 0.0, {1: 0.0})) is initial
    state = initial.update(ctx, frame([person(1, 2.0), person(2, 4.9)], 0.0, {1: 0.0, 2: 0.0}))
    assert state.target_id == 2


# -------------------------------------------------------------------- initial training
def test_initial_training_becomes_tracking_after_the_configured_learnt_frames_in_a_row():
    """A crossing (another box over the target's) in the middle drops what was learnt:
    the track may carry the other person after it, and a model of both takes either for
    the target. Training starts again once the crop is clear."""
    ctx = context()
    state = InitialTraining(1)
    tracks = [person(1, 2.0), person(2, 2.0 + CFG.identity_risk_distance_m + 1.0)]
    for k in range(CFG.initial_training_frames - 1):
        assert state.update(ctx, frame(tracks, 0.1 * k, {1: 0.0, 2: 0.0})) is state
    assert len(ctx.model.learnt) == CFG.initial_training_frames - 1
    resets = ctx.model.resets
    overlapping = {1: (0, 0, 100, 200), 2: (20, 0, 120, 200)}  # 80 % of the target covered
    assert state.update(ctx, frame(tracks, 0.5, {1: 0.0, 2: 0.0}, boxes=overlapping)) is state
    assert ctx.model.resets == resets + 1 and state.frames_learnt == 0  # dropped
    for k in range(CFG.initial_training_frames - 1):
        assert state.update(ctx, frame(tracks, 0.6 + 0.1 * k, {1: 0.0, 2: 0.0})) is state
    nxt = state.update(ctx, frame(tracks, 0.8, {1: 0.0, 2: 0.0}))  # no gap: 0.1 s on
    assert isinstance(nxt, Tracking) and nxt.target_id == 1
    assert len(ctx.model.learnt) == 2 * CFG.initial_training_frames - 1  # (every call)


def test_initial_training_learns_no_frame_in_which_someone_walks_near_the_target():
    """Two people side by side: the tracker could swap them there, and the model would
    learn the other person as the target from its first frames. Training waits until
    they are apart."""
    ctx = context()
    state = InitialTraining(1)
    beside = [person(1, 2.0), person(2, 2.0, y_m=0.5 * CFG.identity_risk_distance_m)]
    for k in range(CFG.initial_training_frames + 2):
        assert state.update(ctx, frame(beside, 0.1 * k, {1: 0.0, 2: 0.0})) is state
    assert ctx.model.learnt == [] and state.frames_learnt == 0
    apart = [person(1, 2.0), person(2, 2.0, y_m=CFG.identity_risk_distance_m + 0.5)]
    assert state.update(ctx, frame(apart, 2.0, {1: 0.0, 2: 0.0})) is state
    assert state.frames_learnt == 1


def test_initial_training_starts_over_when_the_target_is_lost():
    ctx = context()
    state = InitialTraining(1)
    state.update(ctx, frame([person(1, 2.0)], 0.0, {1: 0.0}))
    assert ctx.last_target_position_m is not None
    resets = ctx.model.resets
    nxt = state.update(ctx, frame([person(2, 2.0)], 0.1, {2: 0.0}))
    assert isinstance(nxt, Initial) and nxt.target_id is None
    assert ctx.model.resets == resets + 1 and ctx.last_target_position_m is None


def test_initial_training_that_loses_its_target_chooses_again_in_the_same_frame():
    """The tracker replaces the target's track in a frame: initial training starts over
    on that frame, as every other state hands over within the frame it is lost in, and
    the nearest established track is chosen and learnt there."""
    ctx = context(observed={2: 2})
    state = InitialTraining(1)
    state.update(ctx, frame([person(1, 2.0), person(2, 3.0)], 0.0, {1: 0.0, 2: 0.0}))
    nxt = state.update(ctx, frame([person(2, 3.0), person(3, 1.5)], 0.1, {2: 0.0, 3: 0.0}))
    assert isinstance(nxt, InitialTraining) and nxt.target_id == 2  # 3 is new: not yet
    assert nxt.frames_learnt == 1 and ctx.last_target_s == 0.1


@pytest.mark.parametrize(
    ("unseen_s", "stall", "dropped"),
    [
        (CFG.identity_risk_unseen_s - 0.2, False, False),
        (CFG.identity_risk_unseen_s + 0.2, False, True),
        (CFG.identity_risk_unseen_s + 0.2, True, True),
    ],
)
def test_initial_training_starts_again_after_its_target_went_unseen(unseen_s, stall, dropped):
    """The tracker may have moved the target's track onto someone else while it coasted
    unseen for `identity_risk_unseen_s`, or across a stall of perception as long: the
    frames learnt before are dropped, and the frames in a row start again."""
    ctx = context()
    state, learnt_s = InitialTraining(1), 0.1 * (CFG.initial_training_frames - 2)
    for k in range(CFG.initial_training_frames - 1):
        state = step(state, ctx, frame([person(1, 2.0, last_seen_s=0.1 * k)], 0.1 * k, {1: 0.0}))
    resets = ctx.model.resets
    for k in range(1, 0 if stall else round(unseen_s / 0.1)):  # coasting on the prediction
        hidden = person(1, 2.0, observed=False, last_seen_s=learnt_s)
        assert step(state, ctx, frame([hidden], learnt_s + 0.1 * k, {})) is state
    back_s = learnt_s + unseen_s
    nxt = step(state, ctx, frame([person(1, 2.0, last_seen_s=back_s)], back_s, {1: 0.0}))
    if not dropped:
        assert isinstance(nxt, Tracking) and ctx.model.resets == resets
        return
    assert nxt is state and state.frames_learnt == 1 and ctx.model.resets == resets + 1
    for k in range(1, CFG.initial_training_frames):
        t = back_s + 0.1 * k
        nxt = step(state, ctx, frame([person(1, 2.0, last_seen_s=t)], t, {1: 0.0}))
    assert isinstance(nxt, Tracking)


# --------------------------------------------------------------------------- tracking
def test_tracking_becomes_reidentification_when_the_target_is_lost():
    ctx = tracked_context(observed={2: 5})
    nxt = Tracking(1).update(ctx, frame([person(2, 2.5)], 10.1, {2: 0.9}, {2: 0.9}))
    assert isinstance(nxt, Reidentification)
    assert nxt.status == TargetStatus.REIDENTIFICATION and nxt.target_id is None
    assert nxt.streaks == {2: 1}  # the frame it was lost in already counts as evidence


def test_tracking_learns_while_the_confidence_holds_and_keeps_an_unseen_target():
    ctx = tracked_context()
    state = Tracking(1)
    assert (
        state.update(ctx, frame([person(1, 2.0), person(2, 4.0)], 10.1, {1: 0.5, 2: -0.5})) is state
    )
    assert ctx.model.learnt == [(1, 1)]
    hidden = person(1, 2.0, observed=False, last_seen_s=10.1)
    assert state.update(ctx, frame([hidden, person(2, 4.0)], 10.2, {2: -0.5})) is state
    assert ctx.model.learnt == [(1, 1)]  # nothing to learn from


def test_a_low_confidence_ends_tracking_only_after_someone_came_near():
    low = CFG.id_switch_confidence - 0.1
    ctx = tracked_context(stamp_s=10.0)
    ctx.identity_risk_s = 10.0 - CFG.identity_trust_s - 1.0  # nobody near for a while
    state = Tracking(1)
    alone = [person(1, 2.0, last_seen_s=10.1), person(2, 5.0, last_seen_s=10.1)]
    assert state.update(ctx, frame(alone, 10.1, {1: low, 2: -0.5})) is state  # turned round
    assert ctx.model.learnt == []  # and nothing of the new look is learnt
    near = [person(1, 2.0, last_seen_s=10.2), person(2, 2.0 + 0.5 * CFG.identity_risk_distance_m,
                                                       last_seen_s=10.2)]  # fmt: skip
    nxt = state.update(ctx, frame(near, 10.2, {1: low, 2: -0.5}))
    assert isinstance(nxt, Reidentification) and ctx.identity_risk_s == 10.2


def test_a_low_confidence_while_another_covers_the_target_keeps_tracking():
    low = CFG.id_switch_confidence - 0.1
    ctx = tracked_context(stamp_s=10.0)
    near = [person(1, 2.0, last_seen_s=10.1), person(2, 2.3, last_seen_s=10.1)]
    covered = {1: (0, 0, 100, 200), 2: (40, 0, 140, 200)}
    state = Tracking(1)
    assert state.update(ctx, frame(near, 10.1, {1: low, 2: 0.9}, boxes=covered)) is state
    assert isinstance(state.update(ctx, frame(near, 10.2, {1: low, 2: 0.9})), Reidentification)


def test_after_a_crossing_the_target_is_not_learnt_while_another_looks_more_like_it():
    """A tracker swap hands the target's track to the person crossing it: their crop then
    scores middling on the target's track while the target, on the other track, scores
    higher. Learning that frame would teach the model the stranger."""

    def learnt_after(config, confidences, reid=True):
        ctx = tracked_context(stamp_s=10.0, config=config, reid=reid)
        crossing = [person(1, 2.0, last_seen_s=10.1),
                    person(2, 2.0 + 0.5 * CFG.identity_risk_distance_m, last_seen_s=10.1)]  # fmt: skip
        state = Tracking(1)
        assert state.update(ctx, frame(crossing, 10.1, confidences)) is state  # still named
        return len(ctx.model.learnt)

    assert learnt_after(CFG, {1: 0.1, 2: 0.6}) == 0  # the other looks more like the target
    assert learnt_after(CFG, {1: 0.6, 2: 0.1}) == 1  # the target leads: learnt
    assert learnt_after(CFG, {1: 0.6, 2: 0.6}) == 0  # a tie is no lead
    off = dataclasses.replace(CFG, learn_needs_lead_at_risk="never")
    assert learnt_after(off, {1: 0.1, 2: 0.6}) == 1
    # The default asks it beside a re-id cue only; "always" of the classifier alone too.
    assert learnt_after(CFG, {1: 0.1, 2: 0.6}, reid=False) == 1
    always = dataclasses.replace(CFG, learn_needs_lead_at_risk="always")
    assert learnt_after(always, {1: 0.1, 2: 0.6}, reid=False) == 0


@pytest.mark.parametrize(("with_reid", "learnt"), [(0.8, 0), (0.3, 1)])
def test_at_risk_the_others_are_scored_with_re_id_as_the_target_is(with_reid, learnt):
    """The look that checks the target embeds the target alone: the others are scored
    by the classifier, on another scale than the target's re-id-fused score. Whether the
    target leads is asked of them scored alike (their embeddings completed)."""
    ctx = tracked_context(stamp_s=10.0)
    crossing = [person(1, 2.0, last_seen_s=10.1),
                person(2, 2.0 + 0.5 * CFG.identity_risk_distance_m, last_seen_s=10.1)]  # fmt: skip
    looked = frame(crossing, 10.1, {1: 0.6, 2: 0.1})  # 0.1: track 2 by the classifier alone
    unembedded = dataclasses.replace(looked.appearances[2], embedding=None)
    looked.appearances[2] = unembedded
    SCRIPTED_CONFIDENCES[id(unembedded)] = 0.1
    SCRIPTED_WITH_REID[id(unembedded)] = with_reid
    state = Tracking(1)
    assert state.update(ctx, looked) is state  # still named
    assert len(ctx.model.learnt) == learnt
    assert looked.appearances[2].embedding is not None
    assert looked.confidences == {1: 0.6, 2: with_reid}


def test_a_person_passing_in_front_puts_the_identity_at_risk_though_far_behind_on_the_floor():
    """Boxes that overlap in the image are a moment the tracker could swap two people,
    whatever their distance on the floor (a passer-by nearer the camera covers the
    target): a low confidence after it is not excused as the target turning round."""
    ctx = tracked_context(stamp_s=10.0)
    ctx.identity_risk_s = 10.0 - CFG.identity_trust_s - 1.0  # nobody near for a while
    state = Tracking(1)
    far_apart = [person(1, 5.0, last_seen_s=10.1), person(2, 2.0, last_seen_s=10.1)]
    touching = {1: (0, 0, 100, 200), 2: (90, 0, 190, 300)}  # 10 % of the target covered
    assert state.update(ctx, frame(far_apart, 10.1, {1: 0.5, 2: -0.5}, boxes=touching)) is state
    assert ctx.identity_risk_s == 10.1
    low = CFG.id_switch_confidence - 0.1
    nxt = state.update(ctx, frame(far_apart, 10.2, {1: low, 2: -0.5}))
    assert isinstance(nxt, Reidentification)


def test_trust_does_not_come_back_with_time_alone_while_no_crop_is_judged():
    """Someone came near while the target was seen without a crop (too small, covered):
    the risk's window passing judged nothing, so the first low confidence after it is
    not excused as a turn, and a frame that confirms the target gives the trust back."""
    low = CFG.id_switch_confidence - 0.1
    near = [person(1, 2.0, last_seen_s=10.1),
            person(2, 2.0 + 0.5 * CFG.identity_risk_distance_m, last_seen_s=10.1)]  # fmt: skip

    def without_crop():  # the target seen, but no crop of it to judge
        seen = frame(near, 10.1, {1: 0.0, 2: -0.5})
        del seen.appearances[1], seen.confidences[1]
        return seen

    ctx = tracked_context(stamp_s=10.0)
    state = Tracking(1)
    assert state.update(ctx, without_crop()) is state and ctx.identity_risk_s == 10.1
    later = 10.1 + CFG.identity_trust_s + 0.5
    apart = [person(1, 2.0, last_seen_s=later), person(2, 5.0, last_seen_s=later)]
    assert not ctx.identity_trusted(later)
    nxt = Tracking(1).update(ctx, frame(apart, later, {1: low, 2: -0.5}))
    assert isinstance(nxt, Reidentification)

    ctx = tracked_context(stamp_s=10.0)
    state = Tracking(1)
    assert state.update(ctx, without_crop()) is state
    assert state.update(ctx, frame(apart, 10.2, {1: 0.6, 2: -0.5})) is state  # confirmed
    assert ctx.identity_trusted(later)
    assert state.update(ctx, frame(apart, later, {1: low, 2: -0.5})) is state  # a turn


def test_marks_of_tracks_the_tracker_dropped_are_forgotten():
    ctx = context()
    ctx.seen_apart, ctx.rejected = {2, 3, 4}, {3, 5}
    ctx.forget_departed(frame([person(1, 2.0), person(3, 4.0)], 1.0, {1: 0.5, 3: 0.0}))
    assert ctx.seen_apart == {3} and ctx.rejected == {3}


def test_after_a_gap_the_target_is_not_learnt_while_a_new_track_looks_more_like_it():
    """The target's track went unseen; the target came back on a new track, and the old
    track was re-attached to someone else, far from the new one."""
    ctx = tracked_context(stamp_s=10.0)
    state = Tracking(1)
    gap = CFG.identity_risk_unseen_s + 0.5
    hidden = person(1, 2.0, observed=False, last_seen_s=10.0)
    assert state.update(ctx, frame([hidden], 10.0 + gap - 0.1, {})) is state
    back = [person(1, 2.0, last_seen_s=10.0 + gap), person(3, 4.0, last_seen_s=10.0 + gap)]
    assert state.update(ctx, frame(back, 10.0 + gap, {1: -0.05, 3: 0.8})) is state
    assert ctx.model.learnt == []


def test_at_risk_the_target_leads_nobody_seen_without_a_crop():
    """After a crossing the target must outscore everyone seen. A person seen without a
    crop (cut by the image's edge, too small) was compared with nobody and may be the
    target the tracker swapped away: the frame is not learnt, vouches for nothing and
    marks nobody as seen beside the target."""

    def run(crop_of_2):
        ctx = tracked_context(stamp_s=10.0)
        ctx.identity_risk_s = 10.0  # someone came near: the identity is at risk
        tracks = [person(1, 2.0, last_seen_s=10.1), person(2, 4.0, last_seen_s=10.1)]
        seen = frame(tracks, 10.1, {1: 0.6, 2: 0.1})
        state = Tracking(1)
        assert state.update(ctx, seen if crop_of_2 else uncropped(seen, 2)) is state
        return ctx

    led = run(crop_of_2=True)
    assert len(led.model.learnt) == 1 and led.vouched_s == 10.1 and led.seen_beside_target(2)
    unled = run(crop_of_2=False)
    assert unled.model.learnt == [] and unled.vouched_s == 10.0
    assert not unled.seen_beside_target(2)


def test_only_people_scored_beside_the_confirmed_target_are_marked_as_seen_beside_it():
    """A frame learnt while the identity is trusted marks the others it compared: one
    seen without a crop was compared with nobody, and stays a candidate."""
    trusted = tracked_context(stamp_s=10.0)
    trusted.identity_risk_s = 10.0 - CFG.identity_trust_s - 1.0  # nobody near for a while
    training = context()
    t = 10.1
    three = [person(1, 2.0, last_seen_s=t), person(2, 4.0, last_seen_s=t),
             person(3, 6.0, last_seen_s=t)]  # fmt: skip
    for ctx, state in ((trusted, Tracking(1)), (training, InitialTraining(1))):
        assert state.update(ctx, uncropped(frame(three, t, {1: 0.6, 2: 0.1, 3: 0.1}), 3)) is state
        assert len(ctx.model.learnt) == 1 and ctx.seen_apart == {2}


def test_away_from_any_risk_the_target_is_learnt_whoever_else_scores_higher():
    ctx = tracked_context(stamp_s=10.0)
    ctx.identity_risk_s = 10.0 - CFG.identity_trust_s - 1.0  # nobody near for a while
    apart = [person(1, 2.0, last_seen_s=10.1), person(2, 5.0, last_seen_s=10.1)]
    state = Tracking(1)
    assert state.update(ctx, frame(apart, 10.1, {1: 0.1, 2: 0.6})) is state
    assert len(ctx.model.learnt) == 1  # a look-alike across the room is no swap


# ------------------------------------------------------------------- re-identification
def reid_frames(state, ctx, tracks, t0, confidences, similarities=None, n=CFG.reid_frames):
    return [
        state.update(ctx, frame(tracks, t0 + 0.1 * k, confidences, similarities)) for k in range(n)
    ]


def test_reidentification_takes_a_candidate_with_absolute_evidence_in_enough_frames():
    ctx = tracked_context(stamp_s=10.0, observed={7: 5})
    state = Reidentification()
    back = [person(7, 2.5)]
    ok = CFG.reid_accept_similarity + 0.05
    states = reid_frames(state, ctx, back, 10.1, {7: CFG.reid_confidence + 0.1}, {7: ok})
    assert states[:-1] == [state] * (CFG.reid_frames - 1)
    assert isinstance(states[-1], Probation) and states[-1].target_id == 7


def test_reidentification_stays_for_a_stranger_who_fails_the_absolute_evidence():
    ctx = tracked_context(stamp_s=10.0, observed={8: 5})
    state = Reidentification()
    stranger = [person(8, 2.5)]
    confident = {8: 0.95}  # the classifier likes it, and nobody else is in view to lead
    weak = {8: CFG.reid_accept_similarity - 0.05}
    states = reid_frames(state, ctx, stranger, 10.1, confident, weak, n=3 * CFG.reid_frames)
    assert all(s is state for s in states) and state.streaks == {8: 0}
    # Without a re-id cue the same confidence is evidence enough: the rule that held it.
    plain = tracked_context(stamp_s=10.0, observed={8: 5}, reid=False)
    assert isinstance(
        reid_frames(Reidentification(), plain, stranger, 10.1, confident)[-1], Probation
    )


def test_with_two_cues_each_must_agree_not_only_their_mean():
    """The simulated stranger in the target's clothes: re-id vouches for them and lifts
    the fused confidence over the bar, while the classifier alone doubts them."""
    ctx = tracked_context(stamp_s=10.0, observed={8: 5})
    fused = {8: CFG.reid_confidence + 0.2}
    similar = {8: CFG.reid_accept_similarity + 0.1}
    stranger = [person(8, 2.5)]

    def run(classifier_alone):
        state = Reidentification()
        return [
            state.update(
                ctx,
                frame(stranger, 10.1 + 0.1 * k, fused, similar, classifier={8: classifier_alone}),
            )  # fmt: skip
            for k in range(3 * CFG.reid_frames)
        ]

    assert all(isinstance(s, Reidentification) for s in run(CFG.reid_confidence - 0.05))
    assert isinstance(run(CFG.reid_confidence + 0.05)[-1], Probation)
    ctx.model.config = dataclasses.replace(CFG, reid_cues_must_agree=False)  # the mean alone
    assert isinstance(run(CFG.reid_confidence - 0.05)[-1], Probation)


def test_re_id_decisive_among_the_people_in_view_passes_without_the_classifier():
    """Under blur or in the dark the classifier can doubt the target for good while
    re-id still tells it from everyone present: with `reid_decisive_margin`, a candidate
    in view since the target was lost whose similarity reaches the bar and exceeds every
    other person's in the frame by the margin passes without the classifier's vote.
    Alone in view, beside a look-alike within the margin, under the bar, or new since
    the loss (someone coming in where the target left), each cue must agree as before."""
    decisive = dataclasses.replace(CFG, reid_decisive_margin=0.15)
    never = dataclasses.replace(CFG, reid_decisive_margin=0.0)
    doubted = CFG.reid_confidence - 0.3  # the classifier alone, under its bar
    high = CFG.reid_strict_similarity + 0.1
    back, other = person(7, 2.5), person(8, 4.0)

    def run(config, people, sims, at_loss=None):
        ctx = tracked_context(stamp_s=10.0, config=config, observed={7: 5, 8: 5})
        state = Reidentification()
        if at_loss is not None:  # who was in view in the frame the target was lost in
            ids = [t.track_id for t in at_loss]
            state.update(ctx, frame(at_loss, 10.05, dict.fromkeys(ids, 0.0)))
        fused = dict.fromkeys(sims, 0.0)  # the fused confidence passes no bar either
        classifier = dict.fromkeys(sims, doubted)
        return [
            state.update(ctx, frame(people, 10.1 + 0.1 * k, fused, sims, classifier=classifier))
            for k in range(3 * CFG.reid_frames)
        ]

    apart = {7: high, 8: high - 0.2}
    taken = run(decisive, [back, other], apart)
    assert isinstance(taken[-1], Probation) and taken[-1].target_id == 7
    assert taken[: CFG.reid_frames - 1] == [taken[0]] * (CFG.reid_frames - 1)  # a full streak
    assert all(isinstance(s, Reidentification) for s in run(never, [back, other], apart))
    newcomer = run(decisive, [back, other], apart, at_loss=[other])
    assert all(isinstance(s, Reidentification) for s in newcomer)
    for people, sims in (
        ([back], {7: high}),  # nobody to be decisive against
        ([back, other], {7: high, 8: high - 0.1}),  # a look-alike within the margin
        ([back, other], {7: CFG.reid_accept_similarity - 0.05, 8: 0.0}),  # under the bar
    ):
        assert all(isinstance(s, Reidentification) for s in run(decisive, people, sims))


def test_re_id_decides_only_for_people_seen_at_the_loss_and_against_everyone_seen():
    """ "In view" means observed: a track coasting unseen in the frame the target was lost
    in may be carried onto anyone later, so it is no one present; and a person seen now
    without a crop (too small, cut by the image's edge) cannot be led by a re-id that did
    not embed them, so the frame is undecided."""
    decisive = dataclasses.replace(CFG, reid_decisive_margin=0.15)
    doubted = CFG.reid_confidence - 0.3
    high = CFG.reid_strict_similarity + 0.1

    def run(at_loss, people, sims, without_crop=()):
        ctx = tracked_context(stamp_s=10.0, config=decisive, observed={7: 5, 8: 5, 9: 5})
        state = Reidentification()
        seen_at_loss = [t.track_id for t in at_loss if t.observation is not None]
        state = state.update(ctx, frame(at_loss, 10.05, dict.fromkeys(seen_at_loss, 0.0)))
        for k in range(3 * CFG.reid_frames):
            f = frame(people, 10.1 + 0.1 * k, dict.fromkeys(sims, 0.0), sims,
                      classifier=dict.fromkeys(sims, doubted))  # fmt: skip
            state = state.update(ctx, uncropped(f, *without_crop))  # seen, no crop
        return state

    people, apart = [person(7, 2.5), person(8, 4.0)], {7: high, 8: high - 0.2}
    assert isinstance(run(people, people, apart), Probation)  # both seen at the loss
    coasting = [person(7, 2.5, observed=False, last_seen_s=9.0), person(8, 4.0)]
    assert isinstance(run(coasting, people, apart), Reidentification)
    look_alike = person(9, 3.0)  # within the margin, seen but not embedded
    three = [*people, look_alike]
    sims = {7: high, 8: high - 0.2, 9: high - 0.05}
    assert isinstance(run(three, three, sims), Reidentification)  # embedded: within margin
    assert isinstance(run(three, three, sims, without_crop=(9,)), Reidentification)
    assert isinstance(run(three, three, {7: high, 8: high - 0.2, 9: high - 0.3}), Probation)


def test_a_failed_probation_hands_back_who_was_in_view_at_the_loss():
    """Re-identification after a failed probation still counts as present only those in
    view when the target was lost: a newcomer since never becomes one."""
    ctx = tracked_context(stamp_s=10.0, observed={7: 5})
    probation = Probation(7, 10.5, present_at_loss={8})
    taller = person(7, 2.5, neck_height_m=1.45 + 0.2)
    state = probation.update(ctx, frame([taller], 10.6, {7: 0.9}, {7: 0.9}))
    assert isinstance(state, Reidentification) and state.present_at_loss == {8}


@pytest.mark.parametrize(
    ("unseen_s", "stall", "decided"),
    [
        (CFG.identity_risk_unseen_s - 0.2, False, True),
        (CFG.identity_risk_unseen_s + 0.3, False, True),  # an occlusion: the tracker's to end
        (CFG.identity_risk_unseen_s + 0.3, True, False),
    ],
)
def test_a_stall_since_the_loss_ends_every_tracks_being_present_at_it(unseen_s, stall, decided):
    """Across a stall of perception longer than `identity_risk_unseen_s` any track may
    be carried onto anyone: re-id alone no longer decides for it, and each cue must
    agree. A track that coasts through an occlusion keeps its place (the tracker retires
    it after `max_unseen_s`)."""
    decisive = dataclasses.replace(CFG, reid_decisive_margin=0.15)
    doubted = CFG.reid_confidence - 0.3  # the classifier alone, under its bar
    high = CFG.reid_strict_similarity + 0.1
    ctx = tracked_context(stamp_s=10.0, config=decisive, observed={7: 5, 8: 5})
    state, loss_s = Reidentification(), 10.05

    def pair(t, seen_7=True):
        return [person(7, 2.5, observed=seen_7, last_seen_s=t if seen_7 else loss_s),
                person(8, 4.0, last_seen_s=t)]  # fmt: skip

    state = step(state, ctx, frame(pair(loss_s), loss_s, {7: 0.0, 8: 0.0}))
    for k in range(1, 0 if stall else round(unseen_s / 0.1)):  # 7 coasts on the prediction
        t = loss_s + 0.1 * k
        state = step(state, ctx, frame(pair(t, seen_7=False), t, {8: 0.0}))
    for k in range(3 * CFG.reid_frames):  # 7 seen again: whoever the tracker gave it
        t = loss_s + unseen_s + 0.1 * k
        state = step(state, ctx, frame(pair(t), t, {7: 0.0, 8: 0.0}, {7: high, 8: high - 0.2},
                                       classifier={7: doubted, 8: doubted}))  # fmt: skip
    assert isinstance(state, Probation if decided else Reidentification)


def test_probation_hands_back_only_those_still_present_at_the_loss():
    """While the candidate is on probation, a stall longer than `identity_risk_unseen_s`
    ends every track's being present at the loss (one coasting through an occlusion
    keeps it): a failed probation hands back what re-identification would hold."""

    def run(stall):
        ctx = tracked_context(stamp_s=10.0, observed={7: 20, 8: 20, 9: 20})
        probation, t = Probation(7, 10.5, present_at_loss={8, 9}), 10.5
        ctx.note_frame(t)  # the frame it was named in

        def three(t, seen_8=True, neck_height_m=1.45):
            return [person(7, 2.5, neck_height_m=neck_height_m, last_seen_s=t),
                    person(8, 4.0, observed=seen_8, last_seen_s=t if seen_8 else 10.5),
                    person(9, 5.5, last_seen_s=t)]  # fmt: skip

        scores = {7: 0.9, 8: -0.5, 9: -0.5}, {7: 0.9}
        while t < 10.5 + CFG.identity_risk_unseen_s + 0.2:  # 8 coasts, else a stall
            t += CFG.identity_risk_unseen_s + 0.2 if stall else 0.1
            assert step(probation, ctx, frame(three(t, seen_8=stall), t, *scores)) is probation
        t += 0.1
        taller = frame(three(t, neck_height_m=1.65), t, *scores)
        state = step(probation, ctx, taller)  # the stature fails: back to re-identification
        assert isinstance(state, Reidentification)
        return state.present_at_loss

    assert run(stall=False) == {8, 9}
    assert run(stall=True) == set()


def test_the_evidence_needed_rises_the_longer_the_target_is_gone():
    ctx = tracked_context(stamp_s=10.0, observed={7: 5})
    between = 0.5 * (CFG.reid_accept_similarity + CFG.reid_strict_similarity)
    confident = {7: CFG.reid_strict_confidence + 0.1}
    soon = reid_frames(Reidentification(), ctx, [person(7, 2.5)], 10.1, confident, {7: between})
    assert isinstance(soon[-1], Probation)
    late_s = 10.0 + CFG.reid_strict_after_s + 1.0  # close by, but long gone
    ctx.last_target_s = late_s
    late = reid_frames(Reidentification(), ctx, [person(7, 2.5)], late_s, confident, {7: between})
    assert all(isinstance(s, Reidentification) for s in late)


def test_reidentification_rejects_a_look_alike_too_far_too_new_or_of_another_height():
    ctx = tracked_context(stamp_s=10.0, observed={5: 5, 6: 5})
    good = {5: 0.9}, {5: 0.9}
    reach_m = CFG.reid_reach_m + CFG.reid_reach_speed_mps * 0.3
    far = [person(5, 2.0 + reach_m + 0.5)]
    assert all(
        isinstance(s, Reidentification)
        for s in reid_frames(Reidentification(), ctx, far, 10.1, *good)
    )
    taller = [person(5, 2.5, neck_height_m=1.45 + CFG.reid_height_tolerance_m + 0.05)]
    assert all(
        isinstance(s, Reidentification)
        for s in reid_frames(Reidentification(), ctx, taller, 10.1, *good)
    )
    ctx.observed_frames[4] = CFG.min_target_observations - 1
    new = [person(4, 2.5)]  # a track seen in too few frames (a split skeleton's ghost)
    good_new = {4: 0.9}, {4: 0.9}
    assert all(
        isinstance(s, Reidentification)
        for s in reid_frames(Reidentification(), ctx, new, 10.1, *good_new)
    )
    same = [person(5, 2.5, neck_height_m=1.45 + 0.5 * CFG.reid_height_tolerance_m)]
    assert isinstance(reid_frames(Reidentification(), ctx, same, 10.1, *good)[-1], Probation)


def test_reidentification_never_names_a_track_the_tracker_has_not_confirmed():
    """Seen in enough frames for the identifier, but still tentative for a tracker that
    confirms later (min_updates_to_confirm above min_target_observations): as for the
    first choice, a track the tracker does not vouch for is never the target."""
    ctx = tracked_context(stamp_s=10.0, observed={7: 5})
    tentative = [dataclasses.replace(person(7, 2.5), confirmed=False)]
    ok = {7: 0.9}, {7: CFG.reid_accept_similarity + 0.1}
    states = reid_frames(Reidentification(), ctx, tentative, 10.1, *ok, n=3 * CFG.reid_frames)
    assert all(isinstance(s, Reidentification) for s in states)
    assert isinstance(reid_frames(Reidentification(), ctx, [person(7, 2.5)], 11.0, *ok)[-1],
                      Probation)  # fmt: skip


def test_reidentification_needs_every_part_of_the_targets_colours():
    """A candidate passing every other test is taken only while its torso and legs are
    each within `reid_part_colour_distance` of the target's colours; before any part
    colours were learnt the rule lets everyone through."""
    bar = CFG.reid_part_colour_distance
    back = [person(7, 2.5)]
    good = {7: 0.9}, {7: 0.9}

    def run(parts):
        ctx = tracked_context(stamp_s=10.0, observed={7: 5})
        state = Reidentification()
        return [
            state.update(ctx, frame(back, 10.1 + 0.1 * k, *good, parts=parts))
            for k in range(CFG.reid_frames)
        ][-1]

    assert isinstance(run({7: bar + 0.05}), Reidentification)  # other trousers
    assert isinstance(run({7: bar}), Probation)
    assert isinstance(run(None), Probation)  # nothing learnt: no part colours to compare


def test_the_stature_allowance_adds_the_estimates_std_to_the_tolerance_in_quadrature():
    ctx = tracked_context(stamp_s=10.0)  # target neck height 1.45 m, std 0.01 m
    tol_m = CFG.reid_height_tolerance_m  # 0.03; 2 combined stds of two settled estimates: 0.028
    assert ctx.same_height(person(5, 2.5, neck_height_m=1.45 + 0.035))
    # 5 cm off: within the two added up (0.058), not within them in quadrature (0.041)
    assert not ctx.same_height(person(5, 2.5, neck_height_m=1.45 + 0.05))
    # a new track's wide estimate (std 0.06 m) leaves room for its error
    assert ctx.same_height(person(5, 2.5, neck_height_m=1.45 + 0.08, height_std_m=0.06))
    ctx.config = dataclasses.replace(CFG, reid_height_tolerance_stds=0.0)
    assert not ctx.same_height(person(5, 2.5, neck_height_m=1.45 + tol_m + 0.005))
    assert ctx.same_height(person(5, 2.5, neck_height_m=1.45 + tol_m - 0.005))


def test_reidentification_needs_a_lead_and_an_unbroken_streak():
    cfg = dataclasses.replace(CFG, reid_margin=0.2)
    ctx = tracked_context(stamp_s=10.0, config=cfg, observed={5: 5, 6: 5})
    sims = {5: 0.9, 6: 0.9}
    twins = [person(5, 2.5), person(6, 2.0)]
    state = Reidentification()
    states = reid_frames(state, ctx, twins, 10.1, {5: 0.8, 6: 0.7}, sims, n=4)
    assert all(s is state for s in states)  # neither leads the other by 0.2
    assert state.update(ctx, frame(twins, 10.5, {5: 0.8, 6: 0.5}, sims)) is state  # 1 frame
    assert state.update(ctx, frame(twins, 10.6, {5: 0.8, 6: 0.7}, sims)) is state  # broken
    assert state.streaks == {5: 0, 6: 0}
    nxt = reid_frames(state, ctx, twins, 10.7, {5: 0.8, 6: 0.5}, sims)[-1]
    assert isinstance(nxt, Probation) and nxt.target_id == 5


def test_reidentification_leads_nobody_seen_without_a_crop():
    """A lead over the others seen is over every one of them: a person seen without a
    crop (cut by the image's edge, too small) was compared with nobody, so the frame is
    no lead, as re-id alone leaves it undecided."""
    ctx = tracked_context(stamp_s=10.0, observed={7: 5, 8: 5})
    pair = [person(7, 2.5), person(8, 3.5)]
    scores = {7: 0.9, 8: 0.2}, {7: 0.9, 8: 0.5}
    state = Reidentification()
    for k in range(3 * CFG.reid_frames):
        assert state.update(ctx, uncropped(frame(pair, 10.1 + 0.1 * k, *scores), 8)) is state
    assert isinstance(reid_frames(state, ctx, pair, 10.8, *scores)[-1], Probation)


@pytest.mark.parametrize("state", [Initial(), InitialTraining(3), Tracking(3), Reidentification()])
def test_each_state_reports_its_status_and_target(state):
    expected = {
        Initial: (TargetStatus.INITIAL, None),
        InitialTraining: (TargetStatus.INITIAL_TRAINING, 3),
        Tracking: (TargetStatus.TRACKING, 3),
        Reidentification: (TargetStatus.REIDENTIFICATION, None),
    }[type(state)]
    assert (state.status, state.target_id) == expected


def test_a_person_seen_beside_the_confirmed_target_is_never_taken_for_it():
    def run(config):
        ctx = tracked_context(stamp_s=10.0, config=config, observed={1: 5, 2: 5})
        tracking = Tracking(1)
        together = [person(1, 2.0, last_seen_s=10.1), person(2, 5.0, last_seen_s=10.1)]
        assert tracking.update(ctx, frame(together, 10.1, {1: 0.9, 2: -0.5})) is tracking
        # The target walks out of view; the other, dressed and as tall alike, steps in.
        alike = [person(2, 2.2, last_seen_s=10.2)]
        state = tracking.update(ctx, frame(alike, 10.2, {2: 0.9}, {2: 0.9}, classifier={2: 0.9}))
        for k in range(CFG.reid_frames):
            state = state.update(
                ctx, frame(alike, 10.3 + 0.1 * k, {2: 0.9}, {2: 0.9}, classifier={2: 0.9})
            )  # fmt: skip
        return state

    assert isinstance(run(CFG), Reidentification)
    off = dataclasses.replace(CFG, reid_excludes_seen_beside=False)
    assert isinstance(run(off), Probation)  # the evidence alone would have named it


def test_a_frame_not_learnt_at_risk_sets_neither_the_stature_nor_who_was_seen_beside():
    """After a crossing the tracker may carry a stranger on the target's track and the
    target on another. A frame in which someone else scores higher is not learnt, and it
    vouches for nothing else either: the stranger's height must not become the bar the
    real target is then refused by, nor the real target, on its other track, count as a
    person seen beside it. A frame in which the target leads vouches for both."""

    def run(stranger_score):
        ctx = tracked_context(stamp_s=10.0, observed={1: 20, 2: 20, 3: 20})
        tracking = Tracking(1)
        t = 10.1
        crossing = [
            person(1, 2.0, last_seen_s=t),
            person(2, 2.0 + 0.5 * CFG.identity_risk_distance_m, last_seen_s=t),
        ]
        tracking.update(ctx, frame(crossing, t, {1: 0.9, 2: -0.5}))  # its identity at risk
        assert len(ctx.model.learnt) == 1  # the target leads: learnt
        for _ in range(5):  # track 1 now a taller stranger; the target on 3, 2 m away
            t += 0.1
            after = [person(1, 2.0, neck_height_m=1.60, last_seen_s=t),
                     person(3, 4.0, last_seen_s=t)]  # fmt: skip
            assert tracking.update(ctx, frame(after, t, {1: stranger_score, 3: 0.7})) is tracking
        return ctx

    doubted = run(stranger_score=0.05)
    assert len(doubted.model.learnt) == 1 and doubted.target_height[0] == pytest.approx(1.45)
    assert not doubted.seen_beside_target(3)
    assert doubted.same_height(person(3, 4.0, neck_height_m=1.45))
    leading = run(stranger_score=0.9)
    assert len(leading.model.learnt) == 6 and leading.target_height[0] == pytest.approx(1.60)
    assert leading.seen_beside_target(3)


def swapped_after_crossing(stranger_score, **context_kwargs):
    """A crossing puts the target's identity at risk; then, for five frames, track 1
    carries a stranger 15 cm taller scoring `stranger_score`, and the target is on track
    3, 2 m away, scoring 0.7."""
    ctx = tracked_context(stamp_s=10.0, observed={1: 20, 2: 20, 3: 20}, **context_kwargs)
    tracking, t = Tracking(1), 10.1
    crossing = [person(1, 2.0, last_seen_s=t),
                person(2, 2.0 + 0.5 * CFG.identity_risk_distance_m, last_seen_s=t)]  # fmt: skip
    tracking.update(ctx, frame(crossing, t, {1: 0.9, 2: -0.5}))
    for _ in range(5):
        t += 0.1
        after = [person(1, 2.0, neck_height_m=1.60, last_seen_s=t), person(3, 4.0, last_seen_s=t)]
        assert tracking.update(ctx, frame(after, t, {1: stranger_score, 3: 0.7})) is tracking
    return ctx


@pytest.mark.parametrize(
    ("reid", "config"),
    [(False, CFG), (True, dataclasses.replace(CFG, learn_needs_lead_at_risk="never"))],
)
def test_a_frame_learnt_at_risk_without_a_lead_vouches_for_neither_stature_nor_who_is_beside(
    reid, config
):
    """Without a re-id cue (or where learning needs no lead) a frame at risk is learnt
    whoever scores higher, but its stature and who was seen beside it still need the
    target's lead, for every identifier: the stranger's height must not become the bar
    the real target is refused by, nor the real target count as seen beside it."""
    doubted = swapped_after_crossing(0.05, reid=reid, config=config)
    assert len(doubted.model.learnt) == 6  # learnt all the same
    assert doubted.target_height[0] == pytest.approx(1.45)
    assert not doubted.seen_beside_target(3)
    assert doubted.same_height(person(3, 4.0, neck_height_m=1.45))
    leading = swapped_after_crossing(0.9, reid=reid, config=config)
    assert leading.target_height[0] == pytest.approx(1.60) and leading.seen_beside_target(3)


def test_on_probation_without_re_id_only_a_frame_the_candidate_leads_marks_others_beside_it():
    """A handover is an identity risk: on probation a frame in which someone else scores
    higher than the candidate is learnt without a re-id cue, but marks nobody as seen
    beside the target (that person may be the target)."""

    def marked(other_score):
        ctx = tracked_context(stamp_s=10.0, observed={7: 20, 9: 20}, reid=False)
        state = Probation(7, since_s=10.5)
        beside = [person(7, 2.5), person(9, 2.5, y_m=5.0)]  # well apart
        assert state.update(ctx, frame(beside, 10.6, {7: 0.5, 9: other_score})) is state
        assert len(ctx.model.learnt) == 1
        return ctx.seen_beside_target(9)

    assert not marked(other_score=0.8)
    assert marked(other_score=0.1)


def test_a_person_who_came_near_the_target_may_still_be_it():
    """Where the tracker could have swapped the two tracks, the other one may carry the
    target now: it is not excluded."""
    ctx = tracked_context(stamp_s=10.0, observed={1: 5, 2: 5})
    tracking = Tracking(1)
    apart = [person(1, 2.0, last_seen_s=10.1), person(2, 5.0, last_seen_s=10.1)]
    tracking.update(ctx, frame(apart, 10.1, {1: 0.9, 2: -0.5}))
    assert ctx.seen_beside_target(2)
    near = [person(1, 2.0, last_seen_s=10.2),
            person(2, 2.0 + 0.5 * CFG.identity_risk_distance_m, last_seen_s=10.2)]  # fmt: skip
    tracking.update(ctx, frame(near, 10.2, {1: 0.9, 2: -0.5}))
    assert not ctx.seen_beside_target(2)
    touching = {1: (0, 0, 100, 200), 2: (90, 0, 190, 200)}  # boxes touch, 3 m apart
    ctx.seen_apart.add(2)
    tracking.update(ctx, frame(apart, 10.3, {1: 0.9, 2: -0.5}, boxes=touching))
    assert not ctx.seen_beside_target(2)


# ----------------------------------------------------------------------------- probation
def test_probation_sends_back_a_candidate_whose_settling_stature_is_not_the_targets():
    ctx = tracked_context(stamp_s=10.0, observed={7: 20})
    target_height = ctx.target_height
    state = Probation(7, since_s=10.5)
    assert state.status == TargetStatus.TRACKING  # named and followed meanwhile
    same = [person(7, 2.5)]
    beside = [person(7, 2.5), person(9, 2.5, y_m=5.0)]  # someone else, well apart
    assert state.update(ctx, frame(beside, 10.6, {7: 0.9, 9: 0.0}, {7: 0.9})) is state
    assert ctx.target_height == target_height  # compared with the target, not itself
    assert len(ctx.model.learnt) == 1 and ctx.last_target_s == 10.6  # tracked meanwhile
    assert ctx.seen_beside_target(9)
    taller = [person(7, 2.5, neck_height_m=1.45 + 0.2)]
    nxt = state.update(ctx, frame(taller, 10.7, {7: 0.9}, {7: 0.9}))
    assert isinstance(nxt, Reidentification) and 7 in ctx.rejected
    # What it taught and where it walked are undone: it was never the target.
    assert ctx.model.learnt == [] and ctx.last_target_s == 10.0
    assert not ctx.seen_beside_target(9)  # seen beside a stranger, it may be the target
    # The same track is never named again, however good its evidence.
    strong = reid_frames(nxt, ctx, [person(7, 2.5)], 10.8, {7: 0.95}, {7: 0.95}, n=20)
    assert all(isinstance(s, Reidentification) for s in strong)
    # Losing the track on probation is re-identification too.
    assert isinstance(Probation(8, 10.5).update(ctx, frame(same, 10.9, {7: 0.9})),
                      Reidentification)  # fmt: skip


def test_probation_ends_in_tracking_once_the_stature_held_for_its_time():
    ctx = tracked_context(stamp_s=10.0, observed={7: 20})
    state = Probation(7, since_s=10.5)
    t, states = 10.5, []
    while t < 10.5 + CFG.reid_probation_s + 0.25:
        t += 0.1
        states.append(state.update(ctx, frame([person(7, 2.5)], t, {7: 0.9}, {7: 0.9})))
    waiting = [s for s in states if s is state]
    assert len(waiting) >= int(CFG.reid_probation_s / 0.1) - 1
    assert isinstance(states[-1], Tracking) and states[-1].target_id == 7
    assert len(ctx.model.learnt) == len(states)  # learnt on probation as when tracking


def test_a_reidentified_track_does_not_set_the_stature_the_target_is_judged_by():
    """A stranger who passes every test (the twin in the target's clothes, 3 cm taller)
    is followed, but its height must not become the bar: the real target, back once the
    twin has gone, must still pass the stature test."""
    ctx = tracked_context(stamp_s=10.0, observed={7: 20, 9: 20})
    assert ctx.target_height[0] == pytest.approx(1.45)
    twin = dict(neck_height_m=1.48, height_std_m=0.002)
    state, t = Probation(7, since_s=10.5), 10.5
    for _ in range(int(CFG.reid_probation_s / 0.1) + 35):  # probation, then 3 s followed
        t += 0.1
        state = state.update(ctx, frame([person(7, 2.5, **twin)], t, {7: 0.9}, {7: 0.9}))
    assert type(state) is Tracking and state.target_id == 7  # the twin passed
    assert ctx.target_height[0] == pytest.approx(1.45)
    assert ctx.same_height(person(9, 2.0, neck_height_m=1.44, height_std_m=0.002))


def test_the_stature_is_not_taken_from_a_frame_in_which_another_person_covers_the_target():
    """Another person's box covering the target's: its skeleton may carry that person's
    feet, and its height must not become the bar, as its appearance is not learnt. The
    bar stays the one from the last clear frame, in initial training and tracking, and
    the target coming back at that height is still taken for itself."""
    covered = {1: (0, 0, 100, 200), 2: (20, 0, 120, 200)}  # 80 % of the target covered
    taller = dict(neck_height_m=1.60, last_seen_s=10.1)
    ctx = context()
    training = InitialTraining(1)
    training.update(ctx, frame([person(1, 2.0), person(2, 2.3)], 9.9, {1: 0.0, 2: 0.0}))
    training.update(ctx, frame([person(1, 2.0, neck_height_m=1.60), person(2, 2.3)], 10.0,
                               {1: 0.0, 2: 0.0}, boxes=covered))  # fmt: skip
    assert ctx.target_height[0] == pytest.approx(1.45)
    ctx = tracked_context(stamp_s=10.0, observed={1: 20, 7: 20})
    tracking = Tracking(1)
    together = [person(1, 2.0, **taller), person(2, 2.3, last_seen_s=10.1)]
    assert tracking.update(ctx, frame(together, 10.1, {1: 0.9, 2: -0.5}, boxes=covered)) is tracking
    assert ctx.model.learnt == []  # confirmed, but its crop shows the other person
    assert ctx.target_height[0] == pytest.approx(1.45)
    assert ctx.same_height(person(7, 2.5, neck_height_m=1.45))


def test_probation_judges_no_stature_while_another_person_covers_the_candidate():
    """Another person's box over the candidate's: its skeleton may carry that person's
    feet, so its height that frame is no evidence against it (as tracking takes no
    stature from such a frame), nor a frame that counts towards ending probation; once
    clear, the stature test applies again."""
    covered = {7: (0, 0, 100, 200), 2: (20, 0, 120, 200)}  # 80 % of the candidate covered
    ctx = tracked_context(stamp_s=10.0, observed={7: 20, 2: 20})
    state = Probation(7, since_s=10.5)
    crossing = [person(7, 2.5, neck_height_m=1.65), person(2, 2.7)]
    assert state.update(ctx, frame(crossing, 10.6, {7: 0.9, 2: -0.5}, {7: 0.9},
                                   boxes=covered)) is state  # fmt: skip
    assert 7 not in ctx.rejected and state.observed == 0
    assert state.update(ctx, frame([person(7, 2.5)], 10.7, {7: 0.9}, {7: 0.9})) is state
    assert state.observed == 1
    taller = [person(7, 2.5, neck_height_m=1.65)]
    assert isinstance(state.update(ctx, frame(taller, 10.8, {7: 0.9}, {7: 0.9})), Reidentification)
    assert 7 in ctx.rejected


def test_probation_ends_only_after_enough_frames_whose_stature_was_judged():
    """A candidate covered by another person for the rest of its probation time is not
    yet the target: the frames that judged its stature are too few."""
    covered = {7: (0, 0, 100, 200), 2: (20, 0, 120, 200)}
    ctx = tracked_context(stamp_s=10.0, observed={7: 20, 2: 20})
    state, t = Probation(7, since_s=10.5), 10.5
    while t < 10.5 + CFG.reid_probation_s + 0.5:
        t += 0.1
        together = [person(7, 2.5), person(2, 2.7)]
        state = state.update(ctx, frame(together, t, {7: 0.9, 2: -0.5}, {7: 0.9}, boxes=covered))
        assert isinstance(state, Probation)
    for _ in range(CFG.min_target_observations):
        t += 0.1
        state = state.update(ctx, frame([person(7, 2.5)], t, {7: 0.9}, {7: 0.9}))
    assert type(state) is Tracking and state.target_id == 7


def test_probation_starts_its_time_and_count_again_after_a_gap_between_frames():
    """A stall of perception may hand the candidate's track to someone else: the frames
    and the time before it prove nothing, so one frame after it ends no probation."""
    ctx = tracked_context(stamp_s=10.0, observed={7: 20})
    state, t = Probation(7, since_s=10.5), 10.5
    for _ in range(CFG.min_target_observations - 1):
        t += 0.1
        state = step(state, ctx, frame([person(7, 2.5, last_seen_s=t)], t, {7: 0.9}, {7: 0.9}))
    t += CFG.reid_probation_s  # no frame meanwhile
    assert step(state, ctx, frame([person(7, 2.5, last_seen_s=t)], t, {7: 0.9}, {7: 0.9})) is state
    assert state.observed == 1 and state.since_s == t
    stall_s = t
    while t < stall_s + CFG.reid_probation_s - 0.05:
        t += 0.1
        state = step(state, ctx, frame([person(7, 2.5, last_seen_s=t)], t, {7: 0.9}, {7: 0.9}))
        assert isinstance(state, Probation)
    t += 0.1
    state = step(state, ctx, frame([person(7, 2.5, last_seen_s=t)], t, {7: 0.9}, {7: 0.9}))
    assert type(state) is Tracking and state.target_id == 7
