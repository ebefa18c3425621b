"""CompressedImage messages (`ros.image_topic` ending in `/compressed`, and bags) as
image_transport's compressed transport writes them: `format` is "<source encoding>;
<jpeg|png> compressed [<target>]", the data BGR (or grey) as OpenCV encodes it. 8-bit
images decode in the right colour order; a 16-bit one (a thermal or depth camera's
mono16, lossless as PNG) is refused as its raw Image is, not scaled to a nearly black
frame in which nobody is ever found. Without ROS."""

from __future__ import annotations

from types import SimpleNamespace as Msg

import cv2
import numpy as np
import pytest

from follow.rosmsg import compressed_source_encoding, image_from_msg
from follow.types import InvalidInput

# BGR, as cv_bridge hands image_transport a colour image: red, green, blue columns
COLOURS_BGR = np.zeros((16, 48, 3), np.uint8)
COLOURS_BGR[:, 0:16, 2] = 255
COLOURS_BGR[:, 16:32, 1] = 255
COLOURS_BGR[:, 32:48, 0] = 255
CENTRES = (slice(4, 12), [4, 5, 6, 7, 8, 9, 10, 11, 20, 21, 26, 27, 36, 37, 42, 43])
THERMAL_MONO16 = np.random.default_rng(0).integers(0, 4096, (24, 32), dtype=np.uint16)


def _compressed(image_format: str, image: np.ndarray, extension: str) -> Msg:
    ok, data = cv2.imencode(extension, image)
    assert ok
    return Msg(format=image_format, data=data.tobytes())


@pytest.mark.parametrize("image_format", [
    "png", "bgr8; png compressed bgr8", "rgb8; png compressed bgr8",
    "bgra8; png compressed bgr8", "rgba8; png compressed bgr8", "8UC3; png compressed bgr8",
])  # fmt: skip
def test_8_bit_colour_png_decodes_exactly_in_bgr(image_format):
    """image_transport converts a colour image to bgr8 before compressing it, whatever its
    encoding: an `rgb8` source must not be swapped back."""
    decoded = image_from_msg(_compressed(image_format, COLOURS_BGR, ".png"))
    assert decoded.dtype == np.uint8 and np.array_equal(decoded, COLOURS_BGR)


@pytest.mark.parametrize("image_format", [
    "jpeg", "bgr8; jpeg compressed bgr8", "rgb8; jpeg compressed bgr8",
])  # fmt: skip
def test_8_bit_colour_jpeg_keeps_red_red(image_format):
    decoded = image_from_msg(_compressed(image_format, COLOURS_BGR, ".jpg")).astype(int)
    assert decoded.shape == COLOURS_BGR.shape
    loss = np.abs(decoded - COLOURS_BGR)[CENTRES]  # away from the edges JPEG blurs
    assert loss.max() < 40  # JPEG's loss, not a channel swap (255)


@pytest.mark.parametrize(("image_format", "extension"), [
    ("mono8; jpeg compressed mono8", ".jpg"), ("mono8; png compressed ", ".png"),
    ("8UC1; png compressed ", ".png"),
])  # fmt: skip
def test_8_bit_grey_decodes_to_three_equal_channels(image_format, extension):
    grey = COLOURS_BGR[..., 2]
    decoded = image_from_msg(_compressed(image_format, grey, extension)).astype(int)
    assert decoded.shape == (*grey.shape, 3)
    assert np.array_equal(decoded[..., 0], decoded[..., 2])
    assert np.abs(decoded[..., 1] - grey)[CENTRES].max() < 40


def test_a_png_with_alpha_loses_only_its_alpha():
    bgra = np.dstack([COLOURS_BGR, np.full(COLOURS_BGR.shape[:2], 128, np.uint8)])
    decoded = image_from_msg(_compressed("png", bgra, ".png"))
    assert np.array_equal(decoded, COLOURS_BGR)


@pytest.mark.parametrize("image_format", [
    "mono16; png compressed mono16", "mono16; png compressed ", "16UC1; png compressed ",
])  # fmt: skip
def test_a_16_bit_image_named_in_the_format_is_refused_by_its_encoding(image_format):
    msg = _compressed(image_format, THERMAL_MONO16, ".png")
    source = image_format.split(";")[0]
    with pytest.raises(InvalidInput, match=f"of a '{source}' image is not supported"):
        image_from_msg(msg)


@pytest.mark.parametrize("image", [THERMAL_MONO16, np.dstack([THERMAL_MONO16] * 3)])
def test_16_bit_data_under_a_bare_format_is_refused_not_scaled(image):
    """No source encoding to read ("png"): the decoded data must still be 8-bit."""
    with pytest.raises(InvalidInput, match="holds uint16 pixels: only 8-bit images"):
        image_from_msg(_compressed("png", image, ".png"))


def test_a_source_encoding_not_decoded_from_a_raw_image_is_refused_compressed_too():
    """image_transport's JPEG of a 16-bit image is 8-bit data, squeezed from 16: as
    meaningless to the pose network as the raw image, which is refused."""
    squeezed = (THERMAL_MONO16 >> 4).astype(np.uint8)
    msg = _compressed("mono16; jpeg compressed mono8", squeezed, ".jpg")
    with pytest.raises(InvalidInput, match="'mono16' image is not supported"):
        image_from_msg(msg)


@pytest.mark.parametrize(("image_format", "source"), [
    ("jpeg", None), ("png", None), ("rgb8; jpeg compressed bgr8", "rgb8"),
    ("mono16; png compressed ", "mono16"), ("16UC1; compressedDepth png", "16UC1"),
    ("; png compressed ", None),
])  # fmt: skip
def test_the_source_encoding_is_read_from_image_transport_s_format(image_format, source):
    assert compressed_source_encoding(image_format) == source
