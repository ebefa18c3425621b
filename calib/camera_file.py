"""Reading and writing the camera file, with a record of how it was calibrated.

The file is `follow.camera.CameraModel`'s YAML/JSON; a `calibration` section is added
that people read: which command measured what, and its quality. `follow` reads one note
of it (`follow.camera.has_placeholder_pose`): a pose never measured drives no base.
Files are replaced whole (`write_file_atomic`): a failed write never leaves a measured
camera file half-written.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import secrets
from pathlib import Path

import numpy as np
import yaml

from follow.camera import CameraFileError, CameraModel, read_calibration_notes

# follow.camera's advice on a camera it refuses speaks to someone who typed the file ("a
# typing error in camera_matrix?", "a camera_matrix for another image size?"): of a camera
# a tool computed from photos or from a Tsai file, it would send the user to the wrong place.
_TYPED_FILE_ADVICE = re.compile(
    r" \(a typing error in [\w\[\]]+\?\)|: a camera_matrix for another image size\?"
)


def without_typed_file_advice(reason: str) -> str:
    """`reason` (a refusal of follow.camera) less its advice on a typed camera file."""
    return _TYPED_FILE_ADVICE.sub("", reason)


def write_image_atomic(path: str | Path, image) -> None:
    """Encode `image` in the format `path`'s suffix names and replace `path` with it whole
    (`write_file_atomic`): an overlay that fails half-way never replaces a good one."""
    import cv2

    encoded, data = cv2.imencode(Path(path).suffix, image)
    if not encoded:
        raise OSError(f"cannot encode the image {path}")
    write_file_atomic(path, data.tobytes())


def write_file_atomic(path: str | Path, data: bytes) -> None:
    """Replace `path` with `data` in one step: written to a new file beside it, synced
    to disk, then renamed over it. A failure part-way (disk full) leaves an old file at
    `path` as it was and removes the partial one. An old file's permissions are kept, and
    a symbolic link is followed (its target is replaced, the link stays)."""
    path = Path(os.path.realpath(path))
    temp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
    try:
        mode = os.stat(path).st_mode & 0o7777
    except FileNotFoundError:
        mode = None
    try:
        fd = os.open(temp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        try:
            with os.fdopen(fd, "wb") as file:
                file.write(data)
                file.flush()
                os.fsync(file.fileno())
            if mode is not None:
                os.chmod(temp, mode)
            os.replace(temp, path)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(temp)
            raise
    except OSError as exc:
        raise OSError(f"cannot write {path}: {exc.strerror or exc}") from exc
    with contextlib.suppress(OSError):  # make the rename itself durable
        folder = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(folder)
        finally:
            os.close(folder)


def _plain(value):
    """Notes as text, numbers, lists and mappings, which JSON and YAML both write: numpy
    numbers as numbers, anything else YAML reads in a free-form note (a date, also as a
    key) as its text."""
    if isinstance(value, dict):
        return {k if isinstance(k, str) else str(_plain(k)): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if value is None or isinstance(value, (str, bool, int, float)):
        return value
    return str(value)


def write_camera_file(
    path: str | Path,
    model: CameraModel,
    notes: dict | None = None,
    notes_from: str | Path | None = None,
    keep_notes: bool = True,
) -> None:
    """Write the camera file (YAML for .yaml/.yml, else JSON) with a `calibration` section.

    The notes of the file the model was read from, `notes_from` (default: an existing file
    at `path`), are kept where `notes` does not replace them: they say how the parts of
    the model that were not measured now were measured. `keep_notes=False` for a model
    measured whole: an old file's notes would describe another camera. A camera that
    `follow` would refuse to read is not written (`refuse_unreadable`).
    """
    path = Path(path)
    source = Path(notes_from) if notes_from is not None else path
    merged = read_calibration_notes(source) if keep_notes and source.exists() else {}
    merged.update(notes or {})
    data = model.to_dict()
    if merged:
        data["calibration"] = _plain(merged)
    refuse_unreadable(path, data)
    if path.parent and not path.parent.exists():
        path.parent.mkdir(parents=True)
    if path.suffix.lower() in (".yaml", ".yml"):
        text = yaml.safe_dump(data, sort_keys=False)
    else:
        text = json.dumps(data, indent=2) + "\n"
    write_file_atomic(path, text.encode())


def refuse_unreadable(path: Path, data: dict) -> None:
    """Refuse (CameraFileError naming `path`) to write camera data that every reader of a
    camera file (`CameraModel.from_dict`) refuses. Models are built through the looser
    constructor (a principal point anywhere in the image, as in a cropped one), so a
    calibration could otherwise replace a good file with one nothing reads, the command
    that wrote it included."""
    source = f"camera file {path}"
    try:
        CameraModel.from_dict(data, source=source)
    except CameraFileError as exc:
        reason = without_typed_file_advice(str(exc).removeprefix(f"{source}: "))
        kept = "; the file there is left as it was" if path.exists() else ""
        raise CameraFileError(
            f"{path} not written: follow would refuse to read this camera: {reason}{kept}"
        ) from None
