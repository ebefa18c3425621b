"""`follow demo` refuses a --seconds it cannot run before it writes anything (an earlier
run's log is kept), and refuses CCF weights that are present but fail their hash check
instead of quietly identifying with another feature type; only missing weights fall
back to the colour/gradient channels."""

from __future__ import annotations

import pytest

from follow import cli
from follow.models import ModelError, get_spec
from follow.sim.demo import choose_identifier, run_demo


def _error(capsys, argv) -> str:
    assert cli.main(argv) == 1
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    return err


@pytest.mark.parametrize("seconds", ["0", "-5", "inf", "nan", "0.01"])
def test_a_bad_length_is_refused_before_the_earlier_log_is_touched(tmp_path, capsys, seconds):
    out = tmp_path / "demo"
    out.mkdir()
    earlier = out / "demo.jsonl"
    earlier.write_text('{"log_version":1}\n{"frame":0}\n')
    err = _error(capsys, ["demo", "--seconds", seconds, "--no-video", "--output", str(out)])
    assert "--seconds must be finite and at least one frame" in err
    assert earlier.read_text() == '{"log_version":1}\n{"frame":0}\n'
    assert sorted(p.name for p in out.iterdir()) == ["demo.jsonl"]


@pytest.mark.parametrize("bag", ["existing.mcap", "demo/demo.jsonl", "run.txt"])
def test_a_bag_it_could_not_write_is_refused_before_the_earlier_log_is_touched(tmp_path, capsys,
                                                                              bag):  # fmt: skip
    """The bag was refused only once the demo had opened (and emptied) its own log: with
    `--bag demo/demo.jsonl`, the very log it had just emptied."""
    out = tmp_path / "demo"
    out.mkdir()
    earlier = out / "demo.jsonl"
    earlier.write_text('{"log_version":1}\n{"frame":0}\n')
    (tmp_path / "existing.mcap").write_text("x")
    err = _error(capsys, ["demo", "--seconds", "2", "--no-video", "--output", str(out),
                          "--bag", str(tmp_path / bag)])  # fmt: skip
    assert "exists already" in err or "name a .mcap or .bag file" in err
    assert earlier.read_text() == '{"log_version":1}\n{"frame":0}\n'


@pytest.mark.parametrize("suffix", [".toml", ".camera.yaml"])
def test_a_file_the_demo_writes_beside_its_bag_is_never_overwritten(tmp_path, capsys, suffix):
    """The demo wrote its configuration and camera file beside the bag over whatever was
    there; it is refused, by name, before the earlier log is touched."""
    out = tmp_path / "demo"
    out.mkdir()
    earlier = out / "demo.jsonl"
    earlier.write_text('{"log_version":1}\n')
    beside = tmp_path / f"robot.mcap{suffix}"
    beside.write_text("# kept\n")
    err = _error(capsys, ["demo", "--seconds", "2", "--no-video", "--output", str(out),
                          "--bag", str(tmp_path / "robot.mcap")])  # fmt: skip
    assert f"{beside} exists already" in err
    assert beside.read_text() == "# kept\n" and earlier.read_text() == '{"log_version":1}\n'
    assert not (tmp_path / "robot.mcap").exists()


def test_run_demo_checks_its_length_too(tmp_path):
    with pytest.raises(ValueError, match="--seconds"):
        run_demo(seconds=0.0, identifier="channels", output=tmp_path / "demo")
    assert not (tmp_path / "demo").exists()


def _weights(root, names):
    for f in get_spec("ccf10").files:
        if f.relpath.rsplit("/", 1)[-1] in names:
            path = root / f.relpath
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(b"not the pinned weights")


@pytest.fixture
def model_dirs(tmp_path, monkeypatch):
    models, cache = tmp_path / "models", tmp_path / "cache"
    models.mkdir()
    cache.mkdir()
    monkeypatch.setenv("FOLLOW_MODEL_DIR", str(models))
    monkeypatch.setenv("FOLLOW_CACHE_DIR", str(cache))
    return models


def test_corrupt_ccf_weights_are_refused_with_the_hash_error(model_dirs, tmp_path, capsys):
    _weights(model_dirs, {"conv_t1", "conv_t2"})
    with pytest.raises(ModelError, match="conv_t1 has sha256 .* refusing to load it"):
        choose_identifier(None)
    out = tmp_path / "demo"
    err = _error(capsys, ["demo", "--seconds", "3", "--no-video", "--output", str(out)])
    assert "model 'ccf10'" in err and str(model_dirs) in err and "sha256" in err
    assert not out.exists()


@pytest.mark.parametrize("present", [set(), {"conv_t1"}])
def test_missing_ccf_weights_fall_back_to_the_channels(model_dirs, present):
    _weights(model_dirs, present)
    assert choose_identifier(None) == "channels"
    assert choose_identifier("ccf25") == "ccf25"  # a named identifier is kept as given


@pytest.mark.parametrize("option", ["--output", "--bag", "--identifier"])
def test_an_empty_demo_option_is_refused_not_read_as_this_folder(option, capsys):
    with pytest.raises(SystemExit) as exit_:
        cli.main(["demo", option, "", "--seconds", "1", "--no-video"])
    assert exit_.value.code == 2
    assert f"argument {option}: empty" in capsys.readouterr().err
