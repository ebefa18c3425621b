"""`follow bench`: the whole stack on PETS 2009 frames (or, `--scene robot`, a robot's
view of real people at following distances: follow/eval/robot_scene.py), against the
pose network's own inference time on the same frames at the input heights the stack
runs them at (the floor for the runtime).

One run measures, in this order and in one process:
1. **bare inference**: the pose network alone on each frame (median ms);
2. **stages**: every frame through pose, tracker, identification and control one after
   another, each stage timed (medians over frames, after a warm-up);
3. **runner**: the threads that drive a robot (`build_runner`, stages overlapped as
   configured) fed by a camera at `--camera-fps`: frames processed per second, capture
   to command latency (median, p95), both after the warm-up, and end-to-end time per
   frame over the bare inference time (1.0 would be the floor).
Peak RSS is the process's. `--matrix` runs the robot defaults and the PETS settings
with onnxruntime and with OpenVINO (or the runtimes `--providers` names: `cpu,cuda` on
a GPU machine), each in its own process (so each has its own peak RSS), and prints them
side by side with what each actually ran (pose model and runtime, the runner's stages,
the re-id runtime) and each cell's notes.
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import time

import numpy as np

from follow.cli_args import non_negative_int, positive_float, positive_int
from follow.config import Config
from follow.pose.runtime import GPU_PROVIDERS

PROVIDER_CHOICES = ("auto", "cpu", "openvino", "cuda", "tensorrt")
SETTINGS_CHOICES = ("robot", "pets")
SCENE_CHOICES = ("pets", "robot")
MATRIX_PROVIDERS = ("cpu", "openvino")
# Below this many latencies the 95th percentile lies between the two largest.
MIN_P95_SAMPLES = 20


def provider_list(text: str) -> tuple[str, ...]:
    """`--providers cpu,cuda`: runtimes from PROVIDER_CHOICES, each once, in order."""
    names = tuple(dict.fromkeys(n.strip() for n in text.split(",") if n.strip()))
    unknown = [n for n in names if n not in PROVIDER_CHOICES]
    if not names or unknown:
        import argparse

        raise argparse.ArgumentTypeError(
            f"'{text}': give runtimes from {', '.join(PROVIDER_CHOICES)}, separated by commas"
        )
    return names


ROBOT_SCENE_PEOPLE = 5  # --scene robot's defaults: people in view, the farthest's distance
ROBOT_SCENE_FAR_M = 5.0


def add_arguments(p) -> None:
    p.add_argument("--frames", type=positive_int, default=60, help="frames to time (default 60)")
    p.add_argument("--warmup", type=non_negative_int, default=5, help="frames run before timing")
    p.add_argument("--settings", choices=SETTINGS_CHOICES, default=None,
                   help="robot defaults, or the PETS settings (follow/eval/pets2009.toml; "
                        "default robot)")  # fmt: skip
    p.add_argument("--provider", choices=PROVIDER_CHOICES,
                   help="pose runtime: cpu = onnxruntime (the plain install), openvino, "
                        "cuda, tensorrt (default: the config's); with cpu or openvino the "
                        "re-id network runs on the CPU too")  # fmt: skip
    p.add_argument("--camera-fps", type=positive_float, default=30.0,
                   help="rate the runner's simulated camera delivers frames at (default 30)")  # fmt: skip
    p.add_argument("--scene", choices=SCENE_CHOICES, default="pets",
                   help="frames: PETS 2009 (5-8 people 35-95 px tall), or a robot's 640x480 "
                        "view of real people, the target 2.5 m ahead (default pets)")  # fmt: skip
    p.add_argument("--people", type=positive_int, default=None,
                   help="with --scene robot: people in view, 1-5 (default 5)")  # fmt: skip
    p.add_argument("--far-m", type=positive_float, default=None,
                   help="with --scene robot: the farthest person's distance, 3-15 m; the "
                        "others stand between 3 m and it (default 5)")  # fmt: skip
    p.add_argument("--config", help="TOML configuration over the chosen settings")
    p.add_argument("--matrix", action="store_true",
                   help="robot and PETS settings x runtimes (--providers), one process each")  # fmt: skip
    p.add_argument("--providers", type=provider_list, default=None,
                   help="with --matrix: runtimes to compare (default cpu,openvino; "
                        "cpu,cuda,tensorrt on a GPU machine)")  # fmt: skip
    p.add_argument("--repeats", type=positive_int, default=None,
                   help="with --matrix: runs per cell; the table shows medians (default 1)")  # fmt: skip


def peak_rss_mb() -> float:
    """This process's peak resident set size in megabytes (10^6 bytes, the unit of the
    goal): getrusage gives KiB on Linux, bytes on macOS."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return (peak if sys.platform == "darwin" else peak * 1024.0) / 1e6


def _median(values) -> float | None:
    return round(float(np.median(values)), 3) if len(values) else None


def bench_config(args) -> Config:
    """The settings asked for, `--config` over them, then `--provider`."""
    if args.settings == "pets":
        from follow.eval.pets_setup import pets_config

        config = pets_config(args.config)
    else:
        config = Config.load(args.config) if args.config else Config()
    if args.provider:
        config = config.replace("pose", provider=args.provider)
        if args.provider == "cpu":  # the plain install's runtime for both networks
            config = config.replace("identify", reid_provider="onnxruntime")
        elif args.provider not in ("auto", *GPU_PROVIDERS):  # a CPU cell: all on the CPU
            config = config.replace("identify", reid_provider="cpu")
    return config


def main(args) -> dict:
    if args.frames < 1 or args.warmup < 0:
        raise ValueError("--frames must be >= 1 and --warmup >= 0")
    robot_only = [o for o, v in (("--people", args.people), ("--far-m", args.far_m)) if v]
    if robot_only and args.scene != "robot":  # else they would be ignored in silence
        raise ValueError(f"{' and '.join(robot_only)}: for the robot scene only; add "
                         "--scene robot")  # fmt: skip
    args.people = args.people or ROBOT_SCENE_PEOPLE
    args.far_m = args.far_m or ROBOT_SCENE_FAR_M
    refuse_ignored_options(args)
    if args.matrix:
        args.providers = args.providers or MATRIX_PROVIDERS
        args.repeats = args.repeats or 1
        return run_matrix(args)
    args.settings = args.settings or "robot"
    from follow.pose.detector import CHOSEN_HERE, PoseDetector, auto_fp32_reason

    setup, scene = bench_scene(args)
    config = config_for_scene(bench_config(args), setup, args.scene)
    total = min(args.warmup + args.frames, setup.frame_count)
    first = setup.sequence.read_frame(0)
    detector = PoseDetector(config.pose, frame_size=(first.shape[1], first.shape[0]))
    result = {
        "settings": args.settings,
        "scene": scene,
        "input_height_px": config.pose.input_height_px,
        "network_stages": config.pose.network_stages,
        "identifier": config.identify.identifier,
        "pose_backend": detector.backend_name,
        "pose_model": detector.model_path.name,
        "bare_inference_ms": bare_inference_ms(detector, setup, total, args.warmup, args.json),
    }
    result.update(stage_times(config, detector, setup, total, args.warmup, args.json))
    result.update(runner_times(config, detector, setup, total, args.warmup, args.camera_fps,
                               args.json))  # fmt: skip
    # the same runner with the other stage setting: what overlapping them gains or
    # costs, same run
    other = config.replace("control", overlap_stages=not result["overlap_stages"])
    other_run = runner_times(other, detector, setup, total, args.warmup, args.camera_fps,
                             args.json)  # fmt: skip
    other_name = "overlapped" if other_run["overlap_stages"] else "in_turn"
    for key in ("runner_fps", "capture_to_command_median_ms", "capture_to_command_p95_ms",
                "capture_to_command_samples"):  # fmt: skip
        result[f"{key}_stages_{other_name}"] = other_run[key]
    e2e_ms = result["runner_frame_ms"]
    result["end_to_end_over_inference"] = (
        round(e2e_ms / result["bare_inference_ms"], 3) if e2e_ms else None
    )
    result["peak_rss_mb"] = round(peak_rss_mb(), 1)
    notes = []
    if (config.pose.precision in CHOSEN_HERE and not config.pose.model_file
            and "int8" not in detector.model_path.name):
        # the reason names the missing model (and how to make it), the CPU or the GPU
        notes.append(f"FP32 ran, not the INT8 pose model: {auto_fp32_reason(config.pose)}")
    if result["runner_fps"] and result["runner_fps"] >= 0.95 * args.camera_fps:
        notes.append(f"the runner kept up with the {args.camera_fps:g} fps camera: its figures "
                     "are the camera's rate, not the stack's limit")  # fmt: skip
    if result["runner_fps"] is None:
        notes.append(f"the runner processed {result['runner_frames']} frames, under two after "
                     f"the {args.warmup} of warm-up: no frame rate; more --frames")  # fmt: skip
    samples = result["capture_to_command_samples"]
    if samples < MIN_P95_SAMPLES:
        notes.append(f"the capture-to-command p95 comes from {samples} latencies (under "
                     f"{MIN_P95_SAMPLES}, it is about their largest): more --frames")  # fmt: skip
    result["notes"] = notes
    if not args.json:
        print_report(result, args.camera_fps)
    return result


def config_for_scene(config, setup, scene: str):
    """The settings the bench runs on `scene`: on the robot scene, the pose input height
    `follow run` chooses for its camera; on PETS frames the configured one (the PETS
    settings fix 576 px; the robot defaults' 368 px there is the documented load of many
    small, far people, which the camera rule, sized for a person 8 m away, would shrink)."""
    if scene != "robot":
        return config
    from follow.pose.input_size import pose_config_for_camera

    chosen = pose_config_for_camera(config.pose, setup.camera)
    return config.replace("pose", input_height_px=chosen.input_height_px)


def bench_scene(args):
    """(the frames' setup, a description): PETS 2009, or the robot scene."""
    if args.scene == "pets":
        from follow.eval.pets_setup import PetsSetup

        return PetsSetup.load(), "PETS 2009 frames"
    from follow.eval.robot_scene import RobotScene
    from follow.eval.verification import data_root

    root = data_root(None, has_option=False)
    scene = RobotScene(root, args.people, args.far_m, args.warmup + args.frames)
    far = f", the others 3-{args.far_m:g} m" if args.people > 1 else ""
    return scene, f"robot view, {args.people} people (target 2.5 m{far})"


def bare_inference_ms(detector, setup, total: int, warmup: int, quiet: bool) -> float | None:
    """The pose network alone on the frames (preprocessing and decoding excluded), each
    at the input height the stack runs it at (the people-sized input's choice, as in the
    stage run), so that the end-to-end frame is compared with the same network work."""
    from tqdm import tqdm

    detector.reset_input_sizing()
    times = []
    for index in tqdm(range(total), desc="bench: inference", unit="frame", disable=quiet):
        image = setup.sequence.read_frame(index)
        detector.detect(image)
        if index >= warmup:
            times.append(detector.last_timing_ms["inference"])
    return _median(times)


def stage_times(config, detector, setup, total: int, warmup: int, quiet: bool) -> dict:
    """Each frame through every stage in turn; per-stage medians."""
    from tqdm import tqdm

    from follow.control.controller import FollowingController
    from follow.pipeline import target_motion
    from follow.types import Frame, Odometry

    perception = _learning_perception(config, setup, detector)
    controller = FollowingController(config.control)
    times: dict[str, list[float]] = {k: [] for k in (
        "capture", "preprocess", "inference", "decode", "pose", "tracker", "identify",
        "control", "in_turn")}  # fmt: skip
    per_track, per_person, people, heights = [], [], [], []
    for index in tqdm(range(total), desc="bench: stages", unit="frame", disable=quiet):
        stamp = index / setup.fps
        robot = Odometry.origin(stamp)
        t0 = time.perf_counter()
        image = setup.sequence.read_frame(index)
        t1 = time.perf_counter()
        result = perception.process(Frame(image, stamp), robot, index)
        t2 = time.perf_counter()
        controller.update(target_motion(result, robot), stamp)
        t3 = time.perf_counter()
        if index < warmup:
            continue
        heights.append(detector.last_input_height_px)
        stage_ms = result.timing_ms
        for key, value_ms in (("capture", 1e3 * (t1 - t0)), ("control", 1e3 * (t3 - t2)),
                              ("in_turn", 1e3 * (t3 - t0)),
                              *((k, stage_ms[k]) for k in ("pose", "tracker", "identify")),
                              *((k, v) for k, v in detector.last_timing_ms.items()
                                if k in ("preprocess", "inference", "decode"))):  # fmt: skip
            times[key].append(value_ms)
        if result.tracks:
            per_track.append(stage_ms["tracker"] / len(result.tracks))
        observed = sum(t.observation is not None for t in result.tracks)
        people.append(observed)
        if observed:
            per_person.append(stage_ms["identify"] / observed)
    in_turn = _median(times.pop("in_turn"))
    reid = perception.identifier.identifier.context.model.reid
    return {
        "reid_backend": reid.backend_name if reid is not None else None,
        "frames": len(people),
        "people_in_view_median": _median(people),
        "people_in_view_max": max(people) if people else None,
        "input_height_px_shares": {int(h): round(heights.count(h) / len(heights), 3)
                                   for h in sorted(set(heights))},  # fmt: skip
        **{f"{k}_ms": _median(v) for k, v in times.items()},
        "tracker_ms_per_track": _median(per_track),
        "identify_ms_per_person": _median(per_person),
        "in_turn_ms": in_turn,
        "in_turn_fps": round(1000.0 / in_turn, 2) if in_turn else None,
    }


def runner_times(config, detector, setup, total: int, warmup: int, camera_fps: float,
                 quiet: bool) -> dict:  # fmt: skip
    """The threaded runner of `follow run`, fed at `camera_fps` by a decoding camera."""
    from follow.control.base import NullBase
    from follow.pipeline import build_runner
    from follow.types import Frame

    perception = _learning_perception(config, setup, detector)
    runner = build_runner(perception, NullBase(), config.control)
    done_s: list[float] = []

    def on_result(frame, result) -> None:
        done_s.append(time.perf_counter())

    def camera():
        for index in range(total):
            yield Frame(setup.sequence.read_frame(index), 0.0)  # decoded like a camera's

    if not quiet:
        print(f"bench: runner at {camera_fps:g} fps ({total} frames)...", file=sys.stderr)
    runner.run(camera(), pace_hz=camera_fps, on_result=on_result)
    timed = done_s[warmup:]  # after the warm-up; none where it took every result
    fps = (len(timed) - 1) / (timed[-1] - timed[0]) if len(timed) >= 2 else None
    latency = runner.control.latency.summary_ms(warmup)  # the same results' latencies
    return {
        "overlap_stages": runner.overlap_stages,
        "camera_fps": camera_fps,
        "runner_frames": runner.processed,
        "runner_dropped_frames": runner.dropped_frames,
        "runner_fps": round(fps, 2) if fps else None,
        "runner_frame_ms": round(1000.0 / fps, 3) if fps else None,
        "capture_to_command_median_ms": latency["median"],
        "capture_to_command_p95_ms": latency["p95"],
        "capture_to_command_samples": latency["samples"],  # after the warm-up
    }


class _SelectsSomeone:
    """The identifier, made to select the first confirmed track it is shown, so that its
    learning and checking are timed too (PETS people stand farther away than a robot's
    initial choice reaches). It selects on the thread that updates it: the runner's
    outputs run on another thread, where a selection would race the update."""

    def __init__(self, identifier):
        self.identifier = identifier
        self.selected = False

    def update(self, image_bgr, tracks, stamp_s, robot=None):
        estimate = self.identifier.update(image_bgr, tracks, stamp_s, robot)
        confirmed = [t for t in tracks if t.confirmed]
        if not self.selected and confirmed:
            self.identifier.select_target(confirmed[0].track_id)
            self.selected = True
        return estimate


def _learning_perception(config, setup, detector):
    """The stack on `detector`, with an identifier that learns someone; the detector
    forgets the people of an earlier pass over the frames (each pass starts again at the
    first frame)."""
    from follow.run import build_perception

    detector.reset_input_sizing()
    perception = build_perception(config, setup.camera, lambda frame: detector.detect(frame.image),
                                  detector.backend_name)  # fmt: skip
    perception.identifier = _SelectsSomeone(perception.identifier)
    return perception


def print_report(result: dict, camera_fps: float) -> None:
    shares = ", ".join(f"{h} px {share:.0%}" for h, share in
                       result["input_height_px_shares"].items())  # fmt: skip
    print(f"{result['frames']} frames, {result['scene']} ({result['settings']} settings), pose "
          f"input {result['input_height_px']} px (frames run at: {shares}), "
          f"{result['pose_model']} on {result['pose_backend']}, "
          f"identifier {result['identifier']} (re-id on {result['reid_backend']}), people in "
          f"view median "
          f"{result['people_in_view_median']} (max {result['people_in_view_max']}); medians:")  # fmt: skip
    print(f"  bare inference           {result['bare_inference_ms']} ms (at the input "
          "heights the stages ran at: the floor)")
    for key, value in result.items():
        if (
            key.endswith("_ms")
            and key not in ("bare_inference_ms", "runner_frame_ms")
            and ("capture_to" not in key)
        ):
            print(f"  {key:24s} {value}")
    print(f"  stages in turn: {result['in_turn_fps']} fps")
    print(f"  runner ({'overlapped' if result['overlap_stages'] else 'in turn'}, camera "
          f"{camera_fps:g} fps): {result['runner_fps']} fps, {result['runner_frame_ms']} ms a "
          f"frame = {result['end_to_end_over_inference']} x bare inference; capture to command "
          f"median {result['capture_to_command_median_ms']} ms, p95 "
          f"{result['capture_to_command_p95_ms']} ms (of "
          f"{result['capture_to_command_samples']} frames)")  # fmt: skip
    for other in ("in_turn", "overlapped"):
        if f"runner_fps_stages_{other}" in result:
            print(f"  the same runner with the stages {other.replace('_', ' ')}: "
                  f"{result[f'runner_fps_stages_{other}']} fps; capture to command median "
                  f"{result[f'capture_to_command_median_ms_stages_{other}']} ms, p95 "
                  f"{result[f'capture_to_command_p95_ms_stages_{other}']} ms (of "
                  f"{result[f'capture_to_command_samples_stages_{other}']} frames)")  # fmt: skip
    print(f"  peak RSS {result['peak_rss_mb']} MB")
    for note in result["notes"]:
        print(f"  note: {note}")


MATRIX_KEYS = ("bare_inference_ms", "in_turn_fps", "runner_fps", "end_to_end_over_inference",
               "capture_to_command_median_ms", "capture_to_command_p95_ms",
               "capture_to_command_samples", "peak_rss_mb")  # fmt: skip


def _cell(value, width: int, digits: int) -> str:
    """A matrix figure, or a dash where no run of the cell had one."""
    return f"{value:{width}.{digits}f}" if value is not None else f"{'-':>{width}}"


def ran_on(row: dict) -> str:
    """What a cell ran: pose model and runtime, the runner's stages, the re-id runtime."""
    stages = "stages overlapped" if row["overlap_stages"] else "stages in turn"
    return (f"{row['pose_model']} on {row['pose_backend']}, {stages}, re-id "
            f"{row['reid_backend'] or 'none'}")  # fmt: skip


def refuse_ignored_options(args) -> None:
    """Options that one kind of run would ignore in silence: the matrix picks every
    setting and runtime itself, and a single run has no runtimes to compare or repeat."""
    if args.matrix:
        chosen = [o for o, v in (("--settings", args.settings), ("--provider", args.provider))
                  if v is not None]  # fmt: skip
        if chosen:
            raise ValueError(f"--matrix runs every setting and runtime: leave out "
                             f"{' and '.join(chosen)} (--providers names the runtimes)")  # fmt: skip
        return
    matrix_only = [o for o, v in (("--providers", args.providers), ("--repeats", args.repeats))
                   if v is not None]  # fmt: skip
    if matrix_only:
        raise ValueError(f"{' and '.join(matrix_only)}: with --matrix only (a single run is "
                         "one runtime, --provider, once)")  # fmt: skip


def run_matrix(args) -> dict:
    """Each (settings, runtime) in its own process, `--repeats` times, interleaved so
    that a change in the machine's load touches every cell alike."""
    from tqdm import tqdm

    matrix = [(s, p) for s in SETTINGS_CHOICES for p in args.providers]
    cells: dict[str, list[dict]] = {f"{s}/{p}": [] for s, p in matrix}
    runs = [(s, p) for _ in range(args.repeats) for s, p in matrix]
    for settings, provider in tqdm(runs, desc="bench matrix", unit="run", disable=args.json):
        command = [sys.executable, "-m", "follow.cli", "bench", "--json", "--settings", settings,
                   "--provider", provider, "--frames", str(args.frames), "--warmup",
                   str(args.warmup), "--camera-fps", str(args.camera_fps), "--scene",
                   args.scene]  # fmt: skip
        if args.scene == "robot":
            command += ["--people", str(args.people), "--far-m", str(args.far_m)]
        if args.config:
            command += ["--config", args.config]
        out = subprocess.run(command, capture_output=True, text=True)
        if out.returncode != 0:
            raise RuntimeError(f"bench {settings}/{provider} failed:\n{out.stderr[-2000:]}")
        cells[f"{settings}/{provider}"].append(json.loads(out.stdout.strip().splitlines()[-1]))
    table = {}
    for name, runs_of_cell in cells.items():
        row = {k: _median([r[k] for r in runs_of_cell if r[k] is not None]) for k in MATRIX_KEYS}
        for key in ("pose_backend", "pose_model", "overlap_stages", "reid_backend"):
            row[key] = runs_of_cell[0][key]
        row["notes"] = list(dict.fromkeys(n for r in runs_of_cell for n in r["notes"]))
        row["runs"] = len(runs_of_cell)
        table[name] = row
    if not args.json:
        print(f"medians of {args.repeats} run(s) per cell, camera {args.camera_fps:g} fps")
        print(f"{'cell':18s} {'inference ms':>12s} {'in turn fps':>11s} {'runner fps':>10s} "
              f"{'x inference':>11s} {'latency p50':>11s} {'p95':>7s} {'of':>4s} "
              f"{'peak RSS MB':>11s}  "
              f"ran on")  # fmt: skip
        for name, row in table.items():
            print(f"{name:18s} {_cell(row['bare_inference_ms'], 12, 1)} "
                  f"{_cell(row['in_turn_fps'], 11, 1)} {_cell(row['runner_fps'], 10, 1)} "
                  f"{_cell(row['end_to_end_over_inference'], 11, 2)} "
                  f"{_cell(row['capture_to_command_median_ms'], 11, 1)} "
                  f"{_cell(row['capture_to_command_p95_ms'], 7, 1)} "
                  f"{_cell(row['capture_to_command_samples'], 4, 0)} "
                  f"{_cell(row['peak_rss_mb'], 11, 0)}  {ran_on(row)}")  # fmt: skip
        for name, row in table.items():
            for note in row["notes"]:
                print(f"note ({name}): {note}")
    return {"matrix": table, "repeats": args.repeats, "camera_fps": args.camera_fps}
