"""OpenPose decoding: heatmaps + part affinity fields -> multi-person skeletons.

Steps: (1) keypoint candidates are the local maxima (3x3 non-maximum suppression) of
each heatmap above a threshold (the MAX_PEAKS_PER_KEYPOINT strongest of each), refined
to sub-cell precision by a parabola through the peak and its neighbours; (2) every pair
of candidates of a limb is scored by the line integral of the limb's PAF along the
segment between them; (3) limbs are matched greedily by score and joined into persons;
(4) persons with too few parts are dropped.

All coordinates here are in heatmap cells (stride 8 of the network input).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from follow.config import PoseConfig
from follow.types import NUM_KEYPOINTS

log = logging.getLogger(__name__)
_peaks_dropped_warned_s: float | None = None  # when the last such warning was given

# Limbs as (keypoint a, keypoint b) and the PAF channels (x, y) that point from a to b.
# Ordered so that every limb after the first joins a keypoint already reached (tree from
# the neck); the last two (shoulder-ear) are redundant links that only join existing
# persons. This is the pairing the Lightweight OpenPose network family was trained with;
# tests/test_pose_paf.py checks it against the network's output on real frames.
LIMB_KEYPOINTS: tuple[tuple[int, int], ...] = (
    (1, 2), (1, 5), (2, 3), (3, 4), (5, 6), (6, 7), (1, 8), (8, 9), (9, 10), (1, 11),
    (11, 12), (12, 13), (1, 0), (0, 14), (14, 16), (0, 15), (15, 17), (2, 16), (5, 17),
)  # fmt: skip
LIMB_PAF_CHANNELS: tuple[tuple[int, int], ...] = (
    (12, 13), (20, 21), (14, 15), (16, 17), (22, 23), (24, 25), (0, 1), (2, 3), (4, 5),
    (6, 7), (8, 9), (10, 11), (28, 29), (30, 31), (34, 35), (32, 33), (36, 37), (18, 19),
    (26, 27),
)  # fmt: skip
REDUNDANT_LIMBS = frozenset({17, 18})
# Keypoint candidates kept per heatmap, the strongest: real frames give a few per person
# (at most 6 seen with the real network; a crowd of 30 needs 30), while heatmaps full of
# peaks (a faulty back-end) paired n_a x n_b candidates per limb: seconds and gigabytes
# a frame.
MAX_PEAKS_PER_KEYPOINT = 64
PEAKS_DROPPED_WARNING_PERIOD_S = 10.0
# Changes whenever the same maps decode into different skeletons (keys cached results).
DECODER_VERSION = 3  # 2: duplicate skeletons of one body suppressed; 3: edge keypoints


@dataclass(frozen=True)
class DecodeParams:
    """Thresholds of the decoder (the detector fills them from PoseConfig, whose
    defaults are these)."""

    peak_threshold: float = PoseConfig.heatmap_peak_threshold
    paf_samples: int = PoseConfig.paf_samples
    paf_min_sample_score: float = PoseConfig.paf_min_sample_score
    paf_min_sample_fraction: float = PoseConfig.paf_min_sample_fraction
    min_keypoints_per_person: int = PoseConfig.min_keypoints_per_person
    min_person_mean_score: float = PoseConfig.min_person_mean_score
    duplicate_keypoint_distance: float = PoseConfig.duplicate_keypoint_distance
    duplicate_shared_keypoints: int = PoseConfig.duplicate_shared_keypoints
    duplicate_box_containment: float = PoseConfig.duplicate_box_containment
    top_edge_margin_cells: float = PoseConfig.top_edge_margin_cells
    bottom_edge_margin_cells: float = PoseConfig.bottom_edge_margin_cells


@dataclass(frozen=True)
class DecodedPerson:
    """One person in heatmap cells: (18, 2) coordinates (NaN where missing), (18,) peak
    confidences (0 where missing) and the assembly score."""

    keypoints_cells: np.ndarray
    confidences: np.ndarray
    score: float


def find_peaks(heatmaps: np.ndarray, threshold: float) -> list[np.ndarray]:
    """Per keypoint channel, an (n, 3) array of [x, y, value] local maxima above threshold.

    A cell is a peak when it equals the maximum of its 3x3 neighbourhood; on a flat top
    only the cell with no equal neighbour to its right or below is kept, so a plateau
    yields one peak. x, y are refined by a parabola fit in each axis.
    """
    maps = np.ascontiguousarray(heatmaps[:NUM_KEYPOINTS], dtype=np.float32)
    k, h, w = maps.shape
    padded = np.full((k, h + 2, w + 2), -np.inf, dtype=np.float32)
    padded[:, 1:-1, 1:-1] = maps
    # Only cells above the threshold can be peaks: compare those with their 8 neighbours.
    ch, ys, xs = np.nonzero(maps > threshold)
    values = maps[ch, ys, xs]
    is_max = np.ones(values.shape, dtype=bool)
    after = np.zeros(values.shape, dtype=bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy or dx:
                neighbour = padded[ch, ys + 1 + dy, xs + 1 + dx]
                is_max &= values >= neighbour
                if (dy, dx) > (0, 0):  # right, or the row below
                    after |= neighbour == values
    # A peak is a local maximum; on a plateau, keep only the cell with no equal
    # neighbour to its right or below.
    keep = is_max & ~after
    ch, ys, xs, values = ch[keep], ys[keep], xs[keep], values[keep]
    left = padded[ch, ys + 1, xs]
    right = padded[ch, ys + 1, xs + 2]
    up = padded[ch, ys, xs + 1]
    down = padded[ch, ys + 2, xs + 1]
    fx = _parabola_offset(left, values, right)
    fy = _parabola_offset(up, values, down)
    peaks = np.stack([xs + fx, ys + fy, values], axis=1).astype(np.float64)
    bounds = np.searchsorted(ch, np.arange(k + 1))
    return [peaks[bounds[i] : bounds[i + 1]] for i in range(k)]


def strongest_peaks(peaks: list[np.ndarray], max_per_channel: int) -> tuple[list[np.ndarray], int]:
    """Each channel's `max_per_channel` highest peaks, in their original order (so that
    a channel within the limit decodes as before), and how many were dropped."""
    kept, dropped = [], 0
    for channel in peaks:
        if len(channel) <= max_per_channel:
            kept.append(channel)
            continue
        strongest = np.argsort(-channel[:, 2], kind="stable")[:max_per_channel]
        kept.append(channel[np.sort(strongest)])
        dropped += len(channel) - max_per_channel
    return kept, dropped


def _warn_of_dropped_peaks(dropped: int) -> None:
    """One warning per PEAKS_DROPPED_WARNING_PERIOD_S: a faulty back-end does it every
    frame."""
    global _peaks_dropped_warned_s
    now_s = time.monotonic()
    last_s = _peaks_dropped_warned_s
    if last_s is not None and now_s - last_s < PEAKS_DROPPED_WARNING_PERIOD_S:
        return
    _peaks_dropped_warned_s = now_s
    log.warning("pose decoding: %d keypoint candidates dropped beyond the %d strongest of "
                "a heatmap (heatmaps full of peaks: a faulty back-end?)",
                dropped, MAX_PEAKS_PER_KEYPOINT)  # fmt: skip


def _parabola_offset(before: np.ndarray, centre: np.ndarray, after: np.ndarray) -> np.ndarray:
    """Sub-cell offset of the vertex of the parabola through three samples (0 at borders)."""
    valid = np.isfinite(before) & np.isfinite(after)
    b = np.where(valid, before, centre)
    a = np.where(valid, after, centre)
    denom = b - 2 * centre + a
    with np.errstate(divide="ignore", invalid="ignore"):
        offset = np.where(denom < 0, 0.5 * (b - a) / denom, 0.0)
    return np.clip(offset, -0.5, 0.5)


def score_limbs(
    pafs: np.ndarray, peaks: list[np.ndarray], params: DecodeParams
) -> list[np.ndarray]:
    """For every limb, the (n_a, n_b) PAF line-integral scores of all candidate pairs;
    -inf where the pair is not a limb. All limbs are sampled in one vectorised pass.

    The score is the mean projection of the PAF on the unit segment direction over
    `paf_samples` points, minus a penalty for limbs longer than half the map height; a
    pair is rejected when fewer than `paf_min_sample_fraction` samples agree.
    """
    h, w = pafs.shape[1:]
    starts, ends, chan_x, chan_y, shapes = [], [], [], [], []
    for (ka, kb), (cx, cy) in zip(LIMB_KEYPOINTS, LIMB_PAF_CHANNELS, strict=True):
        na, nb = len(peaks[ka]), len(peaks[kb])
        shapes.append((na, nb))
        if na == 0 or nb == 0:
            continue
        starts.append(np.repeat(peaks[ka][:, :2], nb, axis=0))
        ends.append(np.tile(peaks[kb][:, :2], (na, 1)))
        chan_x.append(np.full(na * nb, cx, np.intp))
        chan_y.append(np.full(na * nb, cy, np.intp))
    if not starts:
        return [np.full(shape, -np.inf) for shape in shapes]
    a = np.concatenate(starts)
    vec = np.concatenate(ends) - a  # (P, 2)
    cx = np.concatenate(chan_x)[:, None]
    cy = np.concatenate(chan_y)[:, None]
    length = np.hypot(vec[:, 0], vec[:, 1])
    safe = np.maximum(length, 1e-6)
    ux, uy = vec[:, 0] / safe, vec[:, 1] / safe
    t = np.linspace(0.0, 1.0, params.paf_samples)
    xi = np.clip(np.rint(a[:, 0:1] + t * vec[:, 0:1]).astype(np.intp), 0, w - 1)
    yi = np.clip(np.rint(a[:, 1:2] + t * vec[:, 1:2]).astype(np.intp), 0, h - 1)
    dots = pafs[cx, yi, xi] * ux[:, None] + pafs[cy, yi, xi] * uy[:, None]  # (P, n)
    agree = (dots > params.paf_min_sample_score).mean(axis=1)
    score = dots.mean(axis=1) + np.minimum(0.5 * h / safe - 1.0, 0.0)
    ok = (agree >= params.paf_min_sample_fraction) & (score > 0) & (length > 1e-6)
    flat = np.where(ok, score, -np.inf)
    out, offset = [], 0
    for na, nb in shapes:
        out.append(flat[offset : offset + na * nb].reshape(na, nb))
        offset += na * nb
    return out


def match_limb(scores: np.ndarray) -> list[tuple[int, int, float]]:
    """Greedy one-to-one matching: best-scoring pairs first, each candidate used once."""
    ia, ib = np.nonzero(np.isfinite(scores))
    if ia.size == 0:
        return []
    order = np.argsort(-scores[ia, ib], kind="stable")
    used_a: set[int] = set()
    used_b: set[int] = set()
    out = []
    for k in order:
        a, b = int(ia[k]), int(ib[k])
        if a in used_a or b in used_b:
            continue
        used_a.add(a)
        used_b.add(b)
        out.append((a, b, float(scores[a, b])))
    return out


def decode(heatmaps: np.ndarray, pafs: np.ndarray, params: DecodeParams) -> list[DecodedPerson]:
    """Skeletons from one image's (>=18, h, w) heatmaps and (38, h, w) PAFs."""
    heatmaps, pafs = _finite(heatmaps), _finite(pafs)
    peaks, dropped = strongest_peaks(
        find_peaks(heatmaps, params.peak_threshold), MAX_PEAKS_PER_KEYPOINT
    )
    if dropped:
        _warn_of_dropped_peaks(dropped)
    # Each person: slot per keypoint holding a candidate index (-1 = none), and a score.
    slots: list[np.ndarray] = []
    scores: list[float] = []
    owner: dict[tuple[int, int], int] = {}  # (keypoint, candidate) -> person index
    all_scores = score_limbs(pafs, peaks, params)
    for limb, (ka, kb) in enumerate(LIMB_KEYPOINTS):
        cand_a, cand_b = peaks[ka], peaks[kb]
        for a, b, s in match_limb(all_scores[limb]):
            pa, pb = owner.get((ka, a)), owner.get((kb, b))
            if pa is not None and pb is None:
                if slots[pa][kb] < 0:
                    _assign(slots, scores, owner, pa, kb, b, cand_b[b, 2] + s)
            elif pb is not None and pa is None:
                if slots[pb][ka] < 0:
                    _assign(slots, scores, owner, pb, ka, a, cand_a[a, 2] + s)
            elif pa is None and pb is None:
                if limb in REDUNDANT_LIMBS:
                    continue
                slots.append(np.full(NUM_KEYPOINTS, -1, dtype=np.intp))
                scores.append(0.0)
                p = len(slots) - 1
                _assign(slots, scores, owner, p, ka, a, cand_a[a, 2])
                _assign(slots, scores, owner, p, kb, b, cand_b[b, 2] + s)
            elif pa != pb and not ((slots[pa] >= 0) & (slots[pb] >= 0)).any():
                _merge(slots, scores, owner, pa, pb, s)
    people = []
    for p, slot in enumerate(slots):
        present = slot >= 0
        count = int(present.sum())
        if count == 0 or count < params.min_keypoints_per_person:
            continue
        if scores[p] / count < params.min_person_mean_score:
            continue
        kps = np.full((NUM_KEYPOINTS, 2), np.nan)
        conf = np.zeros(NUM_KEYPOINTS)
        for k in np.nonzero(present)[0]:
            kps[k] = peaks[k][slot[k], :2]
            conf[k] = peaks[k][slot[k], 2]
        people.append(DecodedPerson(kps, conf, float(scores[p])))
    people = suppress_duplicates(people, params)
    if params.top_edge_margin_cells > 0 or params.bottom_edge_margin_cells > 0:
        people = without_edge_keypoints(people, heatmaps.shape[1], params.top_edge_margin_cells,
                                        params.bottom_edge_margin_cells)  # fmt: skip
    return people


def without_edge_keypoints(people: list[DecodedPerson], rows: int, top_margin_cells: float,
                           bottom_margin_cells: float) -> list[DecodedPerson]:  # fmt: skip
    """The people without their keypoints within `top_margin_cells` of the heatmap's top
    edge or `bottom_margin_cells` of its bottom edge (persons left with none are
    dropped). The outermost row's centre is half a cell from the edge.

    A joint just beyond the frame's top or bottom edge leaves its peak on or next to the
    outermost row: real person crops cut off at the frame's bottom had their ankles
    reported up to 2 cells inside it with the feet up to 5 cells below it, and the necks
    of heads cut off at the top on its first row (docs/pose.md, *Joints beyond the
    frame*). Taken as the ankle, such a point puts a near person farther away than they
    are, and the robot drives on toward them; such a neck does the same.
    """
    out = []
    for person in people:
        y = person.keypoints_cells[:, 1]
        with np.errstate(invalid="ignore"):
            near_edge = (y + 0.5 <= top_margin_cells) | (rows - 0.5 - y <= bottom_margin_cells)
        if not near_edge.any():
            out.append(person)
            continue
        if not (np.isfinite(y) & ~near_edge).any():
            continue
        kps = person.keypoints_cells.copy()
        kps[near_edge] = np.nan
        conf = np.where(near_edge, 0.0, person.confidences)
        out.append(DecodedPerson(kps, conf, person.score))
    return out


def _finite(maps: np.ndarray) -> np.ndarray:
    """The maps with NaN and infinite values set to 0: a back-end fault (an FP16
    overflow) is no evidence of a keypoint or a limb, and an infinite peak would give a
    skeleton an infinite confidence."""
    maps = np.asarray(maps)
    if np.isfinite(maps).all():
        return maps
    return np.where(np.isfinite(maps), maps, 0).astype(maps.dtype, copy=False)


def suppress_duplicates(people: list[DecodedPerson], params: DecodeParams) -> list[DecodedPerson]:
    """One skeleton per body. A person seen large gives wide heatmap blobs with two
    peaks per keypoint, which greedy assembly can join into two skeletons (or a
    skeleton and a fragment); the tracker would make two tracks of them. Skeletons
    are kept largest first (most keypoints, then score); a later one is dropped when
    it repeats keypoints of a kept one at nearly the same place, or lies inside a kept
    one's keypoint box."""
    order = sorted(
        people, key=lambda p: (-int(np.isfinite(p.keypoints_cells[:, 0]).sum()), -p.score)
    )
    kept: list[DecodedPerson] = []
    for person in order:
        if not any(_is_duplicate(person, big, params) for big in kept):
            kept.append(person)
    return kept


def _is_duplicate(small: DecodedPerson, big: DecodedPerson, params: DecodeParams) -> bool:
    big_pts = big.keypoints_cells[np.isfinite(big.keypoints_cells[:, 0])]
    small_present = np.isfinite(small.keypoints_cells[:, 0])
    lo, hi = big_pts.min(axis=0), big_pts.max(axis=0)
    extent = float(max(hi - lo))
    if extent <= 0:
        return False
    both = small_present & np.isfinite(big.keypoints_cells[:, 0])
    gaps = np.hypot(*(small.keypoints_cells[both] - big.keypoints_cells[both]).T)
    if (
        gaps <= params.duplicate_keypoint_distance * extent
    ).sum() >= params.duplicate_shared_keypoints:
        return True
    pts = small.keypoints_cells[small_present]
    inside = ((pts >= lo) & (pts <= hi)).all(axis=1).mean()
    return bool(inside >= params.duplicate_box_containment)


def _assign(slots, scores, owner, person: int, keypoint: int, cand: int, gain: float) -> None:
    slots[person][keypoint] = cand
    scores[person] += float(gain)
    owner[(keypoint, cand)] = person


def _merge(slots, scores, owner, keep: int, drop: int, link_score: float) -> None:
    for k in np.nonzero(slots[drop] >= 0)[0]:
        cand = int(slots[drop][k])
        slots[keep][k] = cand
        owner[(int(k), cand)] = keep
    scores[keep] += scores[drop] + link_score
    slots[drop][:] = -1
    scores[drop] = 0.0
