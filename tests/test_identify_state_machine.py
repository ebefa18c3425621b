"""The target state machine on scripted tracks and synthetic images."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest

from follow.ccf.channels import ChannelFeatureExtractor
from follow.ccf.roi import covered_fraction
from follow.config import IdentifyConfig
from follow.identify.identifier import TargetIdentifier
from follow.types import InvalidInput, Observation, Odometry, TargetStatus, TrackState

IMAGE_SIZE = (640, 480)
RED, BLUE, GREEN, GRAY = (40, 40, 200), (200, 60, 40), (40, 180, 40), (120, 120, 120)
CFG = IdentifyConfig(
    identifier="channels", initial_training_frames=5, reid_frames=3, min_target_observations=1
)


class Person:
    def __init__(self, track_id, x_m, column_px, shirt, trousers=GRAY, confirmed=True):
        self.track_id, self.x_m, self.column_px = track_id, x_m, column_px
        self.shirt, self.trousers, self.confirmed = shirt, trousers, confirmed
        self.observed = True
        self.last_seen_s = 0.0


def frame(people, rng, stamp_s=0.0):
    image = rng.integers(90, 140, size=(IMAGE_SIZE[1], IMAGE_SIZE[0], 3), dtype=np.uint8)
    tracks = []
    for p in people:
        if p.observed:
            p.last_seen_s = stamp_s
        neck = np.array([p.column_px, 120.0])
        ankle = np.array([p.column_px, 400.0])
        x0, x1 = int(p.column_px - 45), int(p.column_px + 45)
        image[100:260, x0:x1] = p.shirt
        image[260:410, x0 + 10 : x1 - 10] = p.trousers
        image[100:410, x0:x1] = np.clip(
            image[100:410, x0:x1] + rng.normal(0, 6, (310, x1 - x0, 3)), 0, 255
        ).astype(np.uint8)
        tracks.append(
            TrackState(
                p.track_id, np.array([p.x_m, 0.0, 0.0, 0.0, 1.45]), np.eye(5) * 0.1,
                p.confirmed, p.last_seen_s,
                observation=Observation(neck, ankle) if p.observed else None,
            )
        )  # fmt: skip
    return image, tracks


def run(identifier, people, n, rng, t0=None):
    """n frames 0.1 s apart from t0, by default just after the identifier's last frame
    (it ignores a frame not stamped after the last)."""
    if t0 is None:
        t0 = 0.0 if identifier.last_stamp_s is None else identifier.last_stamp_s + 0.1
    out = []
    for k in range(n):
        image, tracks = frame(people, rng, t0 + k / 10.0)
        out.append(identifier.update(image, tracks, t0 + k / 10.0))
    return out


@pytest.fixture
def identifier():
    return TargetIdentifier(CFG, ChannelFeatureExtractor((CFG.crop_width_px, CFG.crop_height_px)))


def test_lost_target_is_reidentified_under_a_new_track_id(identifier):
    rng = np.random.default_rng(0)
    target = Person(1, 2.0, 180, RED)
    other = Person(2, 3.5, 460, BLUE)
    est = run(identifier, [target, other], 1, rng)[0]
    assert est.status == TargetStatus.INITIAL_TRAINING and est.target_id == 1  # nearest
    est = run(identifier, [target, other], CFG.initial_training_frames - 1, rng)[-1]
    assert est.status == TargetStatus.TRACKING and est.target_id == 1

    tracking = run(identifier, [target, other], 5, rng)
    assert all(e.status == TargetStatus.TRACKING and e.target_id == 1 for e in tracking)
    assert all(e.confidences[1] > CFG.reid_confidence > e.confidences[2] for e in tracking)

    lost = run(identifier, [other], 4, rng)  # the target leaves the view
    assert all(e.status == TargetStatus.REIDENTIFICATION and e.target_id is None for e in lost)
    assert all(e.confidences[2] < CFG.reid_confidence for e in lost)

    back = Person(7, 2.5, 300, RED)  # comes back: the tracker gives a new id
    ests = run(identifier, [back, other], CFG.reid_frames, rng)
    assert [e.status for e in ests[:-1]] == [TargetStatus.REIDENTIFICATION] * (CFG.reid_frames - 1)
    assert ests[-1].status == TargetStatus.TRACKING and ests[-1].target_id == 7


def test_confidence_drop_triggers_reidentification(identifier):
    rng = np.random.default_rng(1)
    target = Person(1, 2.0, 180, RED)
    other = Person(2, 3.5, 460, BLUE)
    run(identifier, [target, other], CFG.initial_training_frames + 3, rng)
    assert identifier.status == TargetStatus.TRACKING
    other.column_px, other.x_m = 240, 2.5  # the other walks past, close to the target
    run(identifier, [target, other], 1, rng)
    # and the tracker swaps identities: track 1 now follows the other person
    swapped = [Person(1, 2.0, 180, BLUE), Person(2, 3.0, 460, RED)]
    est = run(identifier, swapped, 1, rng)[0]
    assert est.confidences[1] < CFG.id_switch_confidence
    assert est.status == TargetStatus.REIDENTIFICATION and est.target_id is None
    ests = run(identifier, swapped, CFG.reid_frames, rng)
    assert ests[-1].status == TargetStatus.TRACKING and ests[-1].target_id == 2


def test_an_appearance_change_with_nobody_near_keeps_the_target(identifier):
    rng = np.random.default_rng(4)
    target = Person(1, 2.0, 180, RED)
    other = Person(2, 4.0, 460, BLUE)  # 2 m behind and to the side: no swap possible
    run(identifier, [target, other], CFG.initial_training_frames + 3, rng)
    target.shirt = BLUE  # turns round, takes off a jacket: nobody else came near
    ests = run(identifier, [target, other], 5, rng)  # (no stall of frames either)
    assert all(e.confidences[1] < CFG.id_switch_confidence for e in ests)  # it looks new
    assert all(e.status == TargetStatus.TRACKING and e.target_id == 1 for e in ests)
    target.shirt = RED  # and nothing of the new look was learnt
    assert run(identifier, [target, other], 1, rng)[0].confidences[1] > 0.5


def test_a_low_confidence_while_someone_covers_the_target_waits_for_a_clear_view(identifier):
    rng = np.random.default_rng(5)
    target = Person(1, 2.0, 180, RED)
    other = Person(2, 3.5, 460, BLUE)
    run(identifier, [target, other], CFG.initial_training_frames + 3, rng)
    assert identifier.target_id == 1
    # The other passes close by, 0.4 m away on the floor (identity at risk): their boxes
    # overlap and the target's crop shows the other's blue coat.
    other.column_px, other.x_m = 200, 2.4
    target.shirt = BLUE
    ests = run(identifier, [target, other], 4, rng, t0=2.0)
    assert all(e.confidences[1] < CFG.id_switch_confidence for e in ests)
    assert all(e.status == TargetStatus.TRACKING and e.target_id == 1 for e in ests)
    # Clear again, and still the target: tracking goes on.
    other.column_px, target.shirt = 460, RED
    est = run(identifier, [target, other], 1, rng, t0=2.5)[0]
    assert est.status == TargetStatus.TRACKING and est.target_id == 1
    # Had the tracker swapped them, the clear view shows it: re-identification.
    target.shirt = BLUE
    est = run(identifier, [target, other], 1, rng, t0=2.6)[0]
    assert est.status == TargetStatus.REIDENTIFICATION


def test_unobserved_tracks_have_no_appearance_and_do_not_break_tracking(identifier):
    rng = np.random.default_rng(2)
    target = Person(1, 2.0, 180, RED)
    other = Person(2, 3.5, 460, BLUE)
    run(identifier, [target, other], CFG.initial_training_frames, rng)
    target.observed = False  # occluded, but its track lives on
    est = run(identifier, [target, other], 2, rng)[-1]
    assert est.status == TargetStatus.TRACKING and est.target_id == 1
    assert 1 not in est.confidences and 2 in est.confidences


def test_initial_choice_needs_a_confirmed_track_in_front_within_range(identifier):
    rng = np.random.default_rng(3)
    behind = Person(1, -1.0, 180, RED)
    far = Person(2, 9.0, 300, BLUE)
    tentative = Person(3, 1.5, 460, GREEN, confirmed=False)
    est = run(identifier, [behind, far, tentative], 2, rng)[-1]
    assert est.status == TargetStatus.INITIAL and est.target_id is None
    # the robot turned around: the person at x = -1 m is now 2 m in front of it
    image, tracks = frame([behind, far], rng)
    est = identifier.update(image, tracks, 1.0, robot=Odometry(1.0, 0.0, np.pi, 1.0))
    assert est.status == TargetStatus.INITIAL_TRAINING and est.target_id == 1


def test_selected_target_and_loss_during_initial_training(identifier):
    rng = np.random.default_rng(4)
    a, b = Person(1, 2.0, 180, RED), Person(2, 3.0, 460, BLUE)
    identifier.select_target(2)
    assert run(identifier, [a], 1, rng)[0].status == TargetStatus.INITIAL
    est = run(identifier, [a, b], 1, rng)[0]
    assert est.status == TargetStatus.INITIAL_TRAINING and est.target_id == 2
    est = run(identifier, [a], 1, rng)[0]  # lost before it was learnt
    assert est.status == TargetStatus.INITIAL and est.target_id is None


def test_bad_input_is_rejected(identifier):
    with pytest.raises(InvalidInput, match="uint8"):
        identifier.update(np.zeros((48, 64, 3), np.float32), [], 0.0)
    with pytest.raises(InvalidInput, match="stamp"):
        identifier.update(np.zeros((48, 64, 3), np.uint8), [], float("nan"))
    with pytest.raises(ValueError, match="reid_confidence"):
        TargetIdentifier(IdentifyConfig(reid_confidence=-0.5), ChannelFeatureExtractor())


def _count_learning(identifier):
    calls = []
    learn = identifier.model.learn

    def spy(positives, negatives, synthetic=(), mirrored=()):
        calls.append(len(negatives))
        learn(positives, negatives, synthetic, mirrored)

    identifier.model.learn = spy
    return calls


def test_covered_fraction():
    assert covered_fraction((0, 0, 10, 10), (5, 0, 15, 10)) == pytest.approx(0.5)
    assert covered_fraction((0, 0, 10, 10), (20, 0, 30, 10)) == 0.0
    assert covered_fraction((0, 0, 10, 10), (-5, -5, 20, 20)) == 1.0


def test_nothing_is_learnt_while_another_person_covers_the_target(identifier):
    rng = np.random.default_rng(5)
    target, other = Person(1, 2.0, 180, RED), Person(2, 3.5, 460, BLUE)
    run(identifier, [target, other], CFG.initial_training_frames, rng)
    calls = _count_learning(identifier)
    run(identifier, [target, other], 2, rng)
    assert calls == [1, 1]  # apart: the target and one negative per frame

    other.column_px = 230  # walks in front of the target: boxes 140 px wide, 50 px apart
    crossing = run(identifier, [target, other], 4, rng)
    assert len(calls) == 2
    assert all(e.status == TargetStatus.TRACKING and e.target_id == 1 for e in crossing)

    other.observed = False  # hidden behind the target: its predicted box still counts
    image, tracks = frame([target, other], rng)
    hidden = tracks[1]
    tracks[1] = TrackState(
        hidden.track_id, hidden.mean, hidden.cov, True, 0.0,
        expected_neck_px=np.array([200.0, 120.0]), expected_ankle_px=np.array([200.0, 400.0]),
    )  # fmt: skip
    identifier.update(image, tracks, 10.0)
    assert len(calls) == 2

    other.observed, other.column_px = True, 460  # apart again: learning resumes
    run(identifier, [target, other], 1, rng, t0=11.0)
    assert calls[2:] == [1]


def test_initial_training_counts_only_frames_it_could_learn(identifier, caplog):
    rng = np.random.default_rng(6)
    target, other = Person(1, 2.0, 180, RED), Person(2, 3.5, 220, BLUE)
    with caplog.at_level(logging.INFO, logger="follow"):
        ests = run(identifier, [target, other], CFG.initial_training_frames + 2, rng)
    assert all(e.status == TargetStatus.INITIAL_TRAINING for e in ests)
    waits = [r for r in caplog.records if "learning it waits" in r.getMessage()]
    assert len(waits) == 1  # said once, when the wait begins, not every frame
    other.column_px = 460
    ests = run(identifier, [target, other], CFG.initial_training_frames, rng, t0=5.0)
    assert ests[-2].status == TargetStatus.INITIAL_TRAINING
    assert ests[-1].status == TargetStatus.TRACKING and ests[-1].target_id == 1


def test_reidentification_needs_a_lead_over_every_other_track():
    cfg = dataclasses.replace(CFG, reid_margin=0.2)
    identifier = TargetIdentifier(
        cfg, ChannelFeatureExtractor((cfg.crop_width_px, cfg.crop_height_px))
    )
    rng = np.random.default_rng(7)
    target, other = Person(1, 2.0, 180, RED), Person(2, 3.5, 460, BLUE)
    run(identifier, [target, other], CFG.initial_training_frames + 3, rng)
    run(identifier, [other], 2, rng, t0=3.0)  # the target leaves: re-identification
    assert identifier.status == TargetStatus.REIDENTIFICATION

    twin_a, twin_b = Person(5, 2.5, 120, RED), Person(6, 2.5, 320, RED)  # two look-alikes
    ests = run(identifier, [twin_a, twin_b, other], 3 * CFG.reid_frames, rng, t0=4.0)
    assert all(e.confidences[5] >= CFG.reid_confidence for e in ests)
    assert all(e.confidences[6] >= CFG.reid_confidence for e in ests)
    assert all(e.status == TargetStatus.REIDENTIFICATION and e.target_id is None for e in ests)

    ests = run(identifier, [twin_b, other], CFG.reid_frames, rng, t0=8.0)  # one is left
    assert ests[-1].status == TargetStatus.TRACKING and ests[-1].target_id == 6


def test_reidentification_names_only_a_track_the_target_could_have_walked_to(identifier):
    rng = np.random.default_rng(3)
    target, other = Person(1, 2.0, 180, RED), Person(2, 3.5, 460, BLUE)
    run(identifier, [target, other], CFG.initial_training_frames + 3, rng)
    assert identifier.status == TargetStatus.TRACKING
    lost_at_s = 0.1 * (CFG.initial_training_frames + 2)
    # The target vanishes; a look-alike stands 9 m away, too far to have walked there.
    far_twin = Person(8, 11.0, 300, RED)
    ests = run(identifier, [far_twin, other], 3 * CFG.reid_frames, rng, t0=lost_at_s + 0.1)
    assert all(e.confidences[8] >= CFG.reid_confidence for e in ests)  # it looks right
    assert all(e.status == TargetStatus.REIDENTIFICATION for e in ests)
    # Once enough time has passed for the target to have walked that far, it qualifies.
    walk_s = (9.0 - CFG.reid_reach_m) / CFG.reid_reach_speed_mps
    ests = run(identifier, [far_twin, other], CFG.reid_frames, rng, t0=lost_at_s + walk_s + 0.2)
    assert ests[-1].status == TargetStatus.TRACKING and ests[-1].target_id == 8


def test_reach_parameters_must_not_be_negative():
    with pytest.raises(ValueError, match="reid_reach_m"):
        TargetIdentifier(dataclasses.replace(CFG, reid_reach_speed_mps=-1.0),
                         ChannelFeatureExtractor((CFG.crop_width_px, CFG.crop_height_px)))  # fmt: skip


def test_a_stranger_alone_in_view_is_not_taken_for_the_target():
    """The target leaves an empty view; people in other clothes then walk in one at a
    time. With no other track to lead, only absolute evidence could name them: the
    recoloured negatives give it to the boosted classifier."""
    identifier = TargetIdentifier(
        CFG, ChannelFeatureExtractor((CFG.crop_width_px, CFG.crop_height_px))
    )
    rng = np.random.default_rng(3)
    target = Person(1, 2.0, 320, RED, trousers=(30, 30, 30))
    est = run(identifier, [target], 20, rng)[-1]
    assert est.status == TargetStatus.TRACKING and est.target_seen
    assert run(identifier, [], 5, rng, t0=2.0)[-1].status == TargetStatus.REIDENTIFICATION
    for k, shirt in enumerate((BLUE, GREEN, (200, 200, 200), (20, 160, 200))):
        stranger = Person(10 + k, 2.0, 320, shirt, trousers=(200, 180, 150))
        named = [e.target_id for e in run(identifier, [stranger], 15, rng, t0=3.0 + 2 * k)]
        assert set(named) == {None}, f"stranger in {shirt} named the target"
    back = Person(20, 2.0, 320, RED, trousers=(30, 30, 30))
    ests = run(identifier, [back], 15, rng, t0=12.0)
    assert ests[-1].status == TargetStatus.TRACKING and ests[-1].target_id == 20


def test_without_recoloured_negatives_a_lone_stranger_is_not_taken():
    """Learnt from positives alone (no recoloured negatives, nobody else in view), every
    weak classifier votes for the target, and the classifier scored a stranger alone in
    view +1 and named them the target (with the part-colour rule off, which would turn
    this stranger away too). A classifier that never saw the other class is not trained:
    it scores nobody, and vouches for no one."""
    cfg = dataclasses.replace(CFG, min_negatives_per_update=0, reid_part_colour_distance=1.0)
    identifier = TargetIdentifier(
        cfg, ChannelFeatureExtractor((cfg.crop_width_px, cfg.crop_height_px))
    )
    rng = np.random.default_rng(3)
    run(identifier, [Person(1, 2.0, 320, RED, trousers=(30, 30, 30))], 20, rng)
    assert not identifier.model.classifier.is_trained
    run(identifier, [], 5, rng, t0=2.0)
    named = run(identifier, [Person(10, 2.0, 320, BLUE, trousers=(200, 180, 150))], 15, rng, t0=3.0)
    assert {e.target_id for e in named} == {None}
    assert named[-1].confidences[10] < cfg.reid_confidence


def test_a_track_seen_in_too_few_frames_is_not_made_the_target():
    cfg = dataclasses.replace(CFG, min_target_observations=4)
    identifier = TargetIdentifier(
        cfg, ChannelFeatureExtractor((cfg.crop_width_px, cfg.crop_height_px))
    )
    rng = np.random.default_rng(0)
    person = Person(1, 2.0, 320, RED)
    ests = run(identifier, [person], 5, rng)
    assert [e.target_id for e in ests] == [None, None, None, 1, 1]
    person.observed = False  # coasting: seen, then predicted only
    est = run(identifier, [person], 1, rng, t0=1.0)[0]
    assert est.target_id == 1 and not est.target_seen


def test_the_reid_bar_rises_with_the_time_the_target_is_gone(identifier):
    rng = np.random.default_rng(0)
    run(identifier, [Person(1, 2.0, 320, RED)], 3, rng)
    cfg = identifier.config
    assert identifier.required_similarity(0.2) == pytest.approx(cfg.reid_accept_similarity)
    later = 0.2 + cfg.reid_strict_after_s
    assert identifier.required_similarity(later) == pytest.approx(cfg.reid_strict_similarity)
    middle = identifier.required_similarity(0.2 + cfg.reid_strict_after_s / 2)
    assert cfg.reid_accept_similarity < middle < cfg.reid_strict_similarity
    assert identifier.required_confidence(0.2) == pytest.approx(cfg.reid_confidence)
    assert identifier.required_confidence(later) == pytest.approx(cfg.reid_strict_confidence)


def test_a_look_alike_of_another_height_is_not_taken_for_the_target():
    def height_frames(identifier, person, neck_height_m, n, rng, t0, std_m=0.02):
        out = []
        for k in range(n):
            image, tracks = frame([person] if person else [], rng, t0 + k / 10.0)
            tracks = [dataclasses.replace(t, mean=np.r_[t.mean[:4], neck_height_m],
                                          cov=np.diag([0.1, 0.1, 0.1, 0.1, std_m**2]))
                      for t in tracks]  # fmt: skip
            out.append(identifier.update(image, tracks, t0 + k / 10.0))
        return out

    identifier = TargetIdentifier(
        CFG, ChannelFeatureExtractor((CFG.crop_width_px, CFG.crop_height_px))
    )
    rng = np.random.default_rng(1)
    height_frames(identifier, Person(1, 2.0, 320, RED), 1.45, 20, rng, 0.0)
    height_frames(identifier, None, 1.45, 3, rng, 2.0)
    taller = height_frames(identifier, Person(5, 2.0, 320, RED), 1.62, 15, rng, 2.3)
    assert {e.target_id for e in taller} == {None}  # same clothes, 17 cm taller
    back = height_frames(identifier, Person(6, 2.0, 320, RED), 1.46, 15, rng, 4.0)
    assert back[-1].target_id == 6


@pytest.mark.parametrize("part_rule", [True, False])
def test_a_stranger_in_the_targets_shirt_and_other_trousers_is_not_taken(part_rule):
    """The target leaves; a stranger in its shirt and light trousers walks in alone,
    then the target comes back. The whole-crop classifier, seeing mostly the shirt, takes
    the stranger unless every part must match (`reid_part_colour_distance`)."""
    cfg = CFG if part_rule else dataclasses.replace(CFG, reid_part_colour_distance=1.0)
    identifier = TargetIdentifier(
        cfg, ChannelFeatureExtractor((cfg.crop_width_px, cfg.crop_height_px))
    )
    rng = np.random.default_rng(5)
    run(identifier, [Person(1, 2.0, 320, RED, trousers=(30, 30, 30))], 20, rng)
    run(identifier, [], 5, rng, t0=2.0)
    stranger = Person(10, 2.0, 320, RED, trousers=(210, 200, 190))
    named = {e.target_id for e in run(identifier, [stranger], 15, rng, t0=3.0)}
    if not part_rule:
        assert 10 in named  # what the rule is for
        return
    assert named == {None}
    back = run(identifier, [Person(20, 2.0, 320, RED, trousers=(30, 30, 30))], 15, rng, t0=5.0)
    assert back[-1].status == TargetStatus.TRACKING and back[-1].target_id == 20


@pytest.mark.parametrize("track_id", [2.7, True, None, "2", -1])
def test_select_target_refuses_what_is_no_track_id_by_name(identifier, track_id):
    """int() made 2.7 track 2 and True track 1: another person than the one asked for."""
    from follow.types import InvalidInput

    with pytest.raises(InvalidInput, match="select_target: track id"):
        identifier.select_target(track_id)
    identifier.select_target(np.int64(3))  # a numpy id from an array of track ids is fine
    assert identifier.context.requested_id == 3


def test_a_selected_id_never_seen_is_reported_once_and_nobody_else_is_chosen(identifier, caplog):
    """A mistyped id left a library or ROS caller waiting in silence."""
    rng = np.random.default_rng(12)
    people = [Person(1, 2.0, 180, RED), Person(2, 3.0, 460, BLUE)]
    identifier.select_target(9)
    with caplog.at_level(logging.WARNING, logger="follow"):
        ests = run(identifier, people, 50, rng)  # 0 .. 4.9 s: not yet
        assert not identifier.selected_id_missing and not caplog.records
        ests += run(identifier, people, 30, rng)  # 5.0 s on
    assert identifier.selected_id_missing
    (warning,) = [r.getMessage() for r in caplog.records]
    assert "selected track 9" in warning and "[1, 2]" in warning
    assert all(e.status == TargetStatus.INITIAL and e.target_id is None for e in ests)

    est = run(identifier, [*people, Person(9, 2.5, 320, GREEN)], 1, rng)[0]
    assert not identifier.selected_id_missing
    assert est.status == TargetStatus.INITIAL_TRAINING and est.target_id == 9
    identifier.select_target(7)
    run(identifier, people, 60, rng)
    assert identifier.selected_id_missing
    identifier.select_nearest()  # nothing selected: nothing missing
    assert not identifier.selected_id_missing


def missing_warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if "not among the tracks" in r.getMessage()]


@pytest.mark.parametrize("gone", ["before it was confirmed", "in initial training"])
def test_a_selected_track_gone_before_it_became_the_target_is_reported(identifier, caplog, gone):
    """A selected track that appeared and was retired before it became the target (ids
    are never reused) left the identifier waiting for it in silence: nothing followed,
    `selected_id_missing` False. Its absence is timed from its first absent frame."""
    rng = np.random.default_rng(12)
    other = Person(1, 3.5, 460, BLUE)
    selected = Person(2, 2.0, 180, RED, confirmed=gone != "before it was confirmed")
    identifier.select_target(2)
    in_view = run(identifier, [other, selected], 2 if selected.confirmed else 20, rng)
    expected = TargetStatus.INITIAL if gone == "before it was confirmed" else (
        TargetStatus.INITIAL_TRAINING)  # fmt: skip
    assert in_view[-1].status == expected
    run(identifier, [other], 30, rng)  # absent 0 .. 2.9 s
    with caplog.at_level(logging.WARNING, logger="follow"):
        ests = run(identifier, [other], 19, rng)  # .. 4.8 s (6.8 s since the selection)
        assert not identifier.selected_id_missing and not missing_warnings(caplog)
        ests += run(identifier, [other], 20, rng)  # 4.9 s on
    assert identifier.selected_id_missing
    (warning,) = missing_warnings(caplog)
    assert "selected track 2" in warning and "after it was last seen" in warning
    assert "[1]" in warning
    assert all(e.status == TargetStatus.INITIAL and e.target_id is None for e in ests)


def test_a_selected_track_lost_once_it_is_the_target_is_never_reported_missing(identifier, caplog):
    """Once the selected id is the target, losing it is re-identification's to handle:
    the watch rests."""
    rng = np.random.default_rng(12)
    other = Person(1, 3.5, 460, BLUE)
    identifier.select_target(2)
    run(identifier, [other, Person(2, 2.0, 180, RED)], CFG.initial_training_frames + 2, rng)
    assert identifier.status == TargetStatus.TRACKING
    with caplog.at_level(logging.WARNING, logger="follow"):
        ests = run(identifier, [other], 80, rng)
    assert ests[-1].status == TargetStatus.REIDENTIFICATION
    assert not identifier.selected_id_missing and not missing_warnings(caplog)


def test_frames_too_far_apart_to_learn_from_are_said_once(identifier, caplog):
    """Each gap over identity_risk_unseen_s is a stall that drops what initial training
    learnt: on a host that slow nothing is ever learnt, and the user must be told why."""
    rng = np.random.default_rng(5)
    people = [Person(1, 2.0, 180, RED)]
    gap_s = CFG.identity_risk_unseen_s + 0.5
    with caplog.at_level(logging.WARNING, logger="follow.identify"):
        ests = [
            run(identifier, people, 1, rng, t0=k * gap_s)[0]
            for k in range(3 * CFG.initial_training_frames)
        ]
    assert all(e.status != TargetStatus.TRACKING for e in ests)
    said = [r.getMessage() for r in caplog.records if "cannot be learnt" in r.getMessage()]
    assert len(said) == 1 and "frames come" in said[0]
