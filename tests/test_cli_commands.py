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
