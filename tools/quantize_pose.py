#!/usr/bin/env python3
"""Make the INT8 pose model (onnxruntime static quantisation, QDQ) for the fast CPU path.

Calibrates on real PETS 2009 S2.L1 frames (between the frames `follow eval pose` and
`follow bench pose` use) at the network input height the detector will run at, and
writes the model to the user cache, where `[pose] precision = "int8"` finds it:

    python tools/quantize_pose.py                  # -> ~/.cache/follow/models/pose/...
    python tools/quantize_pose.py --height 256 -o /tmp/pose-int8-256.onnx
    follow eval pose --model-file ~/.cache/follow/models/pose/human-pose-estimation-0001-int8.onnx

Needs $FOLLOW_MODEL_DIR (or the cache) for the FP32 model and $FOLLOW_DATA_DIR (or
--data-dir) for the frames.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from follow.config import PoseConfig  # noqa: E402
from follow.eval.bench_pose import CALIBRATION_FRAMES, make_int8_model  # noqa: E402
from follow.eval.pets import PetsSequence  # noqa: E402
from follow.eval.pose import data_dir  # noqa: E402
from follow.pose.quantize import default_int8_path  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, default=None,
                        help=f"output ONNX (default: {default_int8_path()})")  # fmt: skip
    parser.add_argument("--height", type=int, default=PoseConfig().input_height_px,
                        help="network input height to calibrate at")  # fmt: skip
    parser.add_argument("--frames", type=int, default=CALIBRATION_FRAMES,
                        help="number of calibration frames")  # fmt: skip
    parser.add_argument("--data-dir", type=Path, default=None, help="PETS 2009 folder")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    sequence = PetsSequence(data_dir(args.data_dir))
    path = make_int8_model(sequence, args.height, args.output, args.frames)
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
