"""`follow bench`: per-stage latency of the whole stack on PETS 2009 frames, end-to-end
frames per second, and peak resident memory.

Every stage is timed on the same frames in one run, so the split is consistent even on
a busy machine: medians over frames, after a warm-up. The end-to-end figure is the
median time of one frame through capture, pose, tracker, identification and control.
"""

from __future__ import annotations

import resource
import sys
import time

import numpy as np

from follow.config import Config
from follow.eval.pets_setup import PETS_FPS, PetsSetup


def add_arguments(p) -> None:
    p.add_argument("--frames", type=int, default=60, help="PETS frames to time (default 60)")
    p.add_argument("--warmup", type=int, default=5, help="frames run before timing")
    p.add_argument("--config", help="TOML configuration (pose input size, provider, ...)")


def peak_rss_mb() -> float:
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / (1024.0 * 1024.0) if sys.platform == "darwin" else peak / 1024.0


def _median(values) -> float | None:
    return round(float(np.median(values)), 3) if len(values) else None


def main(args) -> dict:
    from tqdm import tqdm

    from follow.control.controller import FollowingController
    from follow.pipeline import target_motion
    from follow.pose.detector import PoseDetector
    from follow.run import build_perception
    from follow.types import Frame, Odometry

    config = Config.load(args.config) if args.config else Config()
    setup = PetsSetup.load()
    detector = PoseDetector(config.pose)
    perception = build_perception(config, setup.camera, lambda frame: detector.detect(frame.image))
    controller = FollowingController(config.control)
    total = min(args.warmup + args.frames, setup.frame_count)
    times: dict[str, list[float]] = {k: [] for k in (
        "capture", "preprocess", "inference", "decode", "pose", "tracker", "identify",
        "control", "end_to_end")}  # fmt: skip
    per_track, per_person = [], []
    selected = False
    for index in tqdm(range(total), desc="bench", unit="frame", disable=args.json):
        stamp = index / PETS_FPS
        robot = Odometry.origin(stamp)
        t0 = time.perf_counter()
        image = setup.sequence.read_frame(index)
        t1 = time.perf_counter()
        result = perception.process(Frame(image, stamp), robot, index)
        t2 = time.perf_counter()
        controller.update(target_motion(result, robot), stamp)
        t3 = time.perf_counter()
        if not selected:  # learn someone, so that the identifier's update is timed too
            confirmed = [t for t in result.tracks if t.confirmed]
            if confirmed:
                perception.identifier.select_target(confirmed[0].track_id)
                selected = True
        if index < args.warmup:
            continue
        stage_ms = result.timing_ms
        for key, value_ms in (("capture", 1e3 * (t1 - t0)), ("control", 1e3 * (t3 - t2)),
                              ("end_to_end", 1e3 * (t3 - t0)),
                              *((k, stage_ms[k]) for k in ("pose", "tracker", "identify")),
                              *((k, v) for k, v in detector.last_timing_ms.items()
                                if k in ("preprocess", "inference", "decode"))):  # fmt: skip
            times[key].append(value_ms)
        if result.tracks:
            per_track.append(stage_ms["tracker"] / len(result.tracks))
        observed = sum(t.observation is not None for t in result.tracks)
        if observed:
            per_person.append(stage_ms["identify"] / observed)
    e2e = _median(times["end_to_end"])
    result = {
        "frames": len(times["end_to_end"]),
        "input_height_px": config.pose.input_height_px,
        "pose_backend": detector.backend_name,
        "pose_model": detector.model_path.name,
        **{f"{k}_ms": _median(v) for k, v in times.items() if k != "end_to_end"},
        "tracker_ms_per_track": _median(per_track),
        "identify_ms_per_person": _median(per_person),
        "end_to_end_ms": e2e,
        "end_to_end_fps": round(1000.0 / e2e, 2) if e2e else None,
        "peak_rss_mb": round(peak_rss_mb(), 1),
    }
    notes = []
    if config.pose.precision == "auto" and "int8" not in detector.model_path.name:
        notes.append("the INT8 pose model is not made yet, so FP32 ran (2x slower on a CPU): "
                     "`python tools/quantize_pose.py` makes it once")  # fmt: skip
    result["notes"] = notes
    if not args.json:
        print(f"{result['frames']} PETS frames, pose input height {config.pose.input_height_px}"
              f" px, {detector.model_path.name} on {detector.backend_name}; medians:")  # fmt: skip
        for key, value in result.items():
            if key.endswith("_ms") or key.endswith("_per_track") or key.endswith("_per_person"):
                print(f"  {key:24s} {value}")
        print(f"  end-to-end: {result['end_to_end_fps']} fps; peak RSS {result['peak_rss_mb']} MB")
        for note in notes:
            print(f"  note: {note}")
    return result
