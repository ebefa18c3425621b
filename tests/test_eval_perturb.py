"""The perturbation suite: deterministic variants that differ from the original and from
each other, its summary (mean and worst), the content-keyed skeleton cache, and the
`--perturb` output of the PETS evaluations on a short run."""

import json
from types import SimpleNamespace

import numpy as np
import pytest

from follow import cli
from follow.config import PoseConfig
from follow.eval import perturb
from follow.eval.perturb import SUITE, PerturbedSequence, summarise, variant
from follow.types import Skeleton


def _frame(index: int) -> np.ndarray:
    """A textured 60x80 BGR frame (edges and mid-tones, so every change shows)."""
    rng = np.random.default_rng(index)
    image = np.full((60, 80, 3), 110, np.uint8)
    image[10:50, 20:40] = 200
    image[:, 60:] = rng.integers(0, 256, (60, 20, 3), dtype=np.uint8)
    return image


class FakeSequence:
    frame_count = 6

    def __init__(self):
        self.reads = 0

    def read_frame(self, index):
        self.reads += 1
        return _frame(index)

    def frames(self, indices=None):
        for i in range(self.frame_count) if indices is None else indices:
            yield i, self.read_frame(i)

    def boxes_video_px(self, index):
        return [f"box of {index}"]


PIXEL_VARIANTS = [v for v in SUITE if v.changes_pixels]


def test_the_suite_has_every_kind_of_change():
    names = {v.name for v in SUITE}
    assert {"original", "jpeg95", "jpeg75", "jpeg50", "noise", "blur",
            "offset50", "offset100"} <= names  # fmt: skip
    assert any(v.brightness_shift for v in SUITE) and any(v.contrast_gain != 1 for v in SUITE)
    assert len(names) == len(SUITE)


@pytest.mark.parametrize("v", PIXEL_VARIANTS, ids=lambda v: v.name)
def test_a_variant_gives_the_same_pixels_every_time_and_differs_from_the_original(v):
    original = _frame(3)
    first = v.apply(original, 3)
    assert np.array_equal(first, v.apply(_frame(3), 3))
    assert np.array_equal(original, _frame(3))  # the input is left as it was
    assert first.shape == original.shape and first.dtype == np.uint8
    assert np.abs(first.astype(int) - original).mean() > 0.5


def test_variants_differ_from_each_other():
    images = {v.name: v.apply(_frame(2), 2) for v in PIXEL_VARIANTS}
    names = list(images)
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            assert not np.array_equal(images[a], images[b]), (a, b)


def test_noise_is_seeded_by_the_frame_index_not_by_the_order_of_reading():
    noise = variant("noise")
    same = _frame(0)
    a, b = noise.apply(same, 4), noise.apply(same, 5)
    assert not np.array_equal(a, b)  # a fresh draw per frame
    assert np.array_equal(noise.apply(same, 5), b)
    seq = PerturbedSequence(FakeSequence(), noise)
    forward = dict(seq.frames([1, 2, 3]))
    backward = dict(seq.frames([3, 2, 1]))
    assert all(np.array_equal(forward[i], backward[i]) for i in (1, 2, 3))


def test_a_later_start_keeps_the_pixels_and_drops_the_first_frames():
    late = variant("offset50")
    assert not late.changes_pixels
    assert np.array_equal(late.apply(_frame(1), 1), _frame(1))
    assert late.frame_range(795, None) == list(range(50, 795))
    assert late.frame_range(795, 20) == list(range(50, 70))
    with pytest.raises(ValueError, match="starts at frame 50"):
        late.frame_range(40, None)


def test_a_perturbed_sequence_keeps_the_ground_truth():
    seq = PerturbedSequence(FakeSequence(), variant("blur"))
    assert seq.frame_count == 6 and seq.boxes_video_px(2) == ["box of 2"]
    assert not np.array_equal(seq.read_frame(2), _frame(2))


def test_unknown_variants_are_named_in_the_error():
    with pytest.raises(ValueError, match="'jpeg10'.*jpeg50"):
        perturb.selected_variants(SimpleNamespace(variants="jpeg50,jpeg10", perturb=False))
    assert perturb.selected_variants(SimpleNamespace(variants=None, perturb=False)) is None
    assert len(perturb.selected_variants(SimpleNamespace(variants=None, perturb=True))) == len(
        SUITE
    )


def test_evaluations_without_a_sequence_take_only_the_pixel_changes():
    def pick(variants=None, perturb=False):
        args = SimpleNamespace(variants=variants, perturb=perturb)
        return perturb_module.selected_pixel_variants(args, "crops")

    perturb_module = perturb
    assert pick() is None
    names = [v.name for v in pick(perturb=True)]
    assert names[0] == "original" and "blur" in names
    assert not any(v.first_frame for v in pick(perturb=True))
    assert len(names) == len(SUITE) - sum(1 for v in SUITE if v.first_frame)
    assert [v.name for v in pick("noise,dark")] == ["noise", "dark"]
    with pytest.raises(ValueError, match="offset50 starts later: crops has no sequence"):
        pick("noise,offset50")


def test_mean_and_worst_take_each_metric_in_its_own_direction():
    per_variant = {
        "a": {"ours": {"mota": 0.9, "misses": 10}, "frames": 5},
        "b": {"ours": {"mota": 0.7, "misses": 30}, "frames": 5},
        "c": {"ours": {"mota": 0.8, "misses": 20}, "frames": 5},
    }
    s = summarise(per_variant, {"mota": True, "misses": False})
    assert s["mean"]["ours"] == {"mota": pytest.approx(0.8), "misses": pytest.approx(20.0)}
    assert s["worst"]["ours"] == {"mota": 0.7, "misses": 30.0}
    assert s["worst_variant"]["ours"] == {"mota": "b", "misses": "b"}
    assert "frames" not in s["mean"]  # not a method
    alike = {k: {"ours": {"never_reacquired": 0}} for k in ("seed 0", "seed 1")}
    assert summarise(alike, {"never_reacquired": False})["worst_variant"]["ours"] == {
        "never_reacquired": None}  # no seed is worse than another


# --- the skeleton cache, keyed by the frames' pixels ---


class PixelDetector:
    """Stands in for the pose network: one skeleton whose score is the frame's mean."""

    calls = 0

    def __init__(self, config):
        pass

    def detect(self, image):
        PixelDetector.calls += 1
        kp = np.full((18, 2), np.nan)
        kp[1] = (10.0, 10.0)
        conf = np.zeros(18)
        conf[1] = 1.0
        return [Skeleton(kp, conf, float(image.mean()))]


def test_a_perturbed_variant_does_not_reuse_the_original_skeletons(tmp_path, monkeypatch):
    from follow.eval import pets_setup

    monkeypatch.setattr("follow.pose.detector.PoseDetector", PixelDetector)
    model = tmp_path / "pose.onnx"
    model.write_bytes(b"model one")
    config = PoseConfig(model_file=str(model), network_stages=2)
    original = SimpleNamespace(sequence=FakeSequence())
    bright = SimpleNamespace(sequence=PerturbedSequence(FakeSequence(), variant("bright")))
    frames = [0, 1, 2]
    PixelDetector.calls = 0
    first = pets_setup.pets_skeletons(original, frames, config)
    assert PixelDetector.calls == 3
    again = pets_setup.pets_skeletons(original, frames, config)
    assert PixelDetector.calls == 3  # served from the cache
    assert [s.score for i in frames for s in again[i]] == [s.score for i in frames
                                                           for s in first[i]]  # fmt: skip
    seen = pets_setup.pets_skeletons(bright, frames, config)
    assert PixelDetector.calls == 6  # other pixels: detected again
    assert all(seen[i][0].score > first[i][0].score + 10 for i in frames)


def test_the_cache_key_follows_pixels_frames_pose_settings_and_model_bytes(tmp_path):
    from follow.eval.pets_setup import _cache_path, frames_digest

    model = tmp_path / "pose.onnx"
    model.write_bytes(b"model one")
    config = PoseConfig(model_file=str(model), network_stages=2)
    pixels = frames_digest(FakeSequence(), [0, 1])
    assert pixels == frames_digest(FakeSequence(), [0, 1])
    key = _cache_path(config, [0, 1], pixels)
    noisy = frames_digest(PerturbedSequence(FakeSequence(), variant("jpeg95")), [0, 1])
    assert noisy != pixels and _cache_path(config, [0, 1], noisy) != key
    assert frames_digest(FakeSequence(), [0, 2]) != pixels
    assert _cache_path(PoseConfig(model_file=str(model), network_stages=2,
                                  input_height_px=256), [0, 1], pixels) != key  # fmt: skip
    other = tmp_path / "other.onnx"
    other.write_bytes(b"model two")  # same size, other bytes
    assert _cache_path(PoseConfig(model_file=str(other), network_stages=2), [0, 1], pixels) != key


# --- the evaluations' --perturb output, on real data (a few frames, a small input) ---


def _run(capsys, *args) -> dict:
    capsys.readouterr()
    assert cli.main(list(args)) == 0
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])


@pytest.fixture
def small_pose(data_path, model_path, tmp_path):
    data_path("pets2009_s2l1/View_001.avi")
    model_path("pose/human-pose-estimation-0001.onnx")
    path = tmp_path / "small.toml"
    path.write_text('[pose]\ninput_height_px = 256\nprecision = "fp32"\n')
    return str(path)


def _assert_suite_shape(r: dict, methods: set[str], metrics: dict[str, bool]):
    assert set(r["variants"]) == {"jpeg50", "offset50"}
    for key in ("mean", "worst", "worst_variant"):
        assert set(r[key]) == methods, key
    for method in methods:
        for metric, higher_is_better in metrics.items():
            values = [r["variants"][v][method][metric] for v in ("jpeg50", "offset50")]
            values = [x for x in values if np.isfinite(x)]  # e.g. MOTP with no match
            if not values:
                continue
            assert r["mean"][method][metric] == pytest.approx(np.mean(values), abs=1e-4)
            pick = min if higher_is_better else max
            assert r["worst"][method][metric] == pytest.approx(pick(values), abs=1e-4)


def test_tracking_under_perturbation_reports_variants_mean_and_worst(small_pose, capsys,
                                                                      tmp_path):  # fmt: skip
    from follow.eval.tracking import METHODS, SUITE_METRICS

    r = _run(capsys, "eval", "tracking", "--frames", "12", "--variants", "jpeg50,offset50",
             "--config", small_pose, "--plot", str(tmp_path / "t.png"), "--json")  # fmt: skip
    _assert_suite_shape(r, set(METHODS), SUITE_METRICS)
    assert r["frames"] == {"jpeg50": 12, "offset50": 12}
    # Other frames, other people: the two runs see different ground truth.
    gt = [r["variants"][v]["ours"]["gt_objects"] for v in ("jpeg50", "offset50")]
    assert min(gt) > 25 and gt[0] != gt[1]
    # counts are summarised as rates: the windows differ in length
    v = r["variants"]["jpeg50"]["ours"]
    assert v["misses_per_1000_gt"] == pytest.approx(1000 * v["misses"] / v["gt_objects"], abs=0.01)
    assert "misses" not in r["worst"]["ours"] and "misses_per_1000_gt" in r["worst"]["ours"]
    assert (tmp_path / "t.png").stat().st_size > 10_000


def test_pose_and_identification_under_perturbation(small_pose, capsys):
    from follow.eval.identification import SUITE_METRICS as ID_METRICS
    from follow.eval.pose import SUITE_METRICS as POSE_METRICS

    pose = _run(capsys, "eval", "pose", "--frames", "3", "--sizes", "256", "--precision", "fp32",
                "--variants", "jpeg50,offset50", "--json")  # fmt: skip
    _assert_suite_shape(pose, {"256"}, POSE_METRICS)
    assert pose["variants"]["jpeg50"]["256"]["people"] > 5
    ident = _run(capsys, "eval", "identification", "--frames", "12", "--identifiers", "ccf10",
                 "--min-visible-s", "1", "--max-targets", "1", "--config", small_pose,
                 "--variants", "jpeg50,offset50", "--json")  # fmt: skip
    _assert_suite_shape(ident, {"ccf10"}, ID_METRICS)
    for result in ident["variants"].values():
        r = result["ccf10"]
        assert r["ct_cl"] == pytest.approx(r["ct"] + r["cl"], abs=1e-3)


def test_an_unknown_variant_is_a_clear_error(small_pose, capsys):
    assert cli.main(["eval", "tracking", "--frames", "5", "--variants", "fog"]) != 0
    assert "unknown perturbation variant 'fog'" in capsys.readouterr().err


@pytest.mark.parametrize("command, window, runner", [
    (["eval", "tracking", "--frames", "12", "--score-until-frame", "30"], "--score-until-frame 30",
     "variant_inputs"),
    (["eval", "pose", "--frames", "3", "--sizes", "256", "--until-frame", "80"],
     "no frames from 100 until 80", "evaluate_size"),
])  # fmt: skip
def test_frames_a_later_start_cannot_score_are_refused_before_any_variant_runs(
    small_pose, capsys, monkeypatch, command, window, runner
):
    """offset100 starts after the frames asked for: said before the variants ahead of it
    have run, not after."""
    from importlib import import_module

    module = import_module(f"follow.eval.{command[1]}")
    ran = []
    monkeypatch.setattr(module, runner, lambda *a, **k: ran.append(a) or 1 / 0)
    capsys.readouterr()
    assert cli.main([*command, "--variants", "jpeg50,offset100"]) == 1
    err = capsys.readouterr().err
    assert "offset100" in err and window in err and not ran


def test_scoring_can_stop_before_the_end_of_the_run(small_pose, capsys):
    args = ["eval", "tracking", "--frames", "12", "--config", small_pose, "--json"]
    whole = _run(capsys, *args)
    first = _run(capsys, *args, "--score-until-frame", "6")
    second = _run(capsys, *args, "--score-from-frame", "6")
    counts = [r["ours"]["gt_objects"] for r in (first, second, whole)]
    assert counts[0] + counts[1] == counts[2] and 0 < counts[0] < counts[2]
    assert cli.main([*args[:-1], "--score-from-frame", "6", "--score-until-frame", "6"]) != 0
    assert "--score-until-frame 6 leaves no frame to score" in capsys.readouterr().err


def test_an_empty_scoring_window_is_refused_before_the_pose_network_runs(small_pose, capsys,
                                                                         monkeypatch):  # fmt: skip
    """Said after the pose network had run over every frame (minutes on a cold cache)."""
    from follow.eval import tracking

    monkeypatch.setattr(tracking, "variant_inputs", lambda *a, **k: 1 / 0)
    args = ["eval", "tracking", "--frames", "12", "--config", small_pose]
    assert cli.main([*args, "--score-from-frame", "8", "--score-until-frame", "6"]) == 1
    assert "--score-until-frame 6 leaves no frame to score" in capsys.readouterr().err


def test_the_cache_key_follows_the_runtime_auto_picks(tmp_path, monkeypatch):
    """`provider = "auto"` runs OpenVINO where it is installed, onnxruntime where not:
    their skeletons differ, so one's cache must not serve the other."""
    from follow.eval.pets_setup import _cache_path, frames_digest
    from follow.pose import runtime

    model = tmp_path / "pose.onnx"
    model.write_bytes(b"model one")
    pixels = frames_digest(FakeSequence(), [0, 1])
    auto = PoseConfig(model_file=str(model), network_stages=2, provider="auto")
    monkeypatch.setattr(runtime, "openvino_installed", lambda: False)
    monkeypatch.setattr(runtime, "ort_available_providers", lambda: ["CPUExecutionProvider"])
    on_ort = _cache_path(auto, [0, 1], pixels)
    assert on_ort == _cache_path(PoseConfig(model_file=str(model), network_stages=2,
                                            provider="cpu"), [0, 1], pixels)  # fmt: skip
    monkeypatch.setattr(runtime, "openvino_installed", lambda: True)
    assert runtime.auto_provider(model) == "openvino"
    assert _cache_path(auto, [0, 1], pixels) != on_ort


def test_a_skeleton_cache_cut_short_or_of_another_shape_is_made_again(tmp_path, caplog):
    """A cache file truncated (a full disk, a killed copy) or missing an array used to
    end the evaluation with a zipfile or key error naming neither the file nor a fix."""
    import numpy as np

    from follow.eval.pets_setup import _read_cached_skeletons

    good = tmp_path / "good.npz"
    np.savez_compressed(good, frame=np.array([3]), kp=np.zeros((1, 18, 2)),
                        conf=np.ones((1, 18)), score=np.array([0.7]))  # fmt: skip
    cached = _read_cached_skeletons(good, [3, 4])
    assert [len(cached[3]), len(cached[4])] == [1, 0] and cached[3][0].score == 0.7
    cut = tmp_path / "cut.npz"
    cut.write_bytes(good.read_bytes()[:40])
    no_score = tmp_path / "no_score.npz"
    np.savez_compressed(no_score, frame=np.array([3]), kp=np.zeros((1, 18, 2)),
                        conf=np.ones((1, 18)))  # fmt: skip
    for path in (cut, no_score):
        assert _read_cached_skeletons(path, [3, 4]) is None
        assert f"cache {path} is unreadable" in caplog.text


def test_a_cache_folder_that_cannot_be_made_is_refused_before_the_network_runs(
    tmp_path, monkeypatch
):
    """With a file where the skeletons' folder goes, the evaluation used to run the pose
    network over every frame (13 minutes on PETS) and then fail to keep its work."""
    from follow.eval import pets_setup

    monkeypatch.setattr("follow.pose.detector.PoseDetector", PixelDetector)
    monkeypatch.setenv("FOLLOW_CACHE_DIR", str(tmp_path / "cache" / "models"))
    (tmp_path / "cache").mkdir()
    (tmp_path / "cache" / "eval").write_text("in the way")
    model = tmp_path / "pose.onnx"
    model.write_bytes(b"model one")
    config = PoseConfig(model_file=str(model), network_stages=2)
    PixelDetector.calls = 0
    for use_cache in (True, False):
        with pytest.raises(OSError, match="cannot write .*eval, in the cache"):
            pets_setup.pets_skeletons(SimpleNamespace(sequence=FakeSequence()), [0, 1],
                                      config, use_cache)  # fmt: skip
    assert PixelDetector.calls == 0


def test_the_cache_key_names_the_runtime_that_ran_where_a_listed_gpu_does_not_start(
    tmp_path, monkeypatch
):
    """onnxruntime lists CUDA, but it does not start, so `auto` runs OpenVINO: the
    skeletons are OpenVINO's and must be kept under OpenVINO's key, not CUDA's (served as
    CUDA's once CUDA works)."""
    from follow.eval import pets_setup
    from follow.pose import runtime

    monkeypatch.setattr(runtime, "GPU_FAILURES", {})
    monkeypatch.setattr(runtime, "openvino_installed", lambda: True)
    monkeypatch.setattr(runtime, "ort_available_providers",
                        lambda: ["CUDAExecutionProvider", "CPUExecutionProvider"])  # fmt: skip

    class CudaNotStarting(PixelDetector):
        def __init__(self, config):
            runtime.GPU_FAILURES["cuda"] = "the session runs on CPUExecutionProvider only"

    monkeypatch.setattr("follow.pose.detector.PoseDetector", CudaNotStarting)
    model = tmp_path / "pose.onnx"
    model.write_bytes(b"model one")
    config = PoseConfig(model_file=str(model), network_stages=2, provider="auto")
    frames = [0, 1]
    pixels = pets_setup.frames_digest(FakeSequence(), frames)
    cuda_key = pets_setup._cache_path(config, frames, pixels)
    pets_setup.pets_skeletons(SimpleNamespace(sequence=FakeSequence()), frames, config)
    ran_key = pets_setup._cache_path(config, frames, pixels)  # OpenVINO's, as it ran
    assert ran_key != cuda_key and ran_key.exists() and not cuda_key.exists()
