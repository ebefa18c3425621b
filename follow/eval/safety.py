"""`follow eval safety`: every fault, through the real runner, against the simulated rover.

Each case is a short real-time run of the stack as the demo runs it (simulated world and
camera, synthetic skeletons, tracker, identifier, `build_runner`'s ThreadedRunner and
ControlLoop, MavlinkBase over UDP to `SimRover`): a person walks away from the robot,
the robot follows, and at `fault_at_s` one thing goes wrong. Reported per case, from the
rover's true motion: the time from the fault until the rover stands still for good
(|speed| and |turn rate| under `STANDING_*`) and the distance it drove after the fault.

Goals: standing within 1.0 s in every case but the cut link (which only the vehicle's
own GUIDED timeout can stop) and at most 0.5 m driven after the target leaves the view.
A case counts only if the rover was driving (`DRIVING_AT_FAULT_MPS`) when the fault came:
a rover that never moved would stand "at once" after every fault.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from follow.cli_args import float_within, non_negative_int
from follow.config import Config, MavlinkConfig
from follow.control import mavlink_frames as mf
from follow.sim.people import Walker

log = logging.getLogger(__name__)

STANDING_SPEED_MPS = 0.05
STANDING_YAW_RATE_RADPS = 0.05
MONITOR_RATE_HZ = 100.0
GOAL_STOP_S = 1.0
GOAL_DRIVEN_AFTER_LOSS_M = 0.5
DRIVING_AT_FAULT_MPS = 0.5  # half the walker's pace: slower, a stop proves little
TARGET_ID = 1


@dataclass
class FaultContext:
    """What a fault may act on, and when it happened (monotonic clock)."""

    rover: object
    fault_s: float | None = None
    hide_target: bool = False
    left_image_s: float | None = None  # side exit: the target's first frame outside the image
    stalled: threading.Event = field(default_factory=threading.Event)
    released: threading.Event = field(default_factory=threading.Event)


@dataclass(frozen=True)
class Case:
    name: str
    inject: Callable[[FaultContext], None]  # called once, at fault_at_s
    after_s: float = 3.0  # how long the run goes on after the fault
    side_exit: bool = False  # the target runs out of the side of the view instead


def _mark(ctx: FaultContext) -> None:
    ctx.fault_s = time.monotonic()


def _leave_view(ctx):
    ctx.hide_target = True
    _mark(ctx)


def _stall(ctx):
    ctx.stalled.set()
    _mark(ctx)


def _odometry(ctx):
    ctx.rover.pause_telemetry()
    _mark(ctx)


def _cut(ctx):
    ctx.rover.cut_link()
    _mark(ctx)


def _pilot(ctx):
    ctx.rover.pilot_set_mode(mf.ROVER_MODE_MANUAL)
    _mark(ctx)


def _signal(signum: int) -> Callable[[FaultContext], None]:
    def inject(ctx):
        _mark(ctx)
        os.kill(os.getpid(), signum)

    return inject


CASES = (
    Case("target_leaves_view", _leave_view),
    Case("target_exits_side", _mark, side_exit=True),
    Case("perception_stalls", _stall),
    Case("odometry_stops", _odometry),
    Case("link_cut", _cut, after_s=5.0),
    Case("pilot_mode_change", _pilot),
    Case("sigint", _signal(signal.SIGINT)),
    Case("sigterm", _signal(signal.SIGTERM)),
)
CASE_NAMES = tuple(c.name for c in CASES)
SIGNAL_CASES = ("sigint", "sigterm")
MAX_FAULT_AT_S = 60.0  # each case runs in real time: a minute of following is enough
MIN_FAULT_AT_S = 3.0  # the robot has started following by then


def target_walker(fault_at_s: float, side_exit: bool) -> Walker:
    """Walks away from the robot from 2.6 m ahead at 1 m/s from t = 1 s; for a side
    exit it turns left at the fault time and runs across the view at 3 m/s. The turn is
    the fault: a dash that sudden is outside the tracker's gate (a new track), so the
    target is lost there, frames before it leaves the image."""
    turn_x = 2.6 + (fault_at_s - 1.0) * 1.0
    if side_exit:
        waypoints = np.array([[2.6, 0.0], [turn_x, 0.0], [turn_x, 30.0]])
        speeds = np.array([1.0, 3.0])
    else:
        waypoints = np.array([[2.6, 0.0], [60.0, 0.0]])
        speeds = np.array([1.0])
    return Walker(TARGET_ID, 1.75, waypoints, speeds_mps=speeds, start_s=1.0)


class RoverMonitor:
    """Samples the rover's true pose and velocity in its own thread."""

    def __init__(self, rover):
        self.rover = rover
        self.samples: list[tuple[float, float, float, float, float]] = []  # t, x, y, v, w
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="rover-monitor", daemon=True)

    def __enter__(self) -> RoverMonitor:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(2.0)

    def _run(self) -> None:
        while not self._stop.wait(1.0 / MONITOR_RATE_HZ):
            pose = self.rover.true_pose()
            v, w = self.rover.true_velocity()
            self.samples.append((pose.stamp_s, pose.x_m, pose.y_m, v, w))


def stop_and_distance(samples, fault_s: float) -> tuple[float | None, float]:
    """Seconds from the fault until the rover stands still for the rest of the samples
    (None if it never does), and metres driven after the fault."""
    after = np.array([s for s in samples if s[0] >= fault_s])
    if len(after) < 2:
        return None, 0.0
    moving = (np.abs(after[:, 3]) >= STANDING_SPEED_MPS) | (
        np.abs(after[:, 4]) >= STANDING_YAW_RATE_RADPS
    )
    driven = float(np.hypot(*np.diff(after[:, 1:3], axis=0).T).sum())
    if moving[-1]:
        return None, driven
    last_moving = np.flatnonzero(moving)
    standing_from = after[last_moving[-1] + 1, 0] if last_moving.size else after[0, 0]
    return float(standing_from - fault_s), driven


def run_case(case: Case, fault_at_s: float = 5.0, seed: int = 0,
             config: Config | None = None) -> dict:  # fmt: skip
    """One fault; returns {"stop_s", "driven_m", ...}."""
    from follow.control.mavlink_base import MavlinkBase
    from follow.control.target import ViewCone
    from follow.pipeline import build_runner
    from follow.shutdown import ShutdownSignals
    from follow.sim.appearance import Appearance
    from follow.sim.demo import DEMO_CAMERA, TARGET_LOOK, sim_frames, sim_perception
    from follow.sim.rover import SimRover
    from follow.sim.world import World

    if case.name in SIGNAL_CASES and threading.current_thread() is not threading.main_thread():
        raise RuntimeError(f"case {case.name}: signals can only be handled in the main thread")
    config = (config or Config()).replace("identify", identifier="channels", seed=seed)
    rng = np.random.default_rng(seed)
    walker = target_walker(fault_at_s, case.side_exit)
    bystander = Walker(2, 1.68, np.array([[9.0, 6.0], [9.0, 12.0]]), speeds_mps=0.5)
    world = World([walker, bystander], camera=DEMO_CAMERA, seed=seed)
    camera = DEMO_CAMERA.detection_camera()
    looks = {TARGET_ID: TARGET_LOOK, 2: Appearance.random(rng)}
    n_frames = int(round((fault_at_s + case.after_s) * DEMO_CAMERA.fps))
    with SimRover(seed=seed) as rover, RoverMonitor(rover) as monitor:
        ctx = FaultContext(rover)
        mav = dataclasses.replace(config.mavlink or MavlinkConfig(), connection=rover.connection)
        base = MavlinkBase(mav)
        perception = sim_perception(camera, config, seed)
        inner_detect = perception.detect

        def detect(frame):
            if ctx.stalled.is_set():  # a detector that hangs until the case is over
                ctx.released.wait(case.after_s + 5.0)
            return inner_detect(frame)

        perception.detect = detect

        def edit(wf):
            if ctx.fault_s is None and wf.stamp_s >= fault_at_s:
                case.inject(ctx)
            if case.side_exit and ctx.fault_s is not None and ctx.left_image_s is None:
                target = wf.person(TARGET_ID)
                if target is not None and not _neck_in_image(target, wf.robot, camera):
                    ctx.left_image_s = time.monotonic()
            if ctx.hide_target:
                return dataclasses.replace(
                    wf, people=[p for p in wf.people if p.person_id != TARGET_ID]
                )
            return wf

        runner = build_runner(perception, base, config.control, ViewCone.from_camera(camera))
        interrupted = None
        try:
            with ShutdownSignals() as signals:
                try:
                    runner.run(sim_frames(world, rover, camera, looks, n_frames, seed, edit,
                                          pace_hz=DEMO_CAMERA.fps),
                               pace_hz=DEMO_CAMERA.fps)  # fmt: skip
                except KeyboardInterrupt:
                    if case.name not in SIGNAL_CASES or ctx.fault_s is None:
                        raise  # the user's Ctrl-C, not the case's own signal: stop here
                    interrupted = signals.reason
            if interrupted:  # as `follow run` does: close the base, then wait and watch
                base.close()
                time.sleep(max(0.0, ctx.fault_s + case.after_s - time.monotonic()))
        finally:
            ctx.released.set()
            base.close()
    if ctx.fault_s is None or (case.side_exit and ctx.left_image_s is None):
        return {"stop_s": None, "driven_m": None, "note": "the fault never happened"}
    stop_s, driven_m = stop_and_distance(monitor.samples, ctx.fault_s)
    speed_before = _speed_at(monitor.samples, ctx.fault_s)
    result = {
        "stop_s": None if stop_s is None else round(stop_s, 3),
        "driven_m": round(driven_m, 3),
        "speed_at_fault_mps": round(speed_before, 3),
        "watchdog_trips": runner.control.watchdog_trips,
        "odometry_losses": runner.control.odometry.losses,
        **({"signal": interrupted} if interrupted else {}),
    }
    if case.side_exit:  # the turn is the fault; the target then runs out of the image
        result["left_image_after_s"] = round(ctx.left_image_s - ctx.fault_s, 3)
    return result


def _neck_in_image(person, robot, camera) -> bool:
    from follow.frames import odom_to_base

    neck = person.keypoints_m[1]
    base = np.array([[*odom_to_base(neck[None, :2], robot)[0], neck[2]]])
    if camera.base_to_camera(base)[0, 2] <= 0.1:
        return False
    return bool(camera.in_image(camera.project(base))[0])


def _speed_at(samples, t_s: float) -> float:
    before = [s for s in samples if s[0] <= t_s]
    return abs(before[-1][3]) if before else 0.0


def goals_met(name: str, result: dict) -> bool:
    stop_s, driven_m = result["stop_s"], result["driven_m"]
    if stop_s is None or result["speed_at_fault_mps"] < DRIVING_AT_FAULT_MPS:
        return False
    if name == "link_cut":
        return True  # only the vehicle's GUIDED timeout can stop it; reported, no goal
    ok = stop_s <= GOAL_STOP_S
    if name in ("target_leaves_view", "target_exits_side"):
        ok = ok and driven_m <= GOAL_DRIVEN_AFTER_LOSS_M
    return ok


def run_cases(names=CASE_NAMES, fault_at_s: float = 5.0, seed: int = 0,
              config: Config | None = None, progress: bool = False) -> dict:  # fmt: skip
    cases = {}
    for case in tqdm([c for c in CASES if c.name in names], desc="faults", disable=not progress):
        result = run_case(case, fault_at_s, seed, config)
        result["goal_met"] = goals_met(case.name, result)
        cases[case.name] = result
    return {
        "cases": cases,
        "goals": {
            "stop_s": GOAL_STOP_S,
            "driven_after_loss_m": GOAL_DRIVEN_AFTER_LOSS_M,
            "driving_at_fault_mps": DRIVING_AT_FAULT_MPS,
            "link_cut": "vehicle timeout, no goal",
        },  # fmt: skip
        "all_goals_met": all(c["goal_met"] for c in cases.values()),
    }


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cases", nargs="+", choices=CASE_NAMES, default=list(CASE_NAMES),
                        help="which faults (default: all)")  # fmt: skip
    parser.add_argument("--config", help="TOML configuration ([control], [mavlink] are used)")
    parser.add_argument("--fault-at-s", type=float_within(MIN_FAULT_AT_S, MAX_FAULT_AT_S),
                        default=5.0,
                        help=f"when the fault happens, after the start ({MIN_FAULT_AT_S:g}-"
                             f"{MAX_FAULT_AT_S:g} s: the robot must be following by then; the "
                             "run is paced in real time)")  # fmt: skip
    parser.add_argument("--seed", type=non_negative_int, default=0)


def main(args: argparse.Namespace) -> dict:
    config = Config.load(args.config) if args.config else Config()
    report = run_cases(args.cases, args.fault_at_s, args.seed, config, progress=True)
    if not args.json:
        print(f"{'case':<20} {'stop_s':>7} {'driven_m':>9} {'v_fault':>8}  goal")
        for name, r in report["cases"].items():
            print(case_row(name, r))
    return report


def case_row(name: str, r: dict) -> str:
    """One case's line of the text table; a fault that never happened has no figures."""
    stop = "never" if r["stop_s"] is None else f"{r['stop_s']:.2f}"
    driven = "-" if r.get("driven_m") is None else f"{r['driven_m']:.2f}"
    speed = r.get("speed_at_fault_mps")
    speed_text = "-" if speed is None else f"{speed:.2f}"
    goal = "met" if r.get("goal_met") else "MISSED"
    note = f"  ({r['note']})" if r.get("note") else ""
    return f"{name:<20} {stop:>7} {driven:>9} {speed_text:>8}  {goal}{note}"
