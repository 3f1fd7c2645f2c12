"""Where each pixel of the next image was in the last one, for a predicted ground motion.

KLT matches a window of the last image, shifted, to the next one. Over the ground the window
does not only shift: it grows as the ground comes nearer, and shears in turns, and KLT's
shift then misses the window's centre by a bias that is the same for every track (the camera
seems to sink 0.1 mm a frame and to pitch up by a few mdeg; it grows with the window squared
and with the motion). Warping the last image by the motion predicted from the last twist
before KLT leaves only the prediction's error to deform the window: on the rendered drives,
with the true motion as the prediction, the sinking went from -122 to -1 um a frame and the
pitch error from -3.7 to -0.3 mdeg. Numpy and OpenCV only; no ROS.
"""

from __future__ import annotations

import cv2
import numpy as np

from planar_vo.camera import CameraModel, rays_through
from planar_vo.ransac import TransferModel

__all__ = ['GroundWarp']


def _inverse(motion: np.ndarray) -> np.ndarray:
    x, y, yaw = motion
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([-(c * x + s * y), s * x - c * y, -yaw])


class GroundWarp:
    """Per-pixel maps of a camera's next image into its last one, through the ground.

    The maps are computed on a grid of ``step`` pixels and interpolated (they are smooth),
    so a frame costs a few thousand undistortions, not a whole image's.
    """

    def __init__(self, camera: CameraModel, step: int = 8) -> None:
        self.camera, self.step = camera, step
        w, h = camera.width // step, camera.height // step
        # Cell centres, where cv2.resize puts the coarse samples when it scales by ``step``.
        u = np.arange(w) * step + (step - 1) / 2.0
        v = np.arange(h) * step + (step - 1) / 2.0
        uu, vv = np.meshgrid(u, v)
        self._shape = (h, w)
        self._rays = rays_through(camera.normalize(np.c_[uu.ravel(), vv.ravel()]))

    def maps(self, model: TransferModel, motion: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(map_x, map_y), float32 (H, W), for the base_link ``motion`` (x, y, yaw).

        Where each pixel of the image after the motion was in the one before, through the
        ground as ``model`` (its mounting) sees it; far outside the image where the pixel
        sees no ground.
        """
        ground, valid = model.mounting.ground_points(self._rays)
        coarse = np.full((len(self._rays), 2), -1e4)
        if np.any(valid):
            back = self.camera.distort(model.transfer(_inverse(motion), ground[valid]))
            coarse[valid] = np.where(np.isfinite(back), back, -1e4)
        coarse = coarse.reshape(*self._shape, 2).astype(np.float32)
        full = cv2.resize(coarse, (self.camera.width, self.camera.height),
                          interpolation=cv2.INTER_LINEAR)
        return np.ascontiguousarray(full[..., 0]), np.ascontiguousarray(full[..., 1])
