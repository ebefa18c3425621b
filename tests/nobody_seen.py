"""A stand-in for `follow run`'s perception that sees nobody: no pose network, no model
files, so a test of what `follow run` does around perception needs neither."""

from follow.pipeline import Detections, FrameResult
from follow.types import TargetEstimate, TargetStatus


class NobodySeen:
    """Perception (`build_perception`'s) whose every frame has no person in it."""

    def detect_people(self, frame):
        return Detections([], 0.0)

    def conclude(self, frame, robot, index, detections):
        target = TargetEstimate(TargetStatus.INITIAL, None, {}, frame.stamp_s)
        return FrameResult(index, frame.stamp_s, robot, [], [], target)

    def process(self, frame, robot, index):
        return self.conclude(frame, robot, index, self.detect_people(frame))
