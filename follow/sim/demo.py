"""`follow demo`: a simulated robot follows a person among others who cross and hide them.

The whole stack runs, in real time: people walk in a simulated world; a camera on the
robot renders them (coloured clothes, so identification learns from pixels); a synthetic
skeleton detector reports their joints with noise, misses and occlusions; the UKF
tracker, the identifier, and the controller run as on the robot, in the same threaded
runner and control loop as `follow run` (`follow.pipeline.build_runner`: capture-time
odometry, blind-drive bound, watchdog); commands go over MAVLink (UDP loopback) to a
simulated ArduPilot rover, whose pose moves the camera.

Needs no download: with CCF weights available (`$FOLLOW_MODEL_DIR` or the cache) it
identifies with CCF10, else with the weight-free colour/gradient channels.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from follow.cli_args import refuse_non_utf8_name, seed_number
from follow.config import Config, MavlinkConfig
from follow.sim.appearance import Appearance, PersonView, render_scene
from follow.sim.people import Walker
from follow.sim.world import SimCameraConfig, World, WorldFrame
from follow.types import Frame, Odometry, TargetStatus

log = logging.getLogger(__name__)

TARGET_ID = 1
TARGET_LOOK = Appearance((40, 40, 200), (90, 60, 30), (90, 130, 190), (30, 50, 90))
# Dressed like the target from the waist up: colour alone cannot tell them apart.
LOOKALIKE = Appearance((50, 45, 190), (200, 200, 200), (120, 160, 215), (20, 20, 20))
DEMO_VIDEO = "demo.mp4"  # in the --output folder, unless --no-video
DEMO_CAMERA = SimCameraConfig(
    height_m=0.9, pitch_rad=0.0, horizontal_fov_deg=70.0,
    image_width_px=640, image_height_px=480, detection_scale=1.0, fps=15.0,
)  # fmt: skip


def add_arguments(p) -> None:
    p.add_argument("--output", default="follow-demo",
                   help="folder for the video, plot and log (default follow-demo)")  # fmt: skip
    p.add_argument("--seconds", type=float, default=34.0,
                   help="length of the scenario (default 34)")  # fmt: skip
    p.add_argument("--seed", type=seed_number, default=0,
                   help="people's heights and looks (default 0)")  # fmt: skip
    p.add_argument("--identifier", help="identifier to use (default: ccf10 if its weights "
                   "are available, else channels)")  # fmt: skip
    p.add_argument("--no-video", action="store_true", help="skip writing the video")
    p.add_argument("--bag", help="also write the run as a robot bag (.mcap, .bag or a "
                   "directory): images, odometry, skeletons, ground truth; follow run replays it")  # fmt: skip


def scenario(rng: np.random.Generator) -> tuple[list[Walker], dict[int, Appearance]]:
    """The target walks ahead of the robot, turns, stops and goes on; people cross between
    robot and target (hiding it), and a look-alike passes close by."""
    walkers = [
        Walker(TARGET_ID, 1.74, np.array([[2.6, 0.0], [13.0, 0.0], [13.0, 8.0], [6.0, 10.0]]),
               speeds_mps=np.array([1.0, 0.9, 1.0]), pauses_s=np.array([2.0, 1.5, 0.0]),
               start_s=2.0),
        # crosses between robot and target while they walk straight
        Walker(2, 1.82, np.array([[6.3, -4.5], [6.3, 5.5]]), speeds_mps=1.3, start_s=3.6),
        # the look-alike walks towards the robot, passing close to the target
        Walker(3, 1.70, np.array([[22.0, 1.3], [9.0, 1.1], [4.0, 5.0]]), speeds_mps=1.2,
               start_s=1.0),
        # crosses the target's second leg, between robot and target
        Walker(4, 1.66, np.array([[9.0, 2.8], [19.0, 2.8]]), speeds_mps=1.4, start_s=17.0),
        # background walkers
        Walker(5, 1.58, np.array([[18.0, -6.0], [18.0, 12.0], [24.0, 12.0]]), speeds_mps=0.8),
        Walker(6, 1.90, np.array([[4.0, 12.0], [16.0, 14.0], [4.0, 14.0]]), speeds_mps=1.1,
               start_s=5.0),
    ]  # fmt: skip
    looks = {TARGET_ID: TARGET_LOOK, 3: LOOKALIKE}
    for w in walkers:
        looks.setdefault(w.person_id, Appearance.random(rng))
    return walkers, looks


def person_views(world_frame, robot: Odometry, camera, looks) -> list[PersonView]:
    from follow.frames import odom_to_base

    views = []
    for person in world_frame.people:
        kp = person.keypoints_m
        base = np.column_stack([odom_to_base(kp[:, :2], robot), kp[:, 2]])
        depth = camera.base_to_camera(base)[:, 2]
        if depth[1] <= 0.3:
            continue
        views.append(PersonView(camera.project(base), float(depth[1]),
                                camera.K[0, 0] / float(depth[1]), looks[person.person_id]))  # fmt: skip
    return views


def horizon_row(camera) -> float:
    a, b, c = camera.horizon_line()
    u = camera.image_size[0] / 2.0
    return -(a * u + c) / b


def choose_identifier(name: str | None) -> str:
    """`name`, else ccf10 with its weights, else the weight-free channels. Only missing
    weights fall back: weights present but failing their hash check are refused
    (ModelError naming the file), as `follow run` refuses them."""
    if name:
        return name
    from follow.models import ModelError, get_spec, resolve, search_dirs

    try:
        resolve("ccf10")
        return "ccf10"
    except ModelError:
        files = get_spec("ccf10").files
        if any(all((d / f.relpath).exists() for f in files) for d in search_dirs()):
            raise  # found, but not the pinned weights
        log.info("CCF weights not found: identifying with colour/gradient channels")
        return "channels"


def demo_frames(seconds: float) -> int:
    """The number of frames in a scenario of `seconds`, at least one; a ValueError naming
    --seconds otherwise (checked before any output is opened: a bad value must not
    overwrite an earlier run's log)."""
    frames = seconds * DEMO_CAMERA.fps
    if not (math.isfinite(frames) and frames >= 1):
        raise ValueError(
            f"--seconds must be finite and at least one frame ({1 / DEMO_CAMERA.fps:.3g} s), "
            f"got {seconds}"
        )
    return int(round(frames))


class DemoScore:
    """What the summary reports: time the target was correctly tracked, lost, or a wrong
    person followed; distance error while following; switches to another person."""

    def __init__(self, following_distance_m: float, dt_s: float):
        self.following_distance_m = following_distance_m
        self.dt_s = dt_s  # the first frame's share; then the time between scored frames
        self._last_stamp_s: float | None = None
        self.seconds = {"tracked": 0.0, "lost": 0.0, "wrong": 0.0}
        self.distance_errors_m: list[float] = []
        self.person_switches = 0
        self._last_person: int | None = None
        self.timeline: list[str] = []

    def add(self, world_frame, robot_true: Odometry, tracks, target, started: bool) -> None:
        if not started:
            return
        dt_s = self.dt_s if self._last_stamp_s is None else world_frame.stamp_s - self._last_stamp_s
        self._last_stamp_s = world_frame.stamp_s
        track = next((t for t in tracks if t.track_id == target.target_id), None)
        following = target.status == TargetStatus.TRACKING and track is not None
        person = None
        if following:
            d = [(np.linalg.norm(p.position_m - track.position_m), p.person_id)
                 for p in world_frame.people]  # fmt: skip
            dist, pid = min(d)
            person = pid if dist <= 1.0 else -1
        outcome = "lost" if person is None else ("tracked" if person == TARGET_ID else "wrong")
        self.seconds[outcome] += dt_s
        self.timeline.append(outcome)
        if person is not None:
            if self._last_person is not None and person != self._last_person:
                self.person_switches += 1
            self._last_person = person
        truth = world_frame.person(TARGET_ID)
        if outcome == "tracked" and truth is not None:
            gap = math.hypot(truth.position_m[0] - robot_true.x_m,
                             truth.position_m[1] - robot_true.y_m)  # fmt: skip
            self.distance_errors_m.append(gap - self.following_distance_m)

    def summary(self) -> dict:
        e = np.abs(self.distance_errors_m) if self.distance_errors_m else np.array([np.nan])
        return {
            "seconds": {k: round(v, 2) for k, v in self.seconds.items()},
            "distance_error_mean_m": round(float(np.mean(e)), 3),
            "distance_error_worst_m": round(float(np.max(e)), 3),
            "person_switches": self.person_switches,
        }


@dataclasses.dataclass(frozen=True)
class SimFrame(Frame):
    """A rendered frame with the world it shows (the synthetic detector reads it)."""

    world: WorldFrame | None = None


def sim_perception(camera, config: Config, seed: int = 0):
    """The stack as on the robot, with the synthetic detector in place of the pose
    network (it reads the world a `SimFrame` shows)."""
    from follow.identify.factory import build_identifier
    from follow.pipeline import Perception
    from follow.pose.observations import skeletons_to_observations
    from follow.sim.skeletons import SyntheticDetector
    from follow.ukf.tracker import PeopleTracker

    detector = SyntheticDetector(camera, seed=seed)

    def detect(frame: SimFrame):
        return [d.skeleton for d in detector.detect(frame.world)]

    def to_observations(skeletons):  # as `follow run` does with the pose network's
        return skeletons_to_observations(skeletons, camera.image_size, config.pose)

    return Perception(detect, to_observations, PeopleTracker(camera, config.tracker),
                      build_identifier(config.identify))  # fmt: skip


def sim_frames(
    world: World,
    rover,
    camera,
    looks: dict[int, Appearance],
    n_frames: int,
    seed: int = 0,
    edit: Callable[[WorldFrame], WorldFrame] | None = None,
    pace_hz: float | None = None,
    clock: Callable[[], float] = time.monotonic,
) -> Iterator[SimFrame]:
    """The robot's camera: the world stepped once per frame and rendered from the
    rover's true pose. `edit` may change what a frame shows (a person hidden, say).
    With `pace_hz`, each frame waits until it is due before it takes the rover's pose:
    a runner that paces its source takes a frame and then waits for its time, and the
    frame must show the robot where it is at that capture time, not a frame earlier."""
    from follow.pipeline import wait_until_due

    horizon = horizon_row(camera)
    start = clock()
    for index in range(n_frames):
        if pace_hz:
            wait_until_due(start, index, pace_hz, clock)
        world.set_robot_pose(rover.true_pose())
        wf = world.step()
        if edit is not None:
            wf = edit(wf)
        views = person_views(wf, wf.robot, camera, looks)
        image = render_scene(camera.image_size, horizon, views, seed=seed)
        yield SimFrame(image, wf.stamp_s, world=wf)


def run_demo(
    seconds: float = 34.0,
    seed: int = 0,
    identifier: str | None = None,
    output: Path | None = None,
    write_video: bool = True,
    config: Config | None = None,
    clock: Callable[[], float] = time.monotonic,
    bag_path: Path | None = None,
) -> dict:
    from follow.control.mavlink_base import MavlinkBase
    from follow.control.target import ViewCone
    from follow.pipeline import build_runner
    from follow.run import Outputs
    from follow.sim.rover import SimRover

    n_frames = demo_frames(seconds)
    if output and write_video:  # the video is written by OpenCV, which crashes on such a name
        refuse_non_utf8_name(output, "--output")
    config = config or Config()
    ident_name = choose_identifier(identifier)
    config = config.replace("identify", identifier=ident_name, seed=seed)
    rng = np.random.default_rng(seed)
    walkers, looks = scenario(rng)
    world = World(walkers, camera=DEMO_CAMERA, seed=seed)
    camera = DEMO_CAMERA.detection_camera()

    perception = sim_perception(camera, config, seed)
    score = DemoScore(config.control.following_distance_m, world.dt_s)
    trajectory = {"robot": [], "people": {w.person_id: [] for w in walkers}, "outcome": []}
    output = Path(output) if output else None
    outputs = None
    if output:
        try:
            output.mkdir(parents=True, exist_ok=True)
        except OSError as exc:  # FileExistsError: a file of that name
            raise OSError(f"--output {output}: cannot make the demo's folder there: "
                          f"{exc.strerror or exc}") from exc  # fmt: skip
        if not write_video:
            remove_earlier_video(output / DEMO_VIDEO)
        outputs = Outputs(
            {"source": "simulation", "seed": seed, "identifier": ident_name},
            DEMO_CAMERA.fps,
            video_path=output / DEMO_VIDEO if write_video else None,
            log_path=output / "demo.jsonl",
        )
    bag = None
    timing = []
    with SimRover(seed=seed) as rover:
        mav = dataclasses.replace(config.mavlink or MavlinkConfig(), connection=rover.connection)
        with MavlinkBase(mav, clock=clock) as base:
            frames = sim_frames(world, rover, camera, looks, n_frames, seed,
                                pace_hz=DEMO_CAMERA.fps, clock=clock)  # fmt: skip
            runner = build_runner(perception, base, config.control, ViewCone.from_camera(camera),
                                  clock=clock)  # fmt: skip

            def on_result(frame: SimFrame, result) -> None:
                wf = frame.world
                timing.append(sum(result.timing_ms.values()))
                score.add(wf, wf.robot, result.tracks, result.target, started=wf.index > 0)
                trajectory["robot"].append((wf.robot.x_m, wf.robot.y_m))
                for p in wf.people:
                    trajectory["people"][p.person_id].append(tuple(p.position_m))
                trajectory["outcome"].append(score.timeline[-1] if score.timeline else "lost")
                if outputs is not None:
                    outputs.write(frame, result, runner.control.last_command)
                if bag is not None:  # the pose perception used, and the truth
                    bag.write(frame, result.skeletons, result.robot, wf.robot,
                              {p.person_id: tuple(p.position_m) for p in wf.people})  # fmt: skip

            if bag_path:  # once the rover runs: a demo that cannot start leaves no bag
                from follow.sim.demo_bag import DemoBag

                bag = DemoBag(bag_path, camera, ident_name, seed)
            failed = True
            try:
                runner.run(frames, pace_hz=DEMO_CAMERA.fps, on_result=on_result)
                failed = False
            finally:
                try:
                    if outputs is not None:
                        outputs.close()
                finally:  # the bag is finished or removed whatever the outputs did
                    if bag is not None and failed:
                        bag.abort()
                    elif bag is not None:
                        bag.close()
    summary = {
        **score.summary(),
        "identifier": ident_name,
        "seconds_simulated": round(n_frames * world.dt_s, 2),
        "frames_processed": runner.processed,
        "dropped_frames": runner.dropped_frames,
        "watchdog_trips": runner.control.watchdog_trips,
        "perception_ms_median": round(float(np.median(timing)), 2) if timing else None,
        "capture_to_command_ms": runner.control.latency.summary_ms(),
    }
    if output:
        plot_top_down(trajectory, output / "demo_top_down.png")
        video = [DEMO_VIDEO] if write_video and (output / DEMO_VIDEO).exists() else []
        summary["outputs"] = [str(output / n) for n in [*video, "demo_top_down.png", "demo.jsonl"]]
    if bag_path:
        summary.setdefault("outputs", []).append(str(bag_path))
    return summary


def remove_earlier_video(path: Path) -> None:
    """Remove an earlier run's video from the folder of a run that writes none: left
    there, it would pass for this run's, beside this run's log and plot."""
    if not (path.is_file() or path.is_symlink()):
        return
    try:
        path.unlink()
    except OSError as exc:
        raise OSError(f"--output: cannot remove an earlier run's video {path} (this run "
                      f"writes none): {exc.strerror or exc}") from exc  # fmt: skip
    log.info("removed %s, an earlier run's video: this run (--no-video) writes none", path)


def plot_top_down(trajectory: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 6))
    for pid, pts in trajectory["people"].items():
        pts = np.array(pts)
        style = dict(color="tab:red", lw=2.0, label="target") if pid == TARGET_ID else dict(
            color="0.6", lw=1.0, label="others" if pid == 2 else None)  # fmt: skip
        ax.plot(pts[:, 0], pts[:, 1], **style)
        ax.annotate(str(pid), pts[0], fontsize=8, color=style["color"])
    robot = np.array(trajectory["robot"])
    colours = {"tracked": "tab:green", "lost": "tab:orange", "wrong": "tab:purple"}
    outcome = trajectory["outcome"]
    for name, colour in colours.items():
        sel = np.array([o == name for o in outcome])
        if sel.any():
            ax.scatter(robot[sel, 0], robot[sel, 1], s=6, color=colour, label=f"robot: {name}")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("follow demo: robot path coloured by what it was doing")
    ax.legend(fontsize=8, loc="best")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(args) -> dict:
    if args.bag:  # before the demo's own log and video are opened (and emptied)
        from follow.sim.demo_bag import check_demo_bag_path

        check_demo_bag_path(args.bag)
    summary = run_demo(args.seconds, args.seed, args.identifier, Path(args.output),
                       write_video=not args.no_video, bag_path=args.bag)  # fmt: skip
    if not args.json:
        s = summary["seconds"]
        print(f"identifier {summary['identifier']}, {summary['seconds_simulated']} s simulated")
        print(f"target tracked {s['tracked']:.1f} s, lost {s['lost']:.1f} s, "
              f"wrong person {s['wrong']:.1f} s; switches to another person: "
              f"{summary['person_switches']}")  # fmt: skip
        print(f"following distance error: mean {summary['distance_error_mean_m']:.2f} m, "
              f"worst {summary['distance_error_worst_m']:.2f} m")  # fmt: skip
        for out in summary.get("outputs", []):
            print(f"wrote {out}")
    return summary
