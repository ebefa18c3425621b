import dataclasses
import math
import re

import pytest

from follow.config import Config, ConfigError
from follow.config_bounds import BOUNDS, CHOICES, FREE_TEXT


def test_the_defaults_pass_validation():
    Config().validate()


@pytest.mark.parametrize(
    "text,match",
    [
        (
            "[control]\ntarget_timeout_s = 1e9\n",
            r"\[control\] target_timeout_s = 1000000000.0 is out of range: 0 < value <= 2",
        ),
        ("[control]\ncontrol_rate_hz = 1e9\n", r"\[control\] control_rate_hz .* 5 <= value <= 100"),
        ("[control]\nmax_forward_speed_mps = 1e9\n", r"\[control\] max_forward_speed_mps"),
        (
            "[tracker]\ngate_chi2_quantile = 1.5\n",
            r"\[tracker\] gate_chi2_quantile = 1.5 .* 0 < value < 1",
        ),
        ("[tracker]\nmax_unseen_s = -5\n", r"\[tracker\] max_unseen_s = -5.0"),
        ("[pose]\nheatmap_peak_threshold = nan\n", r"\[pose\] heatmap_peak_threshold = nan"),
        (
            "[pose]\ninput_height_px = 100000\n",
            r"\[pose\] input_height_px = 100000 .* multiple of 8",
        ),
        ("[pose]\ninput_height_px = 366\n", r"\[pose\] input_height_px = 366"),
        ("[pose]\nprovider = 'gpu'\n", r"\[pose\] provider = 'gpu': must be one of auto, cpu"),
        ("[pose]\nprecision = 'fp16'\n", r"\[pose\] precision"),
        ("[pose]\nmin_person_input_px = 'big'\n", r"\[pose\] min_person_input_px = 'big': .* auto"),
        ("[pose]\nmin_person_input_px = 8\n", r"\[pose\] min_person_input_px = 8.0 .* 16 <="),
        ("[identify]\nidentifier = 'ccf11'\n", r"\[identify\] identifier"),
        ("[mavlink]\nautopilot = 'dji'\n", r"\[mavlink\] autopilot"),
        ("[control]\noverlap_stages = 'yes'\n", r"\[control\] overlap_stages = 'yes': .* auto"),
        ("[mavlink]\nstream_rate_hz = 2\n", r"\[mavlink\] stream_rate_hz"),
        (
            "[tracker]\nmin_neck_height_m = 2.0\nmax_neck_height_m = 1.0\n",
            "min_neck_height_m .* must not exceed max_neck_height_m",
        ),
        (  # each in its range, but a new track would start at a height the tracker refuses
            "[tracker]\ndefault_neck_height_m = 2.0\nmax_neck_height_m = 1.8\n",
            r"default_neck_height_m \(2.0\) must not exceed max_neck_height_m \(1.8\)",
        ),
        (
            "[tracker]\ndefault_neck_height_m = 0.8\nmin_neck_height_m = 1.0\n",
            r"min_neck_height_m \(1.0\) must not exceed default_neck_height_m \(0.8\)",
        ),
    ],
)
def test_out_of_range_values_are_refused_naming_the_key(tmp_path, text, match):
    path = tmp_path / "c.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=match) as caught:
        Config.load(path)
    assert str(caught.value).startswith(f"config {path}: ")


def test_a_number_or_auto_key_takes_either(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[pose]\nmin_person_input_px = 80\n")
    assert Config.load(path).pose.min_person_input_px == 80.0
    path.write_text("[pose]\nmin_person_input_px = 'auto'\n")
    assert Config.load(path).pose.min_person_input_px == "auto"


def test_every_error_is_one_line_each():
    with pytest.raises(ConfigError) as caught:
        Config.from_dict({"control": {"max_forward_speed_mps": 9.0, "control_rate_hz": 0.0}})
    lines = str(caught.value).splitlines()
    assert len(lines) == 2
    assert "max_forward_speed_mps" in lines[0] and "control_rate_hz" in lines[1]


def test_a_replaced_config_is_validated_too():
    with pytest.raises(ConfigError, match="max_yaw_rate_radps"):
        Config().replace("control", max_yaw_rate_radps=100.0)


def test_values_at_the_bounds_are_accepted():
    cfg = Config.from_dict({"control": {"max_forward_speed_mps": 3.0, "control_rate_hz": 100,
                                        "max_forward_decel_mps2": 3.0}})  # fmt: skip
    assert cfg.control.max_forward_speed_mps == 3.0


def test_braking_too_weak_to_stop_within_the_following_distance_is_refused():
    """At 1.5 m/s a robot braking at 0.1 m/s^2 needs 11 m: a target that stops 1.8 m
    ahead would be run into. Each key is in range; together they are not."""
    with pytest.raises(ConfigError, match=r"max_forward_decel_mps2 \(0.1\).*11.25 m.*0.62"):
        Config().replace("control", max_forward_decel_mps2=0.1)
    with pytest.raises(ConfigError, match="braking takes"):
        Config().replace("control", max_forward_speed_mps=3.0)  # 2.25 m at 2 m/s^2
    slow = Config().replace("control", max_forward_speed_mps=0.5, max_forward_decel_mps2=0.1)
    assert slow.control.max_forward_decel_mps2 == 0.1  # 1.25 m: stops within 1.8 m


def test_integral_bounds_are_written_in_full():
    assert BOUNDS["identify"]["seed"].describe() == "0 <= value <= 4294967295"
    assert BOUNDS["identify"]["gaussian_memory_samples"].describe() == "1 <= value <= 1000000"
    assert BOUNDS["tracker"]["gate_chi2_quantile"].describe() == "0 < value < 1"
    assert BOUNDS["control"]["turn_in_place_bearing_rad"].describe() == "0 < value <= 3.14159"


def test_every_key_has_a_declared_range_or_choice():
    """A new key without a line in follow/config_bounds.py fails validation; and no line
    there names a key that does not exist."""
    for section in dataclasses.fields(Config):
        instance = getattr(Config(), section.name)
        keys = {f.name for f in dataclasses.fields(instance)}
        declared = set(BOUNDS.get(section.name, {})) | set(CHOICES.get(section.name, {}))
        declared |= {k for s, k in FREE_TEXT if s == section.name}
        numeric_or_text = {k for k in keys if not isinstance(getattr(instance, k), bool)}
        assert numeric_or_text == declared, section.name
        for key, rng in BOUNDS.get(section.name, {}).items():
            value = getattr(instance, key)
            if isinstance(value, str):  # a number or a choice ("auto"): the choice
                assert value in CHOICES[section.name][key], (section.name, key)
            else:
                assert rng.contains(value), (section.name, key)
            assert not rng.contains(math.inf) and not rng.contains(math.nan)


def test_identifier_choices_match_the_factory():
    from follow.identify.factory import IDENTIFIERS

    assert set(CHOICES["identify"]["identifier"]) == set(IDENTIFIERS)


@pytest.mark.parametrize("value", ["true", "false", "'auto'"])
def test_a_switch_with_an_auto_choice_takes_either(tmp_path, value):
    path = tmp_path / "c.toml"
    path.write_text(f"[control]\noverlap_stages = {value}\n")
    assert Config.load(path).control.overlap_stages == {"true": True, "false": False}.get(
        value, "auto"
    )


@pytest.mark.parametrize(
    "text, allowed",
    [
        ("[control]\noverlap_stages = 'false'\n",
         "must be one of auto, true, false; true and false are written without quotes"),
        ("[pose]\nmin_person_input_px = '100'\n",
         "must be auto or a number, 16 <= value <= 576"),
    ],
)  # fmt: skip
def test_a_text_value_of_a_key_that_also_takes_a_number_or_a_switch_names_them(
    tmp_path, text, allowed
):
    """The error listed the text choices alone ("must be one of auto"), as if the
    documented true / false or number were not allowed."""
    path = tmp_path / "c.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as caught:
        Config.load(path)
    assert str(caught.value).endswith(allowed)


def test_a_switch_with_an_auto_choice_refuses_other_types_naming_both(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[control]\noverlap_stages = 1\n")
    with pytest.raises(ConfigError, match="'overlap_stages' must be bool or str, got int"):
        Config.load(path)


def test_a_classifier_shape_the_booster_cannot_build_is_refused_at_load():
    """One weak classifier per selector passed validation and failed later, when the
    identifier built its classifier."""
    with pytest.raises(ConfigError, match="weak_classifiers_per_selector"):
        Config.from_dict({"identify": {"weak_classifiers_per_selector": 1}})
    assert Config.from_dict({"identify": {"weak_classifiers_per_selector": 2}})


@pytest.mark.parametrize(
    "section,key", [("control", "max_forward_speed_mps"), ("identify", "seed")]
)
def test_an_integer_too_large_for_a_float_is_refused_by_name(tmp_path, section, key):
    """TOML integers have no size limit in the reader: one past a float's range is an
    out-of-range value like any other, not an OverflowError from inside the check."""
    path = tmp_path / "c.toml"
    path.write_text(f"[{section}]\n{key} = 1{'0' * 400}\n")
    with pytest.raises(
        ConfigError, match=rf"^config {re.escape(str(path))}: \[{section}\] {key} = .* out of range"
    ):
        Config.load(path)


def test_pose_model_choices_are_the_registry_pose_networks():
    """Each choice of [pose] model is a registered model, and another registered model
    (the re-id network, CCF weights) is refused at load, naming the pose networks."""
    from follow import models
    from follow.config_bounds import POSE_MODELS

    assert all(models.get_spec(name) for name in POSE_MODELS)
    registered = {n for n in models.REGISTRY if n.startswith("human-pose-estimation")}
    assert registered == set(POSE_MODELS)  # a pose network added there is a choice here
    with pytest.raises(ConfigError, match="model = 'person-reidentification-retail-0248'"
                       ".*human-pose-estimation-0001"):  # fmt: skip
        Config().replace("pose", model="person-reidentification-retail-0248")


def test_an_id_switch_confidence_above_the_reid_confidence_is_refused_at_load(tmp_path):
    """The identifier refuses it too, but only when `follow run` builds it, after opening
    the source and loading the pose network, naming neither the file nor the section."""
    from follow.identify.identifier import check_identify_config

    path = tmp_path / "c.toml"
    path.write_text("[identify]\nid_switch_confidence = 0.5\n")
    where = rf"^config {re.escape(str(path))}: \[identify\] "
    with pytest.raises(ConfigError, match=where + r"id_switch_confidence \(0.5\) must not "
                       r"exceed reid_confidence \(0.2\)"):  # fmt: skip
        Config.load(path)
    equal = Config().replace("identify", id_switch_confidence=0.2, reid_confidence=0.2)
    check_identify_config(equal.identify)  # the identifier takes what loading takes


@pytest.mark.parametrize(
    "settings",
    [
        {"reid_confidence": 0.6, "reid_strict_confidence": 0.5},
        {"reid_accept_similarity": 0.6, "reid_strict_similarity": 0.5},
        {"id_switch_confidence": 0.5, "reid_confidence": 0.4, "reid_strict_confidence": 0.45},
    ],
)
def test_every_identify_rule_of_the_identifier_is_held_at_load(settings):
    """Each order check_identify_config refuses is refused when a config is made."""
    from follow.config import IdentifyConfig
    from follow.identify.identifier import check_identify_config

    with pytest.raises(ValueError):
        check_identify_config(dataclasses.replace(IdentifyConfig(), **settings))
    with pytest.raises(ConfigError, match="must not exceed"):
        Config().replace("identify", **settings)


@pytest.mark.parametrize(
    "text,match",
    [
        ("telemetry_rate_hz = 0.5\n", r"telemetry_rate_hz \(0.5\) and odometry_timeout_s \(0.5\)"),
        ("odometry_timeout_s = 0.01\n", r"telemetry_rate_hz \(30\) and odometry_timeout_s \(0.01\)"),
        ("telemetry_rate_hz = 3\nodometry_timeout_s = 0.6\n", r"leave 1.8 telemetry periods"),
    ],
)  # fmt: skip
def test_an_odometry_timeout_shorter_than_two_telemetry_periods_is_refused(tmp_path, text, match):
    """A gap between two telemetry messages longer than odometry_timeout_s restarts the
    settle window of the vehicle's clock: the odometry was never fresh, the robot never
    moved, and the only messages blamed the vehicle."""
    path = tmp_path / "c.toml"
    path.write_text("[mavlink]\n" + text)
    with pytest.raises(ConfigError, match=match) as caught:
        Config.load(path)
    assert str(caught.value).startswith(f"config {path}: [mavlink] ")
    assert "at least 2" in str(caught.value) and "never moves" in str(caught.value)


def test_two_telemetry_periods_within_the_odometry_timeout_are_enough():
    cfg = Config().replace("mavlink", telemetry_rate_hz=4.0, odometry_timeout_s=0.5)
    assert cfg.mavlink.telemetry_rate_hz * cfg.mavlink.odometry_timeout_s == 2.0


def test_a_mavlink_driver_made_in_code_refuses_too_few_telemetry_periods():
    from follow.config import MavlinkConfig
    from follow.control.mavlink_base import check_mavlink_config

    config = MavlinkConfig(connection="udpin:0.0.0.0:14550", telemetry_rate_hz=1.0)
    with pytest.raises(ConfigError, match="telemetry_rate_hz .* odometry_timeout_s"):
        check_mavlink_config(config)


def test_the_defaults_and_every_shipped_config_load():
    """The cross-key checks refuse none of what the project ships."""
    from pathlib import Path

    from follow.eval.pets_setup import PETS_SETTINGS

    root = Path(__file__).parents[1]
    shipped = sorted((root / "examples").glob("*.toml")) + [PETS_SETTINGS]
    assert len(shipped) >= 2
    Config().validate()
    for path in shipped:
        Config.load(path)
