"""A pair's tracks as a rolling shutter read them, and as a global shutter at the stamps would.

The 1-point hypotheses model the readout themselves (each track's motion stretched to its
rows' times, :mod:`planar_vo.core.estimation.rolling_shutter`); the attitude and local-ground
refinements, and the readout's reading through the local ground, model a global shutter:
their observations are first carried to their frames' stamps by the pair's motion. Numpy
only; no ROS.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from planar_vo.core.estimation.ransac import TransferModel
from planar_vo.core.estimation.rolling_shutter import ShutterModel, at_stamp
from planar_vo.core.geometry.camera import rays_through
from planar_vo.core.odometry.ground_filter import LocalGroundFilter

__all__ = ['Deskew']


class Deskew(NamedTuple):
    """A pair's tracks as a rolling shutter read them."""

    points: tuple[np.ndarray, np.ndarray]  # (N, 2) ground points in the two frames
    rows: tuple[np.ndarray, np.ndarray]  # (N,) their pixel rows in the two frames
    dt: float  # s between the frames' stamps
    model: TransferModel
    rate: np.ndarray | None  # the twist's rate of change over the pair (None: constant)

    def row_times(self, shutter: ShutterModel, image_height: int,
                  ) -> tuple[np.ndarray, np.ndarray]:
        """Each track's rows' times relative to their frames' stamps, s."""
        return tuple(shutter.row_time(v, image_height) for v in self.rows)

    def at_stamps(self, motion: np.ndarray, shutter: ShutterModel, image_height: int,
                  ground: LocalGroundFilter | None) -> tuple[np.ndarray, np.ndarray]:
        """(frame-1 rays, frame-2 normalized points) as a global shutter at the stamps saw them.

        ``motion``: the pair's (x, y, yaw) over ``dt``; ``ground``: the local ground the
        points stand on (the road ahead is not flat), or None for the plane under the wheels.
        """
        if ground is not None:
            points = [ground.on_surface(p, self.model.mounting.position) for p in self.points]
        else:
            points = [(p, None) for p in self.points]
        m1, m2 = (at_stamp(p, tau, motion, self.dt, self.model, self.rate, centre, height)
                  for (p, height), tau, centre in zip(points,
                                                      self.row_times(shutter, image_height),
                                                      (-self.dt / 2, self.dt / 2)))
        return rays_through(m1), m2
