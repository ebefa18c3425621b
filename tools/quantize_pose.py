#!/usr/bin/env python3
"""Make the INT8 pose model (onnxruntime static quantisation, QDQ) for the fast CPU path.

With no options, the same as `follow models prepare`: the model `[pose] precision =
"auto"/"int8"` runs, calibrated on PETS 2009 and robot-distance frames, in the user
cache. With options, a custom model calibrated on PETS 2009 S2.L1 frames only (between
the frames `follow eval pose` and `follow bench pose` use):

    python tools/quantize_pose.py                  # -> ~/.cache/follow/models/pose/...
    python tools/quantize_pose.py --height 256 -o /tmp/pose-int8-256.onnx
    follow eval pose --model-file /tmp/pose-int8-256.onnx --sizes 256

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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, default=None,
                        help="output ONNX of a custom model")  # fmt: skip
    parser.add_argument("--height", type=int, default=None,
                        help="network input height to calibrate at (a custom PETS-only model)")  # fmt: skip
    parser.add_argument("--frames", type=int, default=None,
                        help=f"number of PETS calibration frames (default {CALIBRATION_FRAMES})")  # fmt: skip
    parser.add_argument("--data-dir", type=Path, default=None, help="PETS 2009 folder")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    if args.output is None and args.height is None and args.frames is None:
        from follow.pose.prepare import prepare_int8

        path = prepare_int8()  # the model `precision = "auto"` runs, as `follow models prepare`
    else:
        if args.output is None:
            parser.error("a custom model (--height, --frames) needs -o/--output")
        sequence = PetsSequence(data_dir(args.data_dir))
        height = args.height or PoseConfig().input_height_px
        path = make_int8_model(sequence, height, args.output, args.frames or CALIBRATION_FRAMES)
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
