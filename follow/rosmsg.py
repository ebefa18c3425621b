"""Conversions between ROS messages and `follow`'s types, without ROS.

The functions read messages by attribute, so they take rclpy messages (the ROS 2
node) and the messages `rosbags` deserialises from ROS 1 and ROS 2 bags alike; the
`*_fields` functions give the keyword arguments that build such messages.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from follow.camera import CameraModel
from follow.types import InvalidInput, Odometry

# Encodings of sensor_msgs/Image we decode: channels and the OpenCV conversion to BGR.
IMAGE_ENCODINGS: dict[str, tuple[int, int | None]] = {
    "bgr8": (3, None),
    "8UC3": (3, None),
    "rgb8": (3, cv2.COLOR_RGB2BGR),
    "bgra8": (4, cv2.COLOR_BGRA2BGR),
    "rgba8": (4, cv2.COLOR_RGBA2BGR),
    "mono8": (1, cv2.COLOR_GRAY2BGR),
    "8UC1": (1, cv2.COLOR_GRAY2BGR),
}
# Channels of a decoded JPEG/PNG (OpenCV's order: grey, BGR, BGRA) -> conversion to BGR.
_DECODED_TO_BGR: dict[int, int | None] = {1: cv2.COLOR_GRAY2BGR, 3: None, 4: cv2.COLOR_BGRA2BGR}
# CameraInfo distortion models that are OpenCV's pinhole coefficients.
_PINHOLE_MODELS = ("", "plumb_bob", "rational_polynomial")


def stamp_s(header) -> float:
    """Seconds of a std_msgs/Header (or of a bare builtin_interfaces/Time)."""
    stamp = getattr(header, "stamp", header)
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


def stamp_fields(seconds: float) -> dict:
    """builtin_interfaces/Time keyword arguments for `seconds`."""
    sec = math.floor(seconds)
    nanosec = min(int(round((seconds - sec) * 1e9)), 999_999_999)
    return {"sec": int(sec), "nanosec": nanosec}


def image_from_msg(msg) -> np.ndarray:
    """A BGR uint8 image from sensor_msgs/Image or CompressedImage."""
    raw = msg.data
    data = raw.ravel() if isinstance(raw, np.ndarray) else np.frombuffer(raw, dtype=np.uint8)
    if hasattr(msg, "format"):  # CompressedImage
        return _decompressed(str(msg.format), data)
    if msg.encoding not in IMAGE_ENCODINGS:
        raise InvalidInput(
            f"image encoding {msg.encoding!r} is not supported; "
            f"use one of {sorted(IMAGE_ENCODINGS)}"
        )
    channels, conversion = IMAGE_ENCODINGS[msg.encoding]
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    if height <= 0 or width <= 0:
        raise InvalidInput(f"image {width}x{height} {msg.encoding} is empty")
    if step < width * channels or data.size != step * height:  # the message's own rule
        raise InvalidInput(
            f"image {width}x{height} {msg.encoding}: step {step} and {data.size} bytes do not "
            f"fit (expected step >= {width * channels} and step x height = {step * height} "
            "bytes): wrong encoding or a damaged message"
        )
    rows = data.reshape(height, step)[:, : width * channels]
    image = rows.reshape(height, width, channels)
    return np.ascontiguousarray(image) if conversion is None else cv2.cvtColor(image, conversion)


def compressed_source_encoding(image_format: str) -> str | None:
    """The encoding of the image a CompressedImage was made from, where its `format`
    names it: image_transport writes `"<encoding>; <jpeg|png> compressed [<target>]"`
    ("rgb8; jpeg compressed bgr8", "mono16; png compressed mono16"), compressedDepth
    `"16UC1; compressedDepth png"`; a bare "jpeg" or "png" names none."""
    if ";" not in image_format:
        return None
    return image_format.split(";", 1)[0].strip() or None


def _decompressed(image_format: str, data: np.ndarray) -> np.ndarray:
    """A BGR uint8 image from a CompressedImage's `format` and bytes. Only 8-bit images
    are taken, as from a raw Image: a 16-bit one (a thermal or depth camera's mono16)
    scaled to 8 bits would be a nearly black frame in which nobody is ever found, with
    no error said. Decoded as stored (no EXIF rotation: the camera's own pixels)."""
    source = compressed_source_encoding(image_format)
    if source is not None and source not in IMAGE_ENCODINGS:
        raise InvalidInput(
            f"compressed image ({image_format!r}) of a {source!r} image is not supported; "
            f"its source encoding must be one of {sorted(IMAGE_ENCODINGS)}"
        )
    if data.size == 0:
        raise InvalidInput(f"compressed image ({image_format!r}) holds no data")
    image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InvalidInput(f"compressed image ({image_format!r}) cannot be decoded")
    if image.dtype != np.uint8:
        raise InvalidInput(
            f"compressed image ({image_format!r}) holds {image.dtype} pixels: only 8-bit "
            "images are decoded (a 16-bit one scaled to 8 bits is nearly black); publish "
            f"one of {sorted(IMAGE_ENCODINGS)}"
        )
    channels = 1 if image.ndim == 2 else image.shape[2]
    if channels not in _DECODED_TO_BGR:
        raise InvalidInput(
            f"compressed image ({image_format!r}) has {channels} channels, not 1, 3 or 4"
        )
    conversion = _DECODED_TO_BGR[channels]
    return np.ascontiguousarray(image) if conversion is None else cv2.cvtColor(image, conversion)


def image_fields(image_bgr: np.ndarray) -> dict:
    """sensor_msgs/Image keyword arguments (no header) for a BGR uint8 image."""
    height, width = image_bgr.shape[:2]
    return {"height": height, "width": width, "encoding": "bgr8", "is_bigendian": 0,
            "step": 3 * width, "data": np.ascontiguousarray(image_bgr).reshape(-1)}  # fmt: skip


def yaw_of_quaternion(q) -> float:
    """Heading (rotation about z) of a geometry_msgs/Quaternion. Drivers publish
    quaternions a little off unit length (float32 maths): this form does not depend on
    the length, where `1 - 2(y² + z²)` would turn 5 % off into 5 degrees off. A zero or
    non-finite quaternion (an orientation never filled in) has no heading."""
    w, x, y, z = float(q.w), float(q.x), float(q.y), float(q.z)
    norm2 = w * w + x * x + y * y + z * z
    if not (math.isfinite(norm2) and norm2 > 1e-12):
        raise InvalidInput(
            f"orientation quaternion {(x, y, z, w)} has no heading (zero or not finite)"
        )
    return math.atan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z)


def quaternion_of_yaw(yaw_rad: float) -> dict:
    """geometry_msgs/Quaternion keyword arguments of a rotation about z."""
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw_rad / 2.0), "w": math.cos(yaw_rad / 2.0)}


def odometry_from_msg(msg) -> Odometry:
    """The planar robot pose of a nav_msgs/Odometry, at its header's stamp."""
    pose = msg.pose.pose
    yaw = yaw_of_quaternion(pose.orientation)
    return Odometry(float(pose.position.x), float(pose.position.y), yaw, stamp_s(msg.header))


def frame_id_of(msg) -> str:
    """A message's header.frame_id as the frame's name: without the leading "/" of ROS 1
    and of older tf names, as the ROS 2 node compares them; "" where it names none."""
    return str(msg.header.frame_id).lstrip("/")


def _field(msg, name: str):
    """A CameraInfo field: lower case in ROS 2 (`k`), upper case in ROS 1 (`K`)."""
    value = getattr(msg, name, None)
    return getattr(msg, name.upper()) if value is None else value


def _cropped(msg) -> tuple[int, int, np.ndarray]:
    """(width, height, K) of the images a CameraInfo goes with: K and (width, height) are
    the full sensor's, and a region of interest (`roi`, all zeros: the full image) crops
    the published images, moving the principal point (binning only scales them, which
    `CameraModel.for_image_size` does from the images' size)."""
    K = np.asarray(_field(msg, "k"), dtype=np.float64).reshape(3, 3)
    width, height = int(msg.width), int(msg.height)
    roi = getattr(msg, "roi", None)
    if roi is None:
        return width, height, K
    x, y, w, h = (int(v) for v in (roi.x_offset, roi.y_offset, roi.width, roi.height))
    if (x, y, w, h) == (0, 0, 0, 0) or (x, y, w, h) == (0, 0, width, height):
        return width, height, K
    if w <= 0 or h <= 0 or x + w > width or y + h > height:
        raise InvalidInput(
            f"camera_info roi (x_offset {x}, y_offset {y}, width {w}, height {h}) does not "
            f"lie inside its {width}x{height} image"
        )
    K = K.copy()
    K[0, 2] -= x
    K[1, 2] -= y
    return w, h, K


def camera_info_key(msg) -> tuple:
    """What of a sensor_msgs/CameraInfo a camera model is built from (size, distortion
    model, K, D, with its region of interest applied): equal keys, the same camera."""
    width, height, K = _cropped(msg)
    return (width, height, str(msg.distortion_model), tuple(float(v) for v in K.ravel()),
            tuple(float(v) for v in _field(msg, "d")))  # fmt: skip


def camera_from_info(msg, mounted: CameraModel) -> CameraModel:
    """`mounted` (the camera file: its pose on the robot) with the intrinsics, distortion
    and image size of a sensor_msgs/CameraInfo (of its region of interest, where the
    images are cropped)."""
    model = str(msg.distortion_model)
    if model not in _PINHOLE_MODELS:
        raise InvalidInput(
            f"camera_info distortion_model {model!r} is not supported; use one of "
            f"{[m for m in _PINHOLE_MODELS if m]}"
        )
    width, height, K = _cropped(msg)
    dist = np.asarray(_field(msg, "d"), dtype=np.float64).ravel()
    if dist.size and not dist.any():
        dist = np.zeros(0)
    try:
        return CameraModel(K, dist, (width, height), mounted.pose)
    except ValueError as exc:
        raise InvalidInput(f"camera_info: {exc}") from None


def camera_info_fields(camera: CameraModel) -> dict:
    """sensor_msgs/CameraInfo keyword arguments (no header) of a camera's intrinsics."""
    dist = np.zeros(5) if camera.dist.size == 0 else camera.dist
    if dist.size == 4:
        dist = np.append(dist, 0.0)
    P = np.hstack([camera.K, np.zeros((3, 1))])
    return {"width": camera.image_size[0], "height": camera.image_size[1],
            "distortion_model": "plumb_bob" if dist.size == 5 else "rational_polynomial",
            "d": dist.astype(np.float64), "k": camera.K.reshape(-1), "r": np.eye(3).reshape(-1),
            "p": P.reshape(-1)}  # fmt: skip
