"""A child process for tests: `follow.ros2.node.run` with the real FollowNode (cmd_vel
on) and no pose network (nobody is ever detected); every cmd_vel is printed, and the
shutdown summary last. With STUB_SHUTDOWN_HANGS set, the shutdown hangs after the
control loop's stop (as a worker thread that never ends would hold it)."""

import json
import os
import time

from follow.camera import CameraModel, CameraPose
from follow.config import Config
from follow.ros2 import node as node_module


class StubNode(node_module.FollowNode):
    def __init__(self, config, camera, **kwargs):
        super().__init__(config, camera, detect=lambda frame: [], **kwargs)

    def shutdown(self):
        if os.environ.get("STUB_SHUTDOWN_HANGS"):  # as a worker that never ends would
            self.control.stop()  # its zero is printed before the hang
            print("shutdown hangs", flush=True)
            time.sleep(60.0)
        return super().shutdown()

    def _publish_twist(self, command):
        print(f"cmd_vel {command.forward_mps} {command.yaw_rate_radps}", flush=True)
        super()._publish_twist(command)


node_module.FollowNode = StubNode
camera = CameraModel.from_fov((320, 240), 70.0, CameraPose(height_m=1.0))
print("spinning", flush=True)
summary = node_module.run(Config().replace("ros", publish_cmd_vel=True), camera, [])
print("summary " + json.dumps(summary), flush=True)
