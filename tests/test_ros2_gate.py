"""The ROS 2 node's cmd_vel gate (no ROS needed): moving commands pass only with fresh
odometry and while following; zero always passes."""

from follow.ros2.gate import CmdVelGate
from follow.types import Odometry, VelocityCommand


def make_gate(now):
    sent = []
    gate = CmdVelGate(sent.append, lambda: now[0], max_odometry_age_s=0.2)
    return gate, sent


def test_moving_needs_fresh_odometry():
    now = [10.0]
    gate, sent = make_gate(now)
    gate.send(VelocityCommand(0.5, 0.1, 10.0))  # no odometry yet
    gate.update_odometry(Odometry(1.0, 2.0, 0.3, 9.9))
    gate.send(VelocityCommand(0.5, 0.1, 10.0))
    now[0] = 10.05
    gate.update_odometry(Odometry(0.0, 0.0, 0.0, 9.0))  # an older sample never replaces
    assert gate.odometry().x_m == 1.0
    now[0] = 10.2
    gate.send(VelocityCommand(0.5, 0.1, 10.2))  # 0.3 s old now: stop
    assert [(c.forward_mps, c.yaw_rate_radps) for c in sent] == [(0, 0), (0.5, 0.1), (0, 0)]
    assert gate.blocked == 2 and gate.odometry() is None and not gate.healthy()


def test_a_stop_request_holds_the_base_until_following_resumes():
    now = [5.0]
    gate, sent = make_gate(now)
    gate.update_odometry(Odometry(0.0, 0.0, 0.0, 5.0))
    gate.following = False
    gate.send(VelocityCommand(1.0, 0.0, 5.0))
    gate.following = True
    gate.send(VelocityCommand(1.0, 0.0, 5.0))
    gate.close()
    assert [c.forward_mps for c in sent] == [0.0, 1.0, 0.0] and sent[-1].is_stop


def test_unsafe_ros_settings_are_refused_by_name():
    import pytest

    from follow.config import ConfigError, RosConfig
    from follow.ros2.gate import check_ros_config

    check_ros_config(RosConfig())
    with pytest.raises(ConfigError, match="max_image_age_s must be positive"):
        check_ros_config(RosConfig(max_image_age_s=0.0))
    with pytest.raises(ConfigError, match="max_odometry_age_s must be positive"):
        check_ros_config(RosConfig(max_odometry_age_s=float("inf")))
    with pytest.raises(ConfigError, match="publish_cmd_vel needs odom_topic"):
        check_ros_config(RosConfig(publish_cmd_vel=True, odom_topic=""))


def test_follow_ros2_without_ros_says_what_to_install(tmp_path, monkeypatch, capsys):
    import sys

    from follow import cli

    monkeypatch.setitem(sys.modules, "rclpy", None)  # as if the ros2 extra were missing
    assert cli.main(["ros2", "--camera", str(tmp_path / "camera.yaml")]) == 1
    assert "pip install 'follow[ros2]'" in capsys.readouterr().err


def test_one_odometry_sample_from_the_future_does_not_block_the_base_for_good():
    """A glitched stamp far ahead would make every correct sample after it look older."""
    now = [1000.0]
    gate, _ = make_gate(now)
    gate.update_odometry(Odometry(0.0, 0.0, 0.0, 1000.0 + 2**31))
    for k in range(1, 5):
        now[0] = 1000.0 + 0.05 * k
        gate.update_odometry(Odometry(0.0, 0.0, 0.0, now[0]))
    assert gate.healthy()


def test_an_operator_stop_is_the_last_command_even_with_a_tick_in_flight():
    """A control tick checked before the stop request and published after its zero would
    leave the base moving until the next tick."""
    import threading

    published, inside, release = [], threading.Event(), threading.Event()

    def publish(command):
        if not command.is_stop:
            inside.set()
            release.wait(2.0)
        published.append(command)

    gate = CmdVelGate(publish, lambda: 10.0, max_odometry_age_s=0.2)
    gate.update_odometry(Odometry(0.0, 0.0, 0.0, 10.0))
    tick = threading.Thread(target=gate.send, args=(VelocityCommand(0.8, 0.0, 10.0),))
    tick.start()
    assert inside.wait(2.0)
    stopper = threading.Thread(target=gate.stop_following, args=(10.0,))
    stopper.start()
    stopper.join(0.2)  # the request comes while the tick is being published
    release.set()
    tick.join(2.0)
    stopper.join(2.0)
    assert published[-1].is_stop and not gate.following


def test_a_node_clock_that_stops_advancing_stops_the_base():
    """With use_sim_time the node's clock is the simulator's /clock: when the simulator is
    paused or dies that clock stands still, and odometry stamped just before it stopped
    would stay fresh for ever. Once the clock has not moved for max_odometry_age_s of
    wall time, nothing moving is published; when it moves again, driving resumes."""
    import time

    now = [50.0]
    gate, sent = make_gate(now)
    gate.update_odometry(Odometry.origin(50.0))
    assert gate.send(VelocityCommand(0.5, 0.0, 50.0)).forward_mps == 0.5
    time.sleep(0.3)  # /clock stopped: the node's clock stays at 50.0 s
    assert gate.send(VelocityCommand(0.5, 0.0, 50.0)).is_stop
    assert sent[-1].is_stop and gate.blocked == 1 and not gate.healthy()
    now[0] += 0.05  # the simulator runs again
    gate.update_odometry(Odometry.origin(now[0]))
    assert gate.send(VelocityCommand(0.5, 0.0, now[0])).forward_mps == 0.5


def test_options_given_after_ros_args_are_named(capsys):
    """`follow ros2 --ros-args -p x:=1 --camera cam.yaml`: --ros-args takes everything
    after it, and argparse said only that --camera was required."""
    from follow import cli

    assert cli.main(["ros2", "--ros-args", "-p", "x:=1", "--camera", "cam.yaml"]) == 1
    err = capsys.readouterr().err
    assert "--camera came after --ros-args" in err and "give --ros-args last" in err
    assert cli.main(["ros2"]) == 1
    assert "--camera is required" in capsys.readouterr().err
