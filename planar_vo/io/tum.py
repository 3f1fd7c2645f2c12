"""Planar trajectories as TUM trajectory files, the format ``evo`` reads."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ['write_tum']


def write_tum(path: str | Path, stamps: np.ndarray, poses: np.ndarray) -> None:
    """TUM trajectory file (``t x y z qx qy qz qw``) that ``evo`` reads."""
    half = 0.5 * poses[:, 2]
    rows = np.column_stack([stamps, poses[:, 0], poses[:, 1], np.zeros(len(poses)),
                            np.zeros(len(poses)), np.zeros(len(poses)), np.sin(half),
                            np.cos(half)])
    np.savetxt(path, rows, fmt='%.9f', header='timestamp tx ty tz qx qy qz qw')
