"""The allowed range of every configuration key, as one table per section.

A value outside its range is refused when a configuration is made (`Config.validate`),
so a typo such as `max_forward_speed_mps = 1e9` or `gate_chi2_quantile = 1.5` stops the
program with one line naming the section and key instead of driving the robot. The
ranges bound what keeps a following robot safe (speeds, timeouts, rates) and what the
code can run at all (sizes, probabilities); docs/config.md lists them.

Adding a key to a section of follow/config.py means adding one line here: a numeric key
without a range, or a text key without its choices, is itself an error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

# Text keys that take one of a fixed set of values.
POSE_PROVIDERS = ("auto", "cpu", "cuda", "tensorrt", "openvino")
POSE_PRECISIONS = ("auto", "fp32", "int8", "int8_if_made")
# The pose networks of the model registry (follow/models.py): another model's name (the
# re-id network, the CCF weights) loads, then fails on the first frame's shapes.
POSE_MODELS = ("human-pose-estimation-0001", "human-pose-estimation-0001-ir")
# A rule of the identifier that may apply only beside a re-id cue
# (follow.identify.appearance.reid_rule_applies).
REID_RULE_CHOICES = ("with_reid", "always", "never")
REID_PROVIDERS = ("auto", "cpu", "cuda", "openvino", "onnxruntime")
IDENTIFIERS = ("ccf10", "ccf25", "channels", "reid", "ccf10+reid", "ccf25+reid", "channels+reid")
AUTOPILOTS = ("ardupilot", "px4")
# Text keys with free values (a file path is checked when it is opened, a connection
# string by pymavlink).
FREE_TEXT = {("pose", "model_file"), ("mavlink", "connection")} | {
    ("ros", name)
    for name in ("image_topic", "camera_info_topic", "odom_topic", "cmd_vel_topic", "odom_frame")
}


@dataclass(frozen=True)
class Range:
    """lo .. hi; an open end (`lo_open`/`hi_open`) excludes the bound itself."""

    lo: float
    hi: float
    lo_open: bool = False
    hi_open: bool = False
    multiple_of: int = 0  # integers only: the value must be a multiple of this

    def contains(self, value: float) -> bool:
        if isinstance(value, float) and not math.isfinite(value):  # an int may exceed floats
            return False
        above = value > self.lo if self.lo_open else value >= self.lo
        below = value < self.hi if self.hi_open else value <= self.hi
        return above and below and (not self.multiple_of or value % self.multiple_of == 0)

    def describe(self) -> str:
        lo = f"{_number(self.lo)} {'<' if self.lo_open else '<='}"
        hi = f"{'<' if self.hi_open else '<='} {_number(self.hi)}"
        extra = f", a multiple of {self.multiple_of}" if self.multiple_of else ""
        return f"{lo} value {hi}{extra}"


def _number(x: float) -> str:
    """A bound as written in a table or a message: an integral bound in full (2**32 - 1 is
    4294967295, not 4.29497e+09), any other the shortest way (`:g`)."""
    if isinstance(x, int) or (math.isfinite(x) and float(x).is_integer()):
        return str(int(x))
    return f"{x:g}"


def closed(lo: float, hi: float) -> Range:
    return Range(lo, hi)


def positive(hi: float) -> Range:
    """0 < value <= hi."""
    return Range(0.0, hi, lo_open=True)


def fraction_open() -> Range:
    """0 < value < 1 (a probability or quantile that must not be 0 or 1)."""
    return Range(0.0, 1.0, lo_open=True, hi_open=True)


UNIT = closed(0.0, 1.0)
THREADS = closed(0, 256)  # 0 = the runtime's default

BOUNDS: dict[str, dict[str, Range]] = {
    "pose": {
        # Up to a 1080p frame at full size; the network needs multiples of its stride 8.
        "input_height_px": Range(96, 1088, multiple_of=8),
        "far_person_distance_m": closed(1.0, 50.0),
        "far_person_height_m": closed(0.5, 2.5),
        "min_person_input_px": closed(16.0, 576.0),
        "network_stages": closed(1, 2),
        "full_input_every_frames": closed(1, 1000),
        "cpu_threads": THREADS,
        "warmup_runs": closed(0, 100),
        "median_filter_radius_px": closed(0, 4),
        "unsharp_amount": closed(0.0, 3.0),
        "unsharp_sigma_px": closed(0.3, 5.0),
        "keypoint_min_confidence": UNIT,
        "min_keypoints_per_person": closed(1, 18),
        "border_margin_px": closed(0.0, 100.0),
        "top_edge_margin_cells": closed(0.0, 4.0),
        "bottom_edge_margin_cells": closed(0.0, 4.0),
        "heatmap_peak_threshold": fraction_open(),
        "paf_samples": closed(2, 100),
        "paf_min_sample_score": UNIT,
        "paf_min_sample_fraction": UNIT,
        "min_person_mean_score": closed(0.0, 2.0),
        "duplicate_keypoint_distance": closed(0.0, 1.0),
        "duplicate_shared_keypoints": closed(1, 18),
        "duplicate_box_containment": Range(0.0, 1.0, lo_open=True),
    },
    "tracker": {
        "accel_noise_mps2": positive(20.0),
        "height_noise_mps": closed(0.0, 1.0),
        "neck_noise_px": positive(100.0),
        "ankle_noise_px": positive(100.0),
        "detection_height_px": closed(32, 4320),
        "neck_position_noise_m": closed(0.0, 1.0),
        "ankle_position_noise_m": closed(0.0, 1.0),
        "single_ankle_position_noise_m": closed(0.0, 2.0),
        "ankle_height_m": closed(0.0, 0.5),
        "ankle_height_per_neck_height": closed(0.0, 0.2),
        "walking_ankle_lift_m": closed(0.0, 0.3),
        "full_gait_speed_mps": positive(5.0),
        "init_velocity_std_mps": positive(10.0),
        "init_height_std_m": positive(1.0),
        "default_neck_height_m": closed(0.5, 2.5),
        "min_neck_height_m": closed(0.1, 2.5),
        "max_neck_height_m": closed(0.5, 3.5),
        "min_projection_depth_m": positive(5.0),
        "sigma_alpha": positive(10.0),
        "sigma_beta": closed(0.0, 10.0),
        "sigma_kappa": closed(-10.0, 10.0),
        "gate_chi2_quantile": fraction_open(),
        "floor_gate_m": positive(100.0),
        "floor_gate_per_range": closed(0.0, 10.0),
        "floor_gate_max_spread_m": closed(0.0, 100.0),
        "neck_only_max_position_std_m": positive(100.0),
        "min_updates_to_confirm": closed(1, 100),
        "max_position_std_m": positive(10.0),
        "max_position_std_per_range": closed(0.0, 1.0),
        "max_unseen_s": positive(10.0),
        "tentative_max_unseen_s": positive(10.0),
        "max_unseen_outside_view_s": closed(0.0, 10.0),
        "max_outside_image_px": closed(0.0, 1000.0),
    },
    "identify": {
        "num_selectors": closed(1, 200),
        "weak_classifiers_per_selector": closed(2, 200),
        "sample_bank_size": closed(1, 10000),
        "rect_min_fraction": positive(1.0),
        "rect_max_fraction": positive(1.0),
        "replace_probability": UNIT,
        "gaussian_memory_samples": closed(1.0, 1e6),
        "min_feature_std": positive(1.0),
        "selector_error_decay": positive(1.0),
        "initial_training_frames": closed(1, 1000),
        "max_initial_distance_m": positive(50.0),
        "id_switch_confidence": closed(-1.0, 1.0),
        "reid_confidence": closed(-1.0, 1.0),
        "reid_frames": closed(1, 1000),
        "reid_margin": closed(0.0, 2.0),
        "reid_reach_m": closed(0.0, 50.0),
        "reid_reach_speed_mps": closed(0.0, 10.0),
        "max_learning_overlap": UNIT,
        "identity_trust_s": closed(0.0, 60.0),
        "identity_risk_distance_m": closed(0.0, 20.0),
        "identity_risk_unseen_s": closed(0.0, 60.0),
        "seed": closed(0, 2**32 - 1),
        "crop_height_px": closed(16, 1024),
        "crop_width_px": closed(8, 1024),
        "feature_threads": THREADS,
        "reid_probation_s": closed(0.0, 60.0),
        "roi_height_per_neck_ankle": positive(10.0),
        "roi_width_per_neck_ankle": positive(10.0),
        "roi_center_offset_per_neck_ankle": closed(-1.0, 1.0),
        "neck_ankle_per_neck_hip": positive(10.0),
        "min_roi_height_px": closed(1.0, 4096.0),
        "min_roi_visible_fraction": UNIT,
        "reid_gallery_size": closed(2, 10000),
        "min_target_observations": closed(1, 1000),
        "reid_accept_similarity": closed(-1.0, 1.0),
        "reid_strict_similarity": closed(-1.0, 1.0),
        "reid_decisive_margin": closed(0.0, 2.0),
        "reid_strict_confidence": closed(-1.0, 1.0),
        "reid_strict_after_s": positive(600.0),
        "reid_height_tolerance_m": closed(0.0, 1.0),
        "reid_part_colour_distance": closed(0.0, 1.0),
        "reid_height_tolerance_stds": closed(0.0, 10.0),
        "min_negatives_per_update": closed(0, 64),
        "reid_same_similarity": closed(-1.0, 1.0),
        "reid_similarity_scale": positive(2.0),
        "reid_weight": UNIT,
        "reid_threads": THREADS,
    },
    "control": {
        "following_distance_m": closed(0.5, 10.0),
        # A person-following ground robot never needs more than a run (3 m/s).
        "max_forward_speed_mps": positive(3.0),
        "max_backward_speed_mps": closed(0.0, 1.0),
        "max_yaw_rate_radps": positive(3.0),
        "max_forward_accel_mps2": positive(5.0),
        "max_forward_decel_mps2": positive(10.0),
        "max_yaw_accel_radps2": positive(20.0),
        "distance_gain_per_s": closed(0.0, 10.0),
        "bearing_gain_per_s": closed(0.0, 10.0),
        "velocity_feedforward_gain": closed(0.0, 2.0),
        "turn_in_place_bearing_rad": positive(math.pi),
        # Stale targets must stop the robot within a couple of seconds at most.
        "target_timeout_s": positive(2.0),
        # Driving toward an unseen target, and a stalled perception, are bounded hard:
        # a frozen result (the target seen in it) is driven on at the speed of that
        # moment until the watchdog trips, so that wait is held to the blind drive's.
        "max_blind_drive_s": positive(1.0),
        "watchdog_timeout_s": positive(1.0),
        "camera_stall_timeout_s": closed(0.0, 600.0),
        "missing_target_warn_s": positive(600.0),
        "search_duration_s": closed(0.0, 10.0),
        "search_yaw_rate_radps": closed(0.0, 3.0),
        # The zero after a stall leaves on the next tick: a period adds to the watchdog.
        "control_rate_hz": closed(5.0, 100.0),
    },
    "mavlink": {
        "heartbeat_timeout_s": positive(10.0),
        # ArduPilot and PX4 drop out of guided/offboard below a few setpoints a second.
        "stream_rate_hz": closed(10.0, 100.0),
        "telemetry_rate_hz": positive(200.0),
        "connect_timeout_s": positive(120.0),
        "command_timeout_s": positive(2.0),
        "odometry_timeout_s": positive(2.0),
        "source_system": closed(1, 255),
        "source_component": closed(0, 255),
        "px4_turn_horizon_s": positive(5.0),
    },
    "ros": {
        # The node's watchdog (`watchdog_timeout_s` of `follow run`), held to its bound.
        "max_image_age_s": positive(1.0),
        "max_odometry_age_s": positive(2.0),
        "diagnostics_period_s": positive(60.0),
    },
}

CHOICES: dict[str, dict[str, tuple[str, ...]]] = {
    # min_person_input_px: "auto" or a number in its range (BOUNDS)
    "pose": {"model": POSE_MODELS, "provider": POSE_PROVIDERS, "precision": POSE_PRECISIONS,
             "min_person_input_px": ("auto",)},  # fmt: skip
    "identify": {
        "identifier": IDENTIFIERS,
        "mirrored_positives": REID_RULE_CHOICES,
        "learn_needs_lead_at_risk": REID_RULE_CHOICES,
        "reid_provider": REID_PROVIDERS,
    },
    "mavlink": {"autopilot": AUTOPILOTS},
    "control": {"overlap_stages": ("auto",)},  # or true / false
}

# (section, smaller key, larger key): pairs whose order matters.
ORDERED: tuple[tuple[str, str, str], ...] = (
    ("tracker", "min_neck_height_m", "max_neck_height_m"),
    # The population prior a new track's height is fused with: inside what the tracker
    # accepts as a standing person's neck.
    ("tracker", "min_neck_height_m", "default_neck_height_m"),
    ("tracker", "default_neck_height_m", "max_neck_height_m"),
    ("tracker", "tentative_max_unseen_s", "max_unseen_s"),
    ("identify", "rect_min_fraction", "rect_max_fraction"),
    ("control", "search_yaw_rate_radps", "max_yaw_rate_radps"),
    ("identify", "reid_confidence", "reid_strict_confidence"),
    ("identify", "reid_accept_similarity", "reid_strict_similarity"),
    # A target taken back by re-id must be held as surely as one kept through a switch
    # (follow.identify.identifier.check_identify_config refuses it when a run starts).
    ("identify", "id_switch_confidence", "reid_confidence"),
)

# The unscented filter's sigma points lie sqrt(sigma_alpha^2 (n + sigma_kappa)) standard
# deviations out (n = 5 state dimensions). At zero or below there is no spread (a
# division by zero, or a negative matrix to factor); the floor keeps the weights, which
# grow as its inverse, from drowning the mean in rounding (alpha = 1e-3, the smallest
# usual choice, gives 5e-6).
SIGMA_POINT_STATE_DIM = 5
MIN_SIGMA_POINT_SPREAD = 1e-6


def _sigma_spread_error(section) -> str | None:
    spread = section.sigma_alpha**2 * (SIGMA_POINT_STATE_DIM + section.sigma_kappa)
    if spread >= MIN_SIGMA_POINT_SPREAD:
        return None
    return (
        f"[tracker] sigma_alpha ({section.sigma_alpha}) and sigma_kappa "
        f"({section.sigma_kappa}) leave the sigma points no spread: sigma_alpha^2 * "
        f"({SIGMA_POINT_STATE_DIM} + sigma_kappa) = {spread:g} must be at least "
        f"{MIN_SIGMA_POINT_SPREAD:g}"
    )


def _braking_error(section) -> str | None:
    """A robot at `max_forward_speed_mps` behind a target that stops dead must stop within
    `following_distance_m` at `max_forward_decel_mps2` (the controller brakes no harder
    while the target is seen), or it drives into the person it follows."""
    speed, decel = section.max_forward_speed_mps, section.max_forward_decel_mps2
    braking_m = speed**2 / (2.0 * decel)
    if braking_m <= section.following_distance_m:
        return None
    needed = speed**2 / (2.0 * section.following_distance_m)
    return (
        f"[control] max_forward_decel_mps2 ({decel:g}) cannot stop the robot from "
        f"max_forward_speed_mps ({speed:g}) within following_distance_m "
        f"({section.following_distance_m:g}): braking takes {braking_m:.2f} m, so a target "
        f"that stops would be run into; brake at least {needed:.2f} m/s^2 or drive slower"
    )


# Telemetry periods the odometry time-out must span: a gap between two messages longer
# than `odometry_timeout_s` restarts the settle window of the vehicle's clock
# (follow.control.mavlink_base), so with fewer the odometry is never fresh, the robot
# never moves, and the only messages blame the vehicle.
MIN_TELEMETRY_PERIODS_PER_ODOMETRY_TIMEOUT = 2.0


def _telemetry_error(section) -> str | None:
    """`odometry_timeout_s` must hold at least two telemetry periods (see above)."""
    rate_hz, timeout_s = section.telemetry_rate_hz, section.odometry_timeout_s
    periods = MIN_TELEMETRY_PERIODS_PER_ODOMETRY_TIMEOUT
    if rate_hz * timeout_s >= periods:
        return None
    return (
        f"[mavlink] telemetry_rate_hz ({rate_hz:g}) and odometry_timeout_s ({timeout_s:g}) "
        f"leave {rate_hz * timeout_s:.3g} telemetry periods within the odometry time-out: "
        f"telemetry_rate_hz * odometry_timeout_s must be at least {periods:g}, or a gap "
        "between two telemetry messages makes the odometry stale for the whole run "
        "(the robot never moves)"
    )


def _allowed(name: str, section, key: str) -> str:
    """What a text key takes: its choices, and true / false or a number where its type
    allows them too (`overlap_stages`, `min_person_input_px`)."""
    from follow.config import field_types

    types = field_types(type(section), key, str)
    words = list(CHOICES[name][key]) + (["true", "false"] if bool in types else [])
    text = f"one of {', '.join(words)}" if len(words) > 1 else words[0]
    if float in types:
        text += f" or a number, {BOUNDS[name][key].describe()}"
    if bool in types:
        text += "; true and false are written without quotes"
    return text


def section_errors(name: str, section) -> list[str]:
    """One line per key of `section` (a config section instance) that is out of range."""
    import dataclasses

    bounds, choices = BOUNDS.get(name, {}), CHOICES.get(name, {})
    errors = []
    out_of_range: set[str] = set()  # keys with a bad value: no cross-key check on them
    for f in dataclasses.fields(section):
        value = getattr(section, f.name)
        where = f"[{name}] {f.name}"
        if isinstance(value, bool):
            continue
        if isinstance(value, str):
            if f.name in choices:
                if value not in choices[f.name]:
                    out_of_range.add(f.name)
                    errors.append(f"{where} = {value!r}: must be {_allowed(name, section, f.name)}")
            elif (name, f.name) not in FREE_TEXT:
                errors.append(f"{where}: no allowed values declared (follow/config_bounds.py)")
            continue
        if f.name not in bounds:
            errors.append(f"{where}: no allowed range declared (follow/config_bounds.py)")
        elif not bounds[f.name].contains(value):
            out_of_range.add(f.name)
            errors.append(f"{where} = {value!r} is out of range: {bounds[f.name].describe()}")
    for sec, small, large in ORDERED:
        if sec != name or {small, large} & out_of_range:
            continue  # unordered pairs are only reported when both values are in range
        if getattr(section, small) > getattr(section, large):
            errors.append(
                f"[{name}] {small} ({getattr(section, small)}) must not exceed "
                f"{large} ({getattr(section, large)})"
            )
    if name == "tracker" and not {"sigma_alpha", "sigma_kappa"} & out_of_range:
        if spread := _sigma_spread_error(section):
            errors.append(spread)
    braking_keys = {"max_forward_speed_mps", "max_forward_decel_mps2", "following_distance_m"}
    if name == "control" and not braking_keys & out_of_range:
        if braking := _braking_error(section):
            errors.append(braking)
    telemetry_keys = {"telemetry_rate_hz", "odometry_timeout_s"}
    if name == "mavlink" and not telemetry_keys & out_of_range:
        if telemetry := _telemetry_error(section):
            errors.append(telemetry)
    return errors


def markdown_tables() -> str:
    """The key tables of docs/config.md: every section, key, default and allowed range
    (`python -m follow.config_bounds` prints them)."""
    import dataclasses

    from follow.config import Config, field_types

    out = []
    for f in dataclasses.fields(Config):
        section = getattr(Config(), f.name)
        out += [f"## [{f.name}]", "", "| key | default | allowed |", "|---|---|---|"]
        for key in dataclasses.fields(section):
            value = getattr(section, key.name)
            if isinstance(value, bool):
                allowed = "`true` \\| `false`"
            elif isinstance(value, str):
                choices = list(CHOICES.get(f.name, {}).get(key.name, ()))
                types = field_types(type(section), key.name, str)
                if bool in types:
                    choices += ["true", "false"]
                if float in types:
                    choices.append(BOUNDS[f.name][key.name].describe())
                allowed = " \\| ".join(f"`{c}`" for c in choices) if choices else "any text"
            else:
                allowed = f"`{BOUNDS[f.name][key.name].describe()}`"
            default = (
                f'"{value}"'
                if isinstance(value, str)
                else str(value).lower()
                if isinstance(value, bool)
                else f"{value:g}"
                if isinstance(value, float)
                else str(value)
            )
            out.append(f"| `{key.name}` | `{default}` | {allowed} |")
        out.append("")
    return "\n".join(out)


if __name__ == "__main__":
    print(markdown_tables())
