"""Loading of the CCF convolution weights (the first two layers of a small re-id network).

The text format has four lines: `N K H W`, then N*K*H*W floats (layout out, in, kh, kw),
then the bias count, then the biases. A truncated or malformed file raises WeightsError
naming the file and what is wrong, never a half-initialised network.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

CONV1_FILE = "conv_t1"
CONV2_FILE = "conv_t2"
INPUT_CHANNELS = 3
FLOAT32_MAX = float(np.finfo(np.float32).max)


class WeightsError(ValueError):
    """A CCF weight file that is missing, truncated or malformed; the message names it."""


@dataclass(frozen=True)
class ConvLayer:
    """One convolution layer: weights (out, in, kh, kw) and biases (out,), float32."""

    weights: np.ndarray
    biases: np.ndarray

    @property
    def out_channels(self) -> int:
        return int(self.weights.shape[0])

    @property
    def in_channels(self) -> int:
        return int(self.weights.shape[1])

    @property
    def kernel_size(self) -> tuple[int, int]:
        return int(self.weights.shape[2]), int(self.weights.shape[3])


@dataclass(frozen=True)
class CcfWeights:
    """conv1 (RGB -> N1 maps) and conv2 (N1 -> N2 maps)."""

    conv1: ConvLayer
    conv2: ConvLayer
    name: str = "ccf"

    @property
    def num_channels(self) -> int:
        return self.conv2.out_channels


def _parse_ints(text: str, path: Path, line_no: int, what: str) -> list[int]:
    try:
        return [int(v) for v in text.split()]
    except ValueError:
        raise WeightsError(
            f"{path}: line {line_no} ({what}) must hold integers, got {text[:60]!r}"
        ) from None


def _parse_floats(text: str, path: Path, line_no: int, what: str, count: int) -> np.ndarray:
    tokens = text.split()
    if len(tokens) != count:
        raise WeightsError(
            f"{path}: line {line_no} ({what}) holds {len(tokens)} values, expected {count}"
            + (" (file truncated?)" if len(tokens) < count else "")
        )
    try:
        values = np.array(tokens, dtype=np.float64)
    except ValueError:
        raise WeightsError(
            f"{path}: line {line_no} ({what}) holds a value that is not a number"
        ) from None
    if not (np.abs(values) <= FLOAT32_MAX).all():  # NaN fails too; 1e39 is inf as float32
        raise WeightsError(f"{path}: line {line_no} ({what}) holds non-finite values (as float32)")
    return values.astype(np.float32)


def load_conv_layer(path: Path) -> ConvLayer:
    """One convolution layer from its text file."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise WeightsError(f"{path}: cannot read CCF weight file ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise WeightsError(f"{path}: not a text CCF weight file") from None
    numbered = [(k, line) for k, line in enumerate(text.splitlines(), 1) if line.strip()]
    lines = [line for _, line in numbered]
    at = [k for k, _ in numbered]  # the file's own line numbers, blank lines counted
    if len(lines) < 4:
        raise WeightsError(
            f"{path}: expected 4 lines (shape, weights, bias count, biases), found {len(lines)}"
            " (file truncated?)"
        )
    if len(lines) > 4:
        raise WeightsError(f"{path}: expected 4 lines, found {len(lines)}")
    shape = _parse_ints(lines[0], path, at[0], "shape N K H W")
    if len(shape) != 4 or min(shape) <= 0:
        raise WeightsError(
            f"{path}: line {at[0]} must be 4 positive integers N K H W, got {shape}"
        )
    weights = _parse_floats(lines[1], path, at[1], f"weights {shape}", int(np.prod(shape)))
    bias_count = _parse_ints(lines[2], path, at[2], "bias count")
    if bias_count != [shape[0]]:
        raise WeightsError(
            f"{path}: line {at[2]} (bias count) is {bias_count}, expected [{shape[0]}]"
        )
    biases = _parse_floats(lines[3], path, at[3], "biases", shape[0])
    return ConvLayer(weights.reshape(shape), biases)


def load_ccf_weights(folder: Path) -> CcfWeights:
    """Both layers from a folder holding `conv_t1` and `conv_t2`, with shape checks."""
    folder = Path(folder)
    if not folder.is_dir():
        raise WeightsError(f"{folder}: CCF weight folder not found")
    conv1 = load_conv_layer(folder / CONV1_FILE)
    conv2 = load_conv_layer(folder / CONV2_FILE)
    if conv1.in_channels != INPUT_CHANNELS:
        raise WeightsError(
            f"{folder / CONV1_FILE}: expects {conv1.in_channels} input channels, not RGB (3)"
        )
    if conv2.in_channels != conv1.out_channels:
        raise WeightsError(
            f"{folder / CONV2_FILE}: expects {conv2.in_channels} input channels but "
            f"{CONV1_FILE} produces {conv1.out_channels}"
        )
    for layer, name in ((conv1, CONV1_FILE), (conv2, CONV2_FILE)):
        kh, kw = layer.kernel_size
        if kh % 2 == 0 or kw % 2 == 0:
            raise WeightsError(f"{folder / name}: kernel {kh}x{kw} must have odd sides")
    return CcfWeights(conv1, conv2, name=folder.name)
