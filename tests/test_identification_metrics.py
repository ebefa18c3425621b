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
