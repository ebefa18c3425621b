"""`follow bench identify`: speed of the identification pieces, per person.

- CCF10 features: a frame's people (`--people` crops, 128 px tall, the real crops of
  $FOLLOW_DATA_DIR/ccf_crops or synthetic ones) through resize, network, quantisation
  and integral images; milliseconds per person.
- one classifier update: the CPU time per sample of a frame's training (one target and
  `--people` - 1 others, plus the banked positives replayed to balance them; all S x W
  weak classifiers, the selector chain, and the frame's weak-classifier replacement),
  right after the frame's extraction. A lone `update()` of one sample (which replaces
  weak classifiers itself) is reported beside it.

The machine may be shared, so every figure is a median over `--repeats` interleaved
repetitions, measured as the CPU time of the calling thread (onnxruntime runs on it with
one thread), which waiting for a busy CPU does not inflate; wall-clock medians are
reported beside them. Reference operations timed in the same loop (a plain cv2.resize of
the same crops; one numpy ufunc call on S x W values) give ratios that stay meaningful
when the machine is busy.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import cv2
import numpy as np

from follow.cli_args import int_at_least, positive_int
from follow.config import Config, IdentifyConfig

GOAL_CCF10_MS_PER_PERSON = 1.0
GOAL_BOOST_UPDATE_MS = 0.1
CROP_HEIGHT_PX = 128


def add_arguments(p) -> None:
    p.add_argument("--people", type=positive_int, default=4, help="people per frame (default 4)")
    p.add_argument("--repeats", type=int_at_least(5), default=200,
                   help="timed repetitions, at least 5 (default 200)")  # fmt: skip
    p.add_argument("--reid", action="store_true", help="also time the re-id embedding")
    p.add_argument("--compiled-boosting", action="store_true",
                   help="time numba's compiled boosting update, as with [identify] "
                   "compiled_boosting = true (needs numba)")  # fmt: skip
    p.add_argument("--config", help="TOML configuration ([identify] section used)")


def _crops(people: int) -> list[np.ndarray]:
    """Real crops when $FOLLOW_DATA_DIR has them, else synthetic ones; 128 px tall."""
    root = os.environ.get("FOLLOW_DATA_DIR")
    paths = sorted((Path(root) / "ccf_crops").glob("*.jpg")) if root else []
    images = [cv2.imread(str(p)) for p in paths[:people]]
    images = [im for im in images if im is not None]
    rng = np.random.default_rng(0)
    while len(images) < people:
        images.append(rng.integers(0, 256, size=(CROP_HEIGHT_PX, 48, 3), dtype=np.uint8))
    return [
        cv2.resize(im, (max(8, round(im.shape[1] * CROP_HEIGHT_PX / im.shape[0])), CROP_HEIGHT_PX))
        for im in images
    ]


def _timed(fn) -> np.ndarray:
    """(CPU seconds of this thread, wall-clock seconds) of one call."""
    wall, cpu = time.perf_counter(), time.thread_time()
    fn()
    return np.array([time.thread_time() - cpu, time.perf_counter() - wall])


def bench(
    config: IdentifyConfig, people: int, repeats: int, with_reid: bool,
    compiled_boosting: bool = False,
) -> dict:
    from tqdm import tqdm

    from follow.boost.online_boosting import OnlineBoostingClassifier
    from follow.identify.factory import build_extractor, build_reid

    if people < 1 or repeats < 5:
        raise ValueError("--people must be >= 1 and --repeats >= 5")
    crops = _crops(people)
    extractor = build_extractor("ccf10", config)
    crop_size = extractor.crop_size
    maps = extractor.extract_crops(crops)
    classifier = OnlineBoostingClassifier(
        extractor.num_channels, config, compiled=True if compiled_boosting else None
    )
    for k in range(4 * config.sample_bank_size):  # warm: full banks, settled selectors
        classifier.update(maps[k % people], 1 if k % 2 else -1)
    reid = build_reid(config) if with_reid else None
    if reid is not None:  # warm: its first run allocates and chooses kernels, once
        reid.embed_crops(crops)
    shape = (config.num_selectors, config.weak_classifiers_per_selector)
    a, b = np.ones(shape), np.ones(shape)

    times: dict[str, list] = {
        k: [] for k in ("ccf", "ccf1", "resize", "update", "update_single", "ufunc", "reid")
    }
    for k in tqdm(range(repeats), desc="bench identify", unit="rep", leave=False):
        times["ccf"].append(_timed(lambda: extractor.extract_crops(crops)) / people)
        times["resize"].append(
            _timed(lambda: [cv2.resize(c, crop_size, interpolation=cv2.INTER_AREA) for c in crops])
            / people
        )
        times["ccf1"].append(_timed(lambda: extractor.extract_crops(crops[:1])))
        # a frame's training: person k is the target, the others are negatives
        target = k % people
        others = [m for i, m in enumerate(maps) if i != target]
        before = classifier.num_updates
        elapsed = _timed(lambda: classifier.train([maps[target]], others))  # noqa: B023
        times["update"].append(elapsed / max(1, classifier.num_updates - before))
        label = 1 if k % 2 else -1
        times["update_single"].append(_timed(lambda: classifier.update(maps[target], label)))  # noqa: B023
        times["ufunc"].append(_timed(lambda: np.add(a, b)))
        if reid is not None and k % 10 == 0:
            times["reid"].append(_timed(lambda: reid.embed_crops(crops)) / people)
    cpu = {k: 1e3 * float(np.median([t[0] for t in v])) for k, v in times.items() if v}
    wall = {k: 1e3 * float(np.median([t[1] for t in v])) for k, v in times.items() if v}
    result = {
        "ccf10_ms_per_person": cpu["ccf"],
        "boost_update_ms": cpu["update"],
        "ccf10_ms_single_person": cpu["ccf1"],
        "boost_update_mean_ms": 1e3 * float(np.mean([t[0] for t in times["update"]])),
        "boost_single_update_ms": cpu["update_single"],
        "reference_resize_ms_per_person": cpu["resize"],
        "reference_numpy_op_ms": cpu["ufunc"],
        "ccf10_over_resize": cpu["ccf"] / cpu["resize"],
        "boost_update_over_numpy_op": cpu["update"] / max(cpu["ufunc"], 1e-9),
        "wall_clock_ms": {
            "ccf10_ms_per_person": wall["ccf"],
            "boost_update_ms": wall["update"],
            "reference_resize_ms_per_person": wall["resize"],
            "reference_numpy_op_ms": wall["ufunc"],
        },
        "timing": "median CPU time of the calling thread",
        "people_per_frame": people,
        "repeats": repeats,
        "crop_size_px": list(crop_size),
        "ccf_backend": extractor.backend,
        "boost_compiled": classifier._kernel is not None,
        "goals_met": {
            "ccf10_ms_per_person": cpu["ccf"] <= GOAL_CCF10_MS_PER_PERSON,
            "boost_update_ms": cpu["update"] <= GOAL_BOOST_UPDATE_MS,
        },
        "load_average_1min": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
        "cpu_count": os.cpu_count(),
    }
    if "reid" in cpu:
        result["reid_ms_per_person"] = cpu["reid"]
    return result


def main(args) -> dict:
    config = Config.load(args.config).identify if args.config else IdentifyConfig()
    result = bench(config, args.people, args.repeats, args.reid, args.compiled_boosting)
    if not args.json:
        r = result
        print(f"CCF10 on {r['people_per_frame']} crops of {r['crop_size_px'][1]} px "
              f"({r['ccf_backend']}), boosting {'numba' if r['boost_compiled'] else 'numpy'}, "
              f"median CPU ms of {r['repeats']} repetitions, "
              f"load average {r['load_average_1min']:.1f} on {r['cpu_count']} CPUs")  # fmt: skip
        rows = [
            ("CCF10 features, ms per person", r["ccf10_ms_per_person"], GOAL_CCF10_MS_PER_PERSON),
            ("  one person alone, ms", r["ccf10_ms_single_person"], None),
            ("  reference cv2.resize, ms per person", r["reference_resize_ms_per_person"], None),
            ("classifier update, ms per sample", r["boost_update_ms"], GOAL_BOOST_UPDATE_MS),
            ("  mean, ms", r["boost_update_mean_ms"], None),
            ("  update() of one sample alone, ms", r["boost_single_update_ms"], None),
            ("  reference numpy op, ms", r["reference_numpy_op_ms"], None),
        ]
        if "reid_ms_per_person" in r:
            rows.append(("re-id embedding, ms per person", r["reid_ms_per_person"], None))
        for name, value, goal in rows:
            verdict = (
                "" if goal is None else f"goal <= {goal}: {'met' if value <= goal else 'NOT met'}"
            )
            print(f"{name:<40} {value:8.3f}  {verdict}")
        w = r["wall_clock_ms"]
        print(f"wall clock: CCF10 {w['ccf10_ms_per_person']:.3f} ms per person, update "
              f"{w['boost_update_ms']:.3f} ms (includes waiting for a shared CPU)")  # fmt: skip
        print(f"ratios: CCF10 / resize = {r['ccf10_over_resize']:.1f}, "
              f"update / numpy op = {r['boost_update_over_numpy_op']:.0f}")  # fmt: skip
    return result
