"""Where the ground is in the image: the pixels whose rays hit it well below the horizon."""

from __future__ import annotations

import cv2
import numpy as np

from planar_vo.core.geometry.camera import (
    MAX_ROUND_TRIP_PX,
    CameraModel,
    CameraModelError,
    Mounting,
)

__all__ = ['ground_mask']


def ground_mask(camera: CameraModel, mounting: Mounting, horizon_margin: float,
                border: int = 8, *, check_round_trip: bool = False) -> np.ndarray:
    """uint8 mask (H, W) of pixels whose rays hit the ground ``horizon_margin`` below it.

    With ``check_round_trip``, a lens model that cannot be inverted where it will be used
    raises CameraModelError: undistortion gives no ray for some pixel, or undistorting and
    distorting again moves a ground pixel by more than MAX_ROUND_TRIP_PX (garbage tracks
    would follow otherwise).
    """
    step = 4
    h, w = camera.height, camera.width
    xs, ys = np.meshgrid(np.arange(0, w, step), np.arange(0, h, step))
    grid = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64)
    rays = camera.rays(grid)
    _, valid = mounting.ground_points(rays, horizon_margin)
    if check_round_trip:
        _check_round_trip(camera, grid, rays, valid)
    coarse = valid.reshape(xs.shape).astype(np.uint8) * 255
    mask = cv2.resize(coarse, (xs.shape[1] * step, xs.shape[0] * step),
                      interpolation=cv2.INTER_NEAREST)[:h, :w].copy()
    mask[:border], mask[-border:], mask[:, :border], mask[:, -border:] = 0, 0, 0, 0
    return mask


def _check_round_trip(camera: CameraModel, grid: np.ndarray, rays: np.ndarray,
                      ground: np.ndarray) -> None:
    """Raise CameraModelError if ``camera`` cannot be inverted over the ground pixels."""
    where = f'{camera.distortion_model} D = {np.round(camera.D, 6).tolist()}'
    no_ray = ~np.all(np.isfinite(rays), axis=1)
    if no_ray.any():
        u, v = grid[np.argmax(no_ray)]
        raise CameraModelError(f'undistortion gives no ray at pixel ({u:.0f}, {v:.0f}) with '
                               f'{where}: check the distortion coefficients')
    if not ground.any():
        return
    error = camera.round_trip_px(grid[ground])
    worst = int(np.argmax(error))
    if error[worst] > MAX_ROUND_TRIP_PX:
        u, v = grid[ground][worst]
        raise CameraModelError(
            f'lens model cannot be inverted over the ground: undistort/distort moves pixel '
            f'({u:.0f}, {v:.0f}) by {error[worst]:.3g} px (limit {MAX_ROUND_TRIP_PX:g}) with '
            f'{where}: check the distortion coefficients and model')
