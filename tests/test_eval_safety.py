"""`follow eval safety` on a fast subset: the runner stops the simulated rover within
the goals when the target leaves the view, when the detector hangs, on SIGTERM and when
the target runs out at the side, timed from before the stack lost it (the other faults
have their own tests: odometry policy, MAVLink link and mode)."""

import numpy as np

from follow.eval import safety


def test_stop_and_distance_from_samples():
    t = np.arange(0.0, 3.0, 0.01)
    v = np.clip(1.0 - np.maximum(t - 1.0, 0.0) * 2.0, 0.0, None)  # brakes from 1 s to 1.5 s
    x = np.cumsum(v) * 0.01
    samples = [(ti, xi, 0.0, vi, 0.0) for ti, xi, vi in zip(t, x, v, strict=True)]
    stop_s, driven_m = safety.stop_and_distance(samples, fault_s=1.0)
    assert abs(stop_s - 0.48) < 0.02  # under 0.05 m/s from 1.475 s
    assert abs(driven_m - 0.25) < 0.02
    still_moving = samples[:140]  # cut off at 1.4 s, still at 0.2 m/s
    assert safety.stop_and_distance(still_moving, fault_s=1.0)[0] is None


def test_rover_stops_after_the_target_leaves_the_view_the_detector_hangs_and_on_sigterm():
    report = safety.run_cases(("target_leaves_view", "perception_stalls", "sigterm"),
                              fault_at_s=5.0)  # fmt: skip
    for name, case in report["cases"].items():
        assert case["speed_at_fault_mps"] > 0.2, (name, case)  # it was driving
        assert case["stop_s"] is not None and case["stop_s"] <= safety.GOAL_STOP_S, (name, case)
    # The goal is 0.5 m: 0.32-0.39 m measured in real time on this shared machine while
    # another evaluation kept both cores busy (the blind speed limit falls from the speed
    # at the last sighting; from the maximum speed it was 0.44-0.51 m). A robot that
    # drove on blind would be metres over in the 3 s after the target left.
    driven_m = report["cases"]["target_leaves_view"]["driven_m"]
    assert driven_m <= safety.GOAL_DRIVEN_AFTER_LOSS_M, report["cases"]
    assert report["cases"]["sigterm"]["signal"] == "SIGTERM"
    assert report["cases"]["perception_stalls"]["watchdog_trips"] >= 1


def test_a_case_where_the_rover_was_not_driving_at_the_fault_misses_its_goal():
    # A rover that never moved "stands" at once after any fault: that proves nothing.
    stood_still = {"stop_s": 0.008, "driven_m": 0.0, "speed_at_fault_mps": 0.0}
    for name in safety.CASE_NAMES:
        assert not safety.goals_met(name, stood_still), name
    driving = {**stood_still, "speed_at_fault_mps": 1.0}
    assert safety.goals_met("target_leaves_view", driving)


def test_the_side_exit_is_timed_from_before_the_stack_lost_the_target(monkeypatch):
    # The 3 m/s dash is outside the tracker's gate: the target is lost at the turn, frames
    # before its neck leaves the image. The fault instant must not come after the loss,
    # or the robot's reaction to it (braking from full speed) goes unmeasured.
    from follow import pipeline

    seen = []  # (capture stamp, target observed)
    conclude = pipeline.Perception.conclude

    def spy(self, frame, robot, index, detections):
        result = conclude(self, frame, robot, index, detections)
        track = result.target_track
        seen.append((frame.stamp_s, track is not None and track.observation is not None))
        return result

    faults = []
    stop_and_distance = safety.stop_and_distance

    def fault_spy(samples, fault_s):
        faults.append(fault_s)
        return stop_and_distance(samples, fault_s)

    monkeypatch.setattr(pipeline.Perception, "conclude", spy)
    monkeypatch.setattr(safety, "stop_and_distance", fault_spy)
    case = safety.run_cases(("target_exits_side",), fault_at_s=5.0)["cases"]["target_exits_side"]
    last_before = [observed for stamp, observed in seen if stamp <= faults[0]][-1]
    assert last_before, case  # the stack still saw the target when the fault came
    assert case["left_image_after_s"] is not None and case["left_image_after_s"] > 0, case
    assert case["goal_met"], case


def test_the_text_table_shows_a_fault_that_never_happened():
    """Its driven distance is None: the table's number format ended the command."""
    from follow.eval.safety import case_row

    row = case_row("link_cut", {"stop_s": None, "driven_m": None, "goal_met": False,
                                "note": "the fault never happened"})  # fmt: skip
    assert "never" in row and "MISSED" in row and "the fault never happened" in row
    row = case_row("sigint", {"stop_s": 0.52, "driven_m": 0.29, "speed_at_fault_mps": 1.09,
                              "goal_met": True})  # fmt: skip
    assert row.split() == ["sigint", "0.52", "0.29", "1.09", "met"]


def test_a_ctrl_c_that_is_not_the_case_s_own_signal_ends_the_evaluation():
    """Ctrl-C during a case was taken for the `sigint` case's own signal: the case ran
    on, was scored from the base's closing, and the next case started; before the fault
    it ended in a TypeError."""
    import os
    import signal
    import threading
    import time

    import pytest

    timer = threading.Timer(3.0, os.kill, (os.getpid(), signal.SIGINT))
    started = time.monotonic()
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):  # the user's Ctrl-C 3 s in, the robot following
            safety.run_case(safety.CASES[0], fault_at_s=5.0)
    finally:
        timer.cancel()
    case_s = 5.0 + safety.CASES[0].after_s
    assert time.monotonic() - started < case_s - 1.0  # not run on to its end
