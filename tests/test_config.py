import pytest

from follow.config import Config, ConfigError


def test_defaults_and_toml_override(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[tracker]\ngate_chi2_quantile = 0.95\nmax_unseen_s = 3\n")
    cfg = Config.load(path)
    assert cfg.tracker.gate_chi2_quantile == 0.95
    assert cfg.tracker.max_unseen_s == 3.0
    assert cfg.control == Config().control


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
