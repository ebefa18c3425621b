"""Identification outcomes per frame, as in Koide et al. (RAS 2020):

- CT, correct tracking: the system names the target's track (also while the target is
  briefly hidden and its track is carried by prediction);
- CL, correct loss: the target is not visible and the system names no track;
- WT, wrong tracking: the system names a track that is not the target's;
- WL, wrong loss: the target is visible but the system names no track.

Totals are durations in seconds and fractions of the time evaluated. Where the
ground truth cannot say whether the named person is the target (two annotated ids that
may be one person), the frame is still WT, and its time is also counted apart as
`wt_undecided_s`: WT minus it is the wrong time the annotation can vouch for.
"""

from __future__ import annotations

from dataclasses import dataclass, field

OUTCOMES = ("ct", "cl", "wt", "wl")


def classify(target_visible: bool, named_track: int | None, named_is_target: bool) -> str:
    """The outcome of one frame. `named_is_target` says whether the named track is the
    target person (ignored when no track is named)."""
    if named_track is None:
        return "wl" if target_visible else "cl"
    return "ct" if named_is_target else "wt"


@dataclass
class OutcomeTally:
    """Seconds spent in each outcome."""

    seconds: dict[str, float] = field(default_factory=lambda: dict.fromkeys(OUTCOMES, 0.0))
    timeline: list[str] = field(default_factory=list)  # outcomes, "wt?" where undecided
    wt_undecided_s: float = 0.0  # WT naming someone who may be the target

    def add(self, outcome: str, duration_s: float, undecided: bool = False) -> None:
        """One frame's outcome; `undecided`: a WT frame whose named person the ground
        truth cannot tell from the target."""
        if outcome not in OUTCOMES:
            raise ValueError(f"unknown outcome {outcome!r}; expected one of {OUTCOMES}")
        if undecided and outcome != "wt":
            raise ValueError(f"only a WT frame can be undecided, not {outcome!r}")
        self.seconds[outcome] += duration_s
        self.wt_undecided_s += duration_s if undecided else 0.0
        self.timeline.append("wt?" if undecided else outcome)

    def merge(self, other: OutcomeTally) -> None:
        for k in OUTCOMES:
            self.seconds[k] += other.seconds[k]
        self.wt_undecided_s += other.wt_undecided_s
        self.timeline.extend(other.timeline)

    @property
    def total_s(self) -> float:
        return sum(self.seconds.values())

    def fractions(self) -> dict[str, float]:
        total = self.total_s
        return {k: (self.seconds[k] / total if total > 0 else 0.0) for k in OUTCOMES}

    def wt_undecided_fraction(self) -> float:
        total = self.total_s
        return self.wt_undecided_s / total if total > 0 else 0.0
