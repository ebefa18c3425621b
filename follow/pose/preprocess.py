"""Image -> network input, and network-output coordinates -> original-image pixels.

The frame is resized to a fixed network input height; the width follows the aspect
ratio and is then padded on the right up to a multiple of the network stride. Pixel
coordinates follow the pixel-centre convention (pixel i covers [i - 0.5, i + 0.5]), so
the mapping between resolutions is x_orig = (x_net + 0.5) / scale_x - 0.5.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from follow.types import InvalidInput

NETWORK_STRIDE_PX = 8
# Padding colour, raw BGR. The network subtracts 128 internally, so 128 pads with zeros.
PAD_VALUE = 128
# The largest frame taken, px a side: 8K video (7680 x 4320, DCI 8192 x 4320) fits. A
# larger array is no camera's (a mosaic, a panorama, a size mixed up), and its filtering,
# resizing and network input would take gigabytes.
MAX_FRAME_SIDE_PX = 8192
# ... and at most this many times as wide as tall: the network input's width follows the
# frame's (an 8192 x 8 strip would make a 368 x 376832 px input, 1.6 GB as floats).
MAX_FRAME_ASPECT = 8


@dataclass(frozen=True)
class Letterbox:
    """How an original image of `original_size` was placed in the network input."""

    original_size: tuple[int, int]  # (width, height) of the frame
    resized_size: tuple[int, int]  # (width, height) after resizing, before padding
    input_size: tuple[int, int]  # (width, height) fed to the network (padded)

    @property
    def scale_xy(self) -> tuple[float, float]:
        return (
            self.resized_size[0] / self.original_size[0],
            self.resized_size[1] / self.original_size[1],
        )

    def to_original(self, points_net_px: np.ndarray) -> np.ndarray:
        """(..., 2) network-input pixel coordinates -> original-image pixels."""
        sx, sy = self.scale_xy
        pts = np.asarray(points_net_px, dtype=np.float64)
        return np.stack([(pts[..., 0] + 0.5) / sx - 0.5, (pts[..., 1] + 0.5) / sy - 0.5], -1)

    def clip_to_original(self, points_px: np.ndarray) -> np.ndarray:
        """(..., 2) original-image pixels clipped to the frame's edges (-0.5 to size -
        0.5; NaN stays NaN): the last heatmap column reaches into the right padding, past
        the frame's last pixel, where nothing was seen."""
        width, height = self.original_size
        pts = np.asarray(points_px, dtype=np.float64)
        return np.stack([np.clip(pts[..., 0], -0.5, width - 0.5),
                         np.clip(pts[..., 1], -0.5, height - 0.5)], -1)  # fmt: skip

    def to_network(self, points_px: np.ndarray) -> np.ndarray:
        """(..., 2) original-image pixels -> network-input pixel coordinates."""
        sx, sy = self.scale_xy
        pts = np.asarray(points_px, dtype=np.float64)
        return np.stack([(pts[..., 0] + 0.5) * sx - 0.5, (pts[..., 1] + 0.5) * sy - 0.5], -1)


def heatmap_to_network_px(cells: np.ndarray, stride_px: int = NETWORK_STRIDE_PX) -> np.ndarray:
    """(..., 2) heatmap cell coordinates -> network-input pixels.

    Cell i covers input pixels [stride*i, stride*i + stride - 1]; its centre is at
    stride*i + (stride - 1) / 2, the point the training labels were placed at.
    """
    return np.asarray(cells, dtype=np.float64) * stride_px + (stride_px - 1) / 2


def plan_letterbox(
    original_size: tuple[int, int], input_height_px: int, stride_px: int = NETWORK_STRIDE_PX
) -> Letterbox:
    """The resize/pad plan for a frame of `original_size` (width, height)."""
    width, height = original_size
    if input_height_px % stride_px:
        raise ValueError(f"pose input height {input_height_px} px is not a multiple of {stride_px}")
    resized_w = max(1, int(round(width * input_height_px / height)))
    padded_w = -(-resized_w // stride_px) * stride_px
    return Letterbox(original_size, (resized_w, input_height_px), (padded_w, input_height_px))


def check_frame(image_bgr: np.ndarray) -> None:
    """Raise InvalidInput naming the problem when `image_bgr` is not a usable BGR frame."""
    if image_bgr is None:
        raise InvalidInput("pose: frame is None (a failed capture or an unreadable file?)")
    if not isinstance(image_bgr, np.ndarray):
        raise InvalidInput(f"pose: frame must be a numpy array, got {type(image_bgr).__name__}")
    if image_bgr.size == 0:
        raise InvalidInput(f"pose: frame is empty (shape {image_bgr.shape})")
    if image_bgr.ndim != 3 or image_bgr.shape[2] != 3:
        raise InvalidInput(f"pose: frame must be HxWx3 BGR, got shape {image_bgr.shape}")
    if image_bgr.dtype != np.uint8:
        raise InvalidInput(f"pose: frame must be uint8, got dtype {image_bgr.dtype}")
    height, width = image_bgr.shape[:2]
    if height < NETWORK_STRIDE_PX or width < NETWORK_STRIDE_PX:
        raise InvalidInput(f"pose: frame too small ({width}x{height} px)")
    if max(width, height) > MAX_FRAME_SIDE_PX:
        raise InvalidInput(f"pose: frame too large ({width}x{height} px; at most "
                           f"{MAX_FRAME_SIDE_PX} px a side)")  # fmt: skip
    if width > MAX_FRAME_ASPECT * height:
        raise InvalidInput(f"pose: frame too wide ({width}x{height} px; at most "
                           f"{MAX_FRAME_ASPECT} times as wide as tall)")  # fmt: skip


def median_filtered(image_bgr: np.ndarray, radius_px: int) -> np.ndarray:
    """The frame through a (2 r + 1)-pixel square median filter, or itself at r = 0.

    Sensor noise and JPEG blocking wash out the fine detail the network finds small,
    far people by; a median removes both and keeps the edges (a Gaussian blur of the
    same size loses more people than the noise did: docs/robustness.md)."""
    if radius_px <= 0:
        return image_bgr
    return cv2.medianBlur(image_bgr, 2 * radius_px + 1)


def unsharp_masked(image_bgr: np.ndarray, amount: float, sigma_px: float) -> np.ndarray:
    """The frame with `amount` times its detail finer than `sigma_px` added back (an
    unsharp mask), or itself at amount 0: outlines softened by the lens, by motion or by
    the upscaling to the network input are steepened again."""
    if amount <= 0.0:
        return image_bgr
    smooth = cv2.GaussianBlur(image_bgr, (0, 0), sigma_px)
    return cv2.addWeighted(image_bgr, 1.0 + amount, smooth, -amount, 0.0)


@dataclass(frozen=True)
class FrameFilter:
    """What is done to a frame before it is resized for the network: a median (noise,
    JPEG blocking), then an unsharp mask (soft outlines). The default does nothing."""

    median_radius_px: int = 0
    unsharp_amount: float = 0.0
    unsharp_sigma_px: float = 1.0

    @classmethod
    def from_config(cls, config) -> FrameFilter:
        """The filter a `PoseConfig` asks for."""
        return cls(config.median_filter_radius_px, config.unsharp_amount, config.unsharp_sigma_px)

    def __call__(self, image_bgr: np.ndarray) -> np.ndarray:
        image_bgr = median_filtered(image_bgr, self.median_radius_px)
        return unsharp_masked(image_bgr, self.unsharp_amount, self.unsharp_sigma_px)


def _resized(
    image_bgr: np.ndarray, input_height_px: int, frame_filter: FrameFilter | None = None
) -> tuple[np.ndarray, Letterbox]:
    check_frame(image_bgr)
    if frame_filter is not None:
        image_bgr = frame_filter(image_bgr)
    height, width = image_bgr.shape[:2]
    plan = plan_letterbox((width, height), input_height_px)
    return cv2.resize(image_bgr, plan.resized_size, interpolation=_interpolation(plan)), plan


def _interpolation(plan: Letterbox) -> int:
    """Bilinear down to half size, area averaging below. Bilinear still reads every
    pixel at half size or more, and is 5-8x faster: 0.2-0.3 ms against 1.4-2.1 ms for
    a 640x480 frame to 256-368 px, a 20th of a 30 fps frame; the robot scene's and the
    robot-camera crops' recall did not change (docs/pose.md). Smaller than half, it
    would skip pixels and alias."""
    return cv2.INTER_AREA if plan.scale_xy[1] < 0.5 else cv2.INTER_LINEAR


def _padded_buffer(buffers, image_bgr, shape, dtype) -> np.ndarray:
    """The caller's array for this frame size and input shape, or a new one; padding
    written once."""
    key = image_bgr.shape[1], image_bgr.shape[0], shape
    array = None if buffers is None else buffers.get(key)
    if array is None:
        array = np.full(shape, PAD_VALUE, dtype)
        if buffers is not None:
            buffers[key] = array
    return array


def prepare_input(
    image_bgr: np.ndarray,
    input_height_px: int,
    buffers: dict[tuple, np.ndarray] | None = None,
    frame_filter: FrameFilter | None = None,
) -> tuple[np.ndarray, Letterbox]:
    """A float32 (1, 3, H, W) raw-BGR tensor for the network, and the plan to map back.

    With `buffers` (one per frame size and input height, kept by the caller: a
    `size_cache.RecentlyUsed` keeps the memory bounded where sizes vary) the tensor is
    written into the same array every frame instead of a new one; the caller must be done
    with the previous tensor before the next call. `frame_filter` (a `FrameFilter`)
    filters the frame first.
    """
    resized, plan = _resized(image_bgr, input_height_px, frame_filter)
    width, height = plan.input_size
    tensor = _padded_buffer(buffers, image_bgr, (1, 3, height, width), np.float32)
    tensor[0, :, :, : plan.resized_size[0]] = resized.transpose(2, 0, 1)
    return tensor, plan


def prepare_frame(
    image_bgr: np.ndarray,
    input_height_px: int,
    buffers: dict[tuple, np.ndarray] | None = None,
    frame_filter: FrameFilter | None = None,
) -> tuple[np.ndarray, Letterbox]:
    """The same as uint8 (1, H, W, 3), for a back-end that converts it inside the graph
    (`runtime.with_frame_input`)."""
    resized, plan = _resized(image_bgr, input_height_px, frame_filter)
    width, height = plan.input_size
    frame = _padded_buffer(buffers, image_bgr, (1, height, width, 3), np.uint8)
    frame[0, :, : plan.resized_size[0]] = resized
    return frame, plan
