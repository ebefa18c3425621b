"""Counts and quantities out of range are refused by the command line, with the option
named, before any work (they used to fail deep inside with a traceback, or run on)."""

from __future__ import annotations

import argparse

import pytest

from follow.cli import main
from follow.cli_args import (
    non_negative_float,
    non_negative_int,
    plot_path,
    positive_float,
    positive_int,
)


@pytest.mark.parametrize(
    "argv, option",
    [
        (["eval", "tracking", "--frames", "0"], "--frames"),
        (["eval", "identification", "--frames", "-1"], "--frames"),
        (["bench", "--matrix", "--repeats", "0"], "--repeats"),
        (["bench", "pose", "--frames", "0"], "--frames"),
        (["bench", "--camera-fps", "0"], "--camera-fps"),
        (["eval", "tracking", "--match-threshold-m", "-1"], "--match-threshold-m"),
        (["eval", "following", "--latency-s", "-0.1"], "--latency-s"),
        (["run", "video.mp4", "--target-id", "-1"], "--target-id"),
    ],
)
def test_out_of_range_options_are_refused_by_name(argv, option, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    assert f"argument {option}: expected" in capsys.readouterr().err


def test_the_types_take_what_is_in_range_and_refuse_the_rest():
    assert positive_int("3") == 3 and non_negative_int("0") == 0
    assert positive_float("0.5") == 0.5 and non_negative_float("0") == 0.0
    for parse, text in ((positive_int, "0"), (positive_int, "2.5"), (non_negative_int, "-1"),
                        (positive_float, "0"), (positive_float, "inf"),
                        (non_negative_float, "nan"), (non_negative_float, "-0.1")):  # fmt: skip
        with pytest.raises(argparse.ArgumentTypeError):
            parse(text)


@pytest.mark.parametrize(
    "name, message",
    [("plot.xyz", "a picture file is needed"), ("missing/plot.png", "does not exist"),
     ("folder.png", "is a folder")],  # fmt: skip
)
def test_a_plot_path_that_cannot_be_written_is_refused_before_the_evaluation(
    tmp_path, monkeypatch, capsys, name, message
):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "folder.png").mkdir()
    with pytest.raises(SystemExit) as exit_:
        main(["eval", "localization", "--duration-s", "5", "--plot", name])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "argument --plot" in err and message in err
    assert plot_path(str(tmp_path / "plot.png")).endswith("plot.png")
