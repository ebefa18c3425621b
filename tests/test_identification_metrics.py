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
