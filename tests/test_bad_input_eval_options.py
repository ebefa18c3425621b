"""`follow eval verification` and `follow eval identification` name a bad option: a data
folder that does not exist, a count of identities or targets that cannot be used (a
negative count used to slice the list from its end)."""

from __future__ import annotations

import pytest
from test_run_bad_input import _error  # one line on stderr, exit 1, no traceback


def test_a_data_dir_that_does_not_exist_is_named(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("FOLLOW_DATA_DIR", str(tmp_path))
    missing = tmp_path / "nonexist"
    err = _error(capsys, ["eval", "verification", "--data-dir", str(missing)])
    assert f"--data-dir {missing}: no such folder" in err


def test_a_data_dir_env_that_does_not_exist_is_named(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("FOLLOW_DATA_DIR", str(tmp_path / "nonexist"))
    err = _error(capsys, ["eval", "verification"])
    assert f"$FOLLOW_DATA_DIR {tmp_path / 'nonexist'}: no such folder" in err


def test_no_data_dir_at_all_says_so(capsys, monkeypatch):
    monkeypatch.delenv("FOLLOW_DATA_DIR", raising=False)
    err = _error(capsys, ["eval", "verification"])
    assert "no --data-dir given and $FOLLOW_DATA_DIR is not set" in err
    from follow.eval.verification import data_root

    with pytest.raises(ValueError) as err:  # bench --scene robot, pose-scene: no --data-dir
        data_root(None, has_option=False)
    assert str(err.value) == "$FOLLOW_DATA_DIR is not set"


@pytest.mark.parametrize("count", ["-1", "0", "3"])
def test_too_few_identities_are_refused(tmp_path, capsys, count):
    err = _error(capsys, ["eval", "verification", "--data-dir", str(tmp_path),
                          "--identities", count])  # fmt: skip
    assert "--identities must be >= 4" in err and f"got {count}" in err


@pytest.mark.parametrize("argv, option", [
    (["--max-targets", "-1"], "--max-targets"),
    (["--match-distance-m", "0"], "--match-distance-m"),
    (["--min-visible-s", "-5"], "--min-visible-s"),
    (["--min-visible-s", "0"], "--min-visible-s"),  # every person a target, seen or not
    (["--max-hidden-fraction", "5"], "--max-hidden-fraction"),  # a share: at most 1
    (["--plot", "timeline.txt"], "--plot"),
])  # fmt: skip
def test_identification_options_are_refused_before_any_data_is_read(capsys, monkeypatch,
                                                                    argv, option):  # fmt: skip
    from follow.cli import main

    monkeypatch.delenv("FOLLOW_DATA_DIR", raising=False)
    with pytest.raises(SystemExit) as exit_:
        main(["eval", "identification", *argv])
    assert exit_.value.code == 2
    assert f"argument {option}:" in capsys.readouterr().err


def test_every_scene_is_checked_before_the_first_one_runs(capsys):
    """A bad last scene used to be found after the first scenes' minutes."""
    from follow.cli import main

    for scenes, bad in (("1:3,6:3", "6:3"), ("2:20", "2:20")):
        with pytest.raises(SystemExit):
            main(["eval", "pose-scene", "--scenes", scenes])
        err = capsys.readouterr().err
        assert f"'{bad}': a scene holds 1-5 people, the farthest 3-15 m away" in err


def test_a_variant_named_twice_is_refused_by_name():
    """It used to cancel itself out of `follow eval pose` (a traceback for original twice)."""
    import argparse

    from follow.eval.perturb import selected_variants

    with pytest.raises(ValueError, match="--variants names original more than once"):
        selected_variants(argparse.Namespace(variants="original,dark,original", perturb=False))
    chosen = selected_variants(argparse.Namespace(variants="original,dark", perturb=False))
    assert [v.name for v in chosen] == ["original", "dark"]


def test_options_that_would_be_silently_ignored_are_refused(tmp_path):
    """`--seed` beside `--seeds`, and `--only-after-learning` with no variant to apply."""
    import argparse

    from follow.eval import strangers, verification

    both = argparse.Namespace(identifiers="ccf10", strangers=1, seed=7, seeds="0-0",
                              config=None, json=True, perturb=False, variants=None,
                              only_after_learning=False)  # fmt: skip
    with pytest.raises(ValueError, match="give --seed or --seeds, not both"):
        strangers.main(both)
    alone = argparse.Namespace(**{**vars(both), "seed": None, "seeds": None,
                                  "only_after_learning": True})  # fmt: skip
    with pytest.raises(ValueError, match="--only-after-learning .* give --perturb or --variants"):
        strangers.main(alone)
    with pytest.raises(ValueError, match="--only-after-learning"):
        verification.main(argparse.Namespace(data_dir=str(tmp_path), identifiers="reid",
                                             identities=None,
                                             config=None, json=True, perturb=False,
                                             variants=None, only_after_learning=True))  # fmt: skip
