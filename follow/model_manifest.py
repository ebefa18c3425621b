"""Integrity records of derived model files (the INT8 pose model, the initial-stage cut).

A registry model has a pinned sha256 (follow/models.py). A file made on this machine
from one has none to pin, so when it is made a JSON sidecar (`<file>.json`) records its
own sha256, the file and sha256 it was made from and how (`made_from`: calibration
frames, input height, ...). Before such a file is run, its bytes are checked against
the record: a truncated or corrupted cache file is refused with a message that says
how to make it again, instead of running and finding nobody.
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Callable
from pathlib import Path

from follow.models import ModelError, cache_write_error, sha256_of

MANIFEST_SUFFIX = ".json"


def manifest_path(model_path: Path) -> Path:
    return Path(str(model_path) + MANIFEST_SUFFIX)


def write_manifest(
    model_path: Path, source_path: Path, made_from: dict | None = None, written: Path | None = None
) -> dict:
    """Record `model_path`'s hash and what it was made from; returns the record.
    `written`: the file holding the bytes, when it is renamed to `model_path` only after
    the record exists (so a reader never finds a file without its record)."""
    record = {
        "file": Path(model_path).name,
        "sha256": sha256_of(Path(written or model_path)),
        "source": str(source_path),
        "source_sha256": sha256_of(Path(source_path)),
        "made_from": made_from or {},
    }
    manifest_path(model_path).write_text(json.dumps(record, indent=2, sort_keys=True) + "\n")
    return record


def install(
    model_path: Path, source_path: Path, made_from: dict, write: Callable[[Path], None]
) -> None:
    """Make `model_path` all or nothing: `write` puts its bytes into a partial file
    beside it, the record is written, then the file is renamed into place (atomic: same
    folder). An error or Ctrl-C on the way leaves no half-written file in the cache, and
    never a truncated file under the name that runs beside a record of the whole one."""
    partial = Path(model_path).with_suffix(f".{os.getpid()}.partial")
    try:
        write(partial)
        write_manifest(model_path, source_path, made_from, written=partial)
        partial.replace(model_path)
    except BaseException as exc:
        with contextlib.suppress(OSError):  # a read-only folder: the first error tells
            partial.unlink(missing_ok=True)
        if isinstance(exc, OSError) and _written_in(exc, partial.parent):
            raise OSError(cache_write_error(partial.parent, exc)) from exc
        raise


def _written_in(exc: OSError, folder: Path) -> bool:
    """Whether `exc` came from writing into `folder` (a file there, or no file named: a
    full disk), not from reading the source: a bare errno naming a temporary file
    (`....partial`) said nothing of the cache it was in."""
    return exc.filename is None or Path(os.fsdecode(exc.filename)).parent == folder


def read_manifest(model_path: Path) -> dict | None:
    path = manifest_path(model_path)
    if not path.exists():
        return None
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):  # unreadable, not UTF-8 (a ValueError) or not JSON
        return None
    return record if isinstance(record, dict) and "sha256" in record else None


def check(model_path: Path) -> str:
    """ "ok", or what is wrong with a derived file against its record."""
    model_path = Path(model_path)
    if not model_path.exists():
        return "missing"
    record = read_manifest(model_path)
    if record is None:
        return f"no integrity record ({manifest_path(model_path).name} missing or unreadable)"
    actual = sha256_of(model_path)
    if actual != record["sha256"]:
        return f"sha256 {actual} != recorded {record['sha256']} (corrupted or changed)"
    return "ok"


def verify_derived(model_path: Path, how_to_rebuild: str) -> dict:
    """The record of a derived file whose bytes match it; else ModelError naming the
    file, what is wrong and how to rebuild it."""
    status = check(model_path)
    if status != "ok":
        raise ModelError(f"model file {model_path}: {status}; refusing to run it. {how_to_rebuild}")
    return read_manifest(model_path)  # type: ignore[return-value]


# How the files made here are named (follow/pose/quantize.py, follow/pose/stages.py): one
# whose record was lost is still found by its name, and reported, not passed over.
DERIVED_NAME_PARTS = ("-int8-", "-initial-stage-")


def derived_files(root: Path) -> list[Path]:
    """Every derived model file under `root` (the user cache): each one recorded, and
    each one named as a made file, recorded or not."""
    root = Path(root)
    records = root.rglob(f"*.onnx{MANIFEST_SUFFIX}")
    recorded = {Path(str(m)[: -len(MANIFEST_SUFFIX)]) for m in records}
    named = {p for p in root.rglob("*.onnx") if any(part in p.name for part in DERIVED_NAME_PARTS)}
    return sorted(recorded | named)
