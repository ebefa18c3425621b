from types import SimpleNamespace

import numpy as np
import pytest

from follow.eval.identification_metrics import OutcomeTally, classify


@pytest.mark.parametrize(
    "visible,named,is_target,expected",
    [
        (True, 3, True, "ct"),
        (False, None, False, "cl"),
        (True, 4, False, "wt"),
        (False, 4, False, "wt"),
        (False, 3, True, "ct"),  # the target's own track, carried through an occlusion
        (True, None, False, "wl"),
    ],
)
def test_classify(visible, named, is_target, expected):
    assert classify(visible, named, is_target) == expected


def test_tally_fractions_and_merge():
    a, b = OutcomeTally(), OutcomeTally()
    for outcome in ["ct"] * 6 + ["wl"] * 2:
        a.add(outcome, 0.5)
    for outcome in ["cl", "wt"]:
        b.add(outcome, 1.0)
    a.merge(b)
    assert a.total_s == pytest.approx(6.0)
    f = a.fractions()
    assert f == pytest.approx({"ct": 0.5, "cl": 1 / 6, "wt": 1 / 6, "wl": 1 / 6})
    assert len(a.timeline) == 10
    with pytest.raises(ValueError, match="unknown outcome"):
        a.add("xx", 1.0)


def test_same_person_map_joins_returning_people_and_rejects_bad_files(tmp_path):
    from follow.eval.identification import first_of_each_person, load_same_person

    same = load_same_person()  # the shipped PETS map
    assert same[3] == same[11] and 11 in same[3]
    assert all(i in group for i, group in same.items())
    gt = [{11: None}, {11: None}, {}, {3: None, 5: None}]
    assert first_of_each_person([3, 5, 11], gt, same) == [5, 11]
    bad = tmp_path / "bad.toml"
    bad.write_text("[[same_person]]\nids = [1, 2]\n[[same_person]]\nids = [2, 3]\n")
    with pytest.raises(ValueError, match="id 2 is in two groups"):
        load_same_person(bad)
    bad.write_text("[[same_person]]\nids = [1]\n")
    with pytest.raises(ValueError, match="two or more ints"):
        load_same_person(bad)


def test_undecided_wrong_time_is_wrong_and_counted_apart():
    a, b = OutcomeTally(), OutcomeTally()
    a.add("ct", 1.0)
    a.add("wt", 1.0, undecided=True)
    b.add("wt", 2.0)
    a.merge(b)
    assert a.fractions()["wt"] == pytest.approx(0.75)
    assert a.wt_undecided_s == pytest.approx(1.0)
    assert a.wt_undecided_fraction() == pytest.approx(0.25)
    assert a.timeline == ["ct", "wt?", "wt"]
    with pytest.raises(ValueError, match="only a WT frame"):
        a.add("ct", 1.0, undecided=True)


def test_undecided_pairs_stand_for_whole_groups_and_never_join_one_person(tmp_path):
    from follow.eval.identification import load_undecided

    shipped = load_undecided()
    assert 2 in shipped[13] and 13 in shipped[2]
    assert {14, 18, 8} <= shipped[15] and 15 in shipped[8]  # 14/18/8 are one person
    assert all(i not in maybe for i, maybe in shipped.items())
    bad = tmp_path / "bad.toml"
    bad.write_text("[[same_person]]\nids = [1, 2]\n[[undecided]]\nids = [2, 1]\n")
    with pytest.raises(ValueError, match="already one person"):
        load_undecided(bad)
    bad.write_text("[[undecided]]\nids = [4]\n")
    with pytest.raises(ValueError, match="two or more ints"):
        load_undecided(bad)


def test_a_named_track_is_the_nearest_annotated_person_within_the_match_distance():
    import numpy as np

    from follow.eval.identification import _person_at

    people = {3: _annotated(0.0, 100.0), 5: _annotated(0.8, 160.0)}
    assert _person_at(people, np.array([0.5, 0.0]), 1.0) == 5
    assert _person_at(people, np.array([0.3, 0.0]), 1.0) == 3
    assert _person_at(people, np.array([3.0, 0.0]), 1.0) is None


def _annotated(x_m: float, box_left_px: float):
    """An annotated person at (x_m, 0) on the floor, box 40 px wide and 100 px tall."""
    import numpy as np

    from follow.eval.identification import Annotated
    from follow.eval.pets import GtBox

    return Annotated(np.array([x_m, 0.0]), 0.0, GtBox(0, box_left_px + 20.0, 100.0, 40.0, 100.0))


def _track(track_id: int, x_m: float, neck_u_px: float | None):
    """A confirmed track at (x_m, 0), its neck detected at column `neck_u_px` (None:
    not detected in this frame)."""
    import numpy as np

    from follow.types import Observation, TrackState

    seen = None if neck_u_px is None else Observation(np.array([neck_u_px, 70.0]))
    return TrackState(track_id, np.array([x_m, 0.0, 0.0, 0.0, 1.5]), np.eye(5), True, 0.0,
                      observation=seen)  # fmt: skip


def _pick(picker, tracks, people, ids, box, status=None, frames=1):
    from follow.types import TargetStatus

    status = status or TargetStatus.INITIAL
    return [picker.update(status, tracks, people, ids, box, 1.0) for _ in range(frames)][-1]


def test_the_target_is_selected_only_where_a_click_would_pick_out_its_track():
    """PETS targets 3 and 4 walk shoulder to shoulder; the ground points of the two (one
    box mostly hidden) are tenths of a metre off, so the track nearest the target on the
    floor was its companion's. A user clicks on the person in the image: the track is
    selected where its detected neck lies in the target's box and in no one else's."""
    from follow.eval.identification import TargetPicker

    overlapping = {3: _annotated(0.0, 100.0), 4: _annotated(0.7, 120.0)}
    # The companion's track is nearest the target on the floor, its neck in both boxes.
    tracks = [_track(28, 0.09, 130.0), _track(26, 0.18, 170.0)]
    assert _pick(TargetPicker(1), tracks, overlapping, (3,), overlapping[3]) is None
    apart = {3: _annotated(0.0, 100.0), 4: _annotated(0.7, 160.0)}
    tracks = [_track(28, 0.5, 180.0), _track(26, 0.15, 110.0)]
    assert _pick(TargetPicker(1), tracks, apart, (3,), apart[3]) == 26
    # Not detected in this frame: nothing to click on.
    assert _pick(TargetPicker(1), [_track(26, 0.15, None)], apart, (3,), apart[3]) is None
    # Picked out in the image but too far on the floor to be the target's.
    assert _pick(TargetPicker(1), [_track(26, 1.5, 110.0)], apart, (3,), apart[3]) is None
    # Two tracks picked out in the target's box alone: a click would be a guess.
    both = [_track(26, 0.15, 110.0), _track(30, 0.3, 115.0)]
    assert _pick(TargetPicker(1), both, apart, (3,), apart[3]) is None
    # The same person under another id (whole-sequence scoring) is the target.
    returning = {11: _annotated(0.0, 100.0)}
    tracks = [_track(31, 0.1, 110.0)]
    assert _pick(TargetPicker(1), tracks, returning, (3, 11), returning[11]) == 31


def test_a_track_whose_neck_is_at_the_targets_waist_is_not_picked_for_it():
    """Under JPEG 75, PETS target 4's companion was detected as a broken skeleton whose
    neck lay at the target's waist: its track was picked out for the target alone (the
    target's own was not yet confirmed) and followed for the rest of the run. A click on
    the target's neck, at the top of its box (100 px tall from y = 50), gets the track
    whose neck is there."""
    import dataclasses

    import numpy as np

    from follow.eval.identification import TargetPicker
    from follow.types import Observation

    people = {4: _annotated(0.0, 100.0)}
    at_waist = dataclasses.replace(
        _track(27, 0.3, 120.0), observation=Observation(np.array([120.0, 95.0]))
    )
    assert _pick(TargetPicker(1), [at_waist], people, (4,), people[4]) is None
    at_neck = _track(29, 0.1, 118.0)  # neck at y = 70, a fifth of the box down
    assert _pick(TargetPicker(1), [at_waist, at_neck], people, (4,), people[4]) == 29


def test_the_target_is_selected_on_a_track_picked_out_for_a_steady_second():
    """PETS person 3 walks inside person 4's box for 20 frames before the annotation
    gives him a box of his own: a single frame in which his track is the only neck in
    person 4's box must not hand him to the identifier as target 4."""
    from follow.eval.identification import TargetPicker

    people = {4: _annotated(0.0, 100.0)}
    his, hers = [_track(25, 0.3, 110.0)], [_track(27, 0.1, 118.0)]
    picker = TargetPicker(3)
    assert _pick(picker, his, people, (4,), people[4], frames=2) is None
    assert _pick(picker, hers, people, (4,), people[4], frames=2) is None  # streak restarts
    assert _pick(picker, hers, people, (4,), people[4]) == 27 and picker.selected_id == 27
    assert _pick(picker, hers, people, (4,), people[4]) is None  # selected once


def test_a_target_is_selected_again_only_when_its_track_ended_before_it_was_learnt():
    from follow.eval.identification import TargetPicker
    from follow.types import TargetStatus

    people = {4: _annotated(0.0, 100.0)}
    box = people[4]
    fresh = [_track(26, 0.1, 110.0)]
    assert _pick(TargetPicker(1), fresh, people, (4,), None) is None
    picker = TargetPicker(1)
    picker.selected_id = 23
    # Still there, or already learnt (re-identification is the identifier's job): keep it.
    there = fresh + [_track(23, 3.0, None)]
    assert _pick(picker, there, people, (4,), box) is None
    for status in (TargetStatus.TRACKING, TargetStatus.REIDENTIFICATION):
        assert _pick(picker, fresh, people, (4,), box, status) is None
    # Track 23 was selected and ended untrained: select the target's new track.
    assert _pick(picker, fresh, people, (4,), box) == 26


def test_a_target_never_selected_is_reported_unscored_not_dropped_in_silence():
    """Target 1 is visible throughout but no track is ever picked out as theirs (the
    detector missed them); target 2 is. Target 1's empty row read CT 0 / WL 0 and its
    time left the pooled figures without a word."""
    from follow.config import Config
    from follow.eval.identification import Annotated, evaluate, summarise_targets
    from follow.eval.pets import GtBox
    from follow.types import Observation, TrackState

    setup = SimpleNamespace(sequence=SimpleNamespace(
        frames=lambda idx: ((i, np.zeros((360, 480, 3), np.uint8)) for i in idx)))  # fmt: skip
    boxes = {1: GtBox(1, 100, 100, 40, 100), 2: GtBox(2, 300, 100, 40, 100)}
    where = {1: np.array([0.0, 0.0]), 2: np.array([5.0, 0.0])}
    gt = [{i: Annotated(where[i], 0.0, boxes[i]) for i in (1, 2)} for _ in range(20)]
    neck_in_box_2 = Observation(np.array([300.0, 60.0]))
    track = TrackState(7, np.array([5.0, 0, 0, 0, 1.5]), np.eye(5), True, 0.0,
                       observation=neck_in_box_2)  # fmt: skip
    per_target = evaluate(setup, list(range(20)), [[track]] * 20, gt, [1, 2], "channels",
                          Config(), 1.0, 0.5)  # fmt: skip
    summary = summarise_targets(per_target)
    assert summary["unscored_targets"] == [1]
    assert list(summary["per_target"]) == ["2"] and summary["seconds"]["wl"] == 0.0
