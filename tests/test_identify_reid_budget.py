"""The re-id network runs only where it decides something: on the target while it is
tracked, on everyone during re-identification."""

import numpy as np
import pytest

from follow.config import IdentifyConfig
from follow.identify.appearance import Appearance, AppearanceModel
from follow.identify.context import FrameTracks, IdentityContext

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
