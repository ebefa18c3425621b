"""An image folder's JPEG with data after its end-of-image marker (a phone's trailer) is
whole; one cut short, with no end-of-image marker of its own, is still refused."""

import cv2
import numpy as np
import pytest

from follow.capture import FrameSource

# What phones append after a JPEG's end-of-image marker (FFD9).
SAMSUNG_TRAILER = b"\x00\x00" + b"Image_UTC_Data1700000000000" + b"SEFH" + bytes(range(256)) * 4
# Apple's and MPF's further images (a depth or gain map): a whole JPEG after the first.
SECOND_IMAGE = cv2.imencode(".jpg", np.full((16, 16, 3), 200, np.uint8))[1].tobytes()

ENCODINGS = {
    "baseline": [],
    "progressive": [cv2.IMWRITE_JPEG_PROGRESSIVE, 1],  # several scans, tables between them
    "restart markers": [cv2.IMWRITE_JPEG_RST_INTERVAL, 2],  # FFD0-FFD7 inside the scan
}


def jpeg(seed: int, params=()) -> bytes:
    image = np.random.default_rng(seed).integers(0, 255, (48, 64, 3), dtype=np.uint8)
    ok, encoded = cv2.imencode(".jpg", image, list(params))
    assert ok
    return encoded.tobytes()


def with_exif_thumbnail(data: bytes) -> bytes:
    """`data` with an APP1 (EXIF) segment after its start marker holding a thumbnail
    JPEG, whose own end-of-image marker comes before the image's data."""
    body = b"Exif\x00\x00" + SECOND_IMAGE
    return data[:2] + b"\xff\xe1" + (len(body) + 2).to_bytes(2, "big") + body + data[2:]


def folder_of(tmp_path, middle: bytes) -> list:
    """The frames of a folder a.jpg, b.jpg (`middle`), c.jpg."""
    (tmp_path / "a.jpg").write_bytes(jpeg(1))
    (tmp_path / "b.jpg").write_bytes(middle)
    (tmp_path / "c.jpg").write_bytes(jpeg(3))
    return list(FrameSource(str(tmp_path)))


@pytest.mark.parametrize("encoding", ENCODINGS)
@pytest.mark.parametrize("trailer", [SAMSUNG_TRAILER, SECOND_IMAGE], ids=["samsung", "mpf"])
def test_a_jpeg_with_a_phones_trailer_after_its_end_is_used_not_taken_for_cut(
    tmp_path, caplog, encoding, trailer
):
    whole = jpeg(2, ENCODINGS[encoding])
    frames = folder_of(tmp_path, whole + trailer)
    assert len(frames) == 3 and "cut short" not in caplog.text
    expected = cv2.imdecode(np.frombuffer(whole, np.uint8), cv2.IMREAD_COLOR)
    assert np.array_equal(frames[1].image, expected)  # the image, not the trailer's


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_a_jpeg_cut_short_is_still_refused_whatever_its_encoding(tmp_path, caplog, encoding):
    whole = jpeg(2, ENCODINGS[encoding])
    frames = folder_of(tmp_path, whole[: len(whole) // 2])
    assert len(frames) == 2 and "b.jpg: a JPEG cut short" in caplog.text


def test_a_jpeg_cut_short_is_refused_though_its_exif_thumbnail_ends_whole(tmp_path, caplog):
    """The thumbnail's FFD9 lies ahead of the image: it is no end of the image."""
    whole = with_exif_thumbnail(jpeg(2))
    assert len(folder_of(tmp_path, whole)) == 3 and "cut short" not in caplog.text
    cut = whole[: len(whole) - 200]  # into the image's data, past the thumbnail
    assert b"\xff\xd9" in cut
    assert len(folder_of(tmp_path, cut)) == 2 and "b.jpg: a JPEG cut short" in caplog.text


def test_a_whole_jpeg_with_a_damaged_byte_pair_in_its_data_is_used_as_before(tmp_path, caplog):
    """A bit error that makes FF 50 in the image data is no marker: the walk stops there,
    and a file that ends with its end marker is used (OpenCV decodes most of it), as
    before the walk; it is not skipped as cut short."""
    whole = bytearray(jpeg(2))
    scan = whole.index(b"\xff\xda")
    at = scan + 2 + int.from_bytes(whole[scan + 2 : scan + 4], "big") + 40
    whole[at : at + 2] = b"\xff\x50"
    frames = folder_of(tmp_path, bytes(whole))
    assert len(frames) == 3 and "cut short" not in caplog.text
