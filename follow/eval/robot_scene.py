"""A robot's view of real people at following distances, for `follow bench --scene robot`.

PETS 2009 frames show 5-8 people 35-95 px tall from a surveillance mast; a following
robot's 640x480 camera, 1 m up, sees its target 2-3 m ahead, 300-450 px tall, and a
few others. With no annotated robot-view video here, this pastes real person crops
(`$FOLLOW_DATA_DIR/ccf_crops`: the target's 14 crops from a robot camera and its two
look-alike strangers; CUHK03 crops for more people) into a grey frame at the size and
place a 60-degree camera 1 m up gives a 1.7 m person at each distance, walking side to
side. The network, tracker and identifier run on these frames as on a camera's; the
grey surround makes it a timing scene, not an accuracy one (`follow eval pose-near`
measures detection at these sizes).
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from follow.camera import CameraModel, CameraPose

FRAME_SIZE = (640, 480)
HORIZONTAL_FOV_DEG = 60.0
CAMERA_HEIGHT_M = 1.0
PERSON_HEIGHT_M = 1.7
TARGET_DISTANCE_M = 2.5
FPS = 30.0
MAX_PEOPLE = 5
MIN_FAR_M, MAX_FAR_M = 3.0, 15.0  # where the farthest person may stand
# Side-to-side walk: amplitude (m) and period (s); each person in their own phase.
SWAY_M = 0.3
SWAY_PERIOD_S = 3.0
# Where each person stands across the view, as a share of its half-width at their distance.
OTHERS_PLACES = (0.0, 0.5, -0.5, 0.85, -0.85)


def scene_crop_files(data_dir: Path) -> list[list[Path]]:
    """Per person, the crops that show them: the target's (p01-p14), each of its two
    look-alikes' (nXX-01, nXX-02), then two CUHK03 people (camera A views)."""
    crops, cuhk = data_dir / "ccf_crops", data_dir / "cuhk03_val"
    people = [sorted(crops.glob("p*.jpg")), sorted(crops.glob("n*-01.jpg")),
              sorted(crops.glob("n*-02.jpg"))]  # fmt: skip
    for identity in ("0000", "0001"):
        people.append([cuhk / f"{identity}_{k:02d}.jpg" for k in range(5)])
    missing = [i for i, files in enumerate(people) if not files or not files[0].exists()]
    if missing:
        raise ValueError(f"robot scene: person crops missing under {data_dir} (ccf_crops/ "
                         "and cuhk03_val/ are needed)")  # fmt: skip
    return people


class RobotScene:
    """`frame_count` frames of `people` (1-5) walking in front of a still robot: the
    target at 2.5 m, the others spread from 3 m out to `far_m`."""

    def __init__(self, data_dir: Path, people: int = MAX_PEOPLE, far_m: float = 5.0,
                 frame_count: int = 65):  # fmt: skip
        if not 1 <= people <= MAX_PEOPLE:
            raise ValueError(f"robot scene: people must be 1-{MAX_PEOPLE}, got {people}")
        if not MIN_FAR_M <= far_m <= MAX_FAR_M:
            raise ValueError(f"robot scene: the farthest person must be {MIN_FAR_M:g}-"
                             f"{MAX_FAR_M:g} m away, got {far_m}")  # fmt: skip
        self.frame_count = frame_count
        self.fps = FPS
        self.camera = CameraModel.from_fov(FRAME_SIZE, HORIZONTAL_FOV_DEG,
                                           CameraPose(height_m=CAMERA_HEIGHT_M))  # fmt: skip
        self.sequence = self  # what the benchmark reads frames from
        # one other person stands at far_m: the farthest, as with more
        others = np.linspace(3.0, far_m, people - 1) if people > 2 else np.full(people - 1, far_m)
        self.distances_m = [TARGET_DISTANCE_M, *others.tolist()]
        crops = scene_crop_files(Path(data_dir))[:people]
        self._crops = [[self._read(p) for p in files] for files in crops]
        # the target in the middle, the others to either side of it in turn
        half_width = [d * math.tan(math.radians(HORIZONTAL_FOV_DEG / 2)) for d in self.distances_m]
        self.lateral_m = [side * half_width[person]
                          for person, side in enumerate(OTHERS_PLACES[:people])]  # fmt: skip

    @staticmethod
    def _read(path: Path) -> np.ndarray:
        image = cv2.imread(str(path))
        if image is None:
            raise ValueError(f"robot scene: cannot read {path}")
        return image

    def person_box_px(self, person: int, index: int) -> tuple[int, int, int, int]:
        """(x0, y0, width, height) of a person in frame `index`."""
        t = index / self.fps
        distance = self.distances_m[person]
        lateral = self.lateral_m[person] + SWAY_M * math.sin(2 * math.pi * t / SWAY_PERIOD_S
                                                             + person)  # fmt: skip
        feet = self.camera.project(np.array([[distance, lateral, 0.0]]))[0]
        head = self.camera.project(np.array([[distance, lateral, PERSON_HEIGHT_M]]))[0]
        height = int(round(feet[1] - head[1]))
        crop = self._crops[person][0]
        width = int(round(height * crop.shape[1] / crop.shape[0]))
        return int(round(feet[0] - width / 2)), int(round(head[1])), width, height

    def read_frame(self, index: int) -> np.ndarray:
        """Frame `index`: the people pasted far to near (nearer ones cover farther)."""
        width, height = FRAME_SIZE
        frame = np.full((height, width, 3), 128, np.uint8)
        for person in np.argsort(self.distances_m)[::-1]:
            crops = self._crops[person]
            crop = crops[(index // 10) % len(crops)]  # a new view every third of a second
            x0, y0, w, h = self.person_box_px(int(person), index)
            pasted = cv2.resize(crop, (w, h), interpolation=cv2.INTER_LINEAR)
            fx0, fy0, fx1, fy1 = max(x0, 0), max(y0, 0), min(x0 + w, width), min(y0 + h, height)
            if fx1 > fx0 and fy1 > fy0:
                frame[fy0:fy1, fx0:fx1] = pasted[fy0 - y0 : fy1 - y0, fx0 - x0 : fx1 - x0]
        return frame
