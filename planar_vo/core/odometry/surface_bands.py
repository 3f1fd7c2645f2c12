"""Bands of the ground off the smooth surface: a speed bump a few metres ahead.

A bump is a band across the road whose tracks are all off the local ground's smooth surface
(:mod:`planar_vo.core.estimation.local_ground`) the same way, along their flow; the surface
cannot follow it, so its tracks bias the pair. The local ground filter leaves such bands out
and refines the pair again. Numpy only; no ROS.
"""

from __future__ import annotations

import numpy as np

from planar_vo.core.estimation.local_ground import LocalGroundResult, surface_residuals
from planar_vo.core.geometry.camera import Mounting

__all__ = ['BAND_REACH', 'off_surface_bands', 'refit_consistent', 'wheel_plane_distance']

# Bands of the ground off the smooth surface together (a speed bump ahead): left out and the
# pair refined again (off_surface_bands). Measured on three rendered bumps drives (752x480,
# seeds 0-2): t_rel 0.268 / 0.246 / 0.310 -> 0.227 / 0.239 / 0.289 %, all four terrains 0.38
# -> 0.32 %; 1 m bands were worse (0.41 % on seed 0); flat, grades, hills and camber
# unchanged (no band found). When more than _BAND_MAX_SHARE of the inliers would go, the
# surface is off everywhere (a wheel's jolt): nothing goes.
_BAND_M = 0.5
_BAND_MIN_TRACKS = 6
_BAND_SIGMAS = 4.0
_BAND_OFFSET = 0.5
_BAND_MAX_SHARE = 1 / 3
_REFIT_SIGMAS = 5.0
BAND_REACH = 0.75  # m: a band's rays meet the wheel plane up to 0.4 m beyond the bump
_MIN_SIGMA_PX = 0.05


def refit_consistent(again: LocalGroundResult, fit: LocalGroundResult) -> bool:
    """Whether the refit without the bands stayed within _REFIT_SIGMAS of the first fit.

    A band is a few tracks' bias, not a different motion: a refit that jumps further lost
    its way (leaving out half the inliers once lost the tracks on a rendered drive).
    """
    change = again.motion - fit.motion
    try:
        return float(change @ np.linalg.solve(fit.covariance, change)) < _REFIT_SIGMAS ** 2
    except np.linalg.LinAlgError:
        return False


def wheel_plane_distance(camera: Mounting, v1: np.ndarray) -> np.ndarray:
    """X (m, base_link) where each ray (N, 3) from the camera meets the wheel plane."""
    c = camera.position
    return c[0] + c[2] / np.maximum(-v1[:, 2], 1e-9) * v1[:, 0]


def off_surface_bands(fit: LocalGroundResult, v1: np.ndarray, m2: np.ndarray,
                      camera: Mounting, hinge: float, focal_px: float) -> np.ndarray | None:
    """Which tracks to keep (N,) bool: bands of ground distance off the surface together go.

    None when no band is (or when too much of the ground would go).

    A speed bump is a band across the road a few metres ahead: its tracks are all off the
    fitted surface the same way, along their flow (the transfer's derivative in x), while a
    track that is merely noisy is off in any direction. A band of _BAND_M whose mean along
    the flow is _BAND_SIGMAS standard errors and _BAND_OFFSET of one track's noise from
    none goes. The distance is the ray's on the wheel plane (close enough to bin).
    """
    params = np.concatenate([fit.motion, fit.rotation, fit.surface])
    r, J, _ = surface_residuals(params, np.ascontiguousarray(v1.T),
                                np.ascontiguousarray(m2.T), camera, hinge)
    flow = J[0] / np.maximum(np.linalg.norm(J[0], axis=0), 1e-12)
    along = focal_px * (r * flow).sum(axis=0)
    distance = wheel_plane_distance(camera, v1)
    inliers = fit.inliers
    sigma = max(float(np.sqrt(np.mean(along[inliers] ** 2))), _MIN_SIGMA_PX)
    band = np.floor(distance / _BAND_M).astype(int)
    keep = np.ones(len(v1), bool)
    for b in np.unique(band[inliers]):
        members = inliers & (band == b)
        n = int(np.count_nonzero(members))
        mean = abs(float(np.mean(along[members]))) if n >= _BAND_MIN_TRACKS else 0.0
        if mean > _BAND_SIGMAS * sigma / np.sqrt(n) and mean > _BAND_OFFSET * sigma:
            keep &= band != b
    dropped = np.count_nonzero(inliers & ~keep)
    if dropped == 0 or dropped > _BAND_MAX_SHARE * np.count_nonzero(inliers):
        return None
    return keep
