"""Accuracy of a planar trajectory against ground truth (numpy only).

- ``t_rel`` (%) and ``r_rel`` (deg/100 m): KITTI's relative errors, averaged over every
  sub-path of fixed lengths. KITTI uses 100..800 m on kilometre-long drives; short
  synthetic bags use 10 %..80 % of the path length, the same proportions.
- ``ate_rmse`` (m): position RMSE with both trajectories starting at the origin (no
  alignment: the scale comes from the camera height and is part of what is tested).
- ``final_drift`` (m, and % of the path), ``scale_ratio``: estimated / true path length.

A trajectory is written for ``evo`` by :func:`planar_vo.io.tum.write_tum` and plotted by
:func:`planar_vo.tools.plots.plot_trajectories`.
"""

from __future__ import annotations

import numpy as np

__all__ = ['associate', 'metrics']

SEGMENT_FRACTIONS = np.arange(1, 9) / 10.0


def associate(
    stamps_a: np.ndarray, stamps_b: np.ndarray, tolerance: float = 1e-3
) -> tuple[np.ndarray, np.ndarray]:
    """Indices (ia, ib) pairing each stamp of ``a`` with the nearest of ``b`` within tolerance."""
    stamps_b = np.asarray(stamps_b)
    order = np.argsort(stamps_b)
    sorted_b = stamps_b[order]
    pos = np.clip(np.searchsorted(sorted_b, stamps_a), 1, max(len(sorted_b) - 1, 1))
    left = np.clip(pos - 1, 0, len(sorted_b) - 1)
    right = np.clip(pos, 0, len(sorted_b) - 1)
    nearest = np.where(np.abs(sorted_b[left] - stamps_a) <= np.abs(sorted_b[right] - stamps_a),
                       left, right)
    ok = np.abs(sorted_b[nearest] - stamps_a) <= tolerance
    return np.flatnonzero(ok), order[nearest[ok]]


def _relative(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """SE(2) ``a^-1 b`` for arrays of poses (..., 3)."""
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    return np.stack([c * dx + s * dy, -s * dx + c * dy,
                     np.angle(np.exp(1j * (b[..., 2] - a[..., 2])))], axis=-1)


def metrics(estimate: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Accuracy of ``estimate`` against ``truth``, both (N, 3) poses x, y, yaw at the same stamps.

    Both are taken relative to their first pose.
    """
    est = _relative(estimate[:1], estimate)
    gt = _relative(truth[:1], truth)
    steps = np.hypot(*np.diff(gt[:, :2], axis=0).T)
    dist = np.concatenate([[0.0], np.cumsum(steps)])
    length = float(dist[-1])
    est_length = float(np.hypot(*np.diff(est[:, :2], axis=0).T).sum())
    t_errors, r_errors = [], []
    for seg in SEGMENT_FRACTIONS * length:
        if seg <= 0:
            continue
        start = np.arange(len(dist))
        end = np.searchsorted(dist, dist + seg)
        ok = end < len(dist)
        start, end = start[ok], end[ok]
        err = _relative(_relative(gt[start], gt[end]), _relative(est[start], est[end]))
        t_errors.append(np.hypot(err[:, 0], err[:, 1]) / seg)
        r_errors.append(np.abs(err[:, 2]) / seg)
    t_rel = float(np.mean(np.concatenate(t_errors))) if t_errors else float('nan')
    r_rel = float(np.mean(np.concatenate(r_errors))) if r_errors else float('nan')
    drift = float(np.hypot(*(est[-1, :2] - gt[-1, :2])))
    return {
        'frames': len(gt),
        'path_length_m': length,
        't_rel_percent': 100.0 * t_rel,
        'r_rel_deg_per_100m': float(np.degrees(r_rel) * 100.0),
        'ate_rmse_m': float(np.sqrt(np.mean(np.sum((est[:, :2] - gt[:, :2]) ** 2, axis=1)))),
        'final_drift_m': drift,
        'final_drift_percent': 100.0 * drift / length if length > 0 else float('nan'),
        'final_yaw_error_deg': float(np.degrees(abs(_relative(gt[-1], est[-1])[2]))),
        'scale_ratio': est_length / length if length > 0 else float('nan'),
    }
