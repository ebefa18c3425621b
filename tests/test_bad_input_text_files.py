"""A binary (not UTF-8) config, camera file or run log is refused with the file named
and what it should have been, not a bare codec error."""

from __future__ import annotations

import re

import pytest

from follow import cli
from follow.camera import CameraFileError, CameraModel
from follow.config import Config, ConfigError
from follow.runlog import read_run_log

BINARY = b"\xff\xfe\x00\x01binary\x80\x81"


def test_a_binary_config_is_named(tmp_path):
    path = tmp_path / "robot.toml"
    path.write_bytes(BINARY)
    with pytest.raises(ConfigError, match=re.escape(f"config {path}: not a text config file")):
        Config.load(path)


def test_a_config_saved_with_a_byte_order_mark_is_read(tmp_path):
    """Windows editors start UTF-8 files with a byte order mark; camera files take it too."""
    path = tmp_path / "robot.toml"
    path.write_bytes(b"\xef\xbb\xbf[control]\nfollowing_distance_m = 2.5\n")
    assert Config.load(path).control.following_distance_m == 2.5


def test_a_binary_camera_file_is_named(tmp_path):
    path = tmp_path / "cam.yaml"
    path.write_bytes(BINARY)
    expected = re.escape(f"camera file {path}: not a text camera file")
    with pytest.raises(CameraFileError, match=expected):
        CameraModel.load(path)


def test_a_binary_run_log_is_named(tmp_path):
    path = tmp_path / "run.jsonl"
    path.write_bytes(b'{"log_version":1}\n' + BINARY)
    with pytest.raises(ValueError, match=re.escape(f"run log {path}: not a text run log")):
        read_run_log(path)


def test_follow_run_says_which_file_is_binary_in_one_line(tmp_path, capsys):
    config = tmp_path / "robot.toml"
    config.write_bytes(BINARY)
    argv = ["run", "x.avi", "--camera", "c.yaml", "--config", str(config)]
    assert cli.main(argv) == 1
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    assert str(config) in err and "not a text config file" in err


def test_a_log_version_written_as_text_is_named_as_such(tmp_path):
    path = tmp_path / "run.jsonl"
    path.write_text('{"log_version": "1"}\n')
    with pytest.raises(ValueError, match=r"log_version '1' \(text, not a number\); this "
                       r"version of follow reads log_version 1"):  # fmt: skip
        read_run_log(path)
