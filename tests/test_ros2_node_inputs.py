"""What the ROS 2 node does with input it cannot use: odometry that is NaN, has no
orientation or is in another frame is dropped (the node lives on; without fresh
odometry the base stops), and an image whose size or camera_info differs from the one
perception started with is refused rather than placed on the floor with the wrong
camera. In process, with a stand-in detector; runs where rclpy imports."""

from __future__ import annotations

import contextlib
import itertools
import threading
import time

import numpy as np
import pytest
from ros2_support import isolated_rclpy, skip_without_ros2

from follow.camera import CameraModel, CameraPose
from follow.config import Config
from follow.rosmsg import camera_info_fields, image_fields, quaternion_of_yaw, stamp_fields

try:
    import rclpy  # noqa: F401 - the import is the check
    from builtin_interfaces.msg import Time
    from nav_msgs.msg import Odometry as OdometryMsg
    from sensor_msgs.msg import CameraInfo, Image
    from std_msgs.msg import Header

    from follow.ros2.node import FollowNode
except ImportError as exc:  # pragma: no cover - depends on the installation
    skip_without_ros2(exc)

CAMERA = CameraModel.from_fov((320, 240), 70.0, CameraPose(height_m=1.0))


ros_context = pytest.fixture(scope="module", autouse=True)(isolated_rclpy)


_FILLS = itertools.count()  # a new picture for each image message


@pytest.fixture
def node():
    config = Config().replace("identify", identifier="channels")  # no model files needed
    made = FollowNode(config.replace("ros", publish_cmd_vel=True), CAMERA,
                      detect=lambda frame: [])  # fmt: skip
    yield made
    made.shutdown()
    made.destroy_node()


def _header(stamp_s: float, frame_id: str) -> Header:
    return Header(stamp=Time(**stamp_fields(stamp_s)), frame_id=frame_id)


def _odometry(stamp_s: float, x_m: float = 0.0, frame_id: str = "odom", quaternion=None):
    msg = OdometryMsg(header=_header(stamp_s, frame_id), child_frame_id="base_link")
    msg.pose.pose.position.x = x_m
    q = quaternion or quaternion_of_yaw(0.0)
    o = msg.pose.pose.orientation
    o.x, o.y, o.z, o.w = q["x"], q["y"], q["z"], q["w"]
    return msg


def _image(stamp_s: float, width: int, height: int, fill: int | None = None) -> Image:
    """An image message; each its own picture (as a sensor's noise makes them) unless
    `fill` gives it one."""
    fill = next(_FILLS) % 256 if fill is None else fill
    fields = image_fields(np.full((height, width, 3), fill, np.uint8))
    return Image(header=_header(stamp_s, "camera"), **{**fields, "data": fields["data"].tobytes()})


@pytest.mark.parametrize("bad", [
    {"x_m": float("nan")},
    {"quaternion": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 0.0}},  # orientation never filled in
])  # fmt: skip
def test_unusable_odometry_is_dropped_and_the_node_lives_on(node, bad):
    now = node.now_s()
    node._on_odometry(_odometry(now, **bad))  # raised out of the callback: the node died
    assert node.odometry_dropped == 1 and not node.gate.healthy()
    node._on_odometry(_odometry(now + 0.01))
    assert node.gate.healthy()


def test_the_controller_knows_the_field_of_view_as_in_follow_run(node):
    """Without it a target predicted outside the image is driven towards blind, where
    `follow run` only turns (`ViewCone`)."""
    from follow.control.target import ViewCone

    now = node.now_s()
    node._on_odometry(_odometry(now))
    node._on_camera_info(CameraInfo(header=_header(now, "camera"), **camera_info_fields(CAMERA)))
    assert node._detect_in(_image(now - 0.05, 320, 240)) is not None
    view = node.control.controller.view
    assert view is not None and view == ViewCone.from_camera(node.perception.tracker.camera)
    assert not view.contains(np.array([3.0, 2.3]))  # 37 degrees left, the image's edge at 35


def test_odometry_in_another_frame_than_ros_odom_frame_is_not_used(node):
    now = node.now_s()
    node._on_odometry(_odometry(now, frame_id="map"))
    assert node.odometry.at(now) is None and not node.gate.healthy()
    assert node.odometry_dropped == 1
    node._on_odometry(_odometry(now + 0.01, frame_id="/odom"))  # the same frame, written so
    assert node.gate.healthy()


def test_odometry_stamped_ahead_of_the_clock_is_dropped_and_counted(node):
    """A base driver whose clock runs ahead: its poses are not fresh (no cmd_vel), and
    the node says why instead of keeping them where images look for their pose."""
    now = node.now_s()
    node._on_odometry(_odometry(now + 3.0))
    assert node.odometry_dropped == 1 and len(node.odometry) == 0 and not node.gate.healthy()
    node._on_odometry(_odometry(now + 0.01))
    assert node.odometry_dropped == 1 and node.gate.healthy()


def test_odometry_without_a_stamp_is_dropped_by_name(node, capfd):
    """A base driver that leaves header.stamp at zero: its poses are never fresh, so the
    base stays stopped; the node must say why, not only that images find no odometry."""
    capfd.readouterr()
    node._on_odometry(_odometry(0.0))
    assert node.odometry_dropped == 1 and len(node.odometry) == 0 and not node.gate.healthy()
    warning = [line for line in capfd.readouterr().err.splitlines() if "no stamp" in line]
    assert len(warning) == 1 and "WARN" in warning[0]
    assert "odometry dropped: its header has no stamp (zero)" in warning[0]
    node._on_odometry(_odometry(node.now_s()))
    assert node.odometry_dropped == 1 and node.gate.healthy()


@contextlib.contextmanager
def _images_only_node():
    """A node on images alone (no odometry, camera_info or cmd_vel), the camera file's
    intrinsics, a stand-in detector; shut down after."""
    config = Config().replace("identify", identifier="channels")
    node = FollowNode(config.replace("ros", odom_topic="", publish_cmd_vel=False,
                                     camera_info_topic=""),
                      CAMERA, detect=lambda frame: [])  # fmt: skip
    try:
        yield node
    finally:
        node.shutdown()
        node.destroy_node()


def test_an_image_of_another_size_mid_run_is_refused():
    with _images_only_node() as node:
        now = node.now_s()
        assert node._detect_in(_image(now - 0.2, 320, 240)) is not None
        assert node._detect_in(_image(now - 0.1, 400, 300)) is None  # the camera switched mode
        assert node.perception.tracker.camera.image_size == (320, 240)
        assert node._detect_in(_image(now, 320, 240)) is not None


def test_one_image_stamped_ahead_of_the_clock_does_not_block_the_images_after_it():
    """Taken as the last one processed, a glitched stamp far ahead would make every
    correct image after it look out of order, and be dropped for as long as the offset."""
    with _images_only_node() as node:
        now = node.now_s()
        assert node._detect_in(_image(now + 3600.0, 320, 240)) is None
        assert node._detect_in(_image(now - 0.05, 320, 240)) is not None
        assert node._detect_in(_image(now, 320, 240)) is not None


def test_the_same_image_stamped_anew_is_dropped_as_a_frozen_driver():
    """A frozen camera driver that republishes its last image with a new stamp would pass
    old news for fresh: the repeat is dropped (counted stale), and a new image is taken."""
    with _images_only_node() as node:
        now = node.now_s()
        assert node._detect_in(_image(now - 0.2, 320, 240, fill=7)) is not None
        assert node._detect_in(_image(now - 0.1, 320, 240, fill=7)) is None
        assert node.stale_frames == 1
        assert node._detect_in(_image(now, 320, 240, fill=8)) is not None


def test_images_without_a_stamp_are_refused_by_name(capfd):
    """A driver that leaves header.stamp at zero: taken, the first such image would be
    the last one processed, and every later one dropped as out of order in silence."""
    with _images_only_node() as node:
        capfd.readouterr()
        assert node._detect_in(_image(0.0, 320, 240)) is None
        assert node.stale_frames == 1 and node._last_stamp is None
        warning = [line for line in capfd.readouterr().err.splitlines() if "no stamp" in line]
        assert len(warning) == 1 and "WARN" in warning[0]
        assert "image dropped: its header has no stamp (zero)" in warning[0]
        assert node._detect_in(_image(node.now_s(), 320, 240)) is not None


def test_an_image_too_small_is_dropped_by_name_and_fixes_no_camera(capfd):
    """A 4x3 image fixed the camera perceived with before Frame refused it: every image of
    the real camera after it was refused as 'the camera changed', until a restart."""
    with _images_only_node() as node:
        now = node.now_s()
        capfd.readouterr()
        assert node._detect_in(_image(now - 0.2, 4, 3)) is None
        warning = [line for line in capfd.readouterr().err.splitlines() if "dropped" in line]
        assert len(warning) == 1 and "WARN" in warning[0], warning
        assert "image dropped: frame image: too small (4x3)" in warning[0]
        assert node._camera_key is None and node._last_stamp is None
        assert node._detect_in(_image(now - 0.1, 320, 240)) is not None
        assert node.perception.tracker.camera.image_size == (320, 240)


def test_a_topic_that_delivers_nothing_is_named_on_the_console(capfd):
    """A typo in ros.image_topic left the node silent: its diagnostics said it, the
    console did not."""
    with _images_only_node() as node:
        node.pub_diagnostics.publish = lambda msg: None
        capfd.readouterr()
        node._publish_diagnostics()
        warning = [line for line in capfd.readouterr().err.splitlines() if "received" in line]
        assert len(warning) == 1 and "WARN" in warning[0]
        assert f"no image received on {node.config.ros.image_topic} yet" in warning[0]
        assert "odometry" not in warning[0]  # no odometry topic on this node
        assert node._warn_of_silent_topics() == [node.config.ros.image_topic]
        node._on_image_msg(_image(node.now_s(), 320, 240))
        assert node.images_received == 1 and node._warn_of_silent_topics() == []


def test_a_camera_info_that_changes_mid_run_is_refused():
    config = Config().replace("identify", identifier="channels")
    node = FollowNode(config.replace("ros", odom_topic="", publish_cmd_vel=False,
                                     camera_info_topic="camera_info"),
                      CAMERA, detect=lambda frame: [])  # fmt: skip
    try:
        info = CameraInfo(header=_header(0.0, "camera"), **camera_info_fields(CAMERA))
        node._on_camera_info(info)
        now = node.now_s()
        assert node._detect_in(_image(now - 0.1, 320, 240)) is not None
        zoomed = CameraInfo(header=_header(0.0, "camera"),
                            **camera_info_fields(CameraModel.from_fov((320, 240), 50.0,
                                                                      CAMERA.pose)))  # fmt: skip
        node._on_camera_info(zoomed)
        assert node._detect_in(_image(now, 320, 240)) is None
    finally:
        node.shutdown()
        node.destroy_node()


def test_what_the_node_publishes_about_an_image_carries_its_stamp_to_the_nanosecond():
    """Float seconds are ~0.2 us apart at today's epoch: outputs stamped from them would
    not match their image in an exact-time synchroniser."""
    config = Config().replace("identify", identifier="channels")
    node = FollowNode(config.replace("ros", odom_topic="", publish_cmd_vel=False,
                                     camera_info_topic="", publish_annotated_image=True),
                      CAMERA, detect=lambda frame: [])  # fmt: skip
    published = []
    for publisher in (node.pub_tracks, node.pub_markers, node.pub_image):
        publisher.publish = published.append
    try:
        msg = _image(0.0, 320, 240)
        msg.header.stamp = Time(sec=int(node.now_s()) - 1, nanosec=123_456_789)  # not ahead
        node._conclude(*node._detect_in(msg))
        stamps = [m.markers[0].header.stamp if hasattr(m, "markers") else m.header.stamp
                  for m in published]  # fmt: skip
        assert len(stamps) == 3
        assert {(s.sec, s.nanosec) for s in stamps} == {(msg.header.stamp.sec, 123_456_789)}
    finally:
        node.shutdown()
        node.destroy_node()


def test_a_target_unseen_longer_than_the_target_timeout_is_not_published_for_nav2():
    """The tracker predicts a hidden target on for up to `tracker.max_unseen_s`; stamped
    with each new image, that pose would lead the following server after a phantom
    long after the controller took the target for lost."""
    from follow.pipeline import FrameResult
    from follow.types import Odometry, TargetEstimate, TargetStatus, TrackState

    config = Config().replace("identify", identifier="channels")
    node = FollowNode(config.replace("ros", odom_topic="", publish_cmd_vel=False,
                                     camera_info_topic=""),
                      CAMERA, detect=lambda frame: [])  # fmt: skip
    published = []
    node.pub_target.publish = published.append
    timeout_s = node.config.control.target_timeout_s
    try:
        msg = _image(node.now_s(), 320, 240)
        frame, *_ = node._detect_in(msg)
        for unseen_s in (0.0, timeout_s + 0.5):
            track = TrackState(3, np.array([3.0, 0.0, 1.0, 0.0, 1.5]), np.eye(5) * 0.01, True,
                               frame.stamp_s - unseen_s)  # fmt: skip
            result = FrameResult(0, frame.stamp_s, Odometry.origin(frame.stamp_s), [], [track],
                                 TargetEstimate(TargetStatus.TRACKING, 3, {3: 0.9}, frame.stamp_s))  # fmt: skip
            node._publish(result, frame.image, True, msg.header, node._choices)
            assert len(published) == 1, f"unseen for {unseen_s} s"
    finally:
        node.shutdown()
        node.destroy_node()


def test_diagnostics_survive_a_frame_concluded_while_they_are_read():
    """The perception thread records each frame's timing while the executor's timer reads
    the recent ones for /diagnostics: read in place, a frame concluded meanwhile raised
    'deque mutated during iteration' out of the timer, and the executor ended the node."""
    import sys
    import threading

    config = Config().replace("identify", identifier="channels")
    node = FollowNode(config.replace("ros", odom_topic="", publish_cmd_vel=False,
                                     camera_info_topic=""),
                      CAMERA, detect=lambda frame: [])  # fmt: skip
    node.pub_diagnostics.publish = lambda msg: None
    switch_interval_s = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # threads switch as often as a loaded robot computer may
    stop = threading.Event()

    def conclude_frames():
        while not stop.is_set():
            node._recent.append((time.monotonic(), {"pose": 1.0}))

    appender = threading.Thread(target=conclude_frames, daemon=True)
    try:
        for _ in range(300):
            node._recent.append((time.monotonic(), {"pose": 1.0}))
        appender.start()
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            node._publish_diagnostics()
    finally:
        stop.set()
        appender.join(2.0)
        sys.setswitchinterval(switch_interval_s)
        node.shutdown()
        node.destroy_node()


def test_the_pose_network_is_warmed_up_at_the_camera_s_image_size(monkeypatch):
    """A runtime that compiles one model per input shape (OpenVINO) does it for every
    input height before the first image, not on the images of each height as it comes."""
    from pathlib import Path

    from follow.pose import detector as detector_module

    sizes = []

    class Detector:
        model_path = Path("pose.onnx")
        backend_name = "openvino:CPU"

        def __init__(self, config, model_path=None, frame_size=(640, 480)):
            sizes.append(frame_size)

        def detect(self, image):
            return []

    monkeypatch.setattr(detector_module, "PoseDetector", Detector)
    made = FollowNode(Config().replace("identify", identifier="channels"), CAMERA)
    try:
        assert sizes == [CAMERA.image_size] == [(320, 240)]
    finally:
        made.shutdown()
        made.destroy_node()


def test_selecting_another_target_stops_the_base_until_a_frame_is_concluded_for_it(
    monkeypatch,
):
    """The newest result tracks the target chosen before `~/select_target`: driving on it
    would take the robot toward the person the operator just chose against, until the
    next frame (up to `ros.max_image_age_s` on a slow pipeline)."""
    from std_msgs.msg import Int32

    from follow import pipeline
    from follow.types import Observation, Odometry, TargetEstimate, TargetStatus, TrackState

    monkeypatch.setattr(pipeline.ControlLoop, "_run", lambda loop: loop._stop.wait())  # tick here
    config = Config().replace("identify", identifier="channels")
    node = FollowNode(config.replace("ros", publish_cmd_vel=True), CAMERA, detect=lambda f: [])
    seen = Observation(np.array([160.0, 100.0]), np.array([160.0, 200.0]))
    try:
        now = node.now_s()
        node._on_odometry(_odometry(now))
        track = TrackState(7, np.array([4.0, 0.0, 0.0, 0.0, 1.5]), np.eye(5) * 0.01, True, now,
                           observation=seen)  # fmt: skip
        node.results.put(pipeline.FrameResult(0, now, Odometry.origin(now), [], [track],
                         TargetEstimate(TargetStatus.TRACKING, 7, {7: 0.9}, now)))  # fmt: skip
        assert node.control.tick().forward_mps > 0  # following track 7
        node._on_select_target(Int32(data=3))
        assert node.control.tick().is_stop and node.gate.last_sent.is_stop
    finally:
        node.shutdown()
        node.destroy_node()


def _drive_toward_a_target(node, twists: list) -> None:
    """Fresh odometry and a result tracking target 7, seen 4 m ahead: a tick drives toward
    it, and cmd_vel says so."""
    from follow import pipeline
    from follow.types import Observation, Odometry, TargetEstimate, TargetStatus, TrackState

    now = node.now_s()
    node._on_odometry(_odometry(now))
    seen = Observation(np.array([160.0, 100.0]), np.array([160.0, 200.0]))
    track = TrackState(7, np.array([4.0, 0.0, 0.0, 0.0, 1.5]), np.eye(5) * 0.01, True, now,
                       observation=seen)  # fmt: skip
    node.results.put(pipeline.FrameResult(0, now, Odometry.origin(now), [], [track],
                     TargetEstimate(TargetStatus.TRACKING, 7, {7: 0.9}, now)))  # fmt: skip
    assert node.control.tick().forward_mps > 0 and twists[-1].linear.x > 0


def test_a_command_computed_while_another_target_is_selected_is_not_sent(monkeypatch):
    """A control tick that took the newest result just before `~/select_target` dropped it
    computes a command toward the target chosen before: zero goes on cmd_vel instead."""
    from std_msgs.msg import Int32

    from follow import pipeline

    monkeypatch.setattr(pipeline.ControlLoop, "_run", lambda loop: loop._stop.wait())  # tick here
    config = Config().replace("identify", identifier="channels")
    node = FollowNode(config.replace("ros", publish_cmd_vel=True), CAMERA, detect=lambda f: [])
    twists: list = []
    node.pub_cmd_vel.publish = twists.append
    controller = node.control.controller
    computing, release = threading.Event(), threading.Event()

    def update(target, stamp_s):  # the command computed, then held before it is sent
        command = type(controller).update(controller, target, stamp_s)
        computing.set()
        release.wait(5.0)
        return command

    ticking = threading.Thread(target=node.control.tick, daemon=True)
    try:
        _drive_toward_a_target(node, twists)
        monkeypatch.setattr(controller, "update", update)
        before = len(twists)
        ticking.start()
        assert computing.wait(5.0)
        node._on_select_target(Int32(data=3))
        release.set()
        ticking.join(5.0)
        assert not ticking.is_alive()
    finally:
        release.set()
        node.shutdown()
        node.destroy_node()
    held = twists[before]  # the held tick's command, published after the selection
    assert held.linear.x == 0.0 and held.angular.z == 0.0, f"cmd_vel: {held.linear.x} m/s"


def _node_and_a_frame_in_perception(monkeypatch):
    """A node whose control loop ticks only when a test says (its twists recorded), and a
    thread (not started) that holds the perception lock as a frame being tracked and
    identified does, from `held` until `release`."""
    from follow import pipeline

    monkeypatch.setattr(pipeline.ControlLoop, "_run", lambda loop: loop._stop.wait())  # tick here
    config = Config().replace("identify", identifier="channels")
    node = FollowNode(config.replace("ros", publish_cmd_vel=True), CAMERA, detect=lambda f: [])
    twists: list = []
    node.pub_cmd_vel.publish = twists.append
    held, release = threading.Event(), threading.Event()

    def perceiving():
        with node._lock:
            held.set()
            release.wait(10.0)

    return node, twists, threading.Thread(target=perceiving, daemon=True), held, release


def test_stop_following_sends_zero_while_a_frame_holds_the_perception_lock(monkeypatch):
    """`~/stop_following` must not wait for the frame being tracked and identified (tens
    of ms, hundreds on a slow CPU): the base gets its zero, and only zeros after it, while
    the perception lock is still held."""
    from std_srvs.srv import Trigger
    from waiting import wait_for


    node, twists, holder, held, release = _node_and_a_frame_in_perception(monkeypatch)
    response: list = []
    stopper = threading.Thread(target=lambda: response.append(node._on_stop_following(
        Trigger.Request(), Trigger.Response())), daemon=True)  # fmt: skip
    try:
        _drive_toward_a_target(node, twists)
        holder.start()
        assert held.wait(3.0)
        stopper.start()
        zeroed = wait_for(lambda: len(twists) > 1 and twists[-1].linear.x == 0.0, 1.0)
        still_held = node._lock.locked()
        node.control.tick()  # a command after the stop: zero too
        after = twists[-1]
    finally:
        release.set()
        holder.join(5.0)
        stopper.join(5.0)
        node.shutdown()
        node.destroy_node()
    assert zeroed and still_held, "no zero on cmd_vel until the perception lock was free"
    assert after.linear.x == 0.0 and after.angular.z == 0.0 and node.gate.blocked >= 1
    assert response and response[0].success and node.following is False


def _result_at(node, stamp_s, status, target_id, people):
    """A FrameResult at `stamp_s` of confirmed, seen tracks {id: (x, y)} (odom, robot at
    the origin) and the identifier's `status` and target."""
    from follow import pipeline
    from follow.types import Observation, Odometry, TargetEstimate, TrackState

    seen = Observation(np.array([160.0, 100.0]), np.array([160.0, 200.0]))
    tracks = [TrackState(i, np.array([x, y, 0.0, 0.0, 1.5]), np.eye(5) * 0.01, True, stamp_s,
                         observation=seen) for i, (x, y) in people.items()]  # fmt: skip
    return pipeline.FrameResult(0, stamp_s, Odometry.origin(stamp_s), [], tracks,
                                TargetEstimate(status, target_id, {}, stamp_s))  # fmt: skip


def _conclude_as(node, result) -> None:
    """`_conclude` of a frame whose tracking and identification give `result`."""
    from follow.types import Frame

    node.perception.conclude = lambda *args, **kwargs: result
    frame = Frame(np.zeros((240, 320, 3), np.uint8), result.stamp_s)
    node._conclude(frame, result.robot, None, _header(result.stamp_s, "camera"))


@contextlib.contextmanager
def _searching_node(monkeypatch):
    """A cmd_vel node whose controller searches for a lost target for 3 s, its control
    loop ticked by the test, perception built, following person 3 (left) with person 7
    (right) in view; yields (node, people, twists)."""
    from follow import pipeline
    from follow.types import TargetStatus

    monkeypatch.setattr(pipeline.ControlLoop, "_run", lambda loop: loop._stop.wait())  # tick here
    config = Config().replace("identify", identifier="channels")
    config = config.replace("ros", publish_cmd_vel=True, camera_info_topic="")
    node = FollowNode(config.replace("control", search_duration_s=3.0), CAMERA,
                      detect=lambda f: [])  # fmt: skip
    twists: list = []
    node.pub_cmd_vel.publish = twists.append
    people = {3: (3.0, 1.2), 7: (3.0, -1.2)}
    try:
        now = node.now_s()
        node._on_odometry(_odometry(now))
        assert node._detect_in(_image(now - 0.05, 320, 240)) is not None  # perception built
        node._on_odometry(_odometry(node.now_s()))  # fresh again: building it takes time
        _conclude_as(node, _result_at(node, node.now_s(), TargetStatus.TRACKING, 3, people))
        assert node.control.tick().yaw_rate_radps > 0  # turning left, toward person 3
        yield node, people, twists
    finally:
        node.shutdown()
        node.destroy_node()


def test_a_target_selected_is_awaited_without_searching_for_the_one_before(monkeypatch):
    """The controller kept the deselected person's last bearing: with a lost-target search
    configured, the base turned toward them as soon as a frame was concluded with the new
    choice, before the identifier tracked anyone. Zero until the new target is tracked."""
    from std_msgs.msg import Int32

    from follow.types import TargetStatus

    with _searching_node(monkeypatch) as (node, people, twists):
        node._on_select_target(Int32(data=7))
        for _ in range(3):  # frames with the new choice, the identifier learning it
            node._on_odometry(_odometry(node.now_s()))
            _conclude_as(node, _result_at(node, node.now_s(), TargetStatus.INITIAL_TRAINING,
                                          None, people))  # fmt: skip
            command = node.control.tick()
            assert command.is_stop and twists[-1].angular.z == 0.0, command
        node._on_odometry(_odometry(node.now_s()))
        _conclude_as(node, _result_at(node, node.now_s(), TargetStatus.TRACKING, 7, people))
        assert node.control.tick().yaw_rate_radps < 0  # person 7, to the right


def test_a_tick_computing_from_the_old_target_while_another_is_selected_leaves_no_search(
    monkeypatch,
):
    """A tick that took the old result just before `~/select_target` updates the
    controller with the old target after the selection: a reset made at the selection
    alone would be undone, and the ticks after it search toward that target."""
    from std_msgs.msg import Int32

    from follow.types import TargetStatus

    with _searching_node(monkeypatch) as (node, people, twists):
        controller = node.control.controller
        computing, release = threading.Event(), threading.Event()

        def update(target, stamp_s):  # the old result taken, computed from after the choice
            computing.set()
            release.wait(5.0)
            return type(controller).update(controller, target, stamp_s)

        controller.update = update
        ticking = threading.Thread(target=node.control.tick, daemon=True)
        ticking.start()
        try:
            assert computing.wait(5.0)
            node._on_select_target(Int32(data=7))
        finally:
            release.set()
            ticking.join(5.0)
            del controller.update  # its own again
        assert not ticking.is_alive() and twists[-1].angular.z == 0.0  # the held tick's
        node._on_odometry(_odometry(node.now_s()))
        _conclude_as(node, _result_at(node, node.now_s(), TargetStatus.INITIAL_TRAINING,
                                      None, people))  # fmt: skip
        assert node.control.tick().is_stop and twists[-1].angular.z == 0.0


@pytest.mark.parametrize("request_", ["stop_following", "select_target"])
def test_no_target_is_published_for_nav2_after_a_stop_or_another_choice(request_):
    """The target was published outside the lock, after the markers: a frame concluded
    just before `~/stop_following` published its target after the service returned (Nav2
    led on after the stop), and before `~/select_target` the person just deselected."""
    from std_msgs.msg import Int32
    from std_srvs.srv import Trigger

    from follow.types import TargetStatus

    config = Config().replace("identify", identifier="channels")
    node = FollowNode(config.replace("ros", odom_topic="", publish_cmd_vel=False,
                                     camera_info_topic=""),
                      CAMERA, detect=lambda frame: [])  # fmt: skip
    published: list = []
    node.pub_target.publish = published.append
    markers, release = threading.Event(), threading.Event()
    publish_markers = node.pub_markers.publish

    def slow_markers(msg):  # the publishers before the target take time
        markers.set()
        release.wait(5.0)
        publish_markers(msg)

    node.pub_markers.publish = slow_markers
    try:
        assert node._detect_in(_image(node.now_s() - 0.05, 320, 240)) is not None
        result = _result_at(node, node.now_s() - 0.01, TargetStatus.TRACKING, 3, {3: (3.0, 0.0)})
        concluding = threading.Thread(target=_conclude_as, args=(node, result), daemon=True)
        concluding.start()
        try:
            assert markers.wait(5.0)
            if request_ == "stop_following":
                node._on_stop_following(Trigger.Request(), Trigger.Response())
            else:
                node._on_select_target(Int32(data=7))
        finally:
            release.set()
            concluding.join(5.0)
        assert not concluding.is_alive() and published == []
        markers.clear()
        node.pub_markers.publish = publish_markers
        if request_ == "select_target":  # a frame concluded with the new choice: published
            _conclude_as(node, _result_at(node, node.now_s(), TargetStatus.TRACKING, 7,
                                          {7: (3.0, 0.0)}))  # fmt: skip
            assert len(published) == 1
    finally:
        node.shutdown()
        node.destroy_node()


def test_select_target_stops_the_base_while_a_frame_holds_the_perception_lock(monkeypatch):
    """`~/select_target` waited for the frame being tracked and identified (the
    perception lock, hundreds of ms on a slow CPU), and so did a `~/stop_following`
    queued behind it (one mutually exclusive callback group): the base drove on toward
    the person just chosen against. It stops at the next control tick instead."""
    from std_msgs.msg import Int32


    node, twists, holder, held, release = _node_and_a_frame_in_perception(monkeypatch)
    selector = threading.Thread(target=node._on_select_target, args=(Int32(data=3),),
                                daemon=True)  # fmt: skip
    try:
        _drive_toward_a_target(node, twists)
        holder.start()
        assert held.wait(3.0)
        selector.start()
        selector.join(1.0)
        returned = not selector.is_alive()
        node._on_odometry(_odometry(node.now_s()))
        command = node.control.tick()
        still_held = node._lock.locked()
    finally:
        release.set()
        holder.join(5.0)
        selector.join(5.0)
        node.shutdown()
        node.destroy_node()
    assert returned and still_held, "~/select_target waited for the perception lock"
    assert command.is_stop and twists[-1].linear.x == 0.0 and twists[-1].angular.z == 0.0


def test_a_frame_concluded_with_the_old_choice_after_a_selection_is_not_driven_toward(
    monkeypatch,
):
    """A selection made while a frame is identified with the choice before it: that
    frame's result, put after the selection dropped the ones before, would drive toward
    the person just chosen against (it tracks them: the controller takes it as the new
    target tracked). It is not put; the identifier takes the choice before the next
    frame, and that frame is followed."""
    from std_msgs.msg import Int32

    from follow.types import Frame, TargetStatus

    with _searching_node(monkeypatch) as (node, people, twists):
        chosen: list = []
        monkeypatch.setattr(node.perception.identifier, "select_target", chosen.append)
        old = _result_at(node, node.now_s(), TargetStatus.TRACKING, 3, people)
        identifying, release = threading.Event(), threading.Event()

        def identify_slowly(*args, **kwargs):  # tracked and identified with the old choice
            identifying.set()
            release.wait(5.0)
            return old

        node.perception.conclude = identify_slowly
        frame = Frame(np.zeros((240, 320, 3), np.uint8), old.stamp_s)
        image_header = _header(old.stamp_s, "camera")
        concluding = threading.Thread(target=node._conclude, daemon=True,
                                      args=(frame, old.robot, None, image_header))  # fmt: skip
        selector = threading.Thread(target=node._on_select_target, args=(Int32(data=7),),
                                    daemon=True)  # fmt: skip
        concluding.start()
        try:
            assert identifying.wait(5.0)
            selector.start()
            selector.join(0.5)
        finally:
            release.set()
            concluding.join(5.0)
            selector.join(5.0)
        assert not concluding.is_alive() and not selector.is_alive()
        node._on_odometry(_odometry(node.now_s()))
        command = node.control.tick()
        assert command.is_stop and twists[-1].angular.z == 0.0, command  # not toward person 3
        assert node.results.peek() is not old
        node._on_odometry(_odometry(node.now_s()))
        _conclude_as(node, _result_at(node, node.now_s(), TargetStatus.TRACKING, 7, people))
        assert chosen == [7]
        assert node.control.tick().yaw_rate_radps < 0  # person 7, to the right


def test_a_target_selected_before_the_first_image_is_followed_once_perception_starts():
    """The identifier is built with the first image: a selection made before it waits."""
    from std_msgs.msg import Int32

    config = Config().replace("identify", identifier="channels")
    node = FollowNode(config.replace("ros", odom_topic="", camera_info_topic=""), CAMERA,
                      detect=lambda frame: [])  # fmt: skip
    try:
        node._on_select_target(Int32(data=5))
        assert node.perception is None
        detected = node._detect_in(_image(node.now_s() - 0.05, 320, 240))
        node._conclude(*detected)
        assert node.perception.identifier.context.requested_id == 5
    finally:
        node.shutdown()
        node.destroy_node()
