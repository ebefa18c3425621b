"""Model registry: each model's files and sha256, and where to find them.

A model is looked up in `$FOLLOW_MODEL_DIR` first, then in the user cache
(`$FOLLOW_CACHE_DIR`, else `~/.cache/follow/models`). Every file's hash is checked before
use: a file whose hash does not match is refused, never loaded.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path


class ModelError(RuntimeError):
    """A model that is missing or whose files do not match their pinned hashes."""


@dataclass(frozen=True)
class ModelFile:
    relpath: str  # relative to the model directory
    sha256: str
    url: str = ""  # official download location, empty where none is published


@dataclass(frozen=True)
class ModelSpec:
    name: str
    description: str
    files: tuple[ModelFile, ...]
    licence: str

    @property
    def main_file(self) -> str:
        """The file (or, for multi-file weights, the folder) a loader is given."""
        first = self.files[0].relpath
        return first if len(self.files) == 1 or first.endswith((".onnx", ".xml")) else str(
            Path(first).parent
        )


REGISTRY: dict[str, ModelSpec] = {
    spec.name: spec
    for spec in (
        ModelSpec(
            "human-pose-estimation-0001",
            "Lightweight OpenPose, 18 keypoints, ONNX FP32",
            (
                ModelFile(
                    "pose/human-pose-estimation-0001.onnx",
                    "b35c3f733bc6a70b9738b32276a9d7c1c67dfea3c46046849055202f76e95d5b",
                ),
            ),
            "Apache-2.0",
        ),
        ModelSpec(
            "human-pose-estimation-0001-ir",
            "Lightweight OpenPose, OpenVINO IR, FP16-INT8",
            (
                ModelFile(
                    "pose/human-pose-estimation-0001.xml",
                    "581b082e749848fdfc6d4b4b70e8189c3c2bae1c2d59c6b2c1a026a5471754e3",
                ),
                ModelFile(
                    "pose/human-pose-estimation-0001.bin",
                    "df2a9f41f15c3a0c8a0c5a704650338a3cc5c7bb588f2bfc14ea7093fa37b446",
                ),
            ),
            "Apache-2.0",
        ),
        ModelSpec(
            "ccf10",
            "convolutional channel features, 10+10 filters",
            (
                ModelFile(
                    "ccf/ccf10/conv_t1",
                    "71ef010dae17c74983a184a6be610d6d077968d1b0d39b2420ecd9fc8c4cf200",
                ),
                ModelFile(
                    "ccf/ccf10/conv_t2",
                    "59a6278dfec6f1221016ecde6714b246f997eeb6e6a671084ab733ee82ebcb07",
                ),
            ),
            "BSD",
        ),
        ModelSpec(
            "ccf25",
            "convolutional channel features, 20+25 filters",
            (
                ModelFile(
                    "ccf/ccf25/conv_t1",
                    "4117dd0f71f47fbf90bd4b6e801a98694e822cb37275ef64f877162f2dc5a80b",
                ),
                ModelFile(
                    "ccf/ccf25/conv_t2",
                    "1f37e6f8818cfde2da51585b14cf9097d4caf391f087e363d957f80c69e1232c",
                ),
            ),
            "BSD",
        ),
        ModelSpec(
            "person-reidentification-retail-0248",
            "person re-identification embedding (256-d), ONNX",
            (
                ModelFile(
                    "reid/person-reidentification-retail-0248.onnx",
                    "43891ce644ff6f4c70cce150028e44d6cf3d150cb5a3eb75bf69bfaef0ebe789",
                ),
            ),
            "Apache-2.0",
        ),
    )
}


def cache_dir() -> Path:
    env = os.environ.get("FOLLOW_CACHE_DIR")
    return Path(env) if env else Path.home() / ".cache" / "follow" / "models"


def search_dirs() -> list[Path]:
    dirs = []
    if os.environ.get("FOLLOW_MODEL_DIR"):
        dirs.append(Path(os.environ["FOLLOW_MODEL_DIR"]))
    dirs.append(cache_dir())
    return dirs


def sha256_of(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def get_spec(name: str) -> ModelSpec:
    try:
        return REGISTRY[name]
    except KeyError:
        raise ModelError(f"unknown model '{name}'; known: {sorted(REGISTRY)}") from None


def resolve(name: str, verify: bool = True) -> Path:
    """The path of a model's main file (or weight folder), hash-checked.

    Raises ModelError naming the model and the places looked in when it is missing, or
    the file when its hash does not match.
    """
    spec = get_spec(name)
    for root in search_dirs():
        if all((root / f.relpath).exists() for f in spec.files):
            if verify:
                for f in spec.files:
                    actual = sha256_of(root / f.relpath)
                    if actual != f.sha256:
                        raise ModelError(
                            f"model '{name}': {root / f.relpath} has sha256 {actual}, "
                            f"expected {f.sha256}; refusing to load it"
                        )
            return root / spec.main_file
    looked = ", ".join(str(d) for d in search_dirs())
    raise ModelError(f"model '{name}' not found (looked in: {looked}); set $FOLLOW_MODEL_DIR")
