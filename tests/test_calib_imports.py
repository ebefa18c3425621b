"""The calibration tools stand apart from the pipeline: they use follow's camera model,
frame helpers and argument types only (README, Layout), so a calibration never depends
on the detector, the tracker or their models."""

from __future__ import annotations

import ast
from pathlib import Path

ALLOWED = {"follow.camera", "follow.frames", "follow.cli_args"}
CALIB = Path(__file__).resolve().parents[1] / "calib"


def follow_imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
        elif isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
    return {n for n in names if n == "follow" or n.startswith("follow.")}


def test_calib_uses_only_the_camera_model_frames_and_argument_types():
    files = sorted(CALIB.glob("*.py"))
    assert files, f"no calibration modules found in {CALIB}"
    used = {f.name: follow_imports(f) - ALLOWED for f in files}
    assert {name: mods for name, mods in used.items() if mods} == {}
