"""`follow bench tracker`: the ground-plane tracker alone, per frame and per track, on
the PETS 2009 detections.

The skeletons come from the PETS evaluation's cache (the pose network runs only when it
is empty), so the figure is the tracker's own: `PeopleTracker.update` on every frame,
`--repeats` passes of a fresh tracker. Times are the CPU time of the calling thread,
which waiting for a shared CPU does not inflate, as medians over frames; per track is a
frame's time over the tracks it returns, as in `follow bench`. A reference timed in the
same loop, one predict and one update of one person with filterpy's stock
`UnscentedKalmanFilter` (fx and hx called point by point), gives a ratio that stays
meaningful on a busy machine.
"""

from __future__ import annotations

import os
import time

import numpy as np

from follow.cli_args import positive_int
from follow.eval.pets_setup import PETS_FPS, load_evaluation


def add_arguments(p) -> None:
    p.add_argument("--frames", type=positive_int, default=200, help="the first N frames (default 200)")
    p.add_argument("--repeats", type=positive_int, default=3, help="passes over the frames (default 3)")
    p.add_argument("--config", help="TOML configuration, over the PETS settings (pets2009.toml)")
    p.add_argument("--no-cache", action="store_true", help="run the pose network again")


def _cpu_ms(fn) -> tuple[float, object]:
    start = time.thread_time()
    out = fn()
    return 1e3 * (time.thread_time() - start), out


def _stock_filterpy_step(camera, config):
    """One person's predict and update with filterpy's stock UKF, for the reference."""
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    from follow.types import Odometry
    from follow.ukf.models import STATE_DIM, MeasurementModel, constant_velocity, process_noise

    cfg = config.tracker
    points = MerweScaledSigmaPoints(
        STATE_DIM, alpha=cfg.sigma_alpha, beta=cfg.sigma_beta, kappa=cfg.sigma_kappa
    )
    ukf = UnscentedKalmanFilter(
        dim_x=STATE_DIM, dim_z=4, dt=0.0, hx=None, fx=constant_velocity, points=points
    )
    model = MeasurementModel(camera, Odometry.origin(), cfg.ankle_height_m)
    x0 = np.array([8.0, 0.5, 0.5, 0.0, 1.45])
    P0 = np.diag([0.3, 0.3, 0.25, 0.25, 0.01])
    dt = 1.0 / PETS_FPS
    ukf.Q = process_noise(dt, cfg.accel_noise_mps2, cfg.height_noise_mps)
    z = model.hx_neck_ankle(constant_velocity(x0, dt))
    R = np.diag([9.0] * 4)

    def step() -> None:
        ukf.x, ukf.P = x0.copy(), P0.copy()
        ukf.predict(dt=dt)
        ukf.update(z, R=R, hx=model.hx_neck_ankle)

    return step


def bench(config, setup, frames: list[int], skeletons, repeats: int) -> dict:
    from tqdm import tqdm

    from follow.pose.observations import skeletons_to_observations
    from follow.ukf.tracker import PeopleTracker

    if repeats < 1 or not frames:
        raise ValueError("--repeats and --frames must be at least 1")
    camera = setup.camera
    observations = [
        skeletons_to_observations(skeletons[i], camera.image_size, config.pose) for i in frames
    ]
    reference = _stock_filterpy_step(camera, config)
    frame_ms, track_ms, tracks, reference_ms = [], [], [], []
    for _ in tqdm(range(repeats), desc="bench tracker", unit="pass", leave=False):
        tracker = PeopleTracker(camera, config.tracker)
        for index, obs in zip(frames, observations, strict=True):
            elapsed_ms, states = _cpu_ms(lambda: tracker.update(obs, index / PETS_FPS))  # noqa: B023
            frame_ms.append(elapsed_ms)
            tracks.append(len(states))
            if states:
                track_ms.append(elapsed_ms / len(states))
            reference_ms.append(_cpu_ms(reference)[0])
    per_track = float(np.median(track_ms)) if track_ms else None
    ref = float(np.median(reference_ms))
    return {
        "tracker_ms_per_frame": round(float(np.median(frame_ms)), 4),
        "tracker_ms_per_track": None if per_track is None else round(per_track, 4),
        "tracks_per_frame": float(np.median(tracks)),
        "reference_filterpy_step_ms": round(ref, 4),
        "per_track_over_reference": None if per_track is None else round(per_track / ref, 3),
        "timing": "median CPU time of the calling thread",
        "frames": len(frames),
        "repeats": repeats,
        "load_average_1min": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
    }


def main(args) -> dict:
    config, setup, frames, skeletons = load_evaluation(args)
    result = bench(config, setup, frames, skeletons, args.repeats)
    if not args.json:
        r = result
        print(f"tracker on {r['frames']} PETS frames x {r['repeats']} passes, "
              f"{r['tracks_per_frame']:g} tracks per frame (median), median CPU time:")  # fmt: skip
        print(f"  per frame {r['tracker_ms_per_frame']:.3f} ms, "
              f"per track {r['tracker_ms_per_track']:.3f} ms")  # fmt: skip
        print(f"  reference: one stock filterpy predict + update {r['reference_filterpy_step_ms']:.3f}"
              f" ms; per track / reference = {r['per_track_over_reference']}")  # fmt: skip
    return result
