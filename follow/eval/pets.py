"""PETS 2009 S2.L1 (view 1) reader: ground-truth boxes, video frames, occlusion.

The ground truth (`PETS2009-S2L1.xml`) gives, per frame and per person id, a box
`xc, yc, w, h` in pixels of the original 768x576 images. The shared video is a 480x360
re-encode, so box coordinates are multiplied by `VIDEO_SCALE` (0.625) to land on video
pixels. People are annotated even while fully hidden, so evaluations need to know how
much of each box lies behind people nearer the camera: `GtBox.hidden_fraction`.

Typical use::

    seq = PetsSequence(Path(os.environ["FOLLOW_DATA_DIR"]) / "pets2009_s2l1")
    for index, image in seq.frames(range(0, 795, 10)):
        for box in seq.boxes_video_px(index):      # GtBox in 480x360 pixels
            if box.hidden_fraction <= 0.5: ...
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

GT_IMAGE_SIZE = (768, 576)  # (width, height) of the images the ground truth refers to
VIDEO_IMAGE_SIZE = (480, 360)  # (width, height) of the shared video
VIDEO_SCALE = VIDEO_IMAGE_SIZE[0] / GT_IMAGE_SIZE[0]  # 0.625
GT_FILE = "PETS2009-S2L1.xml"
VIDEO_FILE = "View_001.avi"


class PetsError(ValueError):
    """A PETS file that is missing or cannot be parsed; the message names it."""


@dataclass(frozen=True)
class GtBox:
    """One annotated person in one frame.

    `xc, yc, w, h` are the box centre and size in pixels (of the image size the box was
    scaled to). `hidden_fraction` in [0, 1] is the part of the box's area covered by
    the boxes of people nearer the camera (whose box bottom is lower in the image).
    """

    person_id: int
    xc: float
    yc: float
    w: float
    h: float
    hidden_fraction: float = 0.0

    @property
    def left(self) -> float:
        return self.xc - self.w / 2

    @property
    def right(self) -> float:
        return self.xc + self.w / 2

    @property
    def top(self) -> float:
        return self.yc - self.h / 2

    @property
    def bottom(self) -> float:
        return self.yc + self.h / 2

    def contains(self, x: float, y: float) -> bool:
        return self.left <= x <= self.right and self.top <= y <= self.bottom

    def scaled(self, factor: float) -> GtBox:
        """The same box in an image scaled by `factor` (hidden fraction is unchanged)."""
        return replace(
            self, xc=self.xc * factor, yc=self.yc * factor, w=self.w * factor, h=self.h * factor
        )


def load_ground_truth(xml_path: str | Path) -> dict[int, list[GtBox]]:
    """Frame number -> boxes (768x576 pixels) with their hidden fractions filled in."""
    from calib.gt_boxes import BoxFileError, read_boxes

    try:
        boxes = read_boxes(xml_path)
    except BoxFileError as exc:
        raise PetsError(f"PETS ground truth: {exc}") from None
    frames: dict[int, list[GtBox]] = {}
    for b in boxes:
        frames.setdefault(b.frame, []).append(GtBox(b.person_id, b.xc_px, b.yc_px, b.w_px, b.h_px))
    return {number: with_hidden_fractions(frame) for number, frame in sorted(frames.items())}


def with_hidden_fractions(boxes: list[GtBox], grid_px: float = 1.0) -> list[GtBox]:
    """The boxes with `hidden_fraction` set: the share of each box's area that lies under
    the union of nearer boxes (bottom edge lower in the image), rasterised at `grid_px`."""
    out = []
    for box in boxes:
        nearer = [b for b in boxes if b is not box and b.bottom > box.bottom]
        out.append(replace(box, hidden_fraction=_covered_fraction(box, nearer, grid_px)))
    return out


def _covered_fraction(box: GtBox, others: list[GtBox], grid_px: float) -> float:
    if not others or box.w <= 0 or box.h <= 0:
        return 0.0
    nx = max(1, int(np.ceil(box.w / grid_px)))
    ny = max(1, int(np.ceil(box.h / grid_px)))
    xs = box.left + (np.arange(nx) + 0.5) * box.w / nx
    ys = box.top + (np.arange(ny) + 0.5) * box.h / ny
    covered = np.zeros((ny, nx), dtype=bool)
    for o in others:
        in_x = (xs >= o.left) & (xs <= o.right)
        in_y = (ys >= o.top) & (ys <= o.bottom)
        covered |= in_y[:, None] & in_x[None, :]
    return float(covered.mean())


class PetsSequence:
    """The S2.L1 view-1 sequence in a folder holding `View_001.avi` and the GT XML."""

    def __init__(self, root: str | Path, gt_file: str = GT_FILE, video_file: str = VIDEO_FILE):
        self.root = Path(root)
        self.gt_path = self.root / gt_file
        self.video_path = self.root / video_file
        for path in (self.gt_path, self.video_path):
            if not path.exists():
                raise PetsError(f"PETS 2009: {path} not found")
        self.ground_truth = load_ground_truth(self.gt_path)
        self._capture: cv2.VideoCapture | None = None
        self._next_index = 0

    @property
    def frame_count(self) -> int:
        return max(self.ground_truth) + 1

    def boxes_gt_px(self, index: int) -> list[GtBox]:
        """Boxes of frame `index` in 768x576 pixels (empty list for an unannotated frame)."""
        return list(self.ground_truth.get(index, []))

    def boxes_video_px(self, index: int) -> list[GtBox]:
        """Boxes of frame `index` in pixels of the 480x360 video."""
        return [b.scaled(VIDEO_SCALE) for b in self.ground_truth.get(index, [])]

    def read_frame(self, index: int) -> np.ndarray:
        """Video frame `index` as a 360x480x3 BGR uint8 array (sequential reads are fast)."""
        if not 0 <= index < self.frame_count:
            raise PetsError(f"PETS 2009: frame {index} out of range 0..{self.frame_count - 1}")
        if self._capture is None:
            self._capture = cv2.VideoCapture(str(self.video_path))
            if not self._capture.isOpened():
                raise PetsError(f"PETS 2009: cannot open video {self.video_path}")
            self._next_index = 0
        if index != self._next_index:
            if index > self._next_index and index - self._next_index < 30:
                while self._next_index < index:
                    self._capture.grab()
                    self._next_index += 1
            else:
                self._capture.set(cv2.CAP_PROP_POS_FRAMES, index)
                self._next_index = index
        ok, image = self._capture.read()
        if not ok or image is None:
            raise PetsError(f"PETS 2009: cannot decode frame {index} of {self.video_path}")
        self._next_index = index + 1
        return image

    def frames(self, indices: Iterable[int] | None = None) -> Iterator[tuple[int, np.ndarray]]:
        """(index, BGR image) for the given frame indices (all frames by default)."""
        for index in range(self.frame_count) if indices is None else indices:
            yield index, self.read_frame(index)

    def close(self) -> None:
        if self._capture is not None:
            self._capture.release()
            self._capture = None


def evenly_spaced_frames(frame_count: int, count: int) -> list[int]:
    """`count` frame indices spread over the sequence (all frames when count >= total)."""
    if count >= frame_count:
        return list(range(frame_count))
    return sorted({int(round(i)) for i in np.linspace(0, frame_count - 1, count)})
