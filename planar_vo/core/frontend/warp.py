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

from planar_vo.core.estimation.ransac import TransferModel
from planar_vo.core.estimation.rolling_shutter import ShutterModel
from planar_vo.core.geometry.camera import CameraModel, rays_through
from planar_vo.core.geometry.se2 import inverse_motion

__all__ = ['GroundWarp']


class GroundWarp:
    """A per-pixel map of a camera's next image into its last one, through the ground.

    The map is computed on a grid of ``step`` pixels and interpolated (it is smooth),
    so a frame costs about a thousand undistortions, not a whole image's. KLT matches the
    warped image at the warp's own positions (the anchors come from the same interpolated
    map), so an interpolation error only deforms the windows a little: 0.04 px at 16 px
    against a 4 px grid on the ``default`` camera, 0.009 px at 8 px for twice the cost.
    """

    def __init__(self, camera: CameraModel, step: int = 16) -> None:
        self.camera, self.step = camera, step
        w, h = -(-camera.width // step), -(-camera.height // step)
        # Cell centres, where cv2.resize puts the coarse samples when it scales by ``step``.
        u = np.arange(w) * step + (step - 1) / 2.0
        v = np.arange(h) * step + (step - 1) / 2.0
        uu, vv = np.meshgrid(u, v)
        self._shape = (h, w)
        self._rays = rays_through(camera.normalize(np.c_[uu.ravel(), vv.ravel()]))
        self._rows = vv.ravel()  # the samples' pixel rows (a rolling shutter's times)
        self._buffer: np.ndarray | None = None  # the last map, reused while its size holds
        self._ground: tuple | None = None  # (mounting, the rays' ground points and validity)

    def pixel_map(self, model: TransferModel, motion: np.ndarray) -> np.ndarray:
        """The (H, W, 2) float32 map of (x, y) for the base_link ``motion`` (x, y, yaw).

        Where each pixel of the image after the motion was in the one before, through the
        ground as ``model`` (its mounting) sees it; far outside the image where the pixel
        sees no ground. ``cv2.remap(last, map, None, ...)`` takes it as it is.
        """
        return self.rows_map(model, motion, 0).copy()

    def rows_map(self, model: TransferModel, motion: np.ndarray, first_row: int,
                 shutter: ShutterModel | None = None, dt: float = 0.0) -> np.ndarray:
        """:meth:`pixel_map`'s rows from ``first_row`` on, (H - first_row, W, 2).

        Only those rows are interpolated (a camera's ground is its lower part), the same
        values as :meth:`pixel_map`'s, into a buffer reused from call to call: the map is a
        view valid until the next call. With a rolling ``shutter`` (``motion`` over ``dt``
        s), each pixel is mapped from where the ground it sees was at its row's time in the
        last image (its motion stretched by the two rows' times, as the estimator has it).
        """
        first_row = int(np.clip(first_row, 0, self.camera.height - 1))
        h, w = self._shape
        step = self.step
        # The padded grid is resized from its row r0 on (see below): only the coarse rows
        # from k0 on are needed (padded row i is coarse row i - 1; two at least).
        r0 = (first_row + step // 2) // step
        k0 = min(max(r0 - 1, 0), h - 2)
        if self._ground is None or self._ground[0] != model.mounting:
            self._ground = (model.mounting, *model.mounting.ground_points(self._rays))
        ground, valid = self._ground[1][k0 * w:], self._ground[2][k0 * w:]
        coarse = np.full((len(valid), 2), -1e4)
        if np.any(valid) and shutter is not None and not shutter.global_shutter:
            def pixels(points: np.ndarray) -> np.ndarray:
                return self.camera.distort(model.transfer(np.zeros(3), points))
            back = shutter.seen_in_other(ground[valid], self._rows[k0 * w:][valid], motion, dt,
                                         pixels, self.camera.height, forward=False)
            coarse[valid] = np.where(np.isfinite(back), back, -1e4)
        elif np.any(valid):
            back = self.camera.distort(model.transfer(inverse_motion(motion), ground[valid]))
            coarse[valid] = np.where(np.isfinite(back), back, -1e4)
        coarse = coarse.reshape(h - k0, w, 2).astype(np.float32)
        # One sample more on every side, extrapolated linearly: every pixel then lies between
        # samples (held at the edge value instead, the outer half cells were up to 8 px off).
        padded = np.empty((h + 2, w + 2, 2), np.float32)
        padded[k0 + 1:-1, 1:-1] = coarse
        if k0 == 0:
            padded[0, 1:-1] = 2 * coarse[0] - coarse[1]
        padded[-1, 1:-1] = 2 * coarse[-1] - coarse[-2]
        used = 0 if k0 == 0 else k0 + 1
        padded[used:, 0], padded[used:, -1] = (2 * padded[used:, 1] - padded[used:, 2],
                                               2 * padded[used:, -2] - padded[used:, -3])
        # Resized from the padded row r0 on, the rows from half a cell below it on are those
        # of the whole resize (the same source rows and weights: the offset is whole cells).
        size = ((w + 2) * step, (h + 2 - r0) * step)
        if self._buffer is None or self._buffer.shape[1::-1] != size:
            self._buffer = np.empty((size[1], size[0], 2), np.float32)
        full = cv2.resize(padded[r0:], size, dst=self._buffer, interpolation=cv2.INTER_LINEAR)
        top = first_row + step - r0 * step
        return full[top:top + self.camera.height - first_row, step:step + self.camera.width]
