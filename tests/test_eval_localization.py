"""`follow eval localization` on a short simulation."""

from __future__ import annotations

import json

import numpy as np
import pytest

from follow import cli
from follow.eval.localization import BINS_M, binned, simulate


def test_short_simulation_scores_both_methods():
    samples = simulate(seed=3, duration_s=12.0, num_people=4)
    assert len(samples.ukf_error_m) == len(samples.ukf_distance_m) > 200
    assert len(samples.direct_error_m) == len(samples.direct_distance_m) > 200
    d = np.asarray(samples.direct_distance_m)
    assert d.min() >= 1.0 and d.max() <= 26.0
    rows = binned(samples)
    assert [r["range_m"] for r in rows] == [list(b) for b in BINS_M]
    for r in rows:
        if r["ukf_samples"]:
            assert 0 <= r["ukf_median_m"] <= r["ukf_p90_m"]
    # Pooled over 5-20 m the filter beats single-frame back-projection.
    u, du = np.asarray(samples.ukf_error_m), np.asarray(samples.ukf_distance_m)
    e = np.asarray(samples.direct_error_m)
    mid_u, mid_d = u[(du >= 5) & (du < 20)], e[(d >= 5) & (d < 20)]
    assert np.median(mid_u) < 0.7 * np.median(mid_d)


def test_a_crowd_whose_ankles_the_tracker_refuses_is_scored():
    """A refused ankle leaves a track holding a copy of its observation without it: each
    track is matched to its person by the skeleton, not by the observation object (a
    crowd of 12 raised KeyError)."""
    samples = simulate(seed=1, duration_s=20.0, num_people=12)
    assert len(samples.ukf_error_m) == len(samples.ukf_distance_m) > 500
    assert np.median(samples.ukf_error_m) < 1.0


def test_cli_prints_table_json_and_plot(tmp_path, capsys):
    png = tmp_path / "loc.png"
    rc = cli.main([
        "eval", "localization", "--json", "--duration-s", "6", "--people", "3",
        "--plot", str(png),
    ])  # fmt: skip
    assert rc == 0
    out = capsys.readouterr().out.strip().splitlines()
    result = json.loads(out[-1])
    assert [b["range_m"] for b in result["bins"]] == [list(b) for b in BINS_M]
    assert set(result["bins"][1]) >= {
        "ukf_median_m",
        "ukf_p90_m",
        "direct_median_m",
        "direct_p90_m",
    }
    sim = result["sim"]
    assert sim["camera"]["height_m"] == 0.6 and sim["camera"]["horizontal_fov_deg"] == 70.0
    assert sim["detector"]["neck_sigma_px"] == 2.0 and sim["detector"]["ankle_sigma_px"] == 3.0
    assert sim["detector"]["miss_probability"] == 0.05
    assert png.stat().st_size > 10_000 and png.read_bytes()[:4] == b"\x89PNG"

    rc = cli.main(["eval", "localization", "--duration-s", "3", "--people", "2"])
    table = capsys.readouterr().out
    assert rc == 0 and "UKF median" in table and "20-25" in table


def test_cli_rejects_nonsense_arguments(capsys):
    with pytest.raises(SystemExit) as exit_:  # refused by argparse, before the work
        cli.main(["eval", "localization", "--duration-s", "0"])
    assert exit_.value.code == 2 and "argument --duration-s" in capsys.readouterr().err
