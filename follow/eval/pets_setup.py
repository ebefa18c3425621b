"""What the PETS 2009 evaluations share: the sequence, its camera, the ground truth on
the floor, and the skeleton detections of every frame, computed once and cached."""

from __future__ import annotations

import hashlib
import json
import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from follow.camera import CameraModel
from follow.cli_args import positive_int
from follow.config import Config, PoseConfig
from follow.types import Skeleton

if TYPE_CHECKING:
    from follow.eval.perturb import Variant

log = logging.getLogger(__name__)

PETS_DIR = "pets2009_s2l1"
PETS_FPS = 7.0
# The measurement-model settings fitted to this sequence (see the file's comments).
PETS_SETTINGS = Path(__file__).with_name("pets2009.toml")


def data_dir() -> Path:
    env = os.environ.get("FOLLOW_DATA_DIR")
    if not env:
        raise ValueError(
            "$FOLLOW_DATA_DIR is not set: point it at the folder holding pets2009_s2l1/"
        )
    path = Path(env) / PETS_DIR
    if not path.is_dir():
        raise ValueError(f"PETS 2009 data not found: {path} is not a folder")
    return path


@dataclass
class PetsSetup:
    """The sequence, the camera at video resolution, and exact ground-plane truth."""

    sequence: object  # follow.eval.pets.PetsSequence
    camera: CameraModel  # at the video's resolution
    tsai: object  # calib.tsai.TsaiCamera, for exact ground truth
    discrepancy_px: float

    @classmethod
    def load(cls, root: Path | None = None) -> PetsSetup:
        from calib.tsai import TsaiCamera
        from follow.eval.pets import VIDEO_IMAGE_SIZE, PetsSequence

        root = root or data_dir()
        tsai = TsaiCamera.from_xml(root / "View_001.xml")
        camera, discrepancy = tsai.to_camera_model()
        return cls(PetsSequence(root), camera.scaled(*VIDEO_IMAGE_SIZE), tsai, discrepancy)

    def ground_truth(self, index: int, max_hidden_fraction: float = 1.0):
        """(ids, positions (N, 2) in metres, boxes) of frame `index`: box bottom centres
        back-projected through the Tsai model, people hidden more than the limit left out."""
        boxes = [b for b in self.sequence.boxes_gt_px(index)
                 if b.hidden_fraction <= max_hidden_fraction]  # fmt: skip
        if not boxes:
            return [], np.empty((0, 2)), []
        feet = np.array([[b.xc, b.bottom] for b in boxes])
        ground = self.tsai.back_project_to_ground(feet)
        ok = np.isfinite(ground).all(axis=1)
        boxes = [b for b, good in zip(boxes, ok, strict=True) if good]
        return [b.person_id for b in boxes], ground[ok], boxes

    @property
    def frame_count(self) -> int:
        return self.sequence.frame_count

    @property
    def fps(self) -> float:
        return PETS_FPS


def add_evaluation_arguments(p) -> None:
    """The options `load_evaluation` reads, for every PETS evaluation command."""
    p.add_argument("--frames", type=positive_int, help="only the first N frames (default: all)")
    p.add_argument("--config", help="TOML configuration, over the PETS settings (pets2009.toml)")
    p.add_argument("--no-cache", action="store_true", help="run the pose network again")


def load_evaluation(
    args, variant: Variant | None = None
) -> tuple[Config, PetsSetup, list[int], dict[int, list[Skeleton]]]:
    """What every PETS evaluation starts from: the configuration (the PETS settings in
    `pets2009.toml`, then `--config` over them), the sequence (seen through a
    `follow.eval.perturb.Variant` when one is given), its first `--frames` frame indices
    and their skeletons (`--no-cache`)."""
    config, setup = load_pets(args)
    return (config, *variant_inputs(args, config, setup, variant))


def pets_config(config_path=None) -> Config:
    """The PETS settings (pets2009.toml), with the TOML file at `config_path` over them."""
    config = Config.load(PETS_SETTINGS)
    return Config.load(config_path, base=config) if config_path else config


def load_pets(args) -> tuple[Config, PetsSetup]:
    """The configuration (pets2009.toml, then `--config`) and the unperturbed sequence."""
    return pets_config(args.config), PetsSetup.load()


def variant_inputs(
    args, config: Config, setup: PetsSetup, variant: Variant | None = None
) -> tuple[PetsSetup, list[int], dict[int, list[Skeleton]]]:
    """The setup seen through `variant` (None: as it is), the frames it runs on (from the
    variant's first frame, at most `--frames`) and their skeletons. A later start shows
    the same pixels as the whole run, so it shares the whole run's detections."""
    from follow.eval.perturb import SUITE, perturbed_setup

    variant = variant or SUITE[0]
    seen = perturbed_setup(setup, variant)
    frames = variant.frame_range(setup.frame_count, args.frames)
    detected = list(range(frames[-1] + 1))
    skeletons = pets_skeletons(seen, detected, config.pose, not args.no_cache)
    return seen, frames, {i: skeletons[i] for i in frames}


def frames_digest(sequence, frames: list[int]) -> str:
    """A hash of the decoded pixels of the given frames (as the sequence shows them), so
    that detections cached for one video or variant are never served for another."""
    from tqdm import tqdm

    digest = hashlib.blake2b(digest_size=16)
    for _, image in tqdm(sequence.frames(frames), total=len(frames), leave=False,
                         desc="hashing frames", unit="frame"):  # fmt: skip
        digest.update(repr(image.shape).encode())
        digest.update(np.ascontiguousarray(image).data)
    return digest.hexdigest()


_MODEL_DIGESTS: dict[tuple[str, int, int], str] = {}


def _model_digest(path: Path) -> str:
    """sha256 of a model file, computed once per file version."""
    from follow.models import sha256_of

    stat = path.stat()
    key = (str(path.resolve()), stat.st_size, stat.st_mtime_ns)
    if key not in _MODEL_DIGESTS:
        _MODEL_DIGESTS[key] = sha256_of(path)
    return _MODEL_DIGESTS[key]


def _cache_path(pose_config: PoseConfig, frames: list[int], pixels_digest: str) -> Path:
    from follow.models import cache_dir
    from follow.pose.decode import DECODER_VERSION
    from follow.pose.detector import model_file_for
    from follow.pose.runtime import auto_provider

    model = model_file_for(pose_config)  # "auto" precision differs between machines
    # and so does the runtime "auto" picks: OpenVINO's skeletons are not onnxruntime's
    pose = dict(pose_config.__dict__)
    if pose["provider"] == "auto":
        pose["provider"] = auto_provider(model)
    key = json.dumps({"pose": pose, "frames": frames, "pixels": pixels_digest,
                      "model_sha256": _model_digest(model), "decoder": DECODER_VERSION},
                     sort_keys=True)  # fmt: skip
    digest = hashlib.sha256(key.encode()).hexdigest()[:16]
    return cache_dir().parent / "eval" / f"pets_skeletons_{digest}.npz"


def _read_cached_skeletons(path: Path, frames: list[int]) -> dict[int, list[Skeleton]] | None:
    """The skeletons kept in `path`, or None (with a warning: they are made again) for a
    file cut short or written by something else."""
    import zipfile

    try:
        with np.load(path) as data:
            out: dict[int, list[Skeleton]] = {i: [] for i in frames}
            for f, kp, conf, score in zip(data["frame"], data["kp"], data["conf"],
                                          data["score"], strict=True):  # fmt: skip
                out[int(f)].append(Skeleton(kp, conf, float(score)))
        return out
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        log.warning("PETS skeletons cache %s is unreadable (%s: %s): running the pose "
                    "network again", path, type(exc).__name__, exc)  # fmt: skip
        return None


def pets_skeletons(
    setup: PetsSetup, frames: list[int], pose_config: PoseConfig, use_cache: bool = True
) -> dict[int, list[Skeleton]]:
    """Skeletons of the given frames, from the pose network; cached on disk, keyed by the
    frames' pixels, the pose settings and the model file's hash, so that every method of
    an evaluation, and every later run on the same frames, sees the same detections."""
    from follow.pose.detector import PoseDetector
    from follow.pose.runtime import runs_on_gpu

    # `auto` with a GPU listed: whether it starts decides the model and runtime the key
    # names (one that does not runs the CPU's choice), so the detector is made first.
    detector = None
    if pose_config.provider == "auto" and runs_on_gpu("auto"):
        detector = PoseDetector(pose_config)
    path = _cache_path(pose_config, frames, frames_digest(setup.sequence, frames))
    from follow.models import make_cache_folder

    # Before the network's minutes (with --no-cache too: its skeletons are kept for the
    # next run): a cache folder that cannot be made is refused now, not after the work.
    make_cache_folder(path.parent)
    if use_cache and path.exists():
        cached = _read_cached_skeletons(path, frames)
        if cached is not None:
            log.info("PETS skeletons from cache %s", path)
            return cached
    from tqdm import tqdm

    detector = detector or PoseDetector(pose_config)
    out = {}
    for index, image in tqdm(setup.sequence.frames(frames), total=len(frames),
                             desc="pose network on PETS", unit="frame", leave=False):  # fmt: skip
        out[index] = detector.detect(image)
    rows = [(i, s) for i in frames for s in out[i]]
    # Written aside, then renamed: a reader (or a second run) never sees half a file.
    partial = path.with_name(f"{path.stem}.{os.getpid()}.partial.npz")
    np.savez_compressed(
        partial,
        frame=np.array([i for i, _ in rows], int),
        kp=np.array([s.keypoints_px for _, s in rows]).reshape(-1, 18, 2),
        conf=np.array([s.confidences for _, s in rows]).reshape(-1, 18),
        score=np.array([s.score for _, s in rows], float),
    )
    os.replace(partial, path)
    return out
