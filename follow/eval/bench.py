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

    from follow.boost.factory import build_identifier
    from follow.control.controller import FollowingController
    from follow.pipeline import FrameResult, target_motion
    from follow.pose.detector import PoseDetector
    from follow.pose.observations import skeletons_to_observations
    from follow.types import Odometry
    from follow.ukf.tracker import PeopleTracker

    config = Config.load(args.config) if args.config else Config()
    setup = PetsSetup.load()
    camera = setup.camera
    detector = PoseDetector(config.pose)
    tracker = PeopleTracker(camera, config.tracker)
    identifier = build_identifier(config.identify)
    controller = FollowingController(config.control)
    total = min(args.warmup + args.frames, setup.frame_count)
    times: dict[str, list[float]] = {k: [] for k in (
        "capture", "preprocess", "inference", "decode", "pose", "tracker", "identify",
        "control", "end_to_end")}  # fmt: skip
    per_track, per_person = [], []
    selected = False
    for index in tqdm(range(total), desc="bench", unit="frame", disable=args.json):
        t0 = time.perf_counter()
        image = setup.sequence.read_frame(index)
        t1 = time.perf_counter()
        skeletons = detector.detect(image)
        t2 = time.perf_counter()
        stamp = index / PETS_FPS
        observations = skeletons_to_observations(skeletons, camera.image_size, config.pose)
        tracks = tracker.update(observations, stamp)
        t3 = time.perf_counter()
        if not selected:
            confirmed = [t for t in tracks if t.confirmed]
            if confirmed:
                identifier.select_target(confirmed[0].track_id)
                selected = True
        estimate = identifier.update(image, tracks, stamp)
        t4 = time.perf_counter()
        result = FrameResult(index, stamp, Odometry.origin(stamp), skeletons, tracks, estimate)
        controller.update(target_motion(result, Odometry.origin(stamp)), stamp)
        t5 = time.perf_counter()
        if index < args.warmup:
            continue
        split = detector.last_timing_ms
        for key, value in (("capture", t1 - t0), ("pose", t2 - t1), ("tracker", t3 - t2),
                           ("identify", t4 - t3), ("control", t5 - t4),
                           ("end_to_end", t5 - t0)):  # fmt: skip
            times[key].append(1e3 * value)
        for key in ("preprocess", "inference", "decode"):
            if key in split:
                times[key].append(split[key])
        if tracks:
            per_track.append(1e3 * (t3 - t2) / len(tracks))
        observed = sum(t.observation is not None for t in tracks)
        if observed:
            per_person.append(1e3 * (t4 - t3) / observed)
    e2e = _median(times["end_to_end"])
    result = {
        "frames": len(times["end_to_end"]),
        "input_height_px": config.pose.input_height_px,
        "pose_backend": detector.backend_name,
        **{f"{k}_ms": _median(v) for k, v in times.items() if k != "end_to_end"},
        "tracker_ms_per_track": _median(per_track),
        "identify_ms_per_person": _median(per_person),
        "end_to_end_ms": e2e,
        "end_to_end_fps": round(1000.0 / e2e, 2) if e2e else None,
        "peak_rss_mb": round(peak_rss_mb(), 1),
    }
    if not args.json:
        print(f"{result['frames']} PETS frames, pose input height {config.pose.input_height_px}"
              f" px on {detector.backend_name}; medians:")  # fmt: skip
        for key, value in result.items():
            if key.endswith("_ms") or key.endswith("_per_track") or key.endswith("_per_person"):
                print(f"  {key:24s} {value}")
        print(f"  end-to-end: {result['end_to_end_fps']} fps; peak RSS {result['peak_rss_mb']} MB")
    return result
