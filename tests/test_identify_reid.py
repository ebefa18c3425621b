"""Re-id embedding, gallery, cue fusion and the identifier factory."""

from __future__ import annotations

import numpy as np
import pytest

from follow.ccf.channels import ChannelFeatureExtractor
from follow.config import ConfigError, IdentifyConfig
from follow.identify.appearance import Appearance, AppearanceModel
from follow.identify.factory import build_identifier, parse_identifier
from follow.identify.reid import ReidEmbedder, ReidGallery


def _unit(v):
    v = np.asarray(v, dtype=np.float32)
    return v / np.linalg.norm(v)


def test_gallery_maps_similarity_to_confidence():
    cfg = IdentifyConfig(reid_same_similarity=0.5, reid_similarity_scale=0.25, reid_gallery_size=2)
    gallery = ReidGallery(cfg)
    with pytest.raises(ValueError, match="empty"):
        gallery.similarity(np.zeros((1, 256), np.float32))
    e = np.eye(256, dtype=np.float32)
    gallery.add(e[0])
    probes = np.stack([e[0], _unit(e[0] + e[1]), e[1]])  # similarity 1, 0.707, 0
    np.testing.assert_allclose(gallery.confidence(probes), [1.0, 0.828, -1.0], atol=1e-3)
    gallery.add(e[1])
    gallery.add(e[2])  # capacity 2: e[0] is forgotten
    assert len(gallery) == 2
    np.testing.assert_allclose(gallery.similarity(np.stack([e[0], e[2]])), [0.0, 1.0])


class _FakeReid:
    """Stands in for the network: the embedding is given by the crop's mean colour."""

    def embed_crops(self, crops):
        return np.stack(
            [_unit(np.r_[c.reshape(-1, 3).mean(0), np.zeros(253)] + 1e-3) for c in crops]
        )


def test_fusion_weighs_boosting_and_reid():
    cfg = IdentifyConfig(reid_weight=0.25, initial_training_frames=1)
    model = AppearanceModel(cfg, ChannelFeatureExtractor(), _FakeReid())
    assert model.name == "channels+reid" and not model.ready
    rng = np.random.default_rng(0)
    red = [
        np.clip(rng.normal((30, 30, 200), 10, (64, 32, 3)), 0, 255).astype(np.uint8)
        for _ in range(6)
    ]
    blue = [
        np.clip(rng.normal((200, 30, 30), 10, (64, 32, 3)), 0, 255).astype(np.uint8)
        for _ in range(6)
    ]
    for r, b in zip(red[:4], blue[:4], strict=True):
        model.learn(model.describe_crops([r]), model.describe_crops([b]))
    probes = model.describe_crops([red[5], blue[5]])
    fused = model.confidence(probes)
    boost = model.classifier.confidence([p.maps for p in probes])
    reid = model.gallery.confidence(np.stack([p.embedding for p in probes]))
    np.testing.assert_allclose(fused, 0.75 * boost + 0.25 * reid)
    assert fused[0] > 0.5 > -0.5 > fused[1]


def test_reid_only_model_scores_with_the_gallery():
    model = AppearanceModel(IdentifyConfig(), None, _FakeReid())
    crop = np.full((64, 32, 3), (30, 30, 200), np.uint8)
    model.learn(model.describe_crops([crop]), [])
    assert model.ready
    assert model.confidence(model.describe_crops([crop]))[0] == pytest.approx(1.0)
    assert model.confidence([Appearance(embedding=_unit(np.r_[0.0, 1.0, np.zeros(254)]))])[0] < 0


def test_real_reid_embeddings_are_unit_length_and_discriminative(model_path, data_path):
    import cv2

    embedder = ReidEmbedder(model_path("reid/person-reidentification-retail-0248.onnx"))
    crops = [cv2.imread(str(data_path(f"ccf_crops/{n}.jpg"))) for n in ("p01", "p02", "n01-01")]
    emb = embedder.embed_crops(crops)
    assert emb.shape == (3, 256)
    np.testing.assert_allclose(np.linalg.norm(emb, axis=1), 1.0, atol=1e-5)
    assert emb[0] @ emb[1] > emb[0] @ emb[2] + 0.2  # same person closer than another
    image = np.zeros((300, 200, 3), np.uint8)
    image[20:148, 50:100] = cv2.resize(crops[0], (50, 128))
    roi_emb = embedder.embed(image, [(50, 20, 100, 148)])
    assert roi_emb[0] @ emb[0] > 0.9


@pytest.mark.parametrize(
    "name, expected",
    [("ccf10", ("ccf10", False)), ("ccf10+reid", ("ccf10", True)), ("reid", (None, True)),
     ("channels", ("channels", False)), ("CCF25+reid", ("ccf25", True))],
)  # fmt: skip
def test_identifier_names(name, expected):
    assert parse_identifier(name) == expected


@pytest.mark.parametrize("name", ["ccf11", "ccf10+ccf25", "", "reid+reid+reid"])
def test_unknown_identifier_names_are_errors(name):
    with pytest.raises(ConfigError, match="identifier"):
        parse_identifier(name)


@pytest.mark.parametrize("name", ["ccf10", "ccf25", "channels", "reid", "ccf10+reid"])
def test_factory_builds_every_configuration(model_path, name):
    model_path("ccf/ccf10")
    identifier = build_identifier(IdentifyConfig(identifier=name))
    assert identifier.name == name


def test_a_full_gallery_drops_the_most_redundant_view_not_the_oldest():
    cfg = IdentifyConfig(reid_gallery_size=3)
    gallery = ReidGallery(cfg)
    basis = np.eye(256, dtype=np.float32)
    front, side = basis[0], basis[1]
    back = (basis[2] + 0.05 * basis[3]) / np.linalg.norm(basis[2] + 0.05 * basis[3])
    for e in (front, side, back):
        gallery.add(e)
    gallery.add(basis[2])  # nearly the back view again
    sims = gallery.similarity(np.stack([front, side, basis[2]]))
    assert len(gallery) == 3 and np.allclose(sims, 1.0, atol=1e-6)


def test_a_snapshot_puts_back_what_was_learnt_after_it():
    """Probation's undo: learning a stranger after the snapshot leaves no trace."""
    cfg = IdentifyConfig(initial_training_frames=1)
    model = AppearanceModel(cfg, ChannelFeatureExtractor(), _FakeReid())
    rng = np.random.default_rng(1)

    def crops(bgr):
        return [np.clip(rng.normal(bgr, 10, (64, 32, 3)), 0, 255).astype(np.uint8)
                for _ in range(4)]  # fmt: skip

    red, blue, green = crops((30, 30, 200)), crops((200, 30, 30)), crops((30, 200, 30))
    for r, b in zip(red[:3], blue[:3], strict=True):
        model.learn(model.describe_crops([r]), model.describe_crops([b]))
    probes = model.describe_crops([red[3], green[3]])
    before, gallery_size = model.confidence(probes), len(model.gallery)
    saved = model.snapshot()
    for g, r in zip(green[:3], red[:3], strict=True):  # a stranger taken for the target
        model.learn(model.describe_crops([g]), model.describe_crops([r]))
    assert not np.allclose(model.confidence(probes), before)
    model.restore(saved)
    np.testing.assert_allclose(model.confidence(probes), before)
    assert len(model.gallery) == gallery_size
    model.learn(model.describe_crops([green[0]]), [])  # the copy put back is its own
    model.restore(saved)
    np.testing.assert_allclose(model.confidence(probes), before)


_CUDA = ["CUDAExecutionProvider", "CPUExecutionProvider"]
_CPU = ["CPUExecutionProvider"]


@pytest.mark.parametrize(
    ("provider", "offered", "openvino_here", "expected"),
    [
        ("auto", _CUDA, True, "cuda"),
        ("auto", _CPU, True, "openvino"),
        ("auto", _CPU, False, "onnxruntime"),
        ("cuda", _CUDA, True, "cuda"),
        ("cpu", _CUDA, True, "openvino"),
        ("cpu", _CUDA, False, "onnxruntime"),
        ("openvino", _CUDA, True, "openvino"),
        ("onnxruntime", _CUDA, True, "onnxruntime"),
    ],
)
def test_the_reid_network_goes_to_the_gpu_where_allowed_else_to_the_fastest_cpu_runtime(
    provider, offered, openvino_here, expected
):
    from follow.identify.reid import reid_runtime

    assert reid_runtime(provider, offered, lambda: openvino_here) == expected


@pytest.mark.parametrize("provider", ["onnxruntime", "cuda"])
def test_onnxruntime_is_chosen_without_asking_whether_openvino_is_installed(provider):
    """Asking imports openvino, about 16 MB of memory on the plain runtime's process."""
    from follow.identify.reid import reid_runtime

    def asked():
        raise AssertionError("openvino was asked for")

    assert reid_runtime(provider, _CUDA if provider == "cuda" else _CPU, asked) == provider


def test_a_reid_runtime_asked_for_but_missing_runs_on_onnxruntime_saying_so(caplog):
    from follow.identify.reid import reid_runtime

    assert reid_runtime("cuda", _CPU, lambda: False) == "onnxruntime"
    assert "reid_provider 'cuda' is not available" in caplog.text
    assert reid_runtime("openvino", _CPU, lambda: False) == "onnxruntime"
    assert "reid_provider 'openvino' is not available" in caplog.text
    with pytest.raises(ValueError, match="reid_provider 'tpu' unknown"):
        reid_runtime("tpu", _CPU, lambda: True)


def test_openvino_gives_the_embeddings_onnxruntime_gives(model_path, data_path):
    """The CPU's faster runtime is only used because it computes the same thing, to the
    rounding of bfloat16 where the CPU has it (cosine 0.9991-0.9992 on these crops
    there; 0.9999998 in float32): far closer than two crops of one person."""
    pytest.importorskip("openvino")
    import cv2

    model = model_path("reid/person-reidentification-retail-0248.onnx")
    crops = [cv2.imread(str(data_path(f"ccf_crops/{n}.jpg"))) for n in ("p01", "n01-01", "n02-02")]
    on_openvino = ReidEmbedder(model, provider="openvino")
    on_onnxruntime = ReidEmbedder(model, provider="onnxruntime")
    assert on_openvino.backend_name == "openvino:CPU"
    assert on_onnxruntime.backend_name == "onnxruntime:CPUExecutionProvider"
    cosine = np.sum(on_openvino.embed_crops(crops) * on_onnxruntime.embed_crops(crops), axis=1)
    assert np.all(cosine > 0.995), cosine


@pytest.mark.parametrize("provider", ["openvino", "onnxruntime"])
def test_a_reid_model_with_a_free_batch_dimension_loads_on_either_runtime(
    model_path, data_path, tmp_path, provider
):
    """The network exported with a named batch dimension gives the embeddings of the
    fixed-batch one on both runtimes (OpenVINO refused it: its input shape was read as a
    static shape)."""
    if provider == "openvino":
        pytest.importorskip("openvino")
    import cv2
    import onnx

    model = model_path("reid/person-reidentification-retail-0248.onnx")
    graph = onnx.load(str(model))
    for value in (graph.graph.input[0], graph.graph.output[0]):
        value.type.tensor_type.shape.dim[0].dim_param = "batch"
    free_batch = tmp_path / "reid_free_batch.onnx"
    onnx.save(graph, str(free_batch))
    crops = [cv2.imread(str(data_path(f"ccf_crops/{n}.jpg"))) for n in ("p01", "n01-01")]
    fixed = ReidEmbedder(model, provider=provider).embed_crops(crops)
    free = ReidEmbedder(free_batch, provider=provider).embed_crops(crops)
    np.testing.assert_allclose(free, fixed, atol=1e-4)


def test_a_reid_provider_outside_the_choices_is_refused_by_the_configuration(tmp_path):
    from follow.config import Config

    path = tmp_path / "c.toml"
    path.write_text('[identify]\nreid_provider = "gpu"\n')
    with pytest.raises(ConfigError, match="reid_provider"):
        Config.load(path)


@pytest.mark.parametrize(("offered", "warm_runs"), [
    (["CUDAExecutionProvider", "CPUExecutionProvider"], 1),
    (["CPUExecutionProvider"], 0),
])  # fmt: skip
def test_the_reid_network_on_a_gpu_is_warmed_up_before_the_first_frame(
    monkeypatch, tmp_path, offered, warm_runs
):
    """On CUDA the first run searches convolution algorithms (1.6 s on an H200): paid at
    start-up, not by the first frame that needs re-id."""
    import types

    import onnxruntime as ort

    runs = []

    class FakeSession:
        def __init__(self, model, options, providers):
            self.providers = providers

        def get_providers(self):
            return self.providers

        def get_inputs(self):
            return [types.SimpleNamespace(name="crop", shape=[1, 256, 128, 3])]

        def run(self, outputs, feeds):
            runs.append(feeds["crop"].shape)
            return [np.ones((1, 256), np.float32)]

    monkeypatch.setattr(ort, "InferenceSession", FakeSession)
    monkeypatch.setattr(ort, "get_available_providers", lambda: offered)
    monkeypatch.setattr("follow.pose.runtime.openvino_installed", lambda: False)
    embedder = ReidEmbedder(tmp_path / "reid.onnx", provider="auto")
    assert embedder.backend_name == f"onnxruntime:{offered[0]}"
    assert runs == [(1, 256, 128, 3)] * warm_runs
