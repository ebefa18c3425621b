"""Reading and writing the camera file, with a record of how it was calibrated.

The file is `follow.camera.CameraModel`'s YAML/JSON; a `calibration` section is added
that `follow` ignores and people read: which command measured what, and its quality.
"""

from __future__ import annotations

import json
from pathlib import Path

import yaml

from follow.camera import CameraModel


def read_calibration_notes(path: str | Path) -> dict:
    """The `calibration` section of an existing camera file ({} if none)."""
    path = Path(path)
    try:
        text = path.read_text()
        data = (
            yaml.safe_load(text) if path.suffix.lower() in (".yaml", ".yml") else json.loads(text)
        )
    except (OSError, ValueError, yaml.YAMLError):
        return {}
    notes = data.get("calibration") if isinstance(data, dict) else None
    return dict(notes) if isinstance(notes, dict) else {}


def write_camera_file(path: str | Path, model: CameraModel, notes: dict | None = None) -> None:
    """Write the camera file (YAML for .yaml/.yml, else JSON) with a `calibration` section.

    Notes from an existing file at `path` are kept unless `notes` replaces them.
    """
    path = Path(path)
    merged = read_calibration_notes(path) if path.exists() else {}
    merged.update(notes or {})
    data = model.to_dict()
    if merged:
        data["calibration"] = json.loads(json.dumps(merged, default=float))
    if path.parent and not path.parent.exists():
        path.parent.mkdir(parents=True)
    if path.suffix.lower() in (".yaml", ".yml"):
        path.write_text(yaml.safe_dump(data, sort_keys=False))
    else:
        path.write_text(json.dumps(data, indent=2) + "\n")
