"""CCF weight loading: shapes of the real files, clear errors on broken ones."""

from __future__ import annotations

import numpy as np
import pytest

from follow.ccf.weights import WeightsError, load_ccf_weights, load_conv_layer


def _write_layer(path, weights: np.ndarray, biases: np.ndarray) -> None:
    path.write_text(
        " ".join(str(v) for v in weights.shape) + "\n"
        + " ".join(f"{v:.6g}" for v in weights.ravel()) + "\n"
        + f"{len(biases)}\n"
        + " ".join(f"{v:.6g}" for v in biases) + "\n"
    )  # fmt: skip


@pytest.fixture
def weight_folder(tmp_path):
    rng = np.random.default_rng(1)
    _write_layer(tmp_path / "conv_t1", rng.normal(size=(4, 3, 5, 5)), rng.normal(size=4))
    _write_layer(tmp_path / "conv_t2", rng.normal(size=(6, 4, 5, 5)), rng.normal(size=6))
    return tmp_path


@pytest.mark.parametrize("name, n1, n2", [("ccf10", 10, 10), ("ccf25", 20, 25)])
def test_real_weights_have_the_documented_shapes(model_path, name, n1, n2):
    weights = load_ccf_weights(model_path(f"ccf/{name}"))
    assert weights.conv1.weights.shape == (n1, 3, 5, 5)
    assert weights.conv1.biases.shape == (n1,)
    assert weights.conv2.weights.shape == (n2, n1, 5, 5)
    assert weights.num_channels == n2
    assert np.isfinite(weights.conv2.weights).all()


def test_round_trip_of_a_written_folder(weight_folder):
    weights = load_ccf_weights(weight_folder)
    assert weights.conv1.weights.shape == (4, 3, 5, 5)
    assert weights.conv2.out_channels == 6
    assert weights.conv1.weights.dtype == np.float32


def test_truncated_file_names_file_and_problem(weight_folder):
    path = weight_folder / "conv_t2"
    text = path.read_text()
    path.write_text(text[: len(text) // 2])
    with pytest.raises(WeightsError, match=r"conv_t2.*(truncated|expected)"):
        load_ccf_weights(weight_folder)


def test_weights_line_cut_short_is_reported_with_counts(weight_folder):
    path = weight_folder / "conv_t1"
    lines = path.read_text().splitlines()
    lines[1] = " ".join(lines[1].split()[:-3])
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(WeightsError, match=r"conv_t1: line 2 .* holds 297 values, expected 300"):
        load_conv_layer(path)


def test_non_numeric_value_is_rejected(weight_folder):
    path = weight_folder / "conv_t1"
    lines = path.read_text().splitlines()
    lines[3] = lines[3].replace(lines[3].split()[0], "abc", 1)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(WeightsError, match="conv_t1: line 4 .* not a number"):
        load_conv_layer(path)


def test_value_beyond_float32_is_rejected(weight_folder):
    """1e39 is a finite double but overflows the float32 the network runs in."""
    path = weight_folder / "conv_t1"
    lines = path.read_text().splitlines()
    lines[1] = "1e39 " + " ".join(lines[1].split()[1:])
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(WeightsError, match="conv_t1: line 2 .* non-finite"):
        load_conv_layer(path)


def test_bias_count_mismatch_is_rejected(weight_folder):
    path = weight_folder / "conv_t1"
    lines = path.read_text().splitlines()
    lines[2] = "5"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(WeightsError, match="bias count"):
        load_conv_layer(path)


def test_layers_that_do_not_chain_are_rejected(tmp_path):
    rng = np.random.default_rng(2)
    _write_layer(tmp_path / "conv_t1", rng.normal(size=(4, 3, 5, 5)), rng.normal(size=4))
    _write_layer(tmp_path / "conv_t2", rng.normal(size=(6, 5, 5, 5)), rng.normal(size=6))
    with pytest.raises(WeightsError, match="expects 5 input channels but conv_t1 produces 4"):
        load_ccf_weights(tmp_path)


def test_missing_folder_and_file(tmp_path, weight_folder):
    with pytest.raises(WeightsError, match="not found"):
        load_ccf_weights(tmp_path / "nope")
    (weight_folder / "conv_t2").unlink()
    with pytest.raises(WeightsError, match="conv_t2: cannot read"):
        load_ccf_weights(weight_folder)


def test_a_blank_line_does_not_shift_the_line_an_error_names(weight_folder):
    """Blank lines are skipped, but the error names the line of the file as an editor
    shows it."""
    path = weight_folder / "conv_t1"
    lines = path.read_text().splitlines()
    lines[3] = lines[3].replace(lines[3].split()[0], "abc", 1)
    path.write_text("\n".join(lines[:1] + [""] + lines[1:]) + "\n")
    with pytest.raises(WeightsError, match="conv_t1: line 5 .* not a number"):
        load_conv_layer(path)
