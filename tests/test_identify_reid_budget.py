"""The re-id network runs only where it decides something: on the target while it is
tracked, on everyone during re-identification."""

import numpy as np
import pytest

from follow.config import IdentifyConfig
from follow.identify.appearance import Appearance, AppearanceModel
from follow.identify.context import FrameTracks, IdentityContext
from follow.types import TargetStatus

IMAGE = np.zeros((240, 320, 3), np.uint8)


class CountingReid:
    """Each ROI's embedding is a unit vector along axis (ROI x0 % 4); counts ROIs run."""

    def __init__(self):
        self.embedded = 0

    def embed(self, image_bgr, rois):
        self.embedded += len(rois)
        out = np.zeros((len(rois), 256), np.float32)
        for k, roi in enumerate(rois):
            out[k, int(roi[0]) % 4] = 1.0
        return out


def _model():
    reid = CountingReid()
    return AppearanceModel(IdentifyConfig(), extractor=None, reid=reid), reid


def test_describe_embeds_only_the_marked_rois_and_complete_fills_in_the_rest():
    model, reid = _model()
    rois = [(0, 0, 10, 20), (1, 0, 11, 20), (2, 0, 12, 20)]
    described = model.describe(IMAGE, rois, embed=[False, True, False])
    assert reid.embedded == 1
    assert [a.embedding is None for a in described] == [True, False, True]
    assert [model.lacks_embedding(a) for a in described] == [True, False, True]
    completed = model.complete(IMAGE, rois, described)
    assert reid.embedded == 3
    assert all(a.embedding is not None for a in completed)
    assert completed[1] is described[1]  # what was there is kept


def test_an_appearance_without_embedding_passes_no_similarity_bar():
    model, _ = _model()
    model.gallery.add(np.eye(256, dtype=np.float32)[1])
    known = Appearance(embedding=np.eye(256, dtype=np.float32)[1])
    similarity = model.similarity([known, Appearance()])
    assert similarity[0] == pytest.approx(1.0)
    assert np.isnan(similarity[1]) and not similarity[1] >= 0.0
    confidence = model.confidence([known, Appearance()])
    assert confidence[0] == pytest.approx(1.0) and confidence[1] == 0.0


class _Model:
    """Records which ROIs `describe` was asked to embed; no classifier."""

    ready = False

    def __init__(self):
        self.asked: list[list[bool]] = []
        self.completed = 0

    def reset(self):
        pass

    def describe(self, image, rois, embed=None):
        self.asked.append(list(embed))
        return [Appearance(embedding=np.ones(1) if e else None) for e in embed]

    def lacks_embedding(self, appearance):
        return appearance.embedding is None

    def complete(self, image, rois, appearances):
        self.completed += sum(a.embedding is None for a in appearances)
        return [Appearance(embedding=np.ones(1)) for _ in appearances]


def test_a_frame_is_embedded_for_the_target_first_and_for_everyone_on_demand(monkeypatch):
    import follow.identify.context as context_module

    rois = {1: (0, 0, 10, 20), 2: (20, 0, 30, 20), 3: (40, 0, 50, 20)}
    monkeypatch.setattr(context_module, "track_rois", lambda tracks, size, cfg: dict(rois))
    monkeypatch.setattr(context_module, "person_boxes", lambda t, r, s, c: dict(r))
    model = _Model()
    ctx = IdentityContext(IdentifyConfig(), model)
    frame = FrameTracks(IMAGE, [], 0.0, None, {})
    ctx.look(frame, only=2)  # tracking target 2
    assert model.asked == [[False, True, False]]
    ctx.look(frame, only=2)  # a second look this frame costs nothing
    assert model.asked == [[False, True, False]] and model.completed == 0
    ctx.look(frame)  # the target was lost this frame: everyone is a candidate now
    assert model.completed == 2
    assert all(a.embedding is not None for a in frame.appearances.values())
    fresh = FrameTracks(IMAGE, [], 0.1, None, {})
    ctx.look(fresh)  # re-identification from the start of a frame
    assert model.asked[-1] == [True, True, True]


def test_the_classifier_speaks_alone_only_with_two_cues_that_must_agree():
    """`classifier_confidence` is what re-identification asks to agree with the fused
    confidence: present with a trained classifier beside re-id and the rule on."""
    import dataclasses

    from follow.ccf.channels import ChannelFeatureExtractor

    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)
    rois = [(10, 10, 60, 200), (200, 10, 250, 200)]
    extractor = ChannelFeatureExtractor((48, 128))

    def trained(config, reid):
        model = AppearanceModel(config, extractor, reid)
        described = model.describe(image, rois)
        model.learn([described[0]], [described[1]])
        return model, described

    both, described = trained(IdentifyConfig(), CountingReid())
    scores = both.classifier_confidence(described)
    assert scores.shape == (2,) and scores[0] > scores[1]
    off = dataclasses.replace(IdentifyConfig(), reid_cues_must_agree=False)
    assert trained(off, CountingReid())[0].classifier_confidence(described) is None
    assert trained(IdentifyConfig(), None)[0].classifier_confidence(described) is None


def test_a_classifier_that_learnt_nothing_vouches_for_no_one():
    """With two cues that must agree, a boosted classifier that learnt nothing usable
    (no weak classifier better than chance) scores every candidate 0, under every bar:
    it was left out, and re-id alone decided who the target was."""
    from follow.ccf.channels import ChannelFeatureExtractor

    grey = np.full((240, 320, 3), 128, np.uint8)
    rois = [(10, 10, 60, 200), (200, 10, 250, 200)]
    model = AppearanceModel(IdentifyConfig(), ChannelFeatureExtractor((48, 128)), CountingReid())
    described = model.describe(grey, rois)
    assert not model.classifier.is_trained
    np.testing.assert_array_equal(model.classifier_confidence(described), [0.0, 0.0])


class ColourReid:
    """Embeds a ROI by its mean colour about mid-grey (a unit vector), so the same
    clothes are similar and other clothes are not; counts the ROIs it ran on."""

    def __init__(self):
        self.embedded = 0

    def embed(self, image_bgr, rois):
        self.embedded += len(rois)
        out = np.zeros((len(rois), 256), np.float32)
        for k, (x0, y0, x1, y1) in enumerate(rois):
            crop = image_bgr[int(y0) : int(y1), int(x0) : int(x1)].reshape(-1, 3)
            mean = crop.mean(axis=0) - 120.0
            out[k, :3] = mean / max(float(np.linalg.norm(mean)), 1e-6)
        return out


def _two_cue_identifier():
    from test_identify_state_machine import CFG

    from follow.ccf.channels import ChannelFeatureExtractor
    from follow.identify.identifier import TargetIdentifier

    reid = ColourReid()
    extractor = ChannelFeatureExtractor((CFG.crop_width_px, CFG.crop_height_px))
    return TargetIdentifier(CFG, extractor, reid), reid


def _stranger_then_target(identifier, reid):
    """The target is learnt, leaves, a stranger in other clothes stands in view, the
    target comes back under a new track id: (statuses, target ids, ROIs embedded) per
    phase."""
    from test_identify_state_machine import BLUE, GREEN, RED, Person, run

    rng = np.random.default_rng(3)
    target = Person(1, 2.0, 180, RED)
    run(identifier, [target], 12, rng)
    phases = {}
    for name, people, frames, t0 in (
        ("stranger", [Person(5, 2.2, 300, GREEN, trousers=BLUE)], 8, 2.0),
        ("target back", [Person(9, 2.4, 320, RED)], 6, 3.0),
    ):
        before = reid.embedded
        ests = run(identifier, people, frames, rng, t0=t0)
        phases[name] = ([e.status for e in ests], [e.target_id for e in ests],
                        reid.embedded - before)  # fmt: skip
    return phases


def test_reidentification_embeds_nobody_while_no_track_passes_the_other_tests():
    """A stranger whom the boosted classifier alone already rejects is never embedded:
    re-id could not make them the target. The target come back is embedded and taken."""
    identifier, reid = _two_cue_identifier()
    phases = _stranger_then_target(identifier, reid)
    statuses, named, embedded = phases["stranger"]
    assert all(s == TargetStatus.REIDENTIFICATION for s in statuses) and set(named) == {None}
    assert embedded == 0
    statuses, named, embedded = phases["target back"]
    assert named[-1] == 9 and embedded > 0


def test_skipping_the_embeddings_changes_no_decision(monkeypatch):
    """The same frames with re-id forced on every track in re-identification name the
    same target in every frame: the embeddings left out decided nothing."""
    identifier, reid = _two_cue_identifier()
    lazy = _stranger_then_target(identifier, reid)
    look = IdentityContext.look
    monkeypatch.setattr(IdentityContext, "look",
                        lambda self, frame, only=None, embed=True: look(self, frame, only))  # fmt: skip
    identifier, reid = _two_cue_identifier()
    full = _stranger_then_target(identifier, reid)
    assert [p[:2] for p in lazy.values()] == [p[:2] for p in full.values()]
    assert full["stranger"][2] == 8  # forced: the stranger embedded in each of 8 frames


class NanReid(CountingReid):
    """Gives a NaN embedding for the ROI starting at x0 = 1 (a faulty network run)."""

    def embed(self, image_bgr, rois):
        out = super().embed(image_bgr, rois)
        for k, roi in enumerate(rois):
            if int(roi[0]) == 1:
                out[k] = np.nan
        return out


def test_a_non_finite_embedding_is_neither_used_nor_learnt():
    model = AppearanceModel(IdentifyConfig(), extractor=None, reid=NanReid())
    rois = [(0, 0, 10, 20), (1, 0, 11, 20)]
    good, faulty = model.describe(IMAGE, rois)
    assert faulty.embedding is None and good.embedding is not None
    model.learn([faulty], [])  # the target's frame with the faulty run: nothing to learn
    model.learn([good], [])
    similarity = model.similarity([good, faulty])
    assert similarity[0] == pytest.approx(1.0) and np.isnan(similarity[1])
    assert np.isfinite(model.confidence([good])).all()


class NanCropReid:
    """Gives a NaN embedding for a crop whose first pixel is 1 (a faulty network run)."""

    def embed_crops(self, crops):
        out = np.zeros((len(crops), 256), np.float32)
        out[:, 0] = 1.0
        for k, crop in enumerate(crops):
            if int(crop[0, 0, 0]) == 1:
                out[k] = np.nan
        return out


def test_a_non_finite_embedding_of_a_whole_crop_is_neither_used_nor_learnt():
    model = AppearanceModel(IdentifyConfig(), extractor=None, reid=NanCropReid())
    good, faulty = model.describe_crops([np.zeros((64, 32, 3), np.uint8),
                                         np.ones((64, 32, 3), np.uint8)])  # fmt: skip
    assert faulty.embedding is None and good.embedding is not None
    model.learn([faulty], [])
    model.learn([good], [])
    similarity = model.similarity([good, faulty])
    assert similarity[0] == pytest.approx(1.0) and np.isnan(similarity[1])
