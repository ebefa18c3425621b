"""The one configuration of `follow`: a dataclass per stage, loaded from TOML.

Defaults are for a robot following one person 1-8 m away with its camera 0.5-1.5 m up
(the comment beside a value says where it comes from: Koide et al., RAS 2020, where the
paper gives one; a measurement named there otherwise). A TOML file
holds the same sections and keys (`[tracker]`, `gate_chi2_quantile = 0.99`, ...); an
unknown section or key, a value of the wrong type, or one outside its allowed range
(follow/config_bounds.py, docs/config.md) is an error naming it.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


class ConfigError(ValueError):
    """A configuration file or value that cannot be used; the message names it."""


@dataclass(frozen=True)
class PoseConfig:
    model: str = "human-pose-estimation-0001"
    # The defaults are for a robot following one person 1-8 m away with a 480p-720p
    # camera 0.5-1.5 m up: people 100-450 px tall (docs/pose.md, `follow eval
    # pose-near`). PETS 2009's ~50 px surveillance people need other settings, kept in
    # follow/eval/pets2009.toml.
    # Network input height; the width follows the frame's aspect ratio (multiple of 8).
    # With input_height_from_camera (the default) `follow run` and the ROS 2 node choose
    # it from the camera instead (follow/pose/input_size.py): the height at which a
    # person far_person_height_m tall, far_person_distance_m away, is
    # min_person_input_px tall in the input, within 256-576 px. This value is used
    # without a camera (benchmarks, evaluations on bare videos) or with the rule off.
    input_height_px: int = 368
    input_height_from_camera: bool = True
    far_person_distance_m: float = 8.0
    far_person_height_m: float = 1.6
    # The height in the network input from which the detector finds a person's neck and
    # ankles: 95 % of real crops and more from 85 px with the INT8 model, 74 px with FP32,
    # chosen on the robot-camera crops, checked on CUHK03 (`follow eval pose-near`;
    # docs/pose.md). "auto": the one of the precision that runs (INT8: a 640x480 camera of
    # 60 degrees gets 376 px, a 16:9 one of 70 336 px).
    min_person_input_px: float | str = "auto"
    # While every person in view is larger than that, run a smaller input (down to 256
    # px, where the smallest of them is still min_person_input_px tall: half the time of
    # 368 px), and the full height every full_input_every_frames frames and whenever the
    # last frame found nobody, so that a far newcomer is found within that many frames
    # (follow/pose/people_sized_input.py; docs/pose.md).
    input_height_from_people: bool = True
    full_input_every_frames: int = 6
    provider: str = "auto"  # auto | cpu | cuda | tensorrt | openvino
    # int8: the INT8 model made by `follow models prepare` (user cache), the fast CPU
    # path; auto: that model when it has been made and the CPU has 8-bit dot products
    # (VNNI), else fp32; int8_if_made: that model when it has been made, on any CPU (for
    # settings chosen with it: pets2009.toml), else fp32.
    precision: str = "auto"  # auto | fp32 | int8 | int8_if_made
    # An explicit model file (e.g. an INT8 ONNX from tools/quantize_pose.py); empty = `model`.
    model_file: str = ""
    # 2: the whole network (its refinement stage finds the ankles of people seen large);
    # 1: the initial stage only (follow/pose/stages.py: more small, far people, 0.65x the
    # time; the PETS setting).
    network_stages: int = 2
    cpu_threads: int = 0  # 0 = the runtime's default
    warmup_runs: int = 1
    # A (2 r + 1)-pixel median filter over the frame before it is resized for the
    # network (0 = none): sensor noise and JPEG blocking hide small, far people from it.
    median_filter_radius_px: int = 0
    # Then an unsharp mask: unsharp_amount times the detail finer than unsharp_sigma_px
    # added back (0 = none), steepening outlines that blur and upscaling soften.
    unsharp_amount: float = 0.0
    unsharp_sigma_px: float = 1.0
    keypoint_min_confidence: float = 0.05  # keypoints below this are not used as observations
    min_keypoints_per_person: int = 2  # e.g. neck + one shoulder, joined by their PAF
    border_margin_px: float = 4.0
    # Keypoints within this many heatmap cells (8 network-input px) of the frame's top /
    # bottom edge are dropped (0 = none): there the network puts joints that are beyond
    # the frame (the ankles of feet cut off by the bottom edge, the neck of a head cut off
    # by the top). Half a cell is the outermost row alone; a neck dropped loses the
    # person, an ankle only its range (docs/pose.md, *Joints beyond the frame*).
    top_edge_margin_cells: float = 0.5
    bottom_edge_margin_cells: float = 2.0
    # Decoding (heatmap cells are 8 network-input pixels). The network's published peak
    # threshold; PETS uses 0.03 to keep its small, faint people.
    heatmap_peak_threshold: float = 0.1
    paf_samples: int = 10
    paf_min_sample_score: float = 0.05
    paf_min_sample_fraction: float = 0.5
    min_person_mean_score: float = 0.05
    # One skeleton per body: a skeleton is dropped as a duplicate of a larger one when
    # at least duplicate_shared_keypoints of its keypoints lie within
    # duplicate_keypoint_distance (a fraction of the larger skeleton's extent) of the
    # same keypoints of the larger one, or when duplicate_box_containment of its
    # keypoints lie inside the larger one's keypoint box (a fragment of the same body).
    duplicate_keypoint_distance: float = 0.1
    duplicate_shared_keypoints: int = 2
    duplicate_box_containment: float = 0.8


@dataclass(frozen=True)
class TrackerConfig:
    # Constant-velocity model: white acceleration noise, integrated over the real time step.
    accel_noise_mps2: float = 1.0
    height_noise_mps: float = 0.01
    # Measurement noise at the detector's resolution (scaled with the image).
    neck_noise_px: float = 3.0
    ankle_noise_px: float = 5.0
    detection_height_px: int = 360  # resolution the pixel noises above refer to
    # How far the keypoints wander from the modelled points (posture, gait), in metres:
    # it adds noise that grows in pixels as people come nearer.
    neck_position_noise_m: float = 0.03
    ankle_position_noise_m: float = 0.08  # the midpoint of both ankles
    single_ankle_position_noise_m: float = 0.25  # one ankle alone: half a step off
    # Height of the ankle keypoint over the floor when standing: a shoe sole
    # (ankle_height_m) plus the malleolus, which sits at 0.039 of stature, i.e. 0.048 of
    # the neck height (Drillis and Contini's segment proportions), so it follows each
    # track's own height estimate; and the gait's mean extra lift when walking at or
    # above full_gait_speed_mps (each ankle rises in its swing phase). With a camera low
    # over the floor the ground position is very sensitive to it: at 10 m from a camera
    # 0.6 m up, 1 cm of ankle height moves the ground point by about 0.2 m.
    ankle_height_m: float = 0.025
    ankle_height_per_neck_height: float = 0.048
    walking_ankle_lift_m: float = 0.025
    full_gait_speed_mps: float = 0.6
    # The gait lift at the track's mean speed instead of each sigma point's: a person
    # standing still is then read at their range, not 4 % nearer, but a new track of a
    # walking person (its mean velocity starts at zero) gets no lift until its velocity
    # settles, and in the stranger simulation the returning target was never
    # re-identified in 1 of 10 seeds (docs/tracking.md). Off until that is solved.
    gait_lift_at_mean_speed: bool = False
    init_velocity_std_mps: float = 1.0
    # Population prior on the neck height, fused into a new track's first estimate.
    init_height_std_m: float = 0.1
    default_neck_height_m: float = 1.45
    # Observations implying a neck outside this range cannot be a standing person.
    min_neck_height_m: float = 0.5
    max_neck_height_m: float = 2.5
    # Sigma points nearer to the camera plane than this project as if at this depth.
    min_projection_depth_m: float = 0.3
    # Unscented transform spread (filterpy's MerweScaledSigmaPoints).
    sigma_alpha: float = 1.0
    sigma_beta: float = 2.0
    sigma_kappa: float = 0.0
    gate_chi2_quantile: float = 0.99
    # A track takes no observation whose ground point (from its ankles) lies farther from
    # the track's predicted position than floor_gate_m + floor_gate_per_range x that
    # point's range + 3 x the track's position std, that last at most
    # floor_gate_max_spread_m. The pixel gate alone is no bound for an unseen track near
    # the camera: its sigma points, projected as if at min_projection_depth_m, spread over
    # the whole image, and it took a person 8 m off. Nor is 3 x the std: an unseen
    # track's grows to 1.4 m before it is retired, and the gate took a person 7 m off.
    floor_gate_m: float = 1.5
    floor_gate_per_range: float = 0.25
    floor_gate_max_spread_m: float = 2.0
    # A neck alone (no ankle) updates only a track whose position std is within this plus
    # max_position_std_per_range x its range: a neck gives a bearing, not a range.
    neck_only_max_position_std_m: float = 0.5
    # A detection whose ankles fit no track but whose neck fits a track left unseen
    # updates that track by the neck alone, instead of starting a second track: a person
    # half hidden behind a nearer one is often given the nearer one's feet.
    neck_fallback_association: bool = True
    # A detection in no track's gate whose ankle fits a confirmed track seen in the last
    # tentative_max_unseen_s and left without an observation, its neck above the same
    # feet, updates that track by the ankle alone, instead of starting a new track for a
    # person whose neck moved faster than the height state follows (crouching, sitting).
    # Off: the descent, fused while still in the gate, reads as the person moving away
    # at up to 1.4 m/s, which a follower would drive after; losing the track stops the
    # robot until the target is re-identified (docs/tracking.md).
    ankle_fallback_association: bool = False
    min_updates_to_confirm: int = 3
    # Deletion when the position std exceeds max_position_std_m plus this fraction of the
    # range (far people are always uncertain along the viewing ray).
    max_position_std_m: float = 1.5
    max_position_std_per_range: float = 0.15
    max_unseen_s: float = 2.0
    tentative_max_unseen_s: float = 0.5
    # An unseen track whose predicted neck lies outside the image is deleted after this
    # long. A robot keeps it as long as any other (max_unseen_s): it turns towards a
    # target that stepped out of the view. A fixed camera never sees that person again
    # under this track: set it low (pets2009.toml).
    max_unseen_outside_view_s: float = 2.0
    # Observations this far outside the image are rejected as broken input.
    max_outside_image_px: float = 2.0


@dataclass(frozen=True)
class IdentifyConfig:
    # ccf10 | ccf25 | channels | reid | ccf10+reid | ccf25+reid | channels+reid. With
    # re-id, re-identification needs absolute evidence (reid_accept_similarity).
    identifier: str = "ccf10+reid"
    # Online boosting (Grabner & Bischof): S selectors of W weak classifiers each.
    num_selectors: int = 15
    weak_classifiers_per_selector: int = 15
    sample_bank_size: int = 32  # recent positives and negatives kept (each)
    rect_min_fraction: float = 0.2  # weak classifier rectangle side, fraction of the map
    rect_max_fraction: float = 0.5
    replace_probability: float = 0.5  # per selector and update: swap out its worst classifier
    gaussian_memory_samples: float = 30.0  # effective sample count of a class Gaussian
    min_feature_std: float = 0.01  # floor of a class Gaussian's std (features in [0, 1])
    selector_error_decay: float = 0.99  # forgetting factor of the selectors' error counts
    # Learn with numba's compiled loops (the `numba` extra): the same classifier, an
    # update 3.4x faster (about 1 ms a frame with five people), but numba's compiler stays
    # resident: about 105 MB more memory.
    compiled_boosting: bool = False
    # Target state machine.
    initial_training_frames: int = 10
    max_initial_distance_m: float = 5.0
    id_switch_confidence: float = -0.1
    reid_confidence: float = 0.2
    reid_frames: int = 5
    reid_margin: float = 0.0  # re-identification: lead over every other track, each frame
    # Re-identification names only a track the target could have walked to since it was
    # last named: within reid_reach_m plus reid_reach_speed_mps per second of its track's
    # last position on the floor (a look-alike across the room is not the person who vanished
    # half a second ago; after a long absence the whole view qualifies).
    reid_reach_m: float = 1.5
    reid_reach_speed_mps: float = 2.0
    # Learning is skipped where the target's crop shows more than one person: no frame is
    # learnt while another person's box covers more than this fraction of the target's.
    max_learning_overlap: float = 0.3
    # A low confidence means another person only where the tracker could have swapped
    # them: when another track came within identity_risk_distance_m of the target on
    # the floor, or the target's track went unseen for identity_risk_unseen_s, within
    # identity_trust_s. Otherwise (a person turning round, say) the frame is only not
    # learnt, and the tracker's identity is kept. Frames handed to the identifier more
    # than identity_risk_unseen_s apart (perception stalled) count as the track unseen
    # for the gap: the tracker matches it again at once, perhaps on someone else.
    identity_trust_s: float = 1.5
    identity_risk_distance_m: float = 1.0
    identity_risk_unseen_s: float = 0.5
    # While the identity is at risk (as above), a frame is learnt only where no other
    # track seen scores higher than the target's own: right after a crossing or a gap the
    # tracker may carry a stranger on the target's track (the target on another), and
    # learning them at a middling confidence teaches the model the stranger. "with_reid":
    # only beside a re-id cue (the classifier alone scores others too unsteadily: the
    # rule cost ccf10 alone on PETS); "always"; "never".
    learn_needs_lead_at_risk: str = "with_reid"
    # A track becomes the target (first choice or re-identification) only while it is
    # seen in the frame and after it has been seen in this many frames: a ghost track
    # made of a few split skeletons is never followed.
    min_target_observations: int = 5
    # Absolute evidence (identifiers with re-id): a re-identification candidate's highest
    # cosine similarity to the target's gallery must reach the bar in each of reid_frames
    # frames, however far it leads the others. The bar rises linearly from
    # reid_accept_similarity to reid_strict_similarity while the target stays away for
    # reid_strict_after_s: the longer it is gone, the more strangers pass by. Calibrated
    # by `follow eval verification` on CUHK03's even identities (false accepts 1 % and
    # 0.1 % of other people's crops across two cameras).
    reid_accept_similarity: float = 0.60
    reid_strict_similarity: float = 0.71
    # The confidence bar (reid_confidence) rises the same way, to reid_strict_confidence:
    # in simulation a stranger in the target's shirt scores 0.4-0.5 with ccf10, the
    # target itself 0.8-1.0 (`follow eval identification-sim`).
    reid_strict_confidence: float = 0.6
    reid_strict_after_s: float = 15.0
    # With two cues (ccf10+reid) each must reach the confidence bar, not only their
    # mean: a re-id network vouching for a stranger in the target's clothes then cannot
    # carry a classifier that doubts them. Costs re-acquisitions where the classifier
    # is weak (PETS's 50-px people; docs/identification.md).
    reid_cues_must_agree: bool = True
    # Unless the re-id network alone is decisive among the people in view: a candidate
    # seen in the frame the target was lost in whose similarity to the gallery reaches
    # the bar and exceeds every other person's seen in the same frame by this much passes
    # without the classifier's vote (0 = never). A change of focus or light can leave
    # the classifier doubting the target for good while re-id still tells it from
    # everyone present (docs/identification.md); a newcomer, or anyone alone in view,
    # needs each cue to agree as before. Chosen on PETS blurred and darkened, checked on
    # the other variants, the unchanged video and the simulated strangers.
    reid_decisive_margin: float = 0.15
    # Clothes can match; stature rarely does: a candidate whose estimated neck height
    # differs from the target's last estimate by more than this and
    # reid_height_tolerance_stds of the two estimates' combined std, added in quadrature,
    # is not the target. Posture and where the network puts
    # the neck, front or back, move one person's estimate by 1-2 cm; a camera pitch
    # 0.06 deg off (follow-calib, rendered views) by about 1 cm between 2 and 8 m.
    # Chosen on seeds 0-4 of `follow eval identification-sim`, checked on seeds 5-9 and
    # PETS 2009 (docs/identification.md); a base that pitches hard when braking, or an
    # uncalibrated camera, needs more.
    reid_height_tolerance_m: float = 0.03
    # The filter's part of that allowance: a new track's estimate starts wide and needs
    # the room; a settled one's std is the filter's floor (height_noise_mps), about 1.4
    # cm at the robot's distances, 3-5 cm for PETS's far people. The two parts are
    # independent errors, so they add in quadrature: added up, they let the twin 5 cm
    # taller through at 3 m (docs/identification.md, *Stature in quadrature*).
    reid_height_tolerance_stds: float = 2.0
    # Every part must match: a candidate's torso and legs must each be within this
    # colour distance (Hellinger, 0-1; 1 turns the rule off) of the colours the target
    # was seen in, so that a stranger in the target's shirt and other trousers is not
    # taken for it. The distance within which 99 % of one person's crops stay, in their
    # least alike part, of their other crops from the same camera, also under the
    # perturbation suite's changes of light, focus and compression (`follow eval
    # verification`, CUHK03's even identities: 0.423).
    reid_part_colour_distance: float = 0.42
    # A re-identified target is on probation this long: the stature test runs again every
    # frame on its settling estimate (a new track's starts wide), and a failure sends it
    # back to re-identification for good, undoing what it taught the model.
    reid_probation_s: float = 2.0
    # Two people seen at once are two people: a track seen beside the target while its
    # identity was confirmed (apart from it: farther than identity_risk_distance_m, the
    # boxes not touching, ever since) is never taken for the target come back.
    reid_excludes_seen_beside: bool = True
    # Online boosting never learns the target from positives alone (it would then call
    # anyone the target): a frame with fewer other people than this is topped up with
    # colour-changed copies of the target's crop as negatives (brightness inverted, hue
    # turned in steps round the circle), which teach it that the target's colours matter.
    min_negatives_per_update: int = 6
    # The target's crop mirrored left-right is learnt as a positive too (the boosted
    # classifier only): seen from its other side, the target wears the same clothes.
    # "with_reid": only beside a re-id cue, where the classifier's part is to veto and a
    # veto keyed on which side a colour is holds the real target back; alone, the
    # classifier must reject strangers by itself, and mirroring loosens it (measured:
    # docs/identification.md, Mirrored positives). "always" | "never".
    mirrored_positives: str = "with_reid"
    seed: int = 0
    # Region of interest cut from a track's neck and ankle pixels.
    crop_height_px: int = 128  # every ROI is resized to this before feature extraction
    crop_width_px: int = 48
    feature_threads: int = 1  # onnxruntime threads of the CCF network
    roi_height_per_neck_ankle: float = 1.35  # ROI height / neck-ankle distance
    roi_width_per_neck_ankle: float = 0.5  # ROI width / neck-ankle distance
    roi_center_offset_per_neck_ankle: float = -0.05  # centre shift along neck->ankle (up < 0)
    neck_ankle_per_neck_hip: float = 2.7  # body proportion used when no ankle is known
    min_roi_height_px: float = 24.0  # smaller ROIs (in the image) are skipped
    min_roi_visible_fraction: float = 0.5  # ROIs more clipped than this are skipped
    # Deep re-id second opinion (identifier "reid" or "*+reid").
    reid_gallery_size: int = 64  # target embeddings kept (the most redundant one goes)
    reid_same_similarity: float = 0.5  # cosine similarity mapped to confidence 0
    reid_similarity_scale: float = 0.25  # similarity span mapped to confidence +-1
    reid_weight: float = 0.5  # weight of the re-id confidence in a fused confidence
    reid_threads: int = 1  # CPU threads of the re-id network (onnxruntime or OpenVINO)
    # Where the re-id network runs: "cpu" = on OpenVINO where the openvino package is
    # installed (1.5x onnxruntime's speed, the same embeddings), else on onnxruntime;
    # "onnxruntime" (its CPU provider always), "openvino", "cuda", or "auto" = CUDA when
    # onnxruntime offers it, else as "cpu". The CPU by default: on CUDA it gained nothing
    # measurable (docs/pose.md).
    reid_provider: str = "cpu"


@dataclass(frozen=True)
class ControlConfig:
    # Following distance: the 1.5-3 m band a walking person accepts behind them.
    following_distance_m: float = 1.8
    max_forward_speed_mps: float = 1.5  # above a brisk walk, so the robot can catch up
    max_backward_speed_mps: float = 0.3
    allow_backing_off: bool = False
    max_yaw_rate_radps: float = 1.0
    max_forward_accel_mps2: float = 1.5
    # Braking may be harder than speeding up; a stop on loss/stale ignores both limits.
    max_forward_decel_mps2: float = 2.0
    max_yaw_accel_radps2: float = 3.0
    # Proportional gains: forward speed per metre of distance error, yaw rate per radian.
    distance_gain_per_s: float = 1.5
    bearing_gain_per_s: float = 1.5
    # Fraction of the target's own motion fed forward (radial speed, bearing rate).
    velocity_feedforward_gain: float = 1.0
    turn_in_place_bearing_rad: float = 0.7
    # A target estimate whose last observation is older than this is lost (zero command).
    target_timeout_s: float = 0.5
    # While the target is not seen in the newest frame, the forward speed limit falls
    # linearly to zero this long after its last observation; meanwhile the robot only
    # turns toward the predicted bearing, at most at search_yaw_rate_radps.
    max_blind_drive_s: float = 0.5
    # The control loop stops the base when perception has produced no result this long.
    watchdog_timeout_s: float = 0.5
    # A live camera that delivers no frame this long ends the run with an error: the
    # watchdog has long stopped the base, but a run that waits forever on a hung camera
    # says nothing. 0 waits forever.
    camera_stall_timeout_s: float = 5.0
    # `follow run --target-id N`: warn when track N has not appeared after this long.
    missing_target_warn_s: float = 5.0
    # After a loss, turn toward the last bearing for this long (0 = stop at once).
    search_duration_s: float = 0.0
    search_yaw_rate_radps: float = 0.4
    control_rate_hz: float = 15.0
    # Run the next frame's pose inference while this frame is tracked, identified and
    # written (two frames in flight at most). "auto": where the pose network runs on a
    # GPU (CUDA, TensorRT), which then infers while the CPU does the rest; in turn on a
    # CPU, where the network already keeps every core busy and overlapping gained 1-5 %
    # of frame rate for 18-30 % more p95 latency (docs/system.md). true | false.
    overlap_stages: bool | str = "auto"


@dataclass(frozen=True)
class MavlinkConfig:
    connection: str = ""  # pymavlink connection string; empty = no base
    autopilot: str = "ardupilot"  # ardupilot | px4
    arm: bool = False
    heartbeat_timeout_s: float = 3.0
    stream_rate_hz: float = 20.0  # velocity setpoints per second (>= 10)
    telemetry_rate_hz: float = 30.0  # requested LOCAL_POSITION_NED / ATTITUDE rate
    connect_timeout_s: float = 10.0  # first heartbeat, mode change acknowledgement
    command_timeout_s: float = 0.5  # a velocity command older than this is replaced by zero
    odometry_timeout_s: float = 0.5  # odometry older than this is not returned
    source_system: int = 1
    source_component: int = 191  # MAV_COMP_ID_ONBOARD_COMPUTER
    # PX4 rovers ignore yaw rate: the turn becomes the direction of the body velocity,
    # pointing where the commanded turn would take the heading within this horizon.
    px4_turn_horizon_s: float = 0.5


@dataclass(frozen=True)
class RosConfig:
    """Topics and safety bounds of `follow ros2` (a bag's streams are named by `follow run`'s
    `--*-topic` options)."""

    # A topic ending in /compressed carries sensor_msgs/CompressedImage, any other Image.
    image_topic: str = "/camera/image_raw"
    camera_info_topic: str = "/camera/camera_info"  # empty = intrinsics from the camera file
    odom_topic: str = "/odom"
    cmd_vel_topic: str = "/cmd_vel"
    odom_frame: str = "odom"  # frame of the published target and tracks
    publish_cmd_vel: bool = False  # drive the base directly (else only feed Nav2)
    publish_annotated_image: bool = False
    # An image older than this (by its stamp) when the controller runs stops the base.
    max_image_age_s: float = 0.5
    # Odometry is matched to an image's stamp within this gap; newer than this is needed
    # for any non-zero cmd_vel.
    max_odometry_age_s: float = 0.2
    diagnostics_period_s: float = 1.0


@dataclass(frozen=True)
class Config:
    pose: PoseConfig = field(default_factory=PoseConfig)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    identify: IdentifyConfig = field(default_factory=IdentifyConfig)
    control: ControlConfig = field(default_factory=ControlConfig)
    mavlink: MavlinkConfig = field(default_factory=MavlinkConfig)
    ros: RosConfig = field(default_factory=RosConfig)

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        """Raise ConfigError listing, one line each, every key outside its allowed range
        (follow/config_bounds.py); every Config, the defaults included, passes here."""
        from follow.config_bounds import section_errors

        errors = [
            line
            for f in dataclasses.fields(self)
            for line in section_errors(f.name, getattr(self, f.name))
        ]
        if errors:
            raise ConfigError("\n".join(errors))

    @classmethod
    def from_dict(cls, data: dict, source: str = "config", base: Config | None = None) -> Config:
        """The config `data` describes; keys it leaves out keep `base`'s values (the
        defaults when no base is given)."""
        base = base if base is not None else cls()
        sections = {f.name: f.type for f in dataclasses.fields(cls)}
        kwargs = {}
        for name, values in data.items():
            if name not in sections:
                raise ConfigError(f"{source}: unknown section [{name}]; known: {sorted(sections)}")
            if not isinstance(values, dict):
                raise ConfigError(f"{source}: [{name}] must be a table")
            kwargs[name] = _build_section(getattr(base, name), values, f"{source} [{name}]")
        try:
            return dataclasses.replace(base, **kwargs)
        except ConfigError as exc:
            raise ConfigError(
                "\n".join(f"{source}: {line}" for line in str(exc).splitlines())
            ) from None

    @classmethod
    def load(cls, path: str | Path, base: Config | None = None) -> Config:
        """A TOML file over `base` (or the defaults)."""
        path = Path(path)
        try:
            data = tomllib.loads(path.read_text(encoding="utf-8-sig"))  # a byte order mark is dropped
        except OSError as exc:
            raise ConfigError(f"config {path}: cannot read ({exc.strerror})") from None
        except UnicodeDecodeError as exc:
            raise ConfigError(
                f"config {path}: not a text config file (TOML; not UTF-8 at byte {exc.start})"
            ) from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"config {path}: not valid TOML ({exc})") from None
        config = cls.from_dict(data, source=f"config {path}", base=base)
        pose = data.get("pose")
        model_file = pose.get("model_file") if isinstance(pose, dict) else None
        if model_file:  # a file named by this config is found beside it, wherever one runs
            resolved = path.parent / Path(model_file).expanduser()
            config = config.replace("pose", model_file=str(resolved))
        return config

    def replace(self, section: str, **changes) -> Config:
        """A copy with some keys of one section changed."""
        return dataclasses.replace(
            self, **{section: dataclasses.replace(getattr(self, section), **changes)}
        )


_TYPE_NAMES = {"bool": bool, "int": int, "float": float, "str": str}


def field_types(section_cls, key: str, default_type: type) -> tuple[type, ...]:
    """The types a key takes: those of its annotation where it names several
    (`bool | str`: a switch with an "auto" choice), else its default's."""
    annotation = next(f.type for f in dataclasses.fields(section_cls) if f.name == key)
    names = [n.strip() for n in str(annotation).split("|")]
    if len(names) > 1 and all(n in _TYPE_NAMES for n in names):
        return tuple(_TYPE_NAMES[n] for n in names)
    return (default_type,)


def _build_section(defaults, values: dict, where: str):
    """`defaults` (a section instance) with the keys in `values`, type-checked."""
    section_cls = type(defaults)
    known = {f.name for f in dataclasses.fields(section_cls)}
    out = {}
    for key, value in values.items():
        if key not in known:
            raise ConfigError(f"{where}: unknown key '{key}'; known: {sorted(known)}")
        expected = field_types(section_cls, key, type(getattr(defaults, key)))
        if float in expected and isinstance(value, int) and not isinstance(value, bool):
            try:
                value = float(value)
            except OverflowError:  # TOML integers are unbounded: past a float, infinite
                value = math.inf if value > 0 else -math.inf
        if not isinstance(value, expected) or (bool not in expected and isinstance(value, bool)):
            names = " or ".join(t.__name__ for t in expected)
            raise ConfigError(f"{where}: '{key}' must be {names}, got {type(value).__name__}")
        out[key] = value
    return dataclasses.replace(defaults, **out)
