import math

import numpy as np

from calib.overlay import _max_valid_radius
from follow.camera import CameraModel, CameraPose


def test_a_border_pixel_without_a_ray_leaves_the_grid_drawn(monkeypatch):
    """A pixel's ray is NaN where none projects onto it: the widest radius in view was
    NaN then, and no point of the floor grid was drawn."""
    camera = CameraModel.from_fov((640, 480), 70.0, CameraPose(0.9, 0.2),
                                  dist=np.array([-0.2, 0.05, 0.001, -0.001, 0.0]))  # fmt: skip
    widest = _max_valid_radius(camera)
    rays = CameraModel.pixel_rays_base

    def one_without(self, pixels):
        out = rays(self, pixels)
        out[len(out) // 3] = np.nan  # a pixel mid-way along the bottom edge
        return out

    monkeypatch.setattr(CameraModel, "pixel_rays_base", one_without)
    assert math.isfinite(_max_valid_radius(camera))
    assert _max_valid_radius(camera) == widest
