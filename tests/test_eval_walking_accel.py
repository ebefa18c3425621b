"""`follow eval walking-accel`: the white-acceleration noise of annotated walkers, and the
PETS setting that comes from it."""

import numpy as np
import pytest

from follow.eval.walking_accel import fit_white_acceleration, velocity_change_variances
from follow.ukf.models import process_noise


def _walkers(accel_mps2: float, noise_m: float, fps: float = 7.0, people: int = 40,
             frames: int = 120, seed: int = 0) -> dict[int, dict[int, np.ndarray]]:  # fmt: skip
    """Constant-velocity walkers driven by the tracker's own process noise, seen with
    `noise_m` of position noise; a gap in each trajectory, as where an annotation ends."""
    rng = np.random.default_rng(seed)
    Q = process_noise(1.0 / fps, accel_mps2, 0.0)[:4, :4]
    F = np.eye(4)
    F[0, 2] = F[1, 3] = 1.0 / fps
    L = np.linalg.cholesky(Q)
    out = {}
    for p in range(people):
        s = np.array([0.0, 0.0, *rng.normal(0.0, 1.0, 2)])
        track = {}
        for f in range(frames):
            if not 50 <= f < 55:
                track[f] = s[:2] + rng.normal(0.0, noise_m, 2)
            s = F @ s + L @ rng.normal(size=4)
        out[p] = track
    return out


@pytest.mark.parametrize("accel", [0.3, 1.0])
def test_the_fit_recovers_the_acceleration_noise_of_the_motion_model(accel):
    rows = velocity_change_variances(_walkers(accel, 0.03), 7.0, 14)
    assert len(rows) == 14 and all(k > 1000 for _, _, k in rows)
    fitted, noise = fit_white_acceleration(rows)
    assert fitted == pytest.approx(accel, rel=0.1)
    assert noise == pytest.approx(0.03, abs=0.02)


def test_annotation_noise_is_not_read_as_acceleration():
    # Position noise dominates the short windows: a fit of the velocity changes alone
    # would read it as a jerky walk.
    rows = velocity_change_variances(_walkers(0.3, 0.1), 7.0, 14)
    fitted, noise = fit_white_acceleration(rows)
    assert fitted == pytest.approx(0.3, rel=0.15)
    assert noise == pytest.approx(0.1, rel=0.2)


def test_too_few_windows_are_refused():
    with pytest.raises(ValueError, match="too few"):
        fit_white_acceleration([(0.1, 0.01, 5)])


def test_the_shipped_pets_acceleration_noise_matches_a_fit_on_the_first_half(data_path, capsys):
    """pets2009.toml's accel_noise_mps2 is the fit on frames < 400 (the annotations
    only: no detector runs), not the robot default: with the default, far people's
    tracks took keypoint jitter into their velocities and swapped at gaps (blur)."""
    import json

    from follow import cli
    from follow.config import Config
    from follow.eval.pets_setup import PETS_SETTINGS

    data_path("pets2009_s2l1/View_001.avi")
    capsys.readouterr()
    assert cli.main(["eval", "walking-accel", "--frames", "400", "--json"]) == 0
    r = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert r["frames"] == 400 and r["people"] >= 8
    shipped = Config.load(PETS_SETTINGS).tracker.accel_noise_mps2
    assert r["accel_noise_mps2"] == pytest.approx(shipped, abs=0.02)
    assert shipped < 0.5 * Config().tracker.accel_noise_mps2
