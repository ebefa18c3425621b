"""The identification evaluation's cue cache hands re-id embeddings to the identifier
only where it asks for them, as on a robot: while the target is tracked, the others are
scored by the classifier alone, and the rules comparing them with the target must see
the same confidences in the evaluation as live."""

import numpy as np

from follow.eval.identification import _CachedDescribe
from follow.identify.appearance import Appearance


class _Model:
    def __init__(self):
        self.calls = []

    def describe(self, image_bgr, rois, embed=None):
        self.calls.append(len(rois))
        return [Appearance(embedding=np.full(4, r[0], np.float32), parts=np.zeros(2))
                for r in rois]  # fmt: skip

    def lacks_embedding(self, appearance):
        return appearance.embedding is None


def test_embeddings_go_only_where_asked_and_each_roi_is_described_once():
    model = _Model()
    cache = _CachedDescribe(model)
    cache.frame_index = 3
    rois = [(10, 0, 20, 40), (30, 0, 40, 40)]
    looked = cache.describe(None, rois, [True, False])
    assert looked[0].embedding is not None and looked[1].embedding is None
    completed = cache.complete(None, rois, looked)
    assert [a.embedding[0] for a in completed] == [10.0, 30.0]
    assert cache.describe(None, rois)[1].embedding is not None  # no mask: all of them
    assert model.calls == [2]  # computed once for the frame, whatever was handed over
    cache.frame_index = 4
    cache.describe(None, rois[:1], [False])
    assert model.calls == [2, 1]
