"""Plots of the CLIs (``--plot``): matplotlib is imported only when one is drawn."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

__all__ = ['pyplot', 'plot_trajectories']


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the non-interactive Agg backend (files only, no display)."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    return plt


def plot_trajectories(path: str | Path, trajectories: dict[str, np.ndarray],
                      title: str = '') -> None:
    """Top view of named (N, 3) trajectories, ground truth first, written to a PNG."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 6))
    for i, (name, poses) in enumerate(trajectories.items()):
        ax.plot(poses[:, 0], poses[:, 1], '-' if i == 0 else '--', lw=2.5 if i == 0 else 1.5,
                label=name)
    ax.plot([0], [0], 'ko', label='start')
    ax.set_aspect('equal', adjustable='datalim')
    ax.set_xlabel('x (m, odom)')
    ax.set_ylabel('y (m, odom)')
    ax.grid(True, alpha=0.3)
    ax.legend()
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
