"""The limb/PAF-channel pairing, checked against the network's output on real frames.

For every body limb, along the segment between the two keypoints' heatmap peaks of the
same person, the PAF channels named for that limb must point from the first keypoint to
the second (positive projection), and better than any other channel pair does.
"""

from __future__ import annotations

import numpy as np

from follow.config import PoseConfig
from follow.eval.pets import PetsSequence
from follow.pose.decode import LIMB_KEYPOINTS, LIMB_PAF_CHANNELS, find_peaks
from follow.pose.detector import PoseDetector

BODY_LIMBS = range(12)  # arms, legs, torso: large enough to measure on PETS frames


def test_paf_channels_point_along_their_limbs(model_path, data_path):
    det = PoseDetector(
        PoseConfig(provider="cpu", input_height_px=720, warmup_runs=0),
        model_path("pose/human-pose-estimation-0001.onnx"),
    )
    pets = PetsSequence(data_path("pets2009_s2l1/View_001.avi").parent)
    agreement = np.zeros((len(LIMB_KEYPOINTS), len(LIMB_PAF_CHANNELS)))
    counts = np.zeros(len(LIMB_KEYPOINTS))
    for index in (0, 300):
        heatmaps, pafs, _ = det.infer(pets.read_frame(index))
        peaks = find_peaks(heatmaps, 0.2)
        for limb, (ka, kb) in enumerate(LIMB_KEYPOINTS):
            for a in peaks[ka]:
                if len(peaks[kb]) == 0:
                    continue
                dist = np.linalg.norm(peaks[kb][:, :2] - a[:2], axis=1)
                j = int(dist.argmin())
                if not 1.0 <= dist[j] <= 8.0:  # same person, long enough to sample
                    continue
                unit = (peaks[kb][j, :2] - a[:2]) / dist[j]
                pts = a[:2] + np.linspace(0, 1, 8)[:, None] * (peaks[kb][j, :2] - a[:2])
                xi, yi = np.rint(pts).astype(int).T
                for c, (cx, cy) in enumerate(LIMB_PAF_CHANNELS):
                    agreement[limb, c] += np.mean(pafs[cx][yi, xi] * unit[0]
                                                  + pafs[cy][yi, xi] * unit[1])  # fmt: skip
                counts[limb] += 1
    for limb in BODY_LIMBS:
        assert counts[limb] >= 1, f"limb {LIMB_KEYPOINTS[limb]}: too few samples"
        mean = agreement[limb] / counts[limb]
        assert mean.argmax() == limb, (
            f"limb {LIMB_KEYPOINTS[limb]}: channels {LIMB_PAF_CHANNELS[mean.argmax()]} "
            f"agree better than {LIMB_PAF_CHANNELS[limb]}"
        )
        assert mean[limb] > 0.4
