"""The identifier's guards against following the wrong person, each driven through the
real states with scripted frames (tests/test_identify_states.py) or the real identifier:
a failed probation leaves no trace in the frame it ends in; evidence counts only in
consecutive frames in which the candidate is seen; probation needs the candidate seen,
and doubts it from its start to its end; the target's stature comes only from frames
that vouched for it; nothing is learnt while someone, seen or half out of view, covers
the target's crop or the target covers theirs; a selected track must be confirmed; "the nearest
person" forgets an earlier selection; a frame stamped before the last, or as the last,
is ignored; a tie is no lead; a stall of perception (no frame for longer than
`identity_risk_unseen_s`) puts the target's identity at risk and ends every
candidate's run of evidence."""

from __future__ import annotations

import collections
import dataclasses

import numpy as np
import pytest
from test_identify_state_machine import BLUE, RED, Person, run
from test_identify_state_machine import CFG as CHANNELS_CFG
from test_identify_state_machine import frame as scene
from test_identify_states import CFG, IMAGE, context, frame, person, tracked_context

import follow.identify.context as context_module
from follow.ccf.channels import ChannelFeatureExtractor
from follow.identify.appearance import Appearance
from follow.identify.context import FrameTracks, IdentityContext
from follow.identify.identifier import TargetIdentifier
from follow.identify.states import Initial, Probation, Reidentification, State, Tracking
from follow.types import Observation, Odometry, TargetStatus, TrackState


class TaughtModel:
    """A model whose confidences change once it is taught: `clean` before, `taught`
    after; with `reid`, embeddings only where asked (`describe`'s `embed`)."""

    ready = True

    def __init__(self, clean, taught, reid=False):
        self.clean, self.taught, self.reid = clean, taught, reid
        self.learnt = []

    def reset(self):
        self.learnt = []

    def describe(self, image, rois, embed=None):
        return [Appearance(maps=np.array([roi[0] // 100]),
                           embedding=np.ones(1) if self.reid and (embed is None or embed[k])
                           else None) for k, roi in enumerate(rois)]  # fmt: skip

    @property
    def has_reid(self):
        return self.reid

    def lacks_embedding(self, appearance):
        return self.reid and appearance.embedding is None

    def complete(self, image, rois, appearances):
        return [dataclasses.replace(a, embedding=np.ones(1)) for a in appearances]

    def confidence(self, appearances):
        table = self.taught if self.learnt else self.clean
        return np.array([table[int(a.maps[0])] for a in appearances])

    def classifier_confidence(self, appearances):
        return None

    def part_distances(self, appearances):
        return None

    def similarity(self, appearances):
        if not self.reid or not appearances:
            return None
        return np.array([0.95 if a.embedding is not None else np.nan for a in appearances])

    def learn(self, positives, negatives, synthetic=(), mirrored=()):
        self.learnt.append((len(positives), len(negatives)))

    def crop(self, image, roi):
        return None

    def synthetic_negatives(self, crop, n):
        return []

    def mirrored_positives(self, crop):
        return []

    def snapshot(self):
        return list(self.learnt)

    def restore(self, snapshot):
        self.learnt = list(snapshot)


def _unscored(tracks, stamp_s) -> FrameTracks:
    return FrameTracks(IMAGE, list(tracks), stamp_s, None, {t.track_id: t for t in tracks})


def _ended_probation(monkeypatch, reid: bool):
    """Candidate 7 is named; once it has taught the model, the model likes stranger 8;
    8 then comes near 7, whose confidence drops: probation ends in that frame."""
    monkeypatch.setattr(context_module, "track_rois", lambda tracks, size, cfg: {
        t.track_id: (100 * t.track_id, 0, 100 * t.track_id + 50, 200)
        for t in tracks if t.observation is not None})  # fmt: skip
    monkeypatch.setattr(context_module, "person_boxes", lambda tracks, rois, size, cfg: dict(rois))
    config = dataclasses.replace(CFG, reid_frames=1)
    model = TaughtModel(clean={7: 0.0, 8: -0.5}, taught={7: -0.5, 8: 0.9}, reid=reid)
    ctx = IdentityContext(config, model)
    ctx.observed_frames = {7: 20, 8: 20}
    seen = frame([person(1, 2.0, last_seen_s=10.0)], 10.0, {1: 0.9})
    ctx.note_target(1, seen)
    ctx.note_stature(1, seen)
    state = Probation(7, since_s=10.5).update(ctx, _unscored([person(7, 2.5, last_seen_s=10.6)],
                                                             10.6))  # fmt: skip
    assert isinstance(state, Probation) and model.learnt
    near = [person(7, 2.5, last_seen_s=10.7), person(8, 3.2, last_seen_s=10.7)]
    after = state.update(ctx, _unscored(near, 10.7))
    assert model.learnt == []  # undone
    return after


def test_the_frame_a_probation_ends_in_is_judged_by_the_model_as_it_was(monkeypatch):
    assert isinstance(_ended_probation(monkeypatch, reid=False), Reidentification)
    lazy = _ended_probation(monkeypatch, reid=True)
    look = IdentityContext.look
    monkeypatch.setattr(IdentityContext, "look",
                        lambda self, f, only=None, embed=True: look(self, f))  # fmt: skip
    every_frame = _ended_probation(monkeypatch, reid=True)
    assert (type(lazy), lazy.target_id) == (type(every_frame), every_frame.target_id)


def test_a_streak_ends_in_a_frame_the_candidate_is_not_seen_in():
    ctx = tracked_context(stamp_s=10.0, observed={7: 5})
    state = Reidentification()
    assert state.update(ctx, frame([person(7, 2.5)], 10.1, {7: 0.9}, {7: 0.9})) is state
    hidden = person(7, 2.5, observed=False, last_seen_s=10.1)
    assert state.update(ctx, frame([hidden], 10.2, {})) is state
    assert state.streaks == {7: 0}
    seen = frame([person(7, 2.5, last_seen_s=10.3)], 10.3, {7: 0.9}, {7: 0.9})
    assert isinstance(state.update(ctx, seen), Reidentification)  # one pass, not two


def _streak_across_a_gap(gap_s: float) -> tuple[State, Reidentification]:
    """Candidate 7 passes in `reid_frames` - 1 frames at 10 fps, then in one more frame
    after no frame at all for `gap_s` (each frame noted, as the identifier does)."""
    ctx = tracked_context(stamp_s=10.0, observed={7: 5})
    ctx.note_frame(10.0)
    state = Reidentification()
    t = 10.0
    for _ in range(CFG.reid_frames - 1):
        t += 0.1
        ctx.note_frame(t)
        seen = frame([person(7, 2.5, last_seen_s=t)], t, {7: 0.9}, {7: 0.9})
        assert state.update(ctx, seen) is state
    t += gap_s
    ctx.note_frame(t)
    seen = frame([person(7, 2.5, last_seen_s=t)], t, {7: 0.9}, {7: 0.9})
    return state.update(ctx, seen), state


def test_a_streak_ends_across_a_stall_of_perception():
    """No frame for longer than `identity_risk_unseen_s`: every track went unseen, and
    the tracker may have moved the candidate's track onto someone else in the gap, though
    it is matched again at once. The frame after the gap starts the run again."""
    after, state = _streak_across_a_gap(1.0)
    assert after is state and state.streaks == {7: 1}
    short = 0.3
    assert short < CFG.identity_risk_unseen_s  # frames this close decide as they did
    after, _ = _streak_across_a_gap(short)
    assert isinstance(after, Probation) and after.target_id == 7


def test_probation_needs_the_candidate_seen_not_only_time():
    ctx = tracked_context(stamp_s=10.0, observed={7: 20})
    state, t = Probation(7, since_s=10.5), 10.5
    while t < 10.5 + CFG.reid_probation_s + 0.05:
        t += 0.1
        state = state.update(ctx, frame([person(7, 2.5, observed=False, last_seen_s=10.5)], t, {}))
    assert type(state) is Probation
    one_check = Probation(7, since_s=10.5).update(
        tracked_context(stamp_s=10.0, observed={7: 20}),
        frame([person(7, 2.5)], 10.5 + CFG.reid_probation_s, {7: 0.9}, {7: 0.9}))  # fmt: skip
    assert type(one_check) is Probation


def test_a_candidate_on_probation_is_doubted_from_the_start():
    """The old target's track was trusted long ago; the candidate's low confidence is not
    excused as a turn."""
    low = CFG.id_switch_confidence - 0.3
    ctx = tracked_context(stamp_s=10.0, observed={7: 50})
    state = Probation(7, since_s=30.0)
    state = state.update(ctx, frame([person(7, 2.5, last_seen_s=30.1)], 30.1, {7: low}, {7: 0.0}))
    assert isinstance(state, Reidentification)


def test_a_candidate_on_probation_is_doubted_to_its_end():
    """Seen alone and liked for longer than `identity_trust_s`, the candidate's low
    confidence before its probation ends is still not excused as a turn."""
    assert CFG.identity_trust_s < CFG.reid_probation_s
    low = CFG.id_switch_confidence - 0.3
    ctx = tracked_context(stamp_s=10.0, observed={7: 50})
    state, t = Probation(7, since_s=10.5), 10.5
    while t < 10.5 + CFG.identity_trust_s + 0.1:
        t += 0.1
        state = state.update(ctx, frame([person(7, 2.5, last_seen_s=t)], t, {7: 0.9}, {7: 0.9}))
    assert type(state) is Probation and ctx.identity_trusted(t)
    t += 0.1
    state = state.update(ctx, frame([person(7, 2.5, last_seen_s=t)], t, {7: low}, {7: 0.0}))
    assert isinstance(state, Reidentification)
    assert ctx.model.learnt == [] and ctx.last_target_s == 10.0  # undone


def test_the_targets_stature_comes_only_from_frames_that_vouched_for_it():
    low = CFG.id_switch_confidence - 0.1
    ctx = tracked_context(stamp_s=10.0)
    state = Tracking(1)
    covered = {1: (0, 0, 100, 200), 2: (40, 0, 140, 200)}
    for k in range(5):
        t = 10.1 + 0.1 * k
        crossing = [person(1, 2.0, neck_height_m=1.37, last_seen_s=t),
                    person(2, 2.3, last_seen_s=t)]  # fmt: skip
        assert state.update(ctx, frame(crossing, t, {1: low, 2: 0.9}, boxes=covered)) is state
    assert ctx.target_height[0] == 1.45


def test_nothing_is_learnt_while_a_person_half_out_of_view_covers_the_target():
    """A passer-by close to the camera, feet out of view: too clipped for a crop of
    their own, they still hide the target."""
    likes_everyone = collections.defaultdict(lambda: 0.9)
    ctx = IdentityContext(CFG, TaughtModel(clean=likes_everyone, taught=likes_everyone))
    seen = frame([person(1, 2.0, last_seen_s=10.0)], 10.0, {1: 0.9})
    ctx.note_target(1, seen)
    ctx.note_stature(1, seen)
    cov = np.eye(5) * 1e-4
    target = TrackState(1, np.array([2.0, 0, 0, 0, 1.45]), cov, True, 10.1,
                        observation=Observation(np.array([320.0, 120.0]),
                                                np.array([320.0, 400.0])))  # fmt: skip
    passer = TrackState(2, np.array([0.8, 0, 0, 0, 1.45]), cov, True, 10.1,
                        expected_neck_px=np.array([330.0, 300.0]),
                        expected_ankle_px=np.array([330.0, 1100.0]),
                        observation=Observation(np.array([330.0, 300.0]), None))  # fmt: skip
    image = np.zeros((480, 640, 3), np.uint8)
    scene_frame = FrameTracks(image, [target, passer], 10.1, None, {1: target, 2: passer})
    assert Tracking(1).update(ctx, scene_frame).target_id == 1
    assert 2 in scene_frame.boxes and 2 not in scene_frame.rois
    assert ctx.model.learnt == []


def test_a_person_the_target_covers_is_not_learnt_as_another_person():
    ctx = tracked_context(stamp_s=10.0)
    boxes = {1: (0, 0, 140, 378), 2: (40, 100, 100, 260)}  # 2 stands behind the target
    tracks = [person(1, 2.0, last_seen_s=10.1), person(2, 3.0, last_seen_s=10.1)]
    Tracking(1).update(ctx, frame(tracks, 10.1, {1: 0.9, 2: -0.5}, boxes=boxes))
    assert ctx.model.learnt == [(1, 0)]  # the target, and nobody as a negative


def test_a_selected_track_must_be_confirmed_by_the_tracker():
    ctx = context(observed={2: 1})
    ctx.requested_id = 2
    initial = Initial()
    ghost = dataclasses.replace(person(2, 2.0), confirmed=False)  # a few split skeletons
    assert initial.update(ctx, frame([ghost], 0.0, {2: 0.0})) is initial
    assert initial.update(ctx, frame([person(2, 2.0)], 0.1, {2: 0.0})).target_id == 2


def test_a_selected_track_lost_before_it_is_learnt_is_waited_for_with_a_warning(caplog):
    """Nobody else is taken in its place (the user chose that person), and the user is
    told to select again."""
    ctx = context(observed={2: 1, 3: 5})
    ctx.requested_id = 2
    state = Initial().update(ctx, frame([person(2, 2.0), person(3, 1.5)], 0.0, {2: 0.0, 3: 0.0}))
    assert state.target_id == 2
    for k in range(1, 20):  # track 2 is gone; 3, nearer, stays in view
        state = state.update(ctx, frame([person(3, 1.5)], 0.1 * k, {3: 0.0}))
    assert isinstance(state, Initial)
    assert "selected track 2 lost before it was learnt" in caplog.text


def test_a_tie_is_no_lead():
    ctx = tracked_context(stamp_s=10.0, observed={5: 5, 6: 5})
    state = Reidentification()
    twins = [person(5, 2.5), person(6, 2.2)]
    for k in range(3 * CFG.reid_frames):
        state = state.update(ctx, frame(twins, 10.1 + 0.1 * k, {5: 1.0, 6: 1.0}, {5: 0.9, 6: 0.9}))
    assert isinstance(state, Reidentification)


@pytest.fixture
def identifier():
    extractor = ChannelFeatureExtractor((CHANNELS_CFG.crop_width_px, CHANNELS_CFG.crop_height_px))
    return TargetIdentifier(CHANNELS_CFG, extractor)


def test_the_nearest_person_again_forgets_an_earlier_selection(identifier):
    identifier.select_target(5)
    identifier.select_nearest()
    near, far = Person(1, 2.0, 180, RED), Person(5, 4.0, 450, BLUE)
    rng = np.random.default_rng(0)
    estimates = run(identifier, [near, far], CHANNELS_CFG.min_target_observations, rng)
    assert estimates[-1].target_id == 1


def test_a_frame_stamped_before_the_last_is_ignored(identifier):
    rng = np.random.default_rng(0)
    target = Person(1, 2.0, 180, RED)
    run(identifier, [target], 12, rng)
    assert identifier.status == TargetStatus.TRACKING
    updates = identifier.model.classifier.num_updates
    seen = identifier.context.observed_frames[1]
    last = identifier.last_stamp_s
    estimate = identifier.update(*scene([target], rng, last), last - 0.6)
    assert estimate.stamp_s == last  # the newest frame's estimate, unchanged
    assert identifier.context.observed_frames[1] == seen
    assert identifier.model.classifier.num_updates == updates


def test_a_frame_stamped_the_same_as_the_last_is_ignored(identifier):
    """The tracker takes it for the last frame again and hands on the same tracks, with
    their observations: counting or learning them twice turns one sighting into two."""
    rng = np.random.default_rng(0)
    target = Person(1, 2.0, 180, RED)
    run(identifier, [target], 12, rng)
    updates = identifier.model.classifier.num_updates
    seen = identifier.context.observed_frames[1]
    last = identifier.last_stamp_s
    estimate = identifier.update(*scene([target], rng, last), last)
    assert estimate.stamp_s == last
    assert identifier.context.observed_frames[1] == seen
    assert identifier.model.classifier.num_updates == updates


def test_a_frame_ignored_after_a_new_selection_names_no_earlier_target(identifier):
    rng = np.random.default_rng(0)
    target = Person(1, 2.0, 180, RED)
    run(identifier, [target], 12, rng)
    assert identifier.status == TargetStatus.TRACKING
    last = identifier.last_stamp_s
    identifier.select_target(5)
    estimate = identifier.update(*scene([target], rng, last), last - 0.1)
    assert (estimate.status, estimate.target_id) == (TargetStatus.INITIAL, None)
    assert estimate.stamp_s == last and identifier.last_stamp_s == last  # still ignored


def _scripted_identifier(monkeypatch, scores: dict[int, float]) -> TargetIdentifier:
    """The real identifier, track 1 selected, on a model that scores each track as
    `scores` says (changed in place as the test goes)."""
    monkeypatch.setattr(context_module, "track_rois", lambda tracks, size, cfg: {
        t.track_id: (100 * t.track_id, 0, 100 * t.track_id + 50, 200)
        for t in tracks if t.observation is not None})  # fmt: skip
    monkeypatch.setattr(context_module, "person_boxes", lambda tracks, rois, size, cfg: dict(rois))
    extractor = ChannelFeatureExtractor((CFG.crop_width_px, CFG.crop_height_px))
    identifier = TargetIdentifier(CFG, extractor)
    identifier.context.model = TaughtModel(clean=scores, taught=scores)
    identifier.select_target(1)
    return identifier


def _after_a_stall(monkeypatch, gap_s: float):
    """Track 1 is selected, learnt and tracked for 3 s at 15 fps, track 2 always 2 m
    away (nobody near, never unseen); then perception stalls, no frame at all for
    `gap_s`, and in the next frame track 1 is matched again but scores low while track 2
    scores high. The identifier and its estimate of that frame."""
    scores = {1: 0.9, 2: -0.5}
    identifier = _scripted_identifier(monkeypatch, scores)

    def both(t):
        return [person(1, 2.0, last_seen_s=t), person(2, 4.0, last_seen_s=t)]

    for k in range(45):
        t = 10.0 + k / 15.0
        estimate = identifier.update(IMAGE, both(t), t)
    assert (estimate.status, estimate.target_id) == (TargetStatus.TRACKING, 1)
    assert identifier.context.identity_trusted(t)
    scores.update({1: -0.5, 2: 0.9})
    t += gap_s
    return identifier, identifier.update(IMAGE, both(t), t)


def test_a_stall_of_perception_puts_the_identity_at_risk(monkeypatch):
    """No frame for 1.5 s: the tracker may have put anyone on the target's track, though
    it is matched again in the next frame (never seen to coast). Its low score is not
    excused as a turn: the target is doubted, as after its track went unseen."""
    identifier, estimate = _after_a_stall(monkeypatch, 1.5)
    assert estimate.status == TargetStatus.REIDENTIFICATION and estimate.target_id is None
    assert identifier.context.identity_risk_s == estimate.stamp_s


def test_a_gap_shorter_than_identity_risk_unseen_s_still_excuses_a_turn(monkeypatch):
    gap_s = 0.3
    assert gap_s < CFG.identity_risk_unseen_s
    identifier, estimate = _after_a_stall(monkeypatch, gap_s)
    assert (estimate.status, estimate.target_id) == (TargetStatus.TRACKING, 1)
    assert identifier.context.identity_risk_s == -np.inf


def test_a_target_first_chosen_after_a_stall_is_not_at_risk(monkeypatch):
    """The gap is before the frame the target is chosen from: nobody was named whose track
    the tracker could have swapped, as a track chosen is one seen now."""
    scores = {1: 0.9, 2: -0.5}
    identifier = _scripted_identifier(monkeypatch, scores)
    for t in (10.0, 10.1):
        identifier.update(IMAGE, [person(2, 4.0, last_seen_s=t)], t)
    assert identifier.status == TargetStatus.INITIAL
    t = 10.1 + 1.5
    both = [person(1, 2.0, last_seen_s=t), person(2, 4.0, last_seen_s=t)]
    estimate = identifier.update(IMAGE, both, t)
    assert (estimate.status, estimate.target_id) == (TargetStatus.INITIAL_TRAINING, 1)
    assert identifier.context.identity_risk_s == -np.inf


def test_the_targets_last_position_follows_an_odometry_jump(monkeypatch):
    """The target is lost 3 m ahead; then the robot's heading is reset by a quarter turn
    (an estimator's yaw reset), and the tracker moves every track into the new odom
    frame, where it stands relative to the robot. The target's last position must move
    with them: left in the old frame, the place the target vanished from lies 3 m to the
    robot's side, where a look-alike is taken for it and the target, back where it was
    ahead of the robot, is out of reach."""
    scores = {1: 0.9, 2: 0.9, 3: 0.95}
    identifier = _scripted_identifier(monkeypatch, scores)
    t = 10.0
    for _ in range(8):
        t += 1 / 15
        estimate = identifier.update(IMAGE, [person(1, 3.0, last_seen_s=t)], t,
                                     robot=Odometry(0.0, 0.0, 0.0, t))  # fmt: skip
    assert (estimate.status, estimate.target_id) == (TargetStatus.TRACKING, 1)
    t += 1 / 15
    estimate = identifier.update(IMAGE, [], t, robot=Odometry(0.0, 0.0, 0.0, t))
    assert estimate.status == TargetStatus.REIDENTIFICATION
    turned = np.pi / 2  # the robot did not move; its heading was reset
    for _ in range(5):  # a look-alike where the old frame's "3 m ahead" is now
        t += 1 / 15
        stranger = person(2, 3.0, 0.5, last_seen_s=t)
        estimate = identifier.update(IMAGE, [stranger], t, robot=Odometry(0.0, 0.0, turned, t))
        assert estimate.target_id is None
    for _ in range(4):  # the target back 3 m ahead of the robot, in the new frame
        t += 1 / 15
        both = [person(2, 3.0, 0.5, last_seen_s=t), person(3, 0.0, 3.0, last_seen_s=t)]
        estimate = identifier.update(IMAGE, both, t, robot=Odometry(0.0, 0.0, turned, t))
    assert estimate.target_id == 3


def test_a_probation_undone_after_an_odometry_jump_puts_back_the_moved_position():
    ctx = tracked_context(target_position_m=(3.0, 0.0), stamp_s=10.0)
    ctx.note_frame(10.0, Odometry(0.0, 0.0, 0.0, 10.0))
    named = ctx.whereabouts()  # a candidate is named: its probation begins
    ctx.note_frame(10.1, Odometry(0.0, 0.0, np.pi / 2, 10.1))  # a yaw reset
    ctx.last_target_position_m = np.array([5.0, 5.0])  # where the candidate walked
    ctx.restore(named)  # the probation fails
    assert ctx.last_target_position_m == pytest.approx([0.0, 3.0])
