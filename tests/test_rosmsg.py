"""ROS message conversions (without ROS) and odometry matched to image stamps."""

from __future__ import annotations

import math
from types import SimpleNamespace as Msg

import cv2
import numpy as np
import pytest

from follow.camera import CameraModel, CameraPose
from follow.odometry_buffer import OdometryBuffer
from follow.rosmsg import (
    camera_from_info,
    camera_info_fields,
    image_fields,
    image_from_msg,
    odometry_from_msg,
    quaternion_of_yaw,
    stamp_fields,
    stamp_s,
    yaw_of_quaternion,
)
from follow.types import InvalidInput, Odometry

IMAGE = np.random.default_rng(1).integers(0, 255, (5, 7, 3), dtype=np.uint8)


def test_images_decode_to_bgr_from_every_supported_encoding():
    fields = image_fields(IMAGE)
    assert np.array_equal(image_from_msg(Msg(**fields)), IMAGE)
    rgb = Msg(**{**fields, "encoding": "rgb8", "data": IMAGE[..., ::-1].reshape(-1)})
    assert np.array_equal(image_from_msg(rgb), IMAGE)
    # Rows padded to 24 bytes (step > width * channels) are cut back.
    padded = np.zeros((5, 24), np.uint8)
    padded[:, :21] = IMAGE.reshape(5, 21)
    assert np.array_equal(image_from_msg(Msg(**{**fields, "step": 24, "data": padded})), IMAGE)
    grey = Msg(**{**fields, "encoding": "mono8", "step": 7, "data": IMAGE[..., 0].reshape(-1)})
    assert np.array_equal(image_from_msg(grey)[..., 2], IMAGE[..., 0])
    ok, png = cv2.imencode(".png", IMAGE)
    assert np.array_equal(image_from_msg(Msg(format="png", data=png.tobytes())), IMAGE)


def test_bad_images_are_named():
    fields = image_fields(IMAGE)
    with pytest.raises(InvalidInput, match="encoding '16UC1' is not supported"):
        image_from_msg(Msg(**{**fields, "encoding": "16UC1"}))
    with pytest.raises(InvalidInput, match="do not fit"):
        image_from_msg(Msg(**{**fields, "data": fields["data"][:-1]}))
    with pytest.raises(InvalidInput, match="cannot be decoded"):
        image_from_msg(Msg(format="jpeg", data=b"not a jpeg"))


def test_stamps_and_headings_round_trip():
    for seconds in (0.0, 1234.5, 1700000000.123456789):
        assert stamp_s(Msg(stamp=Msg(**stamp_fields(seconds)))) == pytest.approx(seconds, abs=1e-9)
    for yaw in (-3.0, -0.4, 0.0, 1.2, 3.1):
        q = quaternion_of_yaw(yaw)
        msg = Msg(header=Msg(stamp=Msg(sec=5, nanosec=0)),
                  pose=Msg(pose=Msg(position=Msg(x=1.0, y=-2.0, z=0.0), orientation=Msg(**q))))  # fmt: skip
        pose = odometry_from_msg(msg)
        assert (pose.x_m, pose.y_m, pose.yaw_rad, pose.stamp_s) == pytest.approx(
            (1.0, -2.0, yaw, 5.0)
        )


def test_camera_info_replaces_intrinsics_and_keeps_the_mounting():
    mounted = CameraModel.from_fov((640, 480), 60.0, CameraPose(height_m=1.1, pitch_rad=0.2))
    other = CameraModel.from_fov((320, 240), 90.0, CameraPose(height_m=5.0),
                                 dist=np.array([0.1, 0.01, 0.0, 0.0, 0.0]))  # fmt: skip
    camera = camera_from_info(Msg(**camera_info_fields(other)), mounted)
    assert camera.pose == mounted.pose and camera.image_size == (320, 240)
    np.testing.assert_allclose(camera.K, other.K)
    np.testing.assert_allclose(camera.dist, other.dist)
    fisheye = Msg(**{**camera_info_fields(other), "distortion_model": "equidistant"})
    with pytest.raises(InvalidInput, match="'equidistant' is not supported"):
        camera_from_info(fisheye, mounted)


def test_camera_info_of_a_cropped_image_gives_the_crop_s_intrinsics():
    """K is for the full sensor; a region of interest (roi) crops the image published
    with it. Scaled to the crop's size instead, a centre crop of half the size would
    halve the focal length and put every person at half their distance."""
    from follow.run import camera_for_frames

    mounted = CameraModel.from_fov((640, 480), 60.0, CameraPose(height_m=1.1))
    roi = Msg(x_offset=160, y_offset=120, width=320, height=240, do_rectify=False)
    info = Msg(**camera_info_fields(mounted), roi=roi, binning_x=0, binning_y=0)
    camera = camera_for_frames(camera_from_info(info, mounted), 320, 240)
    assert camera.image_size == (320, 240)
    np.testing.assert_allclose(camera.K[[0, 1], [0, 1]], mounted.K[[0, 1], [0, 1]])
    np.testing.assert_allclose(camera.K[:2, 2], mounted.K[:2, 2] - [160, 120])
    # all zeros: the full image; binning: the image subsampled, K scaled with it
    full = Msg(x_offset=0, y_offset=0, width=0, height=0, do_rectify=False)
    info = Msg(**camera_info_fields(mounted), roi=full, binning_x=2, binning_y=2)
    camera = camera_for_frames(camera_from_info(info, mounted), 320, 240)
    np.testing.assert_allclose(camera.K[[0, 1], [0, 1]], mounted.K[[0, 1], [0, 1]] / 2)
    # the sky cropped off: the principal point 30 % off the crop's centre, as it should be
    sky = Msg(x_offset=0, y_offset=200, width=640, height=280, do_rectify=False)
    camera = camera_from_info(Msg(**camera_info_fields(mounted), roi=sky), mounted)
    assert camera.K[1, 2] == pytest.approx(mounted.K[1, 2] - 200)
    outside = Msg(x_offset=400, y_offset=0, width=320, height=240, do_rectify=False)
    with pytest.raises(InvalidInput, match="roi"):
        camera_from_info(Msg(**camera_info_fields(mounted), roi=outside), mounted)


def test_odometry_is_interpolated_between_samples_and_never_invented():
    buffer = OdometryBuffer(max_gap_s=0.1)
    buffer.add(Odometry(0.0, 0.0, math.pi - 0.1, 10.0))
    buffer.add(Odometry(0.2, 0.4, -math.pi + 0.1, 10.2))  # heading crosses +-pi
    mid = buffer.at(10.05)
    assert (mid.x_m, mid.y_m, mid.stamp_s) == pytest.approx((0.05, 0.1, 10.05))
    assert abs(abs(mid.yaw_rad) - (math.pi - 0.05)) < 1e-9  # the shorter arc, not through 0
    assert buffer.at(10.25).x_m == 0.2  # just after the last sample: the nearest one
    assert buffer.at(10.35) is None and buffer.at(9.8) is None  # too far: no pose at all
    sparse = OdometryBuffer(max_gap_s=0.1)
    sparse.add(Odometry(0.0, 0.0, 0.0, 0.0))
    sparse.add(Odometry(5.0, 0.0, 0.0, 1.0))
    assert sparse.at(0.5) is None  # a 1 s hole is not bridged
    assert not sparse.wait_until(2.0, timeout_s=0.01) and sparse.wait_until(1.0, timeout_s=0.01)


def _raw(**fields):
    image = np.zeros((6, 8, 3), np.uint8)
    base = dict(height=6, width=8, encoding="bgr8", is_bigendian=0, step=24,
                data=image.reshape(-1))  # fmt: skip
    return Msg(**{**base, **fields})


def test_image_data_longer_than_its_rows_is_refused():
    """bgr8 bytes labelled mono8 would decode as a grey third of the picture."""
    with pytest.raises(InvalidInput, match="step x height = 48 bytes"):
        image_from_msg(_raw(encoding="mono8", step=8))


@pytest.mark.parametrize("msg", [
    _raw(height=0, encoding="mono8", step=8, data=np.zeros(0, np.uint8)),
    _raw(width=0, step=0, encoding="rgb8", data=np.zeros(0, np.uint8)),
    Msg(format="jpeg", data=b""),
])  # fmt: skip
def test_an_empty_image_is_invalid_input_not_an_opencv_error(msg):
    with pytest.raises(InvalidInput):
        image_from_msg(msg)


@pytest.mark.parametrize("scale", [0.5, 0.95, 1.05, 2.0])
def test_the_heading_of_a_quaternion_off_unit_length_is_its_rotation(scale):
    q = quaternion_of_yaw(math.radians(90.0))
    scaled = Msg(**{k: scale * v for k, v in q.items()})
    assert math.degrees(yaw_of_quaternion(scaled)) == pytest.approx(90.0)


@pytest.mark.parametrize("q", [(0.0, 0.0, 0.0, 0.0), (0.0, 0.0, float("nan"), 1.0)])
def test_a_quaternion_with_no_heading_is_refused(q):
    x, y, z, w = q
    with pytest.raises(InvalidInput, match="has no heading"):
        yaw_of_quaternion(Msg(x=x, y=y, z=z, w=w))
