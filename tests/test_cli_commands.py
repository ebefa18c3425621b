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


def test_a_command_named_after_its_groups_options_is_not_taken_for_the_group(monkeypatch, capsys):
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


@pytest.mark.parametrize("library", ["cv2", "onnxruntime"])
def test_a_library_error_on_bad_input_is_one_line_and_a_json_error(monkeypatch, capsys, library):
    """OpenCV's and onnxruntime's own error classes (bad input met inside the library)
    are reported like any other bad input: one line naming the library, no traceback;
    with --json, a last line `{"error": ...}` for the script that reads it."""
    import json

    import follow.eval.walking_accel as command

    if library == "cv2":
        import cv2

        def fail(args):
            return cv2.resize("not an image", (1, 1))  # a message over four lines
    else:
        from onnxruntime import InferenceSession

        def fail(args):
            return InferenceSession(b"not a model")

    monkeypatch.setattr(command, "main", fail)
    assert main(["eval", "walking-accel", "--json"]) == 1
    out = capsys.readouterr()
    assert "Traceback" not in out.err
    [message] = out.err.strip().splitlines()
    assert message.startswith(f"follow eval: error: {library} ")
    if library == "cv2":  # every line kept, OpenCV's prefix and bullets dropped
        assert "in function 'resize'; Overload resolution failed; src is not" in message
        assert "OpenCV(" not in message
    assert json.loads(out.out.strip().splitlines()[-1])["error"] in message


def test_a_multi_line_error_of_ours_is_one_line_too():
    from follow.cli_args import error_text

    text = error_text(RuntimeError("Exception from src/core:\nCheck failed:\nNot divisible\n"))
    assert text == "Exception from src/core; Check failed; Not divisible"


def test_a_bug_of_ours_still_shows_its_traceback(monkeypatch):
    """Only bad input is turned into one line: an error of the project's own code (here a
    KeyError) propagates, so that its report carries the traceback."""
    import follow.eval.walking_accel as command

    monkeypatch.setattr(command, "main", lambda args: {}["missing"])
    with pytest.raises(KeyError):
        main(["eval", "walking-accel"])


def test_a_topic_name_ros_refuses_is_one_line(monkeypatch, capsys):
    """`-p "ros.image_topic:=bad topic!"`: rclpy's own exception, one line, no traceback."""
    validate = pytest.importorskip("rclpy.validate_topic_name")

    import follow.eval.walking_accel as command

    monkeypatch.setattr(command, "main", lambda args: validate.validate_topic_name("bad topic!"))
    assert main(["eval", "walking-accel"]) == 1
    [message] = capsys.readouterr().err.strip().splitlines()
    assert message.startswith("follow eval: error: rclpy InvalidTopicNameException: ")
    assert "'bad topic!'" in message
