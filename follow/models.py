"""Model registry: each model's files and sha256, and where to find them.

A model is looked up in `$FOLLOW_MODEL_DIR` first, then in the user cache
(`$FOLLOW_CACHE_DIR`, else `~/.cache/follow/models`). Every file's hash is checked before
use: a file whose hash does not match is refused, never loaded.

`fetch(name)` downloads a model's official files into the user cache (progress bar,
hash check; a file whose hash does not match is deleted and the fetch fails). Models
with no official download (the ONNX conversions) say how to produce them.
Files made here from a registry model (the INT8 model, the initial-stage cut) carry
an integrity record instead (follow/model_manifest.py); `verify` with no names checks
them too. The command line: `follow models list | fetch [NAME...] | verify [NAME...] | prepare`.
"""

from __future__ import annotations

import argparse
import hashlib
import http.client
import logging
import os
import tempfile
import urllib.error
import urllib.request
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger(__name__)

OMZ_STORAGE = "https://storage.openvinotoolkit.org/repositories/open_model_zoo/2021.4/models_bin/3"
CCF_REPO_RAW = (
    "https://raw.githubusercontent.com/koide3/ccf_person_identification/"
    "33b55ae205fa84b12a22d36f408e2c1105c17870/data"
)
DOWNLOAD_TIMEOUT_S = 30.0


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
    # For files with no official download: how a user produces them.
    how_to_produce: str = ""

    @property
    def main_file(self) -> str:
        """The file (or, for multi-file weights, the folder) a loader is given."""
        first = self.files[0].relpath
        return (
            first
            if len(self.files) == 1 or first.endswith((".onnx", ".xml"))
            else str(Path(first).parent)
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
            "Intel publishes this network only as an OpenVINO IR. Rebuild the ONNX from it: "
            "`follow models fetch human-pose-estimation-0001-ir`, then `python "
            "tools/ir_to_onnx.py <cache>/pose/human-pose-estimation-0001.xml -o model.onnx` "
            "and give the file as [pose] model_file (its bytes differ from the pinned one).",
        ),
        ModelSpec(
            "human-pose-estimation-0001-ir",
            "Lightweight OpenPose, OpenVINO IR, FP16-INT8",
            (
                ModelFile(
                    "pose/human-pose-estimation-0001.xml",
                    "581b082e749848fdfc6d4b4b70e8189c3c2bae1c2d59c6b2c1a026a5471754e3",
                    f"{OMZ_STORAGE}/human-pose-estimation-0001/FP16-INT8/"
                    "human-pose-estimation-0001.xml",
                ),
                ModelFile(
                    "pose/human-pose-estimation-0001.bin",
                    "df2a9f41f15c3a0c8a0c5a704650338a3cc5c7bb588f2bfc14ea7093fa37b446",
                    f"{OMZ_STORAGE}/human-pose-estimation-0001/FP16-INT8/"
                    "human-pose-estimation-0001.bin",
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
                    f"{CCF_REPO_RAW}/cnn_params_tiny/conv_t1",
                ),
                ModelFile(
                    "ccf/ccf10/conv_t2",
                    "59a6278dfec6f1221016ecde6714b246f997eeb6e6a671084ab733ee82ebcb07",
                    f"{CCF_REPO_RAW}/cnn_params_tiny/conv_t2",
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
                    f"{CCF_REPO_RAW}/cnn_params/conv_t1",
                ),
                ModelFile(
                    "ccf/ccf25/conv_t2",
                    "1f37e6f8818cfde2da51585b14cf9097d4caf391f087e363d957f80c69e1232c",
                    f"{CCF_REPO_RAW}/cnn_params/conv_t2",
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
            "Intel publishes this network only as an OpenVINO IR (Open Model Zoo, "
            "intel/person-reidentification-retail-0248, omz_downloader); an ONNX conversion "
            "of it must be placed under $FOLLOW_MODEL_DIR/reid/. tools/ir_to_onnx.py "
            "handles the layer types of the pose network and names any it does not.",
        ),
    )
}


def cache_dir() -> Path:
    env = os.environ.get("FOLLOW_CACHE_DIR")
    return Path(env) if env else Path.home() / ".cache" / "follow" / "models"


def make_cache_folder(folder: Path) -> Path:
    """`folder` (in the cache) made if missing; an OSError that names the cache and its
    setting, not only the errno, where it cannot be (a read-only disk, a file in the
    way)."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OSError(cache_write_error(folder, exc)) from exc
    return folder


def writable_cache_folder(folder: Path) -> Path:
    """`folder` made if missing and proven writable by a file made in it and dropped: a
    read-only cache is named before a long job (INT8 calibration takes ~30 s) instead of
    when that job writes its result."""
    make_cache_folder(folder)
    try:
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        raise OSError(cache_write_error(folder, exc)) from exc
    return folder


def cache_write_error(folder: Path, exc: OSError) -> str:
    """What cannot be written and why, naming the cache and its setting where `folder`
    lies in it (not only the errno, nor a temporary file's name)."""
    reason = exc.strerror or exc
    if not Path(folder).is_relative_to(cache_dir().parent):  # the models' and eval's
        return f"cannot write {folder}: {reason}"
    return f"cannot write {folder}, in the cache ($FOLLOW_CACHE_DIR, now {cache_dir()}): {reason}"


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


def model_root(spec: ModelSpec) -> Path | None:
    """The first search folder that holds every file of `spec`: a model is loaded from
    one folder, never pieced together from several."""
    return next(
        (d for d in search_dirs() if all((d / f.relpath).exists() for f in spec.files)), None
    )


def resolve(name: str, verify: bool = True) -> Path:
    """The path of a model's main file (or weight folder), hash-checked.

    Raises ModelError naming the model and the places looked in when it is missing, or
    the file when its hash does not match.
    """
    spec = get_spec(name)
    root = model_root(spec)
    if root is not None:
        if verify:
            for f in spec.files:
                if not (root / f.relpath).is_file():  # a folder in its place
                    raise ModelError(f"model '{name}': {root / f.relpath} is a folder, not a "
                                     "file; refusing to load it")  # fmt: skip
                actual = sha256_of(root / f.relpath)
                if actual != f.sha256:
                    raise ModelError(
                        f"model '{name}': {root / f.relpath} has sha256 {actual}, "
                        f"expected {f.sha256}; refusing to load it"
                    )
        return root / spec.main_file
    looked = ", ".join(str(d) for d in search_dirs())
    raise ModelError(f"model '{name}' not found (looked in: {looked}); set $FOLLOW_MODEL_DIR")


@dataclass(frozen=True)
class FileStatus:
    """Where one model file was found and whether its hash matches."""

    model: str
    relpath: str
    path: Path | None  # None when missing everywhere
    ok: bool
    detail: str  # "ok", "missing", or the hash mismatch


def verify(name: str) -> list[FileStatus]:
    """Each file of model `name` as `resolve` would load it (from the first folder that
    holds them all), else the first copy found, and whether its sha256 matches."""
    spec = get_spec(name)
    root = model_root(spec)
    out = []

    def first_copy(relpath: str) -> Path | None:
        return next((d / relpath for d in search_dirs() if (d / relpath).exists()), None)

    # Files missing everywhere are the model's problem; only where every file exists
    # somewhere but no one folder holds them all is the layout to blame.
    scattered = root is None and all(first_copy(f.relpath) for f in spec.files)
    for f in spec.files:
        found = root / f.relpath if root is not None else first_copy(f.relpath)
        if found is None:
            out.append(FileStatus(name, f.relpath, None, False, "missing"))
            continue
        if scattered and len(spec.files) > 1:
            out.append(FileStatus(name, f.relpath, found, False,
                                  "not with the model's other files: they must all sit "
                                  "under one folder"))  # fmt: skip
            continue
        if found.is_dir():
            out.append(FileStatus(name, f.relpath, found, False, "a folder, not a file"))
            continue
        actual = sha256_of(found)
        if actual == f.sha256:
            out.append(FileStatus(name, f.relpath, found, True, "ok"))
        else:
            out.append(FileStatus(name, f.relpath, found, False, f"sha256 {actual} != {f.sha256}"))
    return out


def verify_derived_files() -> list[FileStatus]:
    """Each model file made on this machine (INT8, initial-stage cut) in the user cache,
    checked against its integrity record (follow/model_manifest.py)."""
    from follow import model_manifest

    out = []
    for path in model_manifest.derived_files(cache_dir()):
        detail = model_manifest.check(path)
        out.append(FileStatus("(derived)", str(path.relative_to(cache_dir())), path,
                              detail == "ok", detail))  # fmt: skip
    return out


def fetch(name: str, source: str | None = None, force: bool = False) -> Path:
    """Download model `name` into the user cache and return its main path.

    `source` replaces the official location: a base URL or a local folder under which
    each file sits at its registry path (a mirror). Files already in the cache with the
    right hash are kept unless `force`. A download whose sha256 differs from the pinned
    one is deleted and raises ModelError.
    """
    spec = get_spec(name)
    root = cache_dir()
    for f in spec.files:
        target = root / f.relpath
        if target.is_dir():
            raise ModelError(f"model '{name}': {target} is a folder, not a file: move it away "
                             "so that the file can be fetched there")  # fmt: skip
        if target.exists() and not force and sha256_of(target) == f.sha256:
            log.info("%s: already in the cache", target)
            continue
        url = _source_url(f, source)
        if url is None:
            raise ModelError(
                f"model '{name}': {f.relpath} has no official download. "
                f"{spec.how_to_produce or 'Place the file under $FOLLOW_MODEL_DIR.'}"
            )
        _download(url, target, f.sha256)
    return root / spec.main_file


def _source_url(f: ModelFile, source: str | None) -> str | None:
    if source is None:
        return f.url or None
    if "://" in source:
        return source.rstrip("/") + "/" + f.relpath
    return (Path(source).resolve() / f.relpath).as_uri()


_FILE_MODE = 0o666  # what open() gives a new file, before the umask


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _download(url: str, target: Path, sha256: str) -> None:
    """Stream `url` to `target` via a temporary file, checking the hash on the way."""
    from tqdm import tqdm

    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.",
                                        suffix=".part")  # fmt: skip
    except OSError as exc:  # a ModelError: fetching everything goes on to the next model
        raise ModelError(cache_write_error(target.parent, exc)) from exc
    digest = hashlib.sha256()
    tmp = Path(tmp_name)
    out = os.fdopen(fd, "wb")  # closed on every path, a download that never starts included
    try:
        try:
            response = urllib.request.urlopen(url, timeout=DOWNLOAD_TIMEOUT_S)
        except (urllib.error.URLError, OSError) as exc:
            raise ModelError(f"cannot download {url}: {getattr(exc, 'reason', exc)}") from None

        def read() -> bytes:
            try:
                return response.read(1 << 16)
            except (OSError, http.client.HTTPException) as exc:  # stalled, reset, cut short
                raise ModelError(
                    f"download {url} broke off ({type(exc).__name__}: {exc}); the file was not kept"
                ) from None

        with response, out:
            total = int(response.headers.get("Content-Length") or 0) or None
            with tqdm(total=total, unit="B", unit_scale=True, desc=target.name) as bar:
                for chunk in iter(read, b""):
                    out.write(chunk)
                    digest.update(chunk)
                    bar.update(len(chunk))
        actual = digest.hexdigest()
        if actual != sha256:
            raise ModelError(
                f"download {url}: sha256 {actual} does not match the pinned {sha256}; "
                "the file was not kept"
            )
        os.chmod(tmp, _FILE_MODE & ~_umask())  # mkstemp's 0600: a shared model folder
        os.replace(tmp, target)  # would be readable by its owner alone
        log.info("fetched %s", target)
    finally:
        out.close()
        tmp.unlink(missing_ok=True)


# ----------------------------------------------------------------------------- CLI


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("action", choices=("list", "fetch", "verify", "prepare"),
                        help="what to do (prepare: make the INT8 pose model)")  # fmt: skip
    parser.add_argument("names", nargs="*", default=[], help="model names (default: all)")
    parser.add_argument(
        "--from",
        dest="source",
        default=None,
        help="fetch from this base URL or local folder (a mirror) instead of the official sites",
    )
    parser.add_argument("--force", action="store_true",
                        help="fetch (or prepare) even if already cached")  # fmt: skip
    parser.set_defaults(_names_after_options="names")  # names may follow the options too


def main(args: argparse.Namespace) -> dict | int:
    if args.source is not None and args.action != "fetch":
        raise ValueError(f"--from names where fetch downloads from; {args.action} takes none")
    if args.force and args.action not in ("fetch", "prepare"):
        raise ValueError(f"--force fetches or prepares again; {args.action} takes none")
    if args.action == "prepare" and args.names:
        raise ValueError(
            f"prepare takes no model names (it makes the INT8 pose model), got {' '.join(args.names)}"
        )
    if args.action == "prepare":
        from follow import model_manifest
        from follow.pose.prepare import prepare_int8

        path = prepare_int8(force=args.force)
        record = model_manifest.read_manifest(path) or {}
        if not args.json:
            print(f"{path}  sha256 {record.get('sha256')}")
        return {"int8": str(path), "record": record}
    names = args.names or list(REGISTRY)
    for n in names:
        get_spec(n)
    if args.action == "list":
        rows = []
        for n in names:
            spec = REGISTRY[n]
            status = verify(n)
            rows.append(
                {
                    "name": n,
                    "description": spec.description,
                    "licence": spec.licence,
                    "present": all(s.ok for s in status),
                    "downloadable": all(f.url for f in spec.files),
                    "files": [{"path": f.relpath, "url": f.url or None} for f in spec.files],
                }
            )
        if not args.json:
            for r in rows:
                mark = "ok" if r["present"] else "--"
                how = "download" if r["downloadable"] else "convert"
                print(f"{mark}  {r['name']:38s} {how:8s} {r['description']}")
        return {"models": rows}
    if args.action == "fetch":
        fetched, failed, skipped = [], {}, {}
        for n in names:
            spec = REGISTRY[n]
            if not args.names and args.source is None and not all(f.url for f in spec.files):
                # Fetching "everything": models without a download are not failures.
                if not all(s.ok for s in verify(n)):
                    skipped[n] = spec.how_to_produce
                    print(f"{n}: skipped, no official download. {spec.how_to_produce}")
                continue
            try:
                fetched.append({"name": n, "path": str(fetch(n, args.source, args.force))})
            except (ModelError, OSError) as exc:  # one model's failure stops no other's
                failed[n] = str(exc) if isinstance(exc, ModelError) else (
                    f"{exc.filename or 'the cache'}: {exc.strerror or exc}")  # fmt: skip
                print(f"{n}: {failed[n]}")
        result = {"fetched": fetched, "failed": failed, "skipped": skipped}
        if args.json:
            import json

            print(json.dumps(result))
        return 1 if failed else 0
    rows = [s for n in names for s in verify(n)]
    if not args.names:
        rows += verify_derived_files()
    if not args.json:
        for s in rows:
            print(f"{'ok' if s.ok else 'FAIL':4s}  {s.model:38s} {s.relpath:50s} {s.detail}")
    bad = [s for s in rows if not s.ok]
    result = {
        "files": [
            {"model": s.model, "path": str(s.path) if s.path else None, "ok": s.ok,
             "detail": s.detail}
            for s in rows
        ],
        "ok": not bad,
    }  # fmt: skip
    if args.json:
        import json

        print(json.dumps(result))
    return 1 if bad else 0
