"""`follow eval following`: closed-loop following over the simulated MAVLink rover.

A scripted walker (straight, turning, stopping) is followed in real time through the
same threaded runner and control loop as `follow run` (`follow.pipeline.build_runner`):
a scripted perception reports the walker's track, delayed and noised like a tracker's
output, for frames captured at 15 Hz with the odometry that `MavlinkBase` reads back
over UDP from `SimRover`; the control loop turns it into commands that the driver
streams to the rover. The distance error is measured between the walker and the
rover's true pose.
"""

from __future__ import annotations

import argparse
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from follow.cli_args import (
    float_within,
    non_negative_float,
    non_negative_int,
    plot_path,
    positive_float,
)
from follow.config import Config, ControlConfig, MavlinkConfig
from follow.control.mavlink_base import MavlinkBase
from follow.pipeline import Detections, FrameResult, build_runner
from follow.sim.rover import SimRover
from follow.sim.walker_paths import SCENARIOS, WalkerPath, scenario
from follow.types import (
    Frame,
    Observation,
    Odometry,
    TargetEstimate,
    TargetStatus,
    TrackState,
    VelocityCommand,
)

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RunSettings:
    perception_latency_s: float = 0.1  # age of the target estimate handed to the controller
    position_noise_m: float = 0.05  # std of the estimate's position error
    velocity_noise_mps: float = 0.05
    settle_s: float = 2.5  # after the walker changes speed or turn, before "steady"
    packet_loss: float = 0.0
    link_latency_s: float = 0.0
    seed: int = 0


@dataclass
class RunTrace:
    """Samples of one run, one per control period."""

    scenario: str
    following_distance_m: float
    t_s: list[float] = field(default_factory=list)
    distance_error_m: list[float] = field(default_factory=list)
    steady: list[bool] = field(default_factory=list)
    walking: list[bool] = field(default_factory=list)
    forward_mps: list[float] = field(default_factory=list)
    yaw_rate_radps: list[float] = field(default_factory=list)
    walker_xy: list[tuple[float, float]] = field(default_factory=list)
    robot_xy: list[tuple[float, float]] = field(default_factory=list)
    target_missing: int = 0


FRAME_RATE_HZ = 15.0
# A slower link is no MAVLink link a robot follows over (and the simulated vehicle's first
# heartbeat would not arrive within the connection's wait).
MAX_LINK_LATENCY_S = 1.0
_BLANK = np.zeros((8, 8, 3), np.uint8)


class ScriptedPerception:
    """Stands in for pose + tracker + identifier: one confirmed, observed track (id 1)
    where a tracker would put the walker, and the identifier tracking it."""

    def __init__(self, path: WalkerPath, settings: RunSettings, start_s: float):
        self.path, self.settings, self.start_s = path, settings, start_s
        self.rng = np.random.default_rng(settings.seed)

    def detect_people(self, frame: Frame) -> Detections:
        return Detections([], 0.0)  # the walker's track is made whole in `conclude`

    def process(self, frame: Frame, robot: Odometry, frame_index: int) -> FrameResult:
        return self.conclude(frame, robot, frame_index, self.detect_people(frame))

    def conclude(
        self, frame: Frame, robot: Odometry, frame_index: int, detections: Detections
    ) -> FrameResult:
        s = self.settings
        seen_at = frame.stamp_s - self.start_s - s.perception_latency_s
        xy, v = self.path.state(max(seen_at, 0.0))
        xy = xy + self.rng.normal(0.0, s.position_noise_m, 2)
        v = v + self.rng.normal(0.0, s.velocity_noise_mps, 2)
        # Predict the latency away with the estimated velocity, as the control loop carries a
        # real result forward from its capture (`target_motion`); this one is handed over at once.
        xy = xy + v * s.perception_latency_s
        track = TrackState(1, np.array([xy[0], xy[1], v[0], v[1], 1.45]), np.eye(5) * 0.01,
                           True, frame.stamp_s, observation=Observation(np.zeros(2)))  # fmt: skip
        target = TargetEstimate(TargetStatus.TRACKING, 1, {1: 1.0}, frame.stamp_s)
        return FrameResult(frame_index, frame.stamp_s, robot, [], [track], target)


def run_following(
    path: WalkerPath,
    name: str,
    control: ControlConfig = ControlConfig(),  # noqa: B008 (frozen)
    mavlink: MavlinkConfig | None = None,
    settings: RunSettings = RunSettings(),  # noqa: B008 (frozen)
    progress: bool = False,
    clock: Callable[[], float] = time.monotonic,
) -> RunTrace:
    """Follow `path` in real time through MavlinkBase + SimRover; the walker's script starts
    once the vehicle is in GUIDED."""
    trace = RunTrace(name, control.following_distance_m)
    with SimRover(seed=settings.seed) as rover:
        rover.packet_loss, rover.latency_s = settings.packet_loss, settings.link_latency_s
        cfg = mavlink or MavlinkConfig()
        cfg = MavlinkConfig(**{**cfg.__dict__, "connection": rover.connection})
        with MavlinkBase(cfg, clock=clock) as base:
            t0 = clock()
            perception = ScriptedPerception(path, settings, t0)

            def on_command(command: VelocityCommand) -> None:
                t = clock() - t0
                if t <= path.duration_s:
                    _record(trace, path, t, rover, command, control, settings)

            runner = build_runner(perception, base, control, clock=clock, on_command=on_command)
            n_frames = int(path.duration_s * FRAME_RATE_HZ)
            frames = (Frame(_BLANK, 0.0) for _ in range(n_frames))
            with tqdm(total=n_frames, unit="frame", desc=name, disable=not progress) as bar:
                runner.run(frames, pace_hz=FRAME_RATE_HZ, on_result=lambda f, r: bar.update())
            trace.target_missing = runner.skipped_without_odometry
    return trace


def _record(trace, path, t, rover, command, control, settings) -> None:
    truth = rover.true_pose()
    walker_xy, _ = path.state(t)
    distance = math.hypot(walker_xy[0] - truth.x_m, walker_xy[1] - truth.y_m)
    seg = path.segment_at(t)
    walking = seg.speed_mps > 0
    trace.t_s.append(t)
    trace.distance_error_m.append(distance - control.following_distance_m)
    trace.walking.append(walking)
    trace.steady.append(walking and path.time_in_segment(t) >= settings.settle_s)
    trace.forward_mps.append(command.forward_mps)
    trace.yaw_rate_radps.append(command.yaw_rate_radps)
    trace.walker_xy.append((float(walker_xy[0]), float(walker_xy[1])))
    trace.robot_xy.append((truth.x_m, truth.y_m))


def error_statistics(errors_m) -> dict:
    e = np.abs(np.asarray(errors_m, dtype=np.float64))
    if e.size == 0:
        return {"samples": 0}
    signed = np.asarray(errors_m, dtype=np.float64)
    return {
        "samples": int(e.size),
        "mean_m": float(signed.mean()),
        "mean_abs_m": float(e.mean()),
        "median_abs_m": float(np.median(e)),
        "p90_abs_m": float(np.percentile(e, 90)),
        "max_abs_m": float(e.max()),
        "within_0_3_m": float((e <= 0.3).mean()),
    }


def summarize(trace: RunTrace) -> dict:
    err = np.asarray(trace.distance_error_m)
    steady = np.asarray(trace.steady, dtype=bool)
    return {
        "scenario": trace.scenario,
        "duration_s": trace.t_s[-1] if trace.t_s else 0.0,
        "steady_walking": error_statistics(err[steady]),
        "all": error_statistics(err),
        "min_distance_m": float(err.min() + trace.following_distance_m) if err.size else None,
        "max_forward_mps": float(np.max(trace.forward_mps)) if trace.forward_mps else 0.0,
        "max_abs_yaw_rate_radps": float(np.max(np.abs(trace.yaw_rate_radps)))
        if trace.yaw_rate_radps
        else 0.0,
        "target_missing_periods": trace.target_missing,
    }


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--scenario", choices=(*SCENARIOS, "all"), default="all", help="walker script"
    )
    parser.add_argument("--speed-mps", type=positive_float, default=1.0, help="walking speed")
    parser.add_argument("--config", help="TOML file ([control] and [mavlink] are used)")
    parser.add_argument("--latency-s", type=non_negative_float, default=RunSettings.perception_latency_s)
    parser.add_argument("--noise-m", type=non_negative_float, default=RunSettings.position_noise_m)
    parser.add_argument("--packet-loss", type=float_within(0.0, 1.0, highest_open=True),
                        default=0.0, help="fraction, both ways, below 1")  # fmt: skip
    parser.add_argument("--link-latency-s", type=float_within(0.0, MAX_LINK_LATENCY_S),
                        default=0.0, help=f"one way, at most {MAX_LINK_LATENCY_S:g} s")  # fmt: skip
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument("--plot", type=plot_path, help="write a PNG of distance error and paths here")


def main(args: argparse.Namespace) -> dict:
    config = Config.load(args.config) if args.config else Config()
    settings = RunSettings(
        perception_latency_s=args.latency_s, position_noise_m=args.noise_m,
        packet_loss=args.packet_loss, link_latency_s=args.link_latency_s, seed=args.seed,
    )  # fmt: skip
    if not 0.0 <= args.packet_loss < 1.0:
        raise ValueError(f"--packet-loss must be in [0, 1), got {args.packet_loss}")
    names = SCENARIOS if args.scenario == "all" else (args.scenario,)
    start = config.control.following_distance_m
    traces = []
    for name in names:
        path = scenario(name, speed_mps=args.speed_mps, start_distance_m=start)
        traces.append(
            run_following(path, name, config.control, config.mavlink, settings, progress=True)
        )
    results = [summarize(t) for t in traces]
    steady_all = np.concatenate(
        [np.asarray(t.distance_error_m)[np.asarray(t.steady, dtype=bool)] for t in traces]
    )
    overall = error_statistics(steady_all)
    if not args.json:
        _print_table(results, overall, config.control.following_distance_m)
    if args.plot:
        _plot(traces, args.plot)
        print(f"plot written to {args.plot}")
    return {
        "following_distance_m": config.control.following_distance_m,
        "walking_speed_mps": args.speed_mps,
        "settings": settings.__dict__,
        "scenarios": results,
        "steady_walking": overall,
        "goal_abs_error_m": 0.3,
    }


def _print_table(results: list[dict], overall: dict, distance_m: float) -> None:
    print(f"distance error (m) against the {distance_m} m set point, steady walking:")
    print(f"{'scenario':<10} {'n':>5} {'mean':>7} {'median|e|':>10} {'p90|e|':>8} {'max|e|':>8}")
    rows = [(r["scenario"], r["steady_walking"]) for r in results] + [("all", overall)]
    for name, s in rows:
        if not s["samples"]:
            print(f"{name:<10} {0:>5}")
            continue
        print(
            f"{name:<10} {s['samples']:>5} {s['mean_m']:>7.3f} {s['median_abs_m']:>10.3f} "
            f"{s['p90_abs_m']:>8.3f} {s['max_abs_m']:>8.3f}"
        )


def _plot(traces: list[RunTrace], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(traces), figsize=(5 * len(traces), 8), squeeze=False)
    for col, tr in enumerate(traces):
        ax = axes[0][col]
        ax.plot(tr.t_s, tr.distance_error_m, label="distance error")
        steady = np.asarray(tr.steady)
        ax.scatter(np.asarray(tr.t_s)[steady], np.asarray(tr.distance_error_m)[steady], s=3, c="g",
                   label="steady walking")  # fmt: skip
        ax.axhspan(-0.3, 0.3, color="g", alpha=0.1)
        ax.set(title=tr.scenario, xlabel="t (s)", ylabel="distance - set point (m)")
        ax.legend(loc="lower right")
        ax = axes[1][col]
        w, r = np.asarray(tr.walker_xy), np.asarray(tr.robot_xy)
        ax.plot(w[:, 0], w[:, 1], label="walker")
        ax.plot(r[:, 0], r[:, 1], label="rover")
        ax.set(xlabel="odom x (m)", ylabel="odom y (m)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
