"""A fixed suite of perturbed variants of the PETS 2009 sequence, so that an evaluation
reports a distribution (each variant's figures, their mean and their worst) instead of
one run on one encoding of 795 frames, whose figures can sit on a knife edge.

Each variant changes the pixels every frame shows (re-encoding, light, sensor noise,
focus) or starts the run at a later frame. Every change is a pure function of the frame
and its index (the noise is drawn from a generator seeded by the frame index), so a
variant gives the same pixels on every run and in any frame order.

    follow eval tracking --perturb
    follow eval pose --frames 200 --sizes 576 --variants jpeg50,noise,blur
"""

from __future__ import annotations

import dataclasses
import json
import logging
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass

import cv2
import numpy as np

log = logging.getLogger(__name__)

NOISE_SEED = 2009  # with the frame index, seeds each frame's sensor noise
MID_GREY = 128.0  # the contrast changes scale around this level


@dataclass(frozen=True)
class Variant:
    """One way of changing the sequence; the defaults leave it as it is."""

    name: str
    description: str
    jpeg_quality: int | None = None  # re-encode every frame as a JPEG of this quality
    brightness_shift: float = 0.0  # grey levels added to every channel
    contrast_gain: float = 1.0  # scale of every channel around mid-grey
    noise_std: float = 0.0  # grey levels of zero-mean Gaussian sensor noise
    blur_sigma_px: float = 0.0  # Gaussian blur, standard deviation in pixels
    first_frame: int = 0  # the run starts here

    @property
    def changes_pixels(self) -> bool:
        return (
            self.jpeg_quality is not None
            or self.brightness_shift != 0.0
            or self.contrast_gain != 1.0
            or self.noise_std > 0.0
            or self.blur_sigma_px > 0.0
        )

    def apply(self, image_bgr: np.ndarray, index: int) -> np.ndarray:
        """The frame `index` as this variant shows it (a new array; the input is kept)."""
        if not self.changes_pixels:
            return image_bgr
        out = image_bgr
        if self.blur_sigma_px > 0.0:
            out = cv2.GaussianBlur(out, (0, 0), self.blur_sigma_px)
        if self.brightness_shift != 0.0 or self.contrast_gain != 1.0 or self.noise_std > 0.0:
            work = out.astype(np.float32)
            work = (work - MID_GREY) * self.contrast_gain + MID_GREY + self.brightness_shift
            if self.noise_std > 0.0:
                rng = np.random.default_rng((NOISE_SEED, index))
                work += rng.normal(0.0, self.noise_std, work.shape).astype(np.float32)
            out = np.clip(np.rint(work), 0, 255).astype(np.uint8)
        if self.jpeg_quality is not None:
            ok, encoded = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
            if not ok:
                raise RuntimeError(f"variant {self.name}: JPEG encoding failed at frame {index}")
            out = cv2.imdecode(encoded, cv2.IMREAD_COLOR)
        return out

    def frame_range(self, frame_count: int, max_frames: int | None) -> list[int]:
        """The frame indices this variant runs on: from `first_frame`, at most `max_frames`."""
        if self.first_frame >= frame_count:
            raise ValueError(
                f"variant {self.name} starts at frame {self.first_frame}, "
                f"but the sequence has {frame_count} frames"
            )
        end = frame_count if max_frames is None else min(frame_count, self.first_frame + max_frames)
        return list(range(self.first_frame, end))


SUITE: tuple[Variant, ...] = (
    Variant("original", "the shared video as it is"),
    Variant("jpeg95", "re-encoded as JPEG, quality 95", jpeg_quality=95),
    Variant("jpeg75", "re-encoded as JPEG, quality 75", jpeg_quality=75),
    Variant("jpeg50", "re-encoded as JPEG, quality 50", jpeg_quality=50),
    Variant("bright", "brighter by 30 grey levels", brightness_shift=30.0),
    Variant("dark", "darker by 30 grey levels", brightness_shift=-30.0),
    Variant("low_contrast", "contrast x0.6 around mid-grey", contrast_gain=0.6),
    Variant("noise", "Gaussian sensor noise, 8 grey levels", noise_std=8.0),
    Variant("blur", "Gaussian blur, sigma 1.2 px", blur_sigma_px=1.2),
    Variant("offset50", "the run starts at frame 50", first_frame=50),
    Variant("offset100", "the run starts at frame 100", first_frame=100),
)
VARIANTS = {v.name: v for v in SUITE}


def variant(name: str) -> Variant:
    try:
        return VARIANTS[name]
    except KeyError:
        raise ValueError(
            f"unknown perturbation variant {name!r}; the suite has: {', '.join(VARIANTS)}"
        ) from None


class PerturbedSequence:
    """A PETS sequence whose frames are shown through a variant; everything else (ground
    truth, frame count) is the wrapped sequence's."""

    def __init__(self, sequence, variant: Variant):
        self.wrapped = sequence
        self.variant = variant

    def read_frame(self, index: int) -> np.ndarray:
        return self.variant.apply(self.wrapped.read_frame(index), index)

    def frames(self, indices: Iterable[int] | None = None) -> Iterator[tuple[int, np.ndarray]]:
        for index, image in self.wrapped.frames(indices):
            yield index, self.variant.apply(image, index)

    def __getattr__(self, name: str):
        return getattr(self.wrapped, name)


def perturbed_setup(setup, variant: Variant):
    """The PetsSetup with its sequence seen through `variant`."""
    if not variant.changes_pixels:
        return setup
    return dataclasses.replace(setup, sequence=PerturbedSequence(setup.sequence, variant))


def add_perturb_arguments(p) -> None:
    p.add_argument("--perturb", action="store_true",
                   help="run over the perturbation suite (" + ", ".join(VARIANTS) + ") and "
                        "report each variant plus the mean and the worst")  # fmt: skip
    p.add_argument("--variants",
                   help="comma-separated subset of the suite to run (implies --perturb)")  # fmt: skip


def selected_variants(args) -> list[Variant] | None:
    """The variants `--perturb` / `--variants` ask for; None for a plain run."""
    names = getattr(args, "variants", None)
    if names is not None:
        chosen = [variant(n.strip()) for n in names.split(",") if n.strip()]
        if not chosen:
            raise ValueError("--variants names no variant")
        twice = sorted({v.name for v in chosen if chosen.count(v) > 1})
        if twice:  # each variant is one row of the figures, its mean and its worst
            raise ValueError(f"--variants names {', '.join(twice)} more than once")
        return chosen
    return list(SUITE) if getattr(args, "perturb", False) else None


def selected_pixel_variants(args, what: str) -> list[Variant] | None:
    """`selected_variants` for an evaluation without a sequence (`what`: crops, pasted
    frames, a simulation): `--perturb` keeps the variants that change pixels (and the
    original); a later start named in `--variants` means nothing there and is refused."""
    chosen = selected_variants(args)
    if chosen is None:
        if getattr(args, "only_after_learning", False):  # it would be silently ignored
            raise ValueError("--only-after-learning changes what a variant shows: give "
                             "--perturb or --variants with it")  # fmt: skip
        return None
    for v in chosen:
        if v.first_frame and getattr(args, "variants", None) is not None:
            raise ValueError(f"variant {v.name} starts later: {what} has no sequence")
    return [v for v in chosen if not v.first_frame]


def add_learnt_target_perturb_arguments(p) -> None:
    """`--perturb` / `--variants`, and `--only-after-learning`, for evaluations without a
    sequence that learn a target first."""
    add_perturb_arguments(p)
    p.add_argument("--only-after-learning", action="store_true",
                   help="show the target as it is while it is learnt and only what comes "
                        "after through the variant (light, focus or compression that "
                        "change once the target is known)")  # fmt: skip


# A metric's worst value is its lowest when higher is better, else its highest.
Metrics = dict[str, bool]  # metric -> higher is better


def run_suite(variants: list[Variant], evaluate: Callable[[Variant], dict],
              metrics: Metrics) -> dict:  # fmt: skip
    """`evaluate(variant)` -> {method: {metric: value}} for each variant, under one
    progress bar; then per method and metric the mean and the worst over the variants
    (and which variant was worst)."""
    from tqdm import tqdm

    per_variant: dict[str, dict] = {}
    bar = tqdm(variants, desc="perturbation variants", unit="variant")
    for v in bar:
        bar.set_postfix_str(v.name)
        per_variant[v.name] = evaluate(v)
        # Each variant's figures as soon as they are known: a long run is never all lost.
        log.info("variant %s: %s", v.name, json.dumps(per_variant[v.name], default=_plain))
    return {"variants": per_variant, **summarise(per_variant, metrics)}


def _plain(value):
    """numpy scalars and arrays as JSON numbers and lists."""
    return value.tolist() if isinstance(value, np.ndarray | np.generic) else str(value)


def summarise(per_variant: dict[str, dict], metrics: Metrics) -> dict:
    """{"mean", "worst", "worst_variant"}: per method (those every variant reports), per
    metric, over the variants; the worst variant is None where all are alike."""
    methods = [m for m in next(iter(per_variant.values()))
               if all(isinstance(r.get(m), dict) for r in per_variant.values())]  # fmt: skip
    mean: dict[str, dict] = {}
    worst: dict[str, dict] = {}
    worst_variant: dict[str, dict] = {}
    for method in methods:
        mean[method], worst[method], worst_variant[method] = {}, {}, {}
        for metric, higher_is_better in metrics.items():
            values = {name: float(r[method][metric]) for name, r in per_variant.items()
                      if metric in r[method]}  # fmt: skip
            finite = {k: x for k, x in values.items() if np.isfinite(x)}
            if not finite:
                continue
            pick = min if higher_is_better else max
            name = pick(finite, key=finite.get)
            mean[method][metric] = round(float(np.mean(list(finite.values()))), 4)
            worst[method][metric] = round(finite[name], 4)
            # None where every variant gives the same figure: none is worse than another
            # (naming the first would say "seed 0 never took the target back" of 0 s).
            alike = len(set(finite.values())) == 1 and len(finite) > 1
            worst_variant[method][metric] = None if alike else name
    return {"mean": mean, "worst": worst, "worst_variant": worst_variant}


def plot_spread(suite: dict, metrics: list[str], path: str, title: str) -> None:
    """Per method, per metric: a bar at the mean over the variants with whiskers from the
    lowest to the highest variant, and every variant as a dot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = list(suite["mean"])
    per_variant = suite["variants"]
    x = np.arange(len(methods))
    width = 0.8 / len(metrics)
    fig, ax = plt.subplots(figsize=(max(6.0, 1.4 * len(methods) + 2), 4))
    lowest = 0.0
    for k, metric in enumerate(metrics):
        offset = (k - (len(metrics) - 1) / 2) * width
        values = [[float(r[m][metric]) for r in per_variant.values()] for m in methods]
        means = np.array([np.mean(v) for v in values])
        low = means - np.array([min(v) for v in values])
        high = np.array([max(v) for v in values]) - means
        bars = ax.bar(x + offset, means, width * 0.9, yerr=[low, high], capsize=3,
                      label=metric.replace("_", " "))  # fmt: skip
        ax.bar_label(bars, labels=[f"{min(v):.2f}" for v in values], fontsize=7,
                     label_type="center")  # fmt: skip
        for i, v in enumerate(values):
            ax.plot(np.full(len(v), x[i] + offset), v, "k.", markersize=3, alpha=0.5)
        lowest = min(lowest, *(min(v) for v in values))
    ax.set_xticks(x, methods)
    ax.set_ylim(lowest, 1.05)
    ax.set_title(f"{title}\nbars: mean over {len(per_variant)} variants, whiskers: min/max, "
                 "label: worst", fontsize=9)  # fmt: skip
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def print_suite(suite: dict, metrics: list[str], method_label: str = "method",
                rows_key: str = "variants") -> None:  # fmt: skip
    """A per-variant (or per-`rows_key` entry) table of every method's figures, then the
    mean and the worst."""
    methods = list(suite["mean"])
    width = max(12, len(method_label), *(len(m) for m in methods))
    row_label = rows_key.rstrip("s")
    header = f"{row_label:14s} {method_label:{width}s} " + " ".join(f"{m:>12s}" for m in metrics)
    print(header)
    rows = [(name, r) for name, r in suite[rows_key].items()]
    rows += [("MEAN", suite["mean"]), ("WORST", suite["worst"])]
    for name, r in rows:
        for method in methods:
            cells = " ".join(f"{float(r[method].get(k, float('nan'))):12.3f}" for k in metrics)
            print(f"{name:14s} {method:{width}s} {cells}")
