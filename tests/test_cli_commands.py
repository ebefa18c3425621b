"""The `follow` command line itself: a command group named without one of its
commands is wrong input, answered with the commands to choose from and a non-zero
exit status (not the help text and success)."""

from __future__ import annotations

import pytest

from follow.cli import main


@pytest.mark.parametrize("group, one_of_them", [("eval", "identification-sim")])
def test_a_command_group_without_its_command_is_an_error(group, one_of_them, capsys):
    try:
        code = main([group])
    except SystemExit as exit_:
        code = exit_.code
    out = capsys.readouterr()
    assert code == 2
    assert one_of_them in out.err and "Traceback" not in out.err


def test_json_output_is_strict_json_with_no_figure_as_null(monkeypatch, capsys):
    """A figure that does not exist (MOTA with nothing matched: NaN) is printed as null;
    `NaN` is no JSON and a strict parser refuses the whole line."""
    import json

    import numpy as np

    import follow.eval.walking_accel as command

    result = {"mota": float("nan"), "recall": np.float32(0.5), "spread": np.array([np.inf, 1.0]),
              "rows": [(1, np.nan)], "frames": np.int64(3)}  # fmt: skip
    monkeypatch.setattr(command, "main", lambda args: result)
    assert main(["eval", "walking-accel", "--json"]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    parsed = json.loads(line, parse_constant=lambda name: pytest.fail(f"{name} in the output"))
    assert parsed == {"mota": None, "recall": 0.5, "spread": [None, 1.0], "rows": [[1, None]],
                      "frames": 3}  # fmt: skip


def test_a_command_named_after_its_groups_options_is_not_taken_for_the_group(
    monkeypatch, capsys
):
    """`follow bench --frames 5 pose`: the group's own command (`follow bench`) must not
    run in place of the one named (`follow bench pose`), its name silently dropped."""
    import follow.eval.bench as group_command

    ran = []
    monkeypatch.setattr(group_command, "main", lambda args: ran.append(args))
    try:
        code = main(["bench", "--frames", "5", "pose"])
    except SystemExit as exit_:
        code = exit_.code
    assert ran == [] and code == 2
    assert "follow bench pose" in capsys.readouterr().err
