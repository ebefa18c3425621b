"""What a person looks like to the identifier, and the learnt model of the target.

An `Appearance` holds one person's cues in one frame: the feature maps for the boosted
classifier and/or the re-id embedding, and the colours of the torso and the legs. The
`AppearanceModel` learns the target from them (positives) against everyone else
(negatives) and scores any appearance with a confidence in [-1, 1]; with both cues the
confidences are fused as a weighted mean. The part colours are no cue of their own: they
say how far a person's torso or legs are from the colours the target was seen in.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from follow.boost.online_boosting import OnlineBoostingClassifier
from follow.ccf.features import FeatureExtractor, FeatureMaps, Roi, cut_crops, resize_crops
from follow.config import IdentifyConfig
from follow.identify.parts import PartGallery, part_colours
from follow.identify.reid import ReidEmbedder, ReidGallery

log = logging.getLogger(__name__)

PART_GALLERY_SIZE = 32  # the target's part colours kept (the most alike one goes)


@dataclass(frozen=True)
class Appearance:
    """One person's cues in one frame (None where that cue is not used), and the colours
    of their torso and legs (`follow.identify.parts`)."""

    maps: FeatureMaps | None = None
    embedding: np.ndarray | None = None
    parts: np.ndarray | None = None


class AppearanceModel:
    """Online model of the target's appearance from one or two cues."""

    def __init__(
        self,
        config: IdentifyConfig,
        extractor: FeatureExtractor | None,
        reid: ReidEmbedder | None = None,
    ):
        if extractor is None and reid is None:
            raise ValueError(
                "an appearance model needs a feature extractor, a re-id network or both"
            )
        if not 0.0 <= config.reid_weight <= 1.0:
            raise ValueError(f"reid_weight must lie in [0, 1], got {config.reid_weight}")
        self.config = config
        self.extractor = extractor
        self.reid = reid
        self.reset()

    def reset(self) -> None:
        """Forget the target."""
        self.classifier = (
            OnlineBoostingClassifier(self.extractor.num_channels, self.config)
            if self.extractor is not None
            else None
        )
        self.gallery = ReidGallery(self.config) if self.reid is not None else None
        self.part_gallery = PartGallery(PART_GALLERY_SIZE)

    def snapshot(self) -> tuple:
        """A copy of what has been learnt, to be put back with `restore` (the networks
        are not copied)."""
        return copy.deepcopy((self.classifier, self.gallery, self.part_gallery))

    def restore(self, snapshot: tuple) -> None:
        self.classifier, self.gallery, self.part_gallery = copy.deepcopy(snapshot)

    @property
    def name(self) -> str:
        parts = [self.extractor.name] if self.extractor is not None else []
        return "+".join(parts + (["reid"] if self.reid is not None else []))

    @property
    def ready(self) -> bool:
        """Whether it has learnt anything to score with."""
        boost_ready = self.classifier is not None and self.classifier.is_trained
        return boost_ready or (self.gallery is not None and len(self.gallery) > 0)

    def _combine(self, maps, embeddings, crops: np.ndarray) -> list[Appearance]:
        """One Appearance per crop (N, H, W, 3 at the crop size)."""
        parts = part_colours(crops, self.config)
        return [
            Appearance(
                maps[i] if maps is not None else None,
                embeddings[i] if embeddings is not None else None,
                parts[i],
            )
            for i in range(len(crops))
        ]

    def _crop_size(self) -> tuple[int, int]:
        return self.config.crop_width_px, self.config.crop_height_px

    def _maps(self, crops: np.ndarray, at_own_size: Callable[[], list]):
        """The feature maps of `crops` (already at the crop size) where the extractor
        works at that size, else `at_own_size()` (from the originals)."""
        if self.extractor is None:
            return None
        if tuple(self.extractor.crop_size) == self._crop_size():
            return self.extractor.extract_crops(crops)
        return at_own_size()

    def describe(
        self, image_bgr: np.ndarray, rois: Sequence[Roi], embed: Sequence[bool] | None = None
    ) -> list[Appearance]:
        """The cues of each ROI of a frame (all people in one batch). The re-id network
        (~7 ms a person on a laptop core) runs only on the ROIs `embed` marks (default
        all); the others get no embedding until `complete` gives them one."""
        if not rois:
            return []
        crops = cut_crops(image_bgr, rois, self._crop_size())  # cut once for both uses
        maps = self._maps(crops, lambda: self.extractor.extract(image_bgr, rois))
        if self.reid is None:
            return self._combine(maps, None, crops)
        described = self._combine(maps, [None] * len(rois), crops)
        wanted = [i for i in range(len(rois)) if embed is None or embed[i]]
        return self._embedded(image_bgr, rois, described, wanted)

    def complete(
        self, image_bgr: np.ndarray, rois: Sequence[Roi], appearances: Sequence[Appearance]
    ) -> list[Appearance]:
        """The appearances with the re-id embeddings `describe` left out filled in."""
        missing = [i for i, a in enumerate(appearances) if self.lacks_embedding(a)]
        return self._embedded(image_bgr, rois, appearances, missing)

    def _embedded(self, image_bgr, rois, appearances, indices: list[int]) -> list[Appearance]:
        """The appearances with the re-id embeddings of those at `indices` (one batch). A
        non-finite embedding (a faulty run of the network) is left out: learnt, one NaN
        would make every later similarity to the gallery NaN, and the target could never
        be re-identified again."""
        if not indices:
            return list(appearances)
        found = self.reid.embed(image_bgr, [rois[i] for i in indices])
        return _with_embeddings(appearances, indices, found)

    @property
    def has_reid(self) -> bool:
        """Whether a re-id cue is fused with the boosted classifier."""
        return self.reid is not None

    def lacks_embedding(self, appearance: Appearance) -> bool:
        return self.reid is not None and appearance.embedding is None

    def describe_crops(self, crops_bgr: Sequence[np.ndarray]) -> list[Appearance]:
        """The cues of whole person crops."""
        if not crops_bgr:
            return []
        crops = resize_crops(crops_bgr, self._crop_size())  # resized once for both uses
        maps = self._maps(crops, lambda: self.extractor.extract_crops(crops_bgr))
        if self.reid is None:
            return self._combine(maps, None, crops)
        described = self._combine(maps, [None] * len(crops), crops)
        found = self.reid.embed_crops(crops_bgr)  # a non-finite one left out, as `describe`
        return _with_embeddings(described, list(range(len(crops))), found)

    def synthetic_negatives(self, crop_bgr: np.ndarray, count: int) -> list:
        """Feature maps of `count` colour-changed copies of the target's crop: what the
        target would look like in other clothes, for a classifier with too few real
        negatives (it would otherwise call anyone the target)."""
        if self.extractor is None or count <= 0:
            return []
        return self.extractor.extract_crops(recoloured_copies(crop_bgr, count))

    def mirrored_positives(self, crop_bgr: np.ndarray) -> list:
        """Feature maps of the target's crop mirrored left-right, a second positive for
        the boosted classifier (`mirrored_positives`): the target seen from its other
        side, or turned, still wears the same clothes, and a classifier learnt from a
        few seconds of one view otherwise keys on which side a pattern is on. None
        with "never", nor with "with_reid" (the default) where there is no re-id cue."""
        mode = self.config.mirrored_positives
        if self.extractor is None or not reid_rule_applies(mode, self.has_reid):
            return []
        return self.extractor.extract_crops([np.ascontiguousarray(crop_bgr[:, ::-1])])

    def crop(self, image_bgr: np.ndarray, roi: Roi) -> np.ndarray:
        """The ROI of an image at the classifier's crop size."""
        return cut_crops(image_bgr, [roi], self._crop_size())[0]

    def learn(
        self,
        positives: Sequence[Appearance],
        negatives: Sequence[Appearance],
        synthetic_negative_maps: Sequence[FeatureMaps] = (),
        synthetic_positive_maps: Sequence[FeatureMaps] = (),
    ) -> None:
        """One frame's samples: the target (positives) and others (negatives); the
        synthetic ones (recoloured negatives, mirrored positives) train only the boosted
        classifier. The positives' part colours join the target's."""
        if self.classifier is not None:
            self.classifier.train(
                [a.maps for a in positives] + list(synthetic_positive_maps),
                [a.maps for a in negatives] + list(synthetic_negative_maps),
            )
        if self.gallery is not None:
            for a in positives:
                if a.embedding is not None:  # none where the network's output was unusable
                    self.gallery.add(a.embedding)
        for a in positives:
            if a.parts is not None:
                self.part_gallery.add(a.parts)

    def _gallery_scores(self, appearances: Sequence[Appearance], score) -> np.ndarray:
        """`score` (a gallery method) of each appearance's embedding; NaN without one."""
        out = np.full(len(appearances), np.nan)
        has = [i for i, a in enumerate(appearances) if a.embedding is not None]
        if has:
            out[has] = score(np.stack([appearances[i].embedding for i in has]))
        return out

    def similarity(self, appearances: Sequence[Appearance]) -> np.ndarray | None:
        """Each appearance's highest re-id similarity to the target's gallery (NaN for
        one without an embedding, which passes no bar); None without a re-id cue or
        before anything was learnt."""
        if self.gallery is None or len(self.gallery) == 0 or not appearances:
            return None
        return self._gallery_scores(appearances, self.gallery.similarity)

    def part_distances(self, appearances: Sequence[Appearance]) -> np.ndarray | None:
        """Each appearance's distance from the target's colours in its least alike part
        (`follow.identify.parts`; NaN for one without part colours, which passes no
        bar); None before any was learnt."""
        if len(self.part_gallery) == 0 or not appearances:
            return None
        out = np.full(len(appearances), np.nan)
        has = [i for i, a in enumerate(appearances) if a.parts is not None]
        if has:
            out[has] = self.part_gallery.distances(np.stack([appearances[i].parts for i in has]))
        return out

    def classifier_confidence(self, appearances: Sequence[Appearance]) -> np.ndarray | None:
        """The boosted classifier's own confidence in each appearance, where it is one
        of two cues that must agree (`reid_cues_must_agree`; None otherwise): one cue
        vouching strongly must not carry a stranger past a doubtful other."""
        two_cues = self.classifier is not None and self.gallery is not None
        if not (two_cues and self.config.reid_cues_must_agree):
            return None
        if not self.classifier.is_trained:  # it learnt nothing usable: it vouches for no one
            return np.zeros(len(appearances))
        if not appearances:
            return np.zeros(0)
        return self.classifier.confidence([a.maps for a in appearances])

    def confidence(self, appearances: Sequence[Appearance]) -> np.ndarray:
        """Confidence in [-1, 1] of each appearance being the target (0 before learning).
        An appearance without a re-id embedding is scored by the classifier alone."""
        n = len(appearances)
        if n == 0:
            return np.zeros(0)
        total, weight = np.zeros(n), np.zeros(n)
        if self.classifier is not None and self.classifier.is_trained:
            w = 1.0 - self.config.reid_weight if self.gallery is not None else 1.0
            total += w * self.classifier.confidence([a.maps for a in appearances])
            weight += w
        if self.gallery is not None and len(self.gallery) > 0:
            w = self.config.reid_weight if self.classifier is not None else 1.0
            scores = self._gallery_scores(appearances, self.gallery.confidence)
            known = ~np.isnan(scores)
            total[known] += w * scores[known]
            weight[known] += w
        fused = np.divide(total, weight, out=np.zeros(n), where=weight > 0.0)
        return np.clip(fused, -1.0, 1.0)


def _with_embeddings(appearances, indices: list[int], found) -> list[Appearance]:
    """The appearances with the embeddings `found` for those at `indices`; a non-finite
    one is left out (see `AppearanceModel._embedded`)."""
    out = list(appearances)
    for i, embedding in zip(indices, found, strict=True):
        if np.all(np.isfinite(embedding)):
            out[i] = dataclasses.replace(out[i], embedding=embedding)
        else:
            log.warning("re-id: the network gave a non-finite embedding; not used")
    return out


def reid_rule_applies(mode: str, has_reid: bool) -> bool:
    """Whether an identifier rule set to `mode` applies: "always", "never", or
    "with_reid" (only where a re-id cue is fused with the boosted classifier)."""
    return mode == "always" or (mode == "with_reid" and has_reid)


def recoloured_copies(crop_bgr: np.ndarray, count: int) -> list[np.ndarray]:
    """`count` copies of the crop in other colours: its brightness inverted (which
    changes dark or grey clothes, where hue means nothing), then its hue turned by
    steps spread evenly round the circle."""
    if count <= 0:
        return []
    hsv = cv2.cvtColor(crop_bgr, cv2.COLOR_BGR2HSV)
    inverted = hsv.copy()
    inverted[..., 2] = 255 - inverted[..., 2]
    copies = [inverted]
    turns = count - 1
    for k in range(turns):
        turned = hsv.copy()
        step = int(round(180 * (k + 1) / (turns + 1)))  # OpenCV hue runs 0..179
        turned[..., 0] = (turned[..., 0].astype(np.int16) + step) % 180
        copies.append(turned)
    return [cv2.cvtColor(c, cv2.COLOR_HSV2BGR) for c in copies]
