"""`follow run` refuses outputs that would overwrite its inputs or each other, and files
in folders that do not exist, before it opens or writes anything."""

from __future__ import annotations

import argparse

import pytest

from follow.run import check_output_paths


def _args(tmp_path, **outputs) -> argparse.Namespace:
    (tmp_path / "in.avi").write_bytes(b"video")
    (tmp_path / "camera.yaml").write_text("camera")
    values = dict(source=str(tmp_path / "in.avi"), camera=str(tmp_path / "camera.yaml"),
                  config=None, replay=None, output_video=None, log=None, frames_dir=None)  # fmt: skip
    values.update(outputs)
    return argparse.Namespace(**values)


@pytest.mark.parametrize(
    "outputs, message",
    [
        ({"output_video": "in.avi"}, "--output-video .* is also the source"),
        ({"log": "camera.yaml"}, "--log .* is also the --camera"),
        ({"log": "run.jsonl", "output_video": "run.jsonl"}, "is also the --output-video"),
        ({"output_video": "missing/out.mp4"}, "the folder .*missing does not exist"),
        ({"log": "."}, "--log .* is a folder"),
        ({"frames_dir": "in.avi"}, "--frames-dir .* is also the source"),
    ],
)
def test_outputs_that_would_lose_something_are_refused(tmp_path, outputs, message):
    args = _args(tmp_path, **{k: str(tmp_path / v) for k, v in outputs.items()})
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    with pytest.raises(ValueError, match=message):
        check_output_paths(args)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()} == before


def test_new_files_in_existing_folders_pass(tmp_path):
    check_output_paths(_args(tmp_path, output_video=str(tmp_path / "out.mp4"),
                             log=str(tmp_path / "run.jsonl"), frames_dir=str(tmp_path / "f")))  # fmt: skip
