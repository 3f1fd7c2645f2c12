"""Ground off the smooth surface: a speed bump a few metres ahead, the far side of a crown.

A bump is a band across the road whose tracks are all off the local ground's smooth surface
(:mod:`planar_vo.core.estimation.local_ground`) the same way, along their flow; the surface
cannot follow it, so its tracks bias the pair. The local ground filter leaves such bands out
and refines the pair again. The road beyond a crown is a side of the image off the surface
the same way (:func:`side_offsets`); the filter leaves it out of the next pairs. Numpy only;
no ROS.
"""

from __future__ import annotations

import numpy as np

from planar_vo.core.estimation.local_ground import Hinge, LocalGroundResult, surface_residuals
from planar_vo.core.geometry.camera import Mounting

__all__ = ['BAND_M', 'BAND_REACH', 'along_flow', 'bands_of', 'faster_bands', 'flow_excess',
           'off_surface_bands', 'refit_consistent', 'side_offsets', 'track_noise',
           'wheel_plane_distance', 'wheel_plane_lateral']

# Bands of the ground off the smooth surface together (a speed bump ahead): left out and the
# pair refined again (off_surface_bands). Measured on three rendered bumps drives (752x480,
# seeds 0-2): t_rel 0.268 / 0.246 / 0.310 -> 0.227 / 0.239 / 0.289 %, all four terrains 0.38
# -> 0.32 %; 1 m bands were worse (0.41 % on seed 0); flat, grades, hills and camber
# unchanged (no band found). When more than _BAND_MAX_SHARE of the inliers would go, the
# surface is off everywhere (a wheel's jolt): nothing goes.
BAND_M = 0.5
_BAND_MIN_TRACKS = 6
_BAND_SIGMAS = 4.0
_BAND_OFFSET = 0.5
_BAND_MAX_SHARE = 1 / 3
_REFIT_SIGMAS = 5.0
BAND_REACH = 0.75  # m: a band's rays meet the wheel plane up to 0.4 m beyond the bump
_MIN_SIGMA_PX = 0.05
# A bump's tracks move faster than the ground's (they are nearer the camera than the ground
# their rays would meet): on rendered 8 cm bumps 2-6 % faster than the bands a metre before
# and after, a smooth road within 0.5 %. Against the surface before the pair, so the pair's
# own fit cannot bend onto them first. Over _FASTER_MAX it is no bump (a box, a car).
_FASTER = 0.02
_FASTER_MAX = 0.15
_ACROSS = 0.05
# And a band stands out of its tracks' noise: by _BAND_Z standard errors of the medians (each
# track's excess as noisy as the fit's residual over its flow). The far edge's few tracks,
# whose flow is a few pixels, made bands 2-3 % faster by chance: on flat 376x240 drives
# through a rolling shutter, bumps on 19 and 109 of 149 and 199 pairs, near which the surface
# was held back for nothing (ground_filter's _CURVATURE_NEAR_HUMP); at 4 or 5 none, at 3 the
# 30 Hz drive's stayed. 99 rendered drives (stop 68), held back at 0.1: 14.13 % summed at 4,
# 15.15 at 5 (humps found later). The band's own spread for its error instead held a hump's
# shape too: at 5, 16.65 against 15.83.
_BAND_Z = 4.0


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


def wheel_plane_lateral(camera: Mounting, v1: np.ndarray) -> np.ndarray:
    """Y (m, base_link, left positive) where each ray (N, 3) meets the wheel plane."""
    c = camera.position
    return c[1] + c[2] / np.maximum(-v1[:, 2], 1e-9) * v1[:, 1]


def along_flow(fit: LocalGroundResult, v1: np.ndarray, m2: np.ndarray, camera: Mounting,
               hinge: Hinge, focal_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Each track's transfer residual under ``fit`` along its flow, and its whole one, px.

    The flow is the transfer's derivative in x. Both (N,).

    A track on ground off the smooth surface is off along its flow (it moves as a nearer or
    further point would); a merely noisy one is off in any direction.
    """
    params = np.concatenate([fit.motion, fit.rotation, fit.surface])
    r, J, _ = surface_residuals(params, np.ascontiguousarray(v1.T),
                                np.ascontiguousarray(m2.T), camera, hinge)
    flow = J[0] / np.maximum(np.linalg.norm(J[0], axis=0), 1e-12)
    return focal_px * (r * flow).sum(axis=0), focal_px * np.linalg.norm(r, axis=0)


def side_offsets(fit: LocalGroundResult, v1: np.ndarray, m2: np.ndarray, camera: Mounting,
                 hinge: Hinge, focal_px: float, *, half_width: float, left_out: np.ndarray,
                 threshold_px: float) -> np.ndarray:
    """How far the road beyond ``half_width`` on the left and on the right is off the surface.

    (2,): the mean of its tracks' residuals under ``fit`` along their flow, in standard
    errors; 0 where fewer than _BAND_MIN_TRACKS tracks count.

    A crowned road falls away beyond its crown, 1.5-2 m left of a car in its lane: there
    the tracks move as points below the surface do. The tracks that count are ``fit``'s
    inliers and those ``left_out`` (N,) of it for their side, within ``threshold_px``; not
    those on a bump or a band off the surface, which are off on both sides.
    """
    along, whole = along_flow(fit, v1, m2, camera, hinge, focal_px)
    sigma = max(float(np.sqrt(np.mean(along[fit.inliers] ** 2))), _MIN_SIGMA_PX)
    lateral = wheel_plane_lateral(camera, v1)
    counted = fit.inliers | (left_out & (whole < threshold_px))
    out = np.zeros(2)
    for i, side in enumerate((lateral > half_width, lateral < -half_width)):
        members = counted & side
        n = int(np.count_nonzero(members))
        if n >= _BAND_MIN_TRACKS:
            out[i] = float(np.mean(along[members])) / sigma * np.sqrt(n)
    return out


def off_surface_bands(fit: LocalGroundResult, v1: np.ndarray, m2: np.ndarray,
                      camera: Mounting, hinge: Hinge, focal_px: float) -> np.ndarray | None:
    """Which tracks to keep (N,) bool: bands of ground distance off the surface together go.

    None when no band is (or when too much of the ground would go).

    A speed bump is a band across the road a few metres ahead: its tracks are all off the
    fitted surface the same way, along their flow (the transfer's derivative in x), while a
    track that is merely noisy is off in any direction. A band of BAND_M whose mean along
    the flow is _BAND_SIGMAS standard errors and _BAND_OFFSET of one track's noise from
    none goes. The distance is the ray's on the wheel plane (close enough to bin).
    """
    along, _ = along_flow(fit, v1, m2, camera, hinge, focal_px)
    distance = wheel_plane_distance(camera, v1)
    inliers = fit.inliers
    sigma = max(float(np.sqrt(np.mean(along[inliers] ** 2))), _MIN_SIGMA_PX)
    band = np.floor(distance / BAND_M).astype(int)
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


def track_noise(rms_px: float, focal_px: float) -> float:
    """A track's position noise along one axis, normalized, from a fit's residual (px, 2D)."""
    return rms_px / focal_px / np.sqrt(2.0)


def flow_excess(motion: np.ndarray, rotation: np.ndarray, surface: np.ndarray,
                v1: np.ndarray, m1: np.ndarray, m2: np.ndarray, camera: Mounting,
                hinge: Hinge) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How much faster each track moved than over the smooth surface, and which count.

    Each track's flow, relative to the flow ``motion`` and ``rotation`` predict over
    ``surface`` (the surface before the pair, so that the pair's own fit cannot bend onto a
    bump first): (N,) the excess (0.05: 5 % faster), (N,) bool the tracks it holds for, and
    (N,) the predicted flow's length (normalized; a track's noise over it is its excess's).
    ``m1``, ``m2``: (N, 2) normalized coordinates in frames 1 and 2.
    """
    params = np.concatenate([motion, rotation, surface])
    r, _, valid = surface_residuals(params, np.ascontiguousarray(v1.T),
                                    np.ascontiguousarray(m2.T), camera, hinge)
    flow = m2.T + r - m1.T  # predicted
    length2 = np.maximum((flow * flow).sum(axis=0), 1e-12)
    faster = -(r * flow).sum(axis=0) / length2
    across = (r[0] * flow[1] - r[1] * flow[0]) / length2
    # A track off across its flow, or far faster, is on something else (a passing car).
    ok = valid & np.isfinite(faster) & (np.abs(faster) < _FASTER_MAX) & (np.abs(across) < _ACROSS)
    return faster, ok, np.sqrt(length2)


def faster_bands(motion: np.ndarray, rotation: np.ndarray, surface: np.ndarray,
                 v1: np.ndarray, m1: np.ndarray, m2: np.ndarray, camera: Mounting,
                 hinge: Hinge, noise: float) -> np.ndarray:
    """Tracks (N,) bool in bands of ground that move faster than the road around them.

    Arguments as :func:`flow_excess`, ``noise`` the tracks' (:func:`track_noise`); the bands
    as :func:`bands_of`.
    """
    faster, ok, flow = flow_excess(motion, rotation, surface, v1, m1, m2, camera, hinge)
    return bands_of(faster, ok, wheel_plane_distance(camera, v1), noise / flow)


def bands_of(faster: np.ndarray, ok: np.ndarray, distance: np.ndarray,
             noise: np.ndarray) -> np.ndarray:
    """Tracks (N,) bool in bands of ground (``distance``, m) that move faster than around them.

    ``faster``, ``ok``: :func:`flow_excess`'s; ``noise``: (N,) each track's excess's standard
    deviation. A band's median is compared with the mean of the bands a metre before and after
    it (at the far edge, where a bump first shows: the band a metre before), so that a smooth
    trend (a hill, a rotation not quite right) is not a band; and with the medians' noise.
    """
    band = np.floor(distance / BAND_M).astype(int)
    median, error = {}, {}
    for b in np.unique(band[ok]):
        members = ok & (band == b)
        n = np.count_nonzero(members)
        if n >= _BAND_MIN_TRACKS:
            median[b] = float(np.median(faster[members]))
            # A median's standard error is 1.25 times a mean's.
            error[b] = 1.2533 * float(np.sqrt(np.mean(noise[members] ** 2) / n))
    out = np.zeros(len(faster), bool)
    for b, value in median.items():
        if b - 2 in median and b + 2 in median:
            around = 0.5 * (median[b - 2] + median[b + 2])
            around_error = 0.5 * np.hypot(error[b - 2], error[b + 2])
        elif b - 2 in median and b + 1 not in median:
            around, around_error = median[b - 2], error[b - 2]
        else:
            continue
        rise = value - around
        if _FASTER < rise < _FASTER_MAX and rise > _BAND_Z * np.hypot(error[b], around_error):
            out |= band == b
    return out
