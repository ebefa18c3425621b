"""`follow bench ros2`: what the ROS 2 node adds to the latency of perception.

The node runs as its own process on a private ROS graph (localhost, a random domain);
this process publishes PETS 2009 frames with CameraInfo and odometry, one at a time,
and times each from publishing the image to receiving the node's tracks of it. The
node reports each frame's perception time (pose, tracker, identification) in
`~/target_state`; the difference is the node's added latency: serialising and moving
the image through DDS, decoding it, matching odometry, building and publishing the
outputs. Medians over frames after a warm-up.
"""

from __future__ import annotations

import signal
import tempfile
from pathlib import Path

import numpy as np

from follow.cli_args import non_negative_int, positive_int
from follow.config import Config


def add_arguments(p) -> None:
    p.add_argument("--frames", type=positive_int, default=40, help="PETS frames to time (default 40)")
    p.add_argument("--warmup", type=non_negative_int, default=5, help="frames sent before timing")
    p.add_argument("--config", help="TOML configuration (pose input size, provider, ...)")


def _median(values) -> float | None:
    return round(float(np.median(values)), 3) if len(values) else None


def main(args) -> dict:
    import rclpy
    from tqdm import tqdm

    from follow.eval.pets_setup import PETS_FPS, PetsSetup
    from follow.ros2.loopback import RobotSide, isolated_environment, start_node
    from follow.types import Odometry

    if args.frames < 1 or args.warmup < 0:
        raise ValueError("--frames must be at least 1 and --warmup not negative")
    Config.load(args.config) if args.config else Config()  # a bad file fails here, clearly
    setup = PetsSetup.load()
    total = min(args.warmup + args.frames, setup.frame_count)
    work = Path(tempfile.mkdtemp(prefix="follow-bench-ros2-"))
    setup.camera.save(work / "camera.yaml")
    config_file = Path(args.config) if args.config else work / "config.toml"
    if not args.config:
        config_file.write_text("")
    env = isolated_environment()
    log_file = open(work / "node.log", "w")
    node = start_node(work / "camera.yaml", config_file, env, log_file)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=int(env["ROS_DOMAIN_ID"]))
    robot = RobotSide(context)
    round_trip_ms, perception_ms, added_ms = [], [], []
    try:
        robot.wait_for_node(node)
        robot.start_odometry()
        for index in tqdm(range(total), desc="bench ros2", unit="frame", disable=args.json):
            pose = Odometry.origin(index / PETS_FPS)
            image = setup.sequence.read_frame(index)
            stamp, sent_s, answered_s = robot.send_frame(image, setup.camera, pose, node)
            state = robot.state_at(stamp)
            if index < args.warmup or state is None:
                continue
            inside_ms = sum(state["timing_ms"].get(k, 0.0) for k in ("pose", "tracker", "identify"))
            total_ms = 1e3 * (answered_s - sent_s)
            round_trip_ms.append(total_ms)
            perception_ms.append(inside_ms)
            added_ms.append(total_ms - inside_ms)
    finally:
        if node.poll() is None:
            node.send_signal(signal.SIGINT)
            try:
                node.communicate(timeout=20)
            except Exception:
                node.kill()
        robot.close()
        rclpy.try_shutdown(context=context)
        log_file.close()
    result = {
        "frames": len(added_ms),
        "image_size": list(setup.camera.image_size),
        "round_trip_ms": _median(round_trip_ms),
        "perception_ms": _median(perception_ms),
        "node_added_ms": _median(added_ms),
        "node_added_ms_p90": round(float(np.percentile(added_ms, 90)), 3) if added_ms else None,
        "node_log": str(work / "node.log"),
    }
    if not args.json:
        print(f"{result['frames']} PETS frames through follow ros2 (medians): round trip "
              f"{result['round_trip_ms']} ms, perception {result['perception_ms']} ms, "
              f"added by the node {result['node_added_ms']} ms")  # fmt: skip
    return result
