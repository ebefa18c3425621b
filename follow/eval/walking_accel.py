"""`follow eval walking-accel`: how steadily the annotated people of PETS 2009 walk, as
the tracker's white-acceleration process noise (`[tracker] accel_noise_mps2`).

The tracker's motion model is constant velocity disturbed by white acceleration of
spectral density q per axis (`follow.ukf.models.process_noise`, q = accel_noise_mps2^2).
Under that model the mean velocities of a person over two back-to-back windows of T
seconds differ by a zero-mean amount of variance 2 q T / 3 per axis; noise of std s on
the annotated positions adds 6 s^2 / T^2 (the difference is (x(2T) - 2 x(T) + x(0)) / T).
Measured on the annotated ground points for windows of 1 to `MAX_WINDOW_FRAMES` frames,
the two terms are fitted by non-negative least squares. The fit reads only the ground
truth: it is the same for every variant of the video, and says nothing of a detector.
"""

from __future__ import annotations

import numpy as np

from follow.eval.pets_setup import PETS_FPS, add_evaluation_arguments, load_pets

MAX_WINDOW_FRAMES = 14  # 2 s at 7 fps: longer windows than any coasting the tracker does


def add_arguments(p) -> None:
    add_evaluation_arguments(p)


def velocity_change_variances(
    trajectories: dict[int, dict[int, np.ndarray]], fps: float, max_window: int
) -> list[tuple[float, float, int]]:
    """(window T in s, mean square per axis of the change between the mean velocities of
    two back-to-back windows, samples) for windows of 1..`max_window` frames.
    `trajectories`: person -> frame index -> ground position (2,) in metres; only frames
    annotated at all three window ends count."""
    out = []
    for w in range(1, max_window + 1):
        t = w / fps
        changes = [
            (track[f + 2 * w] - 2 * track[f + w] + track[f]) / t
            for track in trajectories.values()
            for f in track
            if f + w in track and f + 2 * w in track
        ]
        if changes:
            d = np.asarray(changes, float)
            out.append((t, float((d**2).sum(axis=1).mean() / 2.0), len(d)))
    return out


def fit_white_acceleration(rows: list[tuple[float, float, int]]) -> tuple[float, float]:
    """(accel noise in m/s^2, i.e. sqrt(q), position noise std in m) fitted to the rows of
    `velocity_change_variances`: mean square = (2 T / 3) q + 6 s^2 / T^2."""
    from scipy.optimize import nnls

    if len(rows) < 2:
        raise ValueError("too few annotated windows to fit the acceleration noise")
    a = np.array([[2.0 * t / 3.0, 6.0 / t**2] for t, _, _ in rows])
    b = np.array([ms for _, ms, _ in rows])
    (q, s2), _ = nnls(a, b)
    return float(np.sqrt(q)), float(np.sqrt(s2))


def annotated_trajectories(setup, frames) -> dict[int, dict[int, np.ndarray]]:
    """person id -> frame -> annotated ground point (hidden people included: their
    annotation goes on through the occlusion)."""
    out: dict[int, dict[int, np.ndarray]] = {}
    for index in frames:
        ids, ground, _ = setup.ground_truth(index)
        for person, xy in zip(ids, ground, strict=True):
            out.setdefault(int(person), {})[index] = np.asarray(xy, float)
    return out


def main(args) -> dict:
    config, setup = load_pets(args)
    n = setup.frame_count if args.frames is None else min(args.frames, setup.frame_count)
    trajectories = annotated_trajectories(setup, range(n))
    rows = velocity_change_variances(trajectories, PETS_FPS, MAX_WINDOW_FRAMES)
    accel, position_std = fit_white_acceleration(rows)
    result = {
        "frames": n,
        "people": len(trajectories),
        "windows": [
            {"t_s": round(t, 3), "mean_square_mps2": round(ms, 5), "samples": k}
            for t, ms, k in rows
        ],  # fmt: skip
        "annotation_noise_m": round(position_std, 3),
        "accel_noise_mps2": round(accel, 3),
        "configured_accel_noise_mps2": config.tracker.accel_noise_mps2,
    }
    if not args.json:
        print(f"{result['people']} annotated people in {n} frames; change of mean velocity "
              f"between back-to-back windows (per axis):")  # fmt: skip
        for t, ms, k in rows:
            print(f"  T {t:4.2f} s  {ms:.4f} (m/s)^2  ({k} samples)")
        print(f"white acceleration fitted: {accel:.3f} m/s^2 (annotation noise "
              f"{position_std:.3f} m); configured: {config.tracker.accel_noise_mps2}")  # fmt: skip
        print(f"setting that matches: [tracker] accel_noise_mps2 = {result['accel_noise_mps2']}")
    return result
