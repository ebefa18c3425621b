"""Counts and quantities out of range are refused by the command line, with the option
named, before any work (they used to fail deep inside with a traceback, or run on)."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

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
        (["run", "frames", "--folder-fps", "0"], "--folder-fps"),
        (["run", "frames", "--folder-fps", "-5"], "--folder-fps"),
        (["run", "frames", "--folder-fps", "nan"], "--folder-fps"),
        (["run", "frames", "--folder-fps", "inf"], "--folder-fps"),
        (["eval", "pose", "--sizes", "368", "100"], "--sizes"),  # not a multiple of 8
        (["eval", "pose", "--sizes", "0"], "--sizes"),
        (["eval", "pose-near", "--sizes", "256", "260"], "--sizes"),
        (["bench", "identify", "--repeats", "1"], "--repeats"),
        (["eval", "following", "--link-latency-s", "-1"], "--link-latency-s"),
        (["eval", "following", "--link-latency-s", "nan"], "--link-latency-s"),
        (["eval", "following", "--packet-loss", "1"], "--packet-loss"),
        (["eval", "pose-near", "--person-heights", "1"], "--person-heights"),
        (["bench", "pose", "--frames", "1", "--height", "0"], "--height"),
        (["bench", "pose", "--frames", "1", "--height", "100000"], "--height"),
        # what the help allows is what the command runs (they used to pass the parser)
        (["eval", "safety", "--fault-at-s", "1"], "--fault-at-s"),  # not yet following
        (["eval", "identification-sim", "--strangers", "0"], "--strangers"),
        (["demo", "--seed", "-1"], "--seed"),  # was named as [identify] seed, a config key
        (["demo", "--seed", str(2**32)], "--seed"),
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
    [
        ("plot.xyz", "a picture file is needed"),
        ("missing/plot.png", "does not exist"),
        ("folder.png", "is a folder"),
        ("notes.txt/plot.png", "notes.txt is a file, not a folder"),
        ("/proc/plot.png", "the folder /proc cannot be written"),
    ],
)
def test_a_plot_path_that_cannot_be_written_is_refused_before_the_evaluation(
    tmp_path, monkeypatch, capsys, name, message
):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "folder.png").mkdir()
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(SystemExit) as exit_:
        main(["eval", "localization", "--duration-s", "5", "--plot", name])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "argument --plot" in err and message in err
    assert plot_path(str(tmp_path / "plot.png")).endswith("plot.png")


@pytest.mark.parametrize("command", ["identification", "identification-sim", "verification",
                                     "crops"])  # fmt: skip
@pytest.mark.parametrize("names, message", [("ccf10,cff10", "'cff10' not understood"),
                                            (",", "names no identifier")])  # fmt: skip
def test_identifier_lists_are_refused_before_the_evaluation(monkeypatch, capsys, command, names,
                                                            message):  # fmt: skip
    """A misspelt name used to fail only once the identifiers before it had run (on PETS
    after the whole tracker run), and an empty list ran none and reported nothing."""
    monkeypatch.delenv("FOLLOW_DATA_DIR", raising=False)
    with pytest.raises(SystemExit) as exit_:
        main(["eval", command, "--identifiers", names])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "argument --identifiers" in err and message in err


def test_bench_matrix_runs_the_runtimes_providers_names(monkeypatch, capsys):
    """`--providers cpu,cuda`: one process per settings x runtime, the table naming the
    back-end each actually ran on (a GPU runtime that falls back shows as the CPU)."""
    import json
    import subprocess
    import types

    from follow.eval import bench

    commands = []

    def fake_run(command, capture_output, text):
        commands.append(command)
        provider = command[command.index("--provider") + 1]
        row = dict.fromkeys(bench.MATRIX_KEYS, 1.0)
        row.update(pose_backend=f"onnxruntime:{provider}", pose_model="m.onnx",
                   overlap_stages=provider == "cuda", reid_backend="onnxruntime:CPU",
                   notes=["the runner kept up"] if provider == "cuda" else [])  # fmt: skip
        return types.SimpleNamespace(returncode=0, stdout=json.dumps(row) + "\n", stderr="")

    monkeypatch.setattr(subprocess, "run", fake_run)
    main(["bench", "--matrix", "--providers", "cpu,cuda,cpu", "--repeats", "2"])
    cells = [(c[c.index("--settings") + 1], c[c.index("--provider") + 1]) for c in commands]
    assert sorted(set(cells)) == [("pets", "cpu"), ("pets", "cuda"), ("robot", "cpu"),
                                  ("robot", "cuda")]  # fmt: skip
    assert len(cells) == 8  # twice each, the repeated name once
    out = capsys.readouterr().out
    # each row says what its cell ran, and the cells' notes are kept
    assert "m.onnx on onnxruntime:cuda, stages overlapped, re-id onnxruntime:CPU" in out
    assert "m.onnx on onnxruntime:cpu, stages in turn, re-id onnxruntime:CPU" in out
    assert "note (robot/cuda): the runner kept up" in out
    with pytest.raises(SystemExit) as exit_:
        main(["bench", "--matrix", "--providers", "cpu,gpu"])
    assert exit_.value.code == 2
    assert "argument --providers: 'cpu,gpu': give runtimes from" in capsys.readouterr().err


@pytest.mark.parametrize("options", [["--people", "3"], ["--far-m", "10"]])
def test_robot_scene_options_without_the_robot_scene_are_refused(options, capsys):
    """`follow bench --people 3` timed the PETS frames and ignored the option."""
    assert main(["bench", *options, "--frames", "1"]) == 1
    assert f"{options[0]}: for the robot scene only" in capsys.readouterr().err


@pytest.mark.parametrize(
    "main, argv",
    [("follow", ["run", "frames/", "--camera", "cam.yaml", "--max-frames", "abc"]),
     ("follow", ["bench", "--frames", "-1"]),
     ("follow-calib", ["ground", "b.png", "--camera", "c.yaml", "--square-size-m", "1",
                       "--pattern", "7"])],
)  # fmt: skip
def test_a_refused_command_line_ends_stdout_with_the_error_under_json(main, argv, capsys):
    from calib import cli as calib_cli
    from follow import cli as follow_cli

    run = follow_cli.main if main == "follow" else calib_cli.main
    for as_json in (False, True):
        with pytest.raises(SystemExit) as exit_:
            run(argv + (["--json"] if as_json else []))
        assert exit_.value.code == 2
        out, err = capsys.readouterr()
        message = err.strip().splitlines()[-1].split(": error: ", 1)[1]
        assert message.startswith("argument --")
        if as_json:
            assert json.loads(out.strip().splitlines()[-1]) == {"error": message}
        else:
            assert out == ""


def test_an_output_folder_is_checked_for_writing_up_to_the_nearest_that_exists(tmp_path):
    """Folders the writer would make are fine; a file in the way, or a folder that cannot
    be written in, is refused before the work."""
    from follow.cli_args import refuse_unwritable

    refuse_unwritable(tmp_path / "new" / "deeper" / "model.onnx", "--int8-model")
    (tmp_path / "notes.txt").write_text("")
    with pytest.raises(OSError, match=r"cannot write .*model\.onnx \(--int8-model\): .*notes\.txt "
                       r"is not a folder that can be written in; made there"):  # fmt: skip
        refuse_unwritable(tmp_path / "notes.txt" / "model.onnx", "--int8-model", "made there")
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    if not os.access(locked, os.W_OK):  # root writes anywhere: nothing to refuse then
        with pytest.raises(OSError, match="locked is not a folder that can be written in"):
            refuse_unwritable(locked / "sub" / "camera.yaml", "-o")


@pytest.mark.parametrize(
    "argv, option",
    [(["run", "x.avi", "--camera", "c.yaml", "--config", ""], "--config"),
     (["eval", "tracking", "--config", "  "], "--config"),
     (["bench", "--config", ""], "--config"),
     (["models", "fetch", "--from", ""], "--from"),
     (["demo", "--output", ""], "--output")],
)  # fmt: skip
def test_an_empty_option_is_refused_by_every_command(argv, option, capsys):
    """An empty text was read as no value: the defaults, the current folder, or the
    configuration's own setting ran instead of what the user seemed to ask for."""
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    assert f"argument {option}: empty" in capsys.readouterr().err


CALIB_BOARD = ["--pattern", "7x5", "--square-size-m", "0.03"]


@pytest.mark.parametrize(
    "tool, argv, option",
    [("follow", ["run", "x.avi", "--camera", "c.yaml", "--config", "a.toml", "--config", "b.toml"],
      "--config"),
     ("follow", ["run", "x.avi", "--camera=c.yaml", "--target-id=1", "--target-id", "2"],
      "--target-id"),
     ("follow", ["eval", "tracking", "--frames", "5", "--frames=6"], "--frames"),
     ("follow", ["eval", "pose", "--sizes", "256", "368", "--sizes", "256"], "--sizes"),
     ("follow", ["models", "fetch", "--from", "a/", "--from=b/"], "--from"),
     ("follow-calib", ["ground", "b.png", *CALIB_BOARD, "--camera", "c.yaml", "--camera=d.yaml"],
      "--camera")],
)  # fmt: skip
def test_an_option_given_twice_is_refused_by_name(tool, argv, option, capsys):
    """argparse kept the last value silently: `--config a.toml --config b.toml` ran b, and
    an override a script appended (or the value before it) was dropped unseen."""
    from calib import cli as calib_cli
    from follow import cli as follow_cli

    build_parser = follow_cli.build_parser if tool == "follow" else calib_cli.build_parser
    with pytest.raises(SystemExit) as exit_:
        build_parser(argv).parse_known_args(argv)
    assert exit_.value.code == 2
    assert f"argument {option}: given more than once" in capsys.readouterr().err


@pytest.mark.parametrize(
    "tool, argv, expected",
    [("follow", ["-v", "-v", "run", "x.avi", "--camera", "c.yaml", "--no-base", "--no-base"],
      {"verbose": True, "no_base": True}),  # a flag said twice says the same
     ("follow", ["-vv", "eval", "pose", "--sizes", "256", "368", "--json", "--json"],
      {"verbose": True, "sizes": [256, 368], "json": True}),  # a list takes its values
     ("follow", ["models", "fetch", "ccf10", "reid"], {"names": ["ccf10", "reid"]}),
     ("follow-calib", ["ground", "a.png", "b.png", *CALIB_BOARD, "--camera", "c.yaml"],
      {"inputs": [Path("a.png"), Path("b.png")]})],
)  # fmt: skip
def test_repeatable_options_and_flags_still_repeat(tool, argv, expected):
    from calib import cli as calib_cli
    from follow import cli as follow_cli

    build_parser = follow_cli.build_parser if tool == "follow" else calib_cli.build_parser
    args, _ = build_parser(argv).parse_known_args(argv)
    assert {key: getattr(args, key) for key in expected} == expected
    assert not any(name.startswith("_options") for name in vars(args))  # no bookkeeping left


def test_an_appended_option_still_accumulates():
    """No command appends yet: the parser's own `append` and `count` are left alone."""
    from follow.cli_args import ArgumentParser

    parser = ArgumentParser(prog="t")
    parser.add_argument("--tag", action="append")
    parser.add_argument("-q", action="count", default=0)
    parser.add_argument("--name")
    args = parser.parse_args(["--tag", "a", "--tag=b", "-qq", "--name", "n"])
    assert (args.tag, args.q, args.name) == (["a", "b"], 2, "n")
