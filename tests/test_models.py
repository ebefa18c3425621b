"""Model registry: lookup, hash checks, fetching from a loopback mirror, the CLI."""

from __future__ import annotations

import functools
import http.server
import json
import os
import shutil
import threading

import pytest

from follow import cli, models
from follow.config import PoseConfig


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """An empty user cache and no $FOLLOW_MODEL_DIR (request it after `mirror`)."""
    monkeypatch.delenv("FOLLOW_MODEL_DIR", raising=False)
    monkeypatch.setenv("FOLLOW_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache"


@pytest.fixture
def mirror(tmp_path, model_path):
    """A folder laid out like the model directory holding the real CCF weights."""
    root = tmp_path / "mirror"
    for rel in ("ccf/ccf10/conv_t1", "ccf/ccf10/conv_t2"):
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(model_path(rel), root / rel)
    return root


@pytest.fixture
def http_server(mirror):
    """Serve the mirror folder on 127.0.0.1 (never the internet)."""
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(mirror))
    handler.log_message = lambda *a, **k: None
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


def test_every_entry_has_a_download_or_a_recipe():
    for spec in models.REGISTRY.values():
        for f in spec.files:
            assert len(f.sha256) == 64
            assert f.url.startswith("https://") or spec.how_to_produce, spec.name


def test_fetch_over_http_with_hash_check(http_server, cache):
    path = models.fetch("ccf10", source=http_server)
    assert path == cache / "ccf/ccf10"
    assert models.resolve("ccf10") == path
    assert all(s.ok for s in models.verify("ccf10"))


def test_fetch_from_a_local_folder(mirror, cache):
    models.fetch("ccf10", source=str(mirror))
    assert (cache / "ccf/ccf10/conv_t2").read_bytes() == (mirror / "ccf/ccf10/conv_t2").read_bytes()


def test_a_download_with_the_wrong_hash_is_refused_and_not_kept(mirror, http_server, cache):
    with open(mirror / "ccf/ccf10/conv_t1", "ab") as fh:
        fh.write(b"0.5\n")
    with pytest.raises(models.ModelError, match="does not match the pinned"):
        models.fetch("ccf10", source=http_server)
    folder = cache / "ccf/ccf10"
    assert not (folder / "conv_t1").exists()
    assert not [p for p in folder.iterdir() if p.name.endswith(".part")]


def test_unreachable_source_is_a_clear_error(cache):
    with pytest.raises(models.ModelError, match="cannot download"):
        models.fetch("ccf10", source="http://127.0.0.1:9")


def test_a_download_that_cannot_start_leaves_no_file_open(cache, tmp_path):
    import os

    open_before = len(os.listdir("/proc/self/fd"))
    for _ in range(3):
        with pytest.raises(models.ModelError, match="cannot download"):
            models.fetch("ccf10", source=str(tmp_path / "no-mirror"))
    assert len(os.listdir("/proc/self/fd")) == open_before


def test_a_download_that_stalls_is_named_and_the_next_model_still_fetched(cache, monkeypatch,
                                                                         capsys):  # fmt: skip
    """A server that stops sending part-way (the read times out) fails that model with
    its URL, leaves no file, and the other models named are still tried."""
    release = threading.Event()

    class Stalling(http.server.BaseHTTPRequestHandler):
        def do_GET(self):
            self.send_response(200)
            self.send_header("Content-Length", "100000")
            self.end_headers()
            self.wfile.write(b"0" * 1000)
            self.wfile.flush()
            release.wait(5)

        def log_message(self, *args):
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Stalling)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    monkeypatch.setattr(models, "DOWNLOAD_TIMEOUT_S", 0.2)
    url = f"http://127.0.0.1:{server.server_address[1]}"
    try:
        assert cli.main(["models", "fetch", "ccf10", "ccf25", "--from", url, "--json"]) == 1
    finally:
        release.set()
        server.shutdown()
        server.server_close()
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert set(result["failed"]) == {"ccf10", "ccf25"}
    assert "broke off (TimeoutError" in result["failed"]["ccf10"]
    assert url in result["failed"]["ccf25"]
    assert [p for p in cache.rglob("*") if p.is_file()] == []


def test_model_without_official_download_explains_how_to_make_it(cache):
    with pytest.raises(models.ModelError, match="ir_to_onnx"):
        models.fetch("human-pose-estimation-0001")


def test_a_model_file_with_the_wrong_hash_is_refused(tmp_path, monkeypatch):
    bad = tmp_path / "models" / "pose" / "human-pose-estimation-0001.onnx"
    bad.parent.mkdir(parents=True)
    bad.write_bytes(b"not the network")
    monkeypatch.setenv("FOLLOW_MODEL_DIR", str(tmp_path / "models"))
    monkeypatch.setenv("FOLLOW_CACHE_DIR", str(tmp_path / "cache"))
    with pytest.raises(models.ModelError, match="refusing to load"):
        models.resolve("human-pose-estimation-0001")
    from follow.pose.detector import PoseDetector

    with pytest.raises(models.ModelError, match="sha256"):
        PoseDetector(PoseConfig())
    (status,) = models.verify("human-pose-estimation-0001")
    assert not status.ok and "!=" in status.detail


def test_cli_fetch_and_verify(http_server, cache, capsys):
    assert cli.main(["models", "verify", "ccf10"]) == 1
    # the names may follow the options as well as come before them
    assert cli.main(["models", "fetch", "--from", http_server, "ccf10"]) == 0
    capsys.readouterr()
    assert cli.main(["models", "verify", "ccf10", "--json"]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert report["ok"] and len(report["files"]) == 2
    assert cli.main(["models", "verify", "--json", "ccf10"]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1]) == report
    with pytest.raises(SystemExit):  # an unknown option after them is still refused
        cli.main(["models", "verify", "--json", "ccf10", "--bogus"])
    assert "unrecognized arguments: ccf10 --bogus" in capsys.readouterr().err
    assert cli.main(["models", "list", "--json"]) == 0
    listing = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    present = {m["name"]: m["present"] for m in listing["models"]}
    assert present["ccf10"] and not present["ccf25"]
    mask = os.umask(0)
    os.umask(mask)
    for f in (cache / "ccf/ccf10").iterdir():  # as any new file, not mkstemp's 0600
        assert f.stat().st_mode & 0o777 == 0o666 & ~mask, f


def test_unknown_model_name(cache):
    with pytest.raises(models.ModelError, match="unknown model 'nope'"):
        models.fetch("nope")
    assert cli.main(["models", "verify", "nope"]) == 1


def test_fetching_everything_skips_models_without_a_download(cache, monkeypatch, capsys):
    fetched = []
    monkeypatch.setattr(models, "fetch", lambda n, *a: fetched.append(n) or cache / n)
    assert cli.main(["models", "fetch", "--json"]) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert "human-pose-estimation-0001" in result["skipped"]
    assert "human-pose-estimation-0001" not in fetched
    assert {"human-pose-estimation-0001-ir", "ccf10", "ccf25"} <= set(fetched)


@pytest.mark.parametrize(
    "argv, named",
    [
        (["models", "prepare", "ccf10"], "ccf10"),
        (["models", "verify", "ccf10", "--from", "/media/usb/models"], "--from"),
        (["models", "prepare", "--from", "/media/usb/models"], "--from"),
        (["models", "list", "--force"], "--force"),
        (["models", "verify", "--force"], "--force"),
    ],
)
def test_what_an_action_does_not_take_is_refused_not_ignored(argv, named, cache, monkeypatch,
                                                              capsys):  # fmt: skip
    from follow.pose import prepare

    made = []
    monkeypatch.setattr(prepare, "prepare_int8", lambda force=False: made.append(force))
    assert cli.main(argv) != 0
    err = capsys.readouterr().err
    assert named in err and "Traceback" not in err
    assert not made


def test_no_action_asks_for_the_action_only(capsys):
    with pytest.raises(SystemExit) as exit_:
        cli.main(["models"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "required: action" in err and "names" not in err.splitlines()[-1]


def test_verify_reports_a_folder_in_place_of_a_model_file_and_goes_on(mirror, cache, monkeypatch,
                                                                       capsys):  # fmt: skip
    (mirror / "ccf/ccf10/conv_t1").unlink()
    (mirror / "ccf/ccf10/conv_t1").mkdir()
    monkeypatch.setenv("FOLLOW_MODEL_DIR", str(mirror))
    assert cli.main(["models", "verify", "ccf10", "--json"]) == 1
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    by_path = {f["path"].rsplit("/", 1)[-1]: f for f in report["files"]}
    assert not by_path["conv_t1"]["ok"] and "folder" in by_path["conv_t1"]["detail"]
    assert by_path["conv_t2"]["ok"]


def test_loading_a_model_with_a_folder_in_place_of_a_file_names_them(mirror, cache,
                                                                      monkeypatch):  # fmt: skip
    """It raised a bare IsADirectoryError from the hashing."""
    (mirror / "ccf/ccf10/conv_t1").unlink()
    (mirror / "ccf/ccf10/conv_t1").mkdir()
    monkeypatch.setenv("FOLLOW_MODEL_DIR", str(mirror))
    with pytest.raises(models.ModelError, match=r"model 'ccf10': .*conv_t1 is a folder, not a file"):
        models.resolve("ccf10")


def test_fetch_names_a_folder_in_place_of_a_cached_file_and_fetches_the_others(mirror, cache,
                                                                               capsys):  # fmt: skip
    """It ended the whole batch with a bare errno, the other models never fetched."""
    (cache / "ccf/ccf10/conv_t1").mkdir(parents=True)
    assert cli.main(["models", "fetch", "ccf10", "ccf25", "--from", str(mirror), "--json"]) == 1
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert "conv_t1 is a folder, not a file" in result["failed"]["ccf10"]
    assert "ccf25" in result["failed"]  # tried all the same (the mirror has no ccf25)
    assert "is a folder" not in result["failed"]["ccf25"]


def test_verify_checks_the_copy_that_resolve_loads(mirror, cache, monkeypatch):
    """A model's files are loaded from one folder: files split between $FOLLOW_MODEL_DIR
    and the cache are no usable model, and a partial copy in the first folder does not
    hide the whole one in the next."""
    monkeypatch.setenv("FOLLOW_MODEL_DIR", str(mirror))
    (cache / "ccf/ccf10").mkdir(parents=True)
    shutil.move(mirror / "ccf/ccf10/conv_t2", cache / "ccf/ccf10/conv_t2")
    with pytest.raises(models.ModelError, match="not found"):
        models.resolve("ccf10")
    statuses = models.verify("ccf10")
    assert not all(s.ok for s in statuses)
    assert "one folder" in " ".join(s.detail for s in statuses)

    shutil.copy(mirror / "ccf/ccf10/conv_t1", cache / "ccf/ccf10/conv_t1")
    (mirror / "ccf/ccf10/conv_t1").write_bytes(b"a partial, corrupt copy")
    assert models.resolve("ccf10") == cache / "ccf/ccf10"
    statuses = models.verify("ccf10")
    assert all(s.ok for s in statuses)
    assert {s.path.parent for s in statuses} == {cache / "ccf/ccf10"}


def test_verify_blames_the_missing_file_not_the_ones_present(mirror, cache, monkeypatch):
    """One file of a model missing everywhere (a fetch cut short): that file is reported
    missing, and the files present are checked as they are, not blamed for the layout."""
    monkeypatch.setenv("FOLLOW_MODEL_DIR", str(mirror))
    (mirror / "ccf/ccf10/conv_t2").unlink()
    by_name = {s.relpath.rsplit("/", 1)[-1]: s for s in models.verify("ccf10")}
    assert by_name["conv_t2"].detail == "missing" and not by_name["conv_t2"].ok
    assert by_name["conv_t1"].ok and by_name["conv_t1"].detail == "ok"


def test_a_model_cache_that_cannot_be_written_is_named_as_the_cache(tmp_path, monkeypatch):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    monkeypatch.setenv("FOLLOW_CACHE_DIR", str(blocker / "cache"))
    target = models.cache_dir() / "ccf/ccf10/conv_t1"
    with pytest.raises(models.ModelError, match=r"in the cache \(\$FOLLOW_CACHE_DIR, now "):
        models._download("file:///nowhere", target, "0" * 64)


def test_a_cache_folder_that_cannot_be_made_names_the_cache(tmp_path, monkeypatch):
    """The INT8 model, the cut network, TensorRT engines and PETS skeletons are kept in
    the cache: a bare `[Errno 20] Not a directory` said none of that."""
    blocker = tmp_path / "notes.txt"
    blocker.write_text("x")
    monkeypatch.setenv("FOLLOW_CACHE_DIR", str(blocker / "c"))
    with pytest.raises(OSError, match=r"in the cache \(\$FOLLOW_CACHE_DIR, now .*notes.txt/c\)"):
        models.make_cache_folder(models.cache_dir() / "pose")
    assert models.make_cache_folder(tmp_path / "ok" / "pose").is_dir()


def read_only(monkeypatch, folder) -> None:
    """Make `folder` read-only for the rest of the test, whoever runs it: chmod stops no
    write by root (CI runs as root), so each way of making or replacing a file in it
    fails as on a read-only disk (EACCES, naming the file)."""
    import builtins
    import errno
    import io
    from pathlib import Path

    folder = Path(os.path.abspath(folder))
    real_open, real_os_open, real_replace = builtins.open, os.open, os.replace

    def check(path) -> None:
        if isinstance(path, int):  # a file descriptor
            return
        name = Path(os.path.abspath(os.fsdecode(path)))
        if folder in (name, name.parent):  # O_TMPFILE opens the folder itself
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(name))

    def guarded_open(file, mode="r", *args, **kwargs):
        if any(c in mode for c in "wax+"):
            check(file)
        return real_open(file, mode, *args, **kwargs)

    def guarded_os_open(path, flags, *args, **kwargs):
        if flags & (os.O_WRONLY | os.O_RDWR | os.O_CREAT):
            check(path)
        return real_os_open(path, flags, *args, **kwargs)

    def guarded_replace(src, dst, *args, **kwargs):
        check(src)
        check(dst)
        return real_replace(src, dst, *args, **kwargs)

    for module in (builtins, io):
        monkeypatch.setattr(module, "open", guarded_open)
    monkeypatch.setattr(os, "open", guarded_os_open)
    monkeypatch.setattr(os, "replace", guarded_replace)
    monkeypatch.setattr(os, "rename", guarded_replace)


def test_a_read_only_cache_folder_is_named_before_any_long_job(tmp_path, monkeypatch):
    """Making the folder succeeded on a read-only cache: INT8 calibration ran ~30 s, then
    failed with a bare `[Errno 13] Permission denied` naming a temporary file."""
    folder = models.make_cache_folder(models.cache_dir() / "pose")
    before = sorted(folder.iterdir())  # other tests' models may be there already
    assert models.writable_cache_folder(folder) == folder
    assert sorted(folder.iterdir()) == before  # the probe leaves nothing behind
    read_only(monkeypatch, folder)
    with pytest.raises(OSError, match=r"^cannot write .*pose, in the cache \(\$FOLLOW_CACHE_DIR"):
        models.writable_cache_folder(folder)
    elsewhere = tmp_path / "elsewhere"
    read_only(monkeypatch, elsewhere)
    with pytest.raises(OSError, match=r"^cannot write .*elsewhere: Permission denied$"):
        models.writable_cache_folder(elsewhere)  # not the cache: not said to be
