"""`follow bench memory`: does a long `follow run` keep its memory bounded?

Synthetic frames go through `follow run`'s own per-frame path (`follow.run.run_frames`:
perception, tracker, identifier, controller, the base, the run summary), with the
simulation's synthetic skeleton detector in place of the pose network. The demo's
scenario is replayed over and over (its people come and go, so tracks are made and
retired throughout) with a still robot. The resident set size is read after a warm-up
and at the end; the growth between them should stay under 5 MiB.
"""

from __future__ import annotations

import argparse
import resource
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from tqdm import tqdm

from follow.cli_args import non_negative_int, positive_int
from follow.config import Config

GOAL_GROWTH_MIB = 5.0


def rss_mib() -> float:
    """The process's resident set size now (Linux /proc), else its peak."""
    status = Path("/proc/self/status")
    if status.exists():
        for line in status.read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux, bytes on macOS
    return peak / (1024.0 * 1024.0) if sys.platform == "darwin" else peak / 1024.0


def measure(frames: int, warmup_frames: int, seed: int = 0, progress: bool = False) -> dict:
    from follow.control.base import NullBase
    from follow.run import Outputs, RunSummary, run_frames
    from follow.sim.demo import DEMO_CAMERA, SimFrame, scenario, sim_perception
    from follow.sim.world import World

    if not 0 < warmup_frames < frames:
        raise ValueError(f"warm-up ({warmup_frames}) must be between 0 and frames ({frames})")
    from follow.memory import fix_mmap_threshold

    fix_mmap_threshold()  # as `follow` does at start (follow/cli.py), in this process too
    config = Config().replace("identify", identifier="channels", seed=seed)
    camera = DEMO_CAMERA.detection_camera()
    perception = sim_perception(camera, config, seed)
    image = np.full((camera.image_size[1], camera.image_size[0], 3), 96, np.uint8)
    rng = np.random.default_rng(seed)
    readings: dict[str, float] = {}
    bar = tqdm(total=frames, unit="frame", desc="frames", disable=not progress)

    def source():
        offset_s, index = 0.0, 0
        while True:
            walkers, _ = scenario(rng)
            world = World(walkers, camera=DEMO_CAMERA, seed=seed)
            for wf in world.run(int(34.0 * DEMO_CAMERA.fps)):
                if index == warmup_frames:
                    readings["warmup"] = rss_mib()
                if index == frames:
                    return
                index += 1
                bar.update()
                yield SimFrame(image, offset_s + wf.stamp_s, world=wf)
            offset_s += world.stamp_s + world.dt_s

    summary = RunSummary()
    args = SimpleNamespace(realtime=False, max_frames=None)
    clip = SimpleNamespace(live=False, fps=DEMO_CAMERA.fps)
    outputs = Outputs({"source": "bench memory"}, DEMO_CAMERA.fps)  # writes nothing
    run_frames(args, config, clip, source(), perception, camera, NullBase(), outputs, summary)
    bar.close()
    readings["end"] = rss_mib()
    growth = readings["end"] - readings["warmup"]
    return {
        "frames": summary.frames,
        "warmup_frames": warmup_frames,
        "rss_after_warmup_mib": round(readings["warmup"], 2),
        "rss_end_mib": round(readings["end"], 2),
        "growth_mib": round(growth, 2),
        "growth_per_1000_frames_kib": round(1024.0 * growth / (frames - warmup_frames) * 1000, 1),
        "goal_growth_mib": GOAL_GROWTH_MIB,
        "states": summary.states,
        "commands": summary.commands,
    }


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--frames", type=positive_int, default=20_000, help="synthetic frames to run")
    parser.add_argument("--warmup-frames", type=positive_int, default=2_000,
                        help="frames before the first reading")  # fmt: skip
    parser.add_argument("--seed", type=non_negative_int, default=0)


def main(args: argparse.Namespace) -> dict:
    if args.warmup_frames >= args.frames:
        raise ValueError(f"--warmup-frames {args.warmup_frames} must be below --frames "
                         f"{args.frames}: the reading after the warm-up needs frames to follow")  # fmt: skip
    result = measure(args.frames, args.warmup_frames, args.seed, progress=True)
    if not args.json:
        print(f"{result['frames']} frames: RSS {result['rss_after_warmup_mib']:.1f} MiB after "
              f"{result['warmup_frames']} frames, {result['rss_end_mib']:.1f} MiB at the end; "
              f"growth {result['growth_mib']:.2f} MiB (goal < {GOAL_GROWTH_MIB} MiB)")  # fmt: skip
    return result
