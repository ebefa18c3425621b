"""The network input height for the next frame, from the size of the people in view.

The configured (or camera-chosen) input height is sized for the farthest person to be
followed (follow/pose/input_size.py). When every person in view is larger, a smaller
input finds them as well, and the network's time falls with the input's area (256 px
costs half of 368 px). Near people are even found better there: their ankles are lost
when they are far larger in the input than the people the network was trained on
(docs/pose.md, *People seen large*).

So each frame runs at the smallest of a few fixed heights (few shapes, each warmed up
once) at which the smallest person seen in the last frame, and in the last two frames
run at the full height, stays `min_person_input_px` tall. Every `full_input_every_frames`
frames, and whenever the last frame found nobody, the full height runs again, so that
a far newcomer is found within that many frames.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from follow.pose.input_size import MIN_INPUT_HEIGHT_PX
from follow.pose.preprocess import NETWORK_STRIDE_PX
from follow.types import Skeleton

# The smaller heights are steps of this many pixels from MIN_INPUT_HEIGHT_PX up: few
# network shapes, since each costs a slow first run and, with OpenVINO (one compiled
# model per shape), 25-30 MiB of memory; steps of 64 px saved 50 MB there but ran five
# people within 5 m 4-5 ms a frame slower (320 px where 288 px did).
HEIGHT_STEP_PX = 32
# At most this many smaller heights: a wide camera's 576 px full height takes wider
# steps rather than eleven shapes (eleven compiled models with OpenVINO).
MAX_SMALLER_HEIGHTS = 4
# A person found at one full-height frame and missed at the next is still looked for at
# a height that finds them until this many full-height frames have missed them: a far
# person the full height finds 9 times in 10 is otherwise lost for a whole schedule
# whenever one full-height frame misses them.
FULL_FRAMES_REMEMBERED = 2
# Skeletons with fewer found keypoints are fragments (a hand and an elbow beside a body,
# the head of someone behind another): their extent says nothing of a person's size.
MIN_KEYPOINTS_FOR_SIZE = 5


def person_height_px(skeleton: Skeleton) -> float | None:
    """The vertical extent of a skeleton's found keypoints (px): a person's height from
    the eyes to the ankles, less where parts are missing or out of the frame, so it
    never overstates how large the person is; None for a fragment of a few keypoints."""
    points = skeleton.keypoints_px[np.isfinite(skeleton.keypoints_px).all(axis=1)]
    if len(points) < MIN_KEYPOINTS_FOR_SIZE:
        return None
    extent = float(points[:, 1].max() - points[:, 1].min())
    return extent if extent > 0 else None


def smallest_person_px(skeletons: list[Skeleton]) -> float | None:
    """The smallest height among the skeletons (px); None without any measurable one."""
    heights = [h for h in map(person_height_px, skeletons) if h is not None]
    return min(heights) if heights else None


class PeopleSizedInput:
    """Chooses each frame's input height and learns from what it found."""

    def __init__(self, full_height_px: int, min_person_input_px: float,
                 full_input_every_frames: int):  # fmt: skip
        if full_input_every_frames < 1:
            raise ValueError(f"full_input_every_frames must be >= 1, got {full_input_every_frames}")
        self.full_height_px = full_height_px
        self.min_person_input_px = min_person_input_px
        self.full_input_every_frames = full_input_every_frames
        strides = math.ceil((full_height_px - MIN_INPUT_HEIGHT_PX) / MAX_SMALLER_HEIGHTS
                            / NETWORK_STRIDE_PX)  # fmt: skip
        step = max(HEIGHT_STEP_PX, strides * NETWORK_STRIDE_PX)
        self.heights_px = sorted({*range(MIN_INPUT_HEIGHT_PX, full_height_px, step),
                                  full_height_px})  # fmt: skip
        self._forget()

    def _forget(self) -> None:
        """No earlier frames: the next one runs at the full height."""
        self._frame_height_px: int | None = None  # of the frames the sizes were seen in
        self._frames_since_full = math.inf
        self._smallest_last_px: float | None = None
        self._smallest_at_full_px: deque[float | None] = deque(maxlen=FULL_FRAMES_REMEMBERED)

    def next_height_px(self, frame_height_px: int) -> int:
        """The input height for the next frame, `frame_height_px` tall."""
        if self._frame_height_px not in (None, frame_height_px):
            self._forget()  # sizes in px of frames of another size say nothing of this one's
        if self._frames_since_full + 1 >= self.full_input_every_frames:
            return self.full_height_px
        if self._smallest_last_px is None:
            return self.full_height_px  # nobody found last frame: look at full size
        sizes = [s for s in (self._smallest_last_px, *self._smallest_at_full_px) if s is not None]
        needed = frame_height_px * self.min_person_input_px / min(sizes)
        return next((h for h in self.heights_px if h >= needed), self.full_height_px)

    def observe(self, skeletons: list[Skeleton], input_height_px: int,
                frame_height_px: int) -> None:  # fmt: skip
        """What a frame `frame_height_px` tall, run at `input_height_px`, found."""
        smallest = smallest_person_px(skeletons)
        self._frame_height_px = frame_height_px
        self._smallest_last_px = smallest
        if input_height_px >= self.full_height_px:
            self._frames_since_full = 0
            self._smallest_at_full_px.append(smallest)
        else:
            self._frames_since_full += 1
