import pytest

from follow.config import Config, ConfigError


def test_defaults_and_toml_override(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[tracker]\ngate_chi2_quantile = 0.95\nmax_unseen_s = 3\n")
    cfg = Config.load(path)
    assert cfg.tracker.gate_chi2_quantile == 0.95
    assert cfg.tracker.max_unseen_s == 3.0
    assert cfg.control == Config().control


def test_a_file_over_a_base_keeps_the_base_where_it_is_silent(tmp_path):
    base_file, over_file = tmp_path / "base.toml", tmp_path / "over.toml"
    base_file.write_text("[tracker]\nankle_height_m = 0.15\nmax_unseen_s = 3\n")
    over_file.write_text("[tracker]\nmax_unseen_s = 1.5\n[pose]\ninput_height_px = 368\n")
    cfg = Config.load(over_file, base=Config.load(base_file))
    assert cfg.tracker.ankle_height_m == 0.15  # from the base
    assert cfg.tracker.max_unseen_s == 1.5  # the file wins
    assert cfg.pose.input_height_px == 368
    assert cfg.control == Config().control
    assert Config.load(over_file).tracker.ankle_height_m == Config().tracker.ankle_height_m


@pytest.mark.parametrize(
    "text,match",
    [
        ("[nope]\na = 1\n", r"unknown section \[nope\]"),
        ("[tracker]\nbogus = 1\n", "unknown key 'bogus'"),
        ("[tracker]\nmax_unseen_s = 'long'\n", "'max_unseen_s' must be float"),
        ("[mavlink]\narm = 1\n", "'arm' must be bool"),
        ("[tracker\n", "not valid TOML"),
    ],
)
def test_bad_config_names_the_problem(tmp_path, text, match):
    path = tmp_path / "c.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=match):
        Config.load(path)


def test_the_shipped_example_configs_load():
    from pathlib import Path

    examples = sorted((Path(__file__).parents[1] / "examples").glob("*.toml"))
    assert examples
    for path in examples:
        cfg = Config.load(path)
        assert cfg != Config(), path  # each one changes something


def test_docs_list_every_key_with_its_range():
    """docs/config.md holds the tables `python -m follow.config_bounds` prints."""
    from pathlib import Path

    from follow.config_bounds import markdown_tables

    docs = (Path(__file__).parents[1] / "docs" / "config.md").read_text()
    missing = [line for line in markdown_tables().splitlines() if line and line not in docs]
    assert not missing, "docs/config.md is out of date; regenerate its tables:\n" + "\n".join(
        missing
    )


def test_a_model_file_named_by_a_config_file_is_found_beside_it(tmp_path, monkeypatch):
    folder = tmp_path / "robot"
    folder.mkdir()
    config_path = folder / "robot.toml"
    config_path.write_text('[pose]\nmodel_file = "nets/pose.onnx"\n')
    monkeypatch.chdir(tmp_path)  # run from elsewhere: the file is still the config's
    assert Config.load(config_path).pose.model_file == str(folder / "nets" / "pose.onnx")
    config_path.write_text(f'[pose]\nmodel_file = "{tmp_path / "abs.onnx"}"\n')
    assert Config.load(config_path).pose.model_file == str(tmp_path / "abs.onnx")
    monkeypatch.setenv("HOME", str(tmp_path))
    config_path.write_text('[pose]\nmodel_file = "~/home.onnx"\n')
    assert Config.load(config_path).pose.model_file == str(tmp_path / "home.onnx")
    config_path.write_text("[pose]\ninput_height_px = 320\n")
    base = Config().replace("pose", model_file="kept.onnx")
    assert Config.load(config_path, base=base).pose.model_file == "kept.onnx"
