"""Derived model files carry an integrity record, checked before they run."""

import argparse
from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper
from test_pose_stages import _two_stage_graph

from follow import model_manifest, models
from follow.config import PoseConfig
from follow.pose.detector import _source_model_file, model_file_for
from follow.pose.quantize import default_int8_path
from follow.pose.stages import initial_stage_file


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("FOLLOW_CACHE_DIR", str(tmp_path / "models"))
    monkeypatch.delenv("FOLLOW_MODEL_DIR", raising=False)
    return tmp_path / "models"


def _save_graph(path, quantized: bool = False) -> None:
    """The miniature two-stage OpenPose with typed outputs (1x1 convolutions keep 16x16)."""
    model = _two_stage_graph(quantized)
    del model.graph.output[:]
    for name, channels in (("out_paf", 38), ("out_heat", 19)):
        model.graph.output.append(
            helper.make_tensor_value_info(name, TensorProto.FLOAT, [1, channels, 16, 16])
        )
    onnx.save(model, str(path))


def _corrupt(path):
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))


def _verify_all(capsys) -> tuple[int, str]:
    code = models.main(argparse.Namespace(action="verify", names=[], json=False, source=None,
                                                force=False))
    return code, capsys.readouterr().out


def test_the_stage_cut_is_recorded_and_a_corrupted_one_is_refused(cache, tmp_path, capsys):
    source = tmp_path / "net.onnx"
    _save_graph(source)
    cut = initial_stage_file(source)
    record = model_manifest.read_manifest(cut)
    assert record["sha256"] == models.sha256_of(cut)
    assert record["source_sha256"] == models.sha256_of(source)
    assert initial_stage_file(source) == cut  # verified and reused
    code, out = _verify_all(capsys)
    assert "ok" in out and cut.name in out

    _corrupt(cut)
    with pytest.raises(models.ModelError, match="corrupted or changed.*cut again"):
        initial_stage_file(source)
    code, out = _verify_all(capsys)
    assert code == 1 and "FAIL" in out and cut.name in out


def test_a_cut_without_a_record_is_made_again(cache, tmp_path):
    source = tmp_path / "net.onnx"
    _save_graph(source)
    cut = initial_stage_file(source)
    model_manifest.manifest_path(cut).unlink()
    _corrupt(cut)
    assert initial_stage_file(source) == cut
    assert model_manifest.check(cut) == "ok"


@pytest.mark.parametrize("precision", ["auto", "int8"])
def test_a_corrupted_int8_model_is_refused_with_how_to_rebuild(
    cache, tmp_path, precision, monkeypatch
):
    """Pinned to the CPU provider: on a GPU `precision = "auto"` takes the FP32 model."""
    from follow.pose import cpu_features

    monkeypatch.setattr(cpu_features, "cpu_flags", lambda: frozenset({"avx512_vnni"}))
    source = tmp_path / "fp32.onnx"
    _save_graph(source, quantized=True)
    int8 = default_int8_path()
    int8.parent.mkdir(parents=True)
    int8.write_bytes(source.read_bytes())
    model_manifest.write_manifest(int8, source, {"calibration": "test"})
    assert _source_model_file(PoseConfig(provider="cpu", precision=precision)) == int8
    _corrupt(int8)
    with pytest.raises(models.ModelError, match="refusing to run it.*follow models prepare"):
        _source_model_file(PoseConfig(provider="cpu", precision=precision))


def test_a_named_model_file_with_a_record_is_checked_against_it(cache, tmp_path):
    """A custom model made here (tools/quantize_pose.py -o PATH) and given as [pose]
    model_file (or --model-file) has its record beside it: a corrupted copy ran anyway."""
    made = tmp_path / "pose-int8-256.onnx"
    _save_graph(made, quantized=True)
    model_manifest.write_manifest(made, made, {"calibration": "test"})
    assert model_file_for(PoseConfig(model_file=str(made))) == made
    assert model_file_for(PoseConfig(), made) == made
    _corrupt(made)
    with pytest.raises(models.ModelError, match="corrupted or changed.*refusing to run it"):
        model_file_for(PoseConfig(model_file=str(made)))
    with pytest.raises(models.ModelError, match="corrupted or changed"):
        model_file_for(PoseConfig(), made)
    plain = tmp_path / "plain.onnx"  # a file with no record is the user's own: run as is
    _save_graph(plain)
    assert model_file_for(PoseConfig(model_file=str(plain))) == plain


def test_an_int8_model_without_a_record_is_refused(cache):
    int8 = default_int8_path()
    int8.parent.mkdir(parents=True)
    int8.write_bytes(b"not a model")
    with pytest.raises(models.ModelError, match="no integrity record"):
        _source_model_file(PoseConfig(precision="int8"))


def test_the_int8_file_is_keyed_by_its_recipe(cache, monkeypatch):
    from follow.pose import prepare

    before = default_int8_path()
    monkeypatch.setitem(prepare.INT8_RECIPE, "near_frames", prepare.INT8_RECIPE["near_frames"] + 1)
    assert default_int8_path() != before
    assert default_int8_path().parent == before.parent


@pytest.mark.slow  # quantises the real network (two calibration frames)
def test_prepare_makes_a_recorded_int8_model_calibrated_on_both_kinds_of_frames(
    tmp_path, monkeypatch, model_path, data_path
):
    from follow.pose import prepare

    model_path("pose/human-pose-estimation-0001.onnx")  # skips without the assets
    data_path("pets2009_s2l1/View_001.avi")
    data_path("ccf_crops")
    monkeypatch.setenv("FOLLOW_CACHE_DIR", str(tmp_path / "models"))
    monkeypatch.setitem(prepare.INT8_RECIPE, "pets_frames", 1)
    monkeypatch.setitem(prepare.INT8_RECIPE, "near_frames", 1)
    monkeypatch.setitem(prepare.INT8_RECIPE, "input_height_px", 128)
    frames = prepare.calibration_frames()
    assert len(frames) == 2 and frames[0].shape != frames[1].shape  # a PETS and a pasted frame
    path = prepare.prepare_int8()
    assert path == default_int8_path() and model_manifest.check(path) == "ok"
    record = model_manifest.read_manifest(path)
    assert "ccf_crops" in record["made_from"]["calibration"]
    assert record["source_sha256"] == models.get_spec("human-pose-estimation-0001").files[0].sha256


def test_a_binary_integrity_record_is_reported_not_a_codec_error(cache, tmp_path, capsys):
    source = tmp_path / "net.onnx"
    _save_graph(source)
    cut = initial_stage_file(source)
    model_manifest.manifest_path(cut).write_bytes(b"\xff\xfe\x00\x01binary\x80\x81")
    assert "no integrity record" in model_manifest.check(cut)
    code, out = _verify_all(capsys)
    assert code == 1 and "FAIL" in out and cut.name in out
    assert initial_stage_file(source) == cut  # an unreadable record: cut again
    assert model_manifest.check(cut) == "ok"


def test_an_interrupted_cut_leaves_no_half_written_file(cache, tmp_path, monkeypatch):
    """Ctrl-C while the cut is written: nothing of it stays in the cache, and the next
    run cuts it whole."""
    import onnx.utils

    source = tmp_path / "net.onnx"
    _save_graph(source)

    def interrupted(_source, output, *_args, **_kwargs):
        with open(output, "wb") as f:
            f.write(b"half a model")
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setattr(onnx.utils, "extract_model", interrupted)
        with pytest.raises(KeyboardInterrupt):
            initial_stage_file(source)
    assert [p.name for p in (cache / "pose").iterdir()] == []
    cut = initial_stage_file(source)
    assert model_manifest.check(cut) == "ok"


def test_an_interrupted_int8_model_leaves_no_half_written_file(cache, tmp_path, monkeypatch):
    """Ctrl-C while the quantised model is copied from the temporary folder into the
    cache (another file system: a copy, not a rename): no truncated INT8 model stays for
    `precision = "auto"` to refuse to run; there is simply none yet."""
    import shutil

    from follow.pose.quantize import quantize_pose_model

    source = tmp_path / "fp32.onnx"
    _save_graph(source)
    frames = [np.full((16, 16, 3), v, np.uint8) for v in (40, 200)]

    def interrupted_copy(src, dst, *_args, **_kwargs):
        with open(dst, "wb") as f:
            f.write(open(src, "rb").read()[:100])
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setattr(shutil, "move", interrupted_copy)
        with pytest.raises(KeyboardInterrupt):
            quantize_pose_model(source, frames, 16)
    assert list(default_int8_path().parent.iterdir()) == []
    path = quantize_pose_model(source, frames, 16)
    assert path == default_int8_path() and model_manifest.check(path) == "ok"


def test_verify_reports_a_made_model_whose_record_was_lost(cache):
    # `follow run` refuses such a file (no record); verify listed only recorded files
    # and said all was well.
    int8 = default_int8_path()
    int8.parent.mkdir(parents=True)
    int8.write_bytes(b"made here, record deleted")
    (int8.parent / "notes.onnx").write_bytes(b"not named as a made file")
    (status,) = models.verify_derived_files()
    assert status.path == int8 and not status.ok
    assert "no integrity record" in status.detail


@pytest.mark.parametrize(
    "settings, message",
    [({"precision": "int8"}, "precision 'int8', but model_file .*pose.onnx is not an INT8"),
     ({"model": "human-pose-estimation-0001-ir"}, "both name the network to run")],
)  # fmt: skip
def test_a_model_file_refuses_settings_it_would_override_in_silence(tmp_path, settings, message):
    """An FP32 file ran where INT8 was asked for, without a word."""
    from follow.models import ModelError

    model = tmp_path / "pose.onnx"
    model.write_bytes(b"not read before the check")
    with pytest.raises(ModelError, match=message):
        model_file_for(PoseConfig(model_file=str(model), **settings))
    named_int8 = tmp_path / "pose-int8.onnx"
    named_int8.write_bytes(b"x")
    with pytest.raises(ModelError, match="is an INT8 model by its name"):
        model_file_for(PoseConfig(model_file=str(named_int8), precision="fp32"))


def test_a_read_only_cache_names_the_cache_not_a_temporary_file(cache, tmp_path, monkeypatch):
    """A bare `[Errno 13] Permission denied: '...<pid>.partial'` named a file the user
    never made, and not the cache or its setting."""
    from test_models import read_only

    source = tmp_path / "net.onnx"
    _save_graph(source)
    folder = models.make_cache_folder(cache / "pose")
    read_only(monkeypatch, folder)
    with pytest.raises(OSError) as caught:
        model_manifest.install(folder / "m.onnx", source, {}, lambda p: p.write_bytes(b"x"))
    message = str(caught.value)
    assert message.startswith(f"cannot write {folder}, in the cache ($FOLLOW_CACHE_DIR, now ")
    assert "partial" not in message and message.endswith("Permission denied")


def test_a_source_that_cannot_be_read_is_not_blamed_on_the_cache(cache, tmp_path):
    folder = models.make_cache_folder(cache / "pose")
    with pytest.raises(FileNotFoundError, match="gone.onnx"):
        model_manifest.install(folder / "m.onnx", tmp_path / "gone.onnx", {},
                               lambda p: p.write_bytes(b"x"))  # fmt: skip
    assert list(folder.iterdir()) == []


def test_int8_calibration_does_not_start_on_a_read_only_cache(cache, tmp_path, monkeypatch):
    """`follow models prepare` calibrated for ~30 s before failing to write its result."""
    from test_models import read_only

    from follow.pose import quantize

    source = tmp_path / "fp32.onnx"
    _save_graph(source)
    calibrated = []
    monkeypatch.setattr(quantize, "prepare_input", lambda *a: calibrated.append(a))
    read_only(monkeypatch, models.make_cache_folder(default_int8_path().parent))
    with pytest.raises(OSError, match=r"cannot write .*pose, in the cache \(\$FOLLOW_CACHE_DIR"):
        quantize.quantize_pose_model(source, [np.zeros((16, 16, 3), np.uint8)], 16)
    assert calibrated == []


def test_models_prepare_reads_no_calibration_frame_on_a_read_only_cache(cache, monkeypatch):
    """`prepare_int8` read its calibration frames (seconds) before the write check."""
    from test_models import read_only

    from follow.pose import prepare

    monkeypatch.setattr(prepare.models, "resolve", lambda name: Path("fp32.onnx"))
    monkeypatch.setattr(prepare, "calibration_frames",
                        lambda: pytest.fail("calibration frames read"))  # fmt: skip
    read_only(monkeypatch, models.make_cache_folder(default_int8_path().parent))
    with pytest.raises(OSError, match=r"cannot write .*pose, in the cache \(\$FOLLOW_CACHE_DIR"):
        prepare.prepare_int8(force=True)
