"""`follow ros2` stops the base on every signal that ends a session: SIGINT and SIGTERM,
and SIGHUP (the terminal or ssh session it was started from closes), whose default
action would kill the node without its zero cmd_vel. Runs where rclpy imports."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from ros2_support import skip_without_ros2

try:
    import rclpy  # noqa: F401

    from follow.ros2.loopback import isolated_environment
except ImportError as exc:  # pragma: no cover - depends on the installation
    skip_without_ros2(exc)

pytestmark = pytest.mark.slow  # a node process per signal, a few seconds each
STUB_NODE = Path(__file__).with_name("ros2_stub_node.py")


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_a_signal_runs_the_shutdown_that_publishes_zero(signum):
    child = subprocess.Popen([sys.executable, str(STUB_NODE)], env=isolated_environment(),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert child.stdout.readline().strip() == "spinning"
        time.sleep(3.0)  # the node is up and its control loop ticking
        child.send_signal(signum)
        out, err = child.communicate(timeout=30)
    finally:
        child.kill()
    lines = out.splitlines()
    assert child.returncode == 0, err[-2000:]
    assert lines[-1].startswith("summary "), lines[-3:]
    assert lines[-2] == "cmd_vel 0.0 0.0"  # the shutdown's zero, last before the summary


def test_a_second_signal_while_the_shutdown_hangs_publishes_zero_and_exits():
    """A shutdown that hangs (a worker that never ends) must not keep the process alive
    against the operator's second Ctrl-C, nor leave without a last zero."""
    env = {**isolated_environment(), "STUB_SHUTDOWN_HANGS": "1"}
    child = subprocess.Popen([sys.executable, str(STUB_NODE)], env=env,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert child.stdout.readline().strip() == "spinning"
        time.sleep(3.0)
        child.send_signal(signal.SIGTERM)
        while (line := child.stdout.readline()) and line.strip() != "shutdown hangs":
            pass
        assert line.strip() == "shutdown hangs"
        started = time.monotonic()
        child.send_signal(signal.SIGINT)
        out, err = child.communicate(timeout=30)
    finally:
        child.kill()
    assert child.returncode == 128 + signal.SIGINT, err[-2000:]
    assert time.monotonic() - started < 10.0  # not the hang's 60 s
    assert out.splitlines() == ["cmd_vel 0.0 0.0"]  # the emergency zero, nothing else
    assert "SIGINT during shutdown: publishing zero and exiting now" in err
