"""The synthetic camera's intrinsics and lens distortion (OpenCV conventions)."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

# Lens models the renderer can simulate, as CameraInfo names them, with default coefficients.
DISTORTION_DEFAULTS = {
    'plumb_bob': (-0.25, 0.07, 0.0005, -0.0005, 0.0),
    'rational_polynomial': (-0.3, 0.09, 0.0005, -0.0005, -0.01, 0.01, 0.002, 0.0),
    'equidistant': (-0.03, 0.004, -0.001, 0.0002),
}


@dataclass(frozen=True)
class SynthCamera:
    """Camera with lens distortion, OpenCV conventions (``equidistant`` is cv2.fisheye)."""

    width: int = 640
    height: int = 480
    fx: float = 460.0
    fy: float = 460.0
    cx: float = 320.0
    cy: float = 240.0
    dist: tuple = DISTORTION_DEFAULTS['plumb_bob']
    distortion_model: str = 'plumb_bob'

    def __post_init__(self) -> None:
        expected = len(DISTORTION_DEFAULTS[self.distortion_model])
        if len(self.dist) != expected:
            raise ValueError(f'{self.distortion_model} takes {expected} coefficients, '
                             f'not {len(self.dist)}')

    @classmethod
    def scaled(cls, width: int, height: int, **kw) -> SynthCamera:
        """Default camera scaled to another image size (same field of view)."""
        s = width / 640.0
        base = dict(width=width, height=height, fx=460.0 * s, fy=460.0 * s,
                    cx=width / 2.0, cy=height / 2.0)
        base.update({k: v for k, v in kw.items() if v is not None})
        if 'dist' not in base:
            base['dist'] = DISTORTION_DEFAULTS[base.get('distortion_model', 'plumb_bob')]
        return cls(**base)

    def k_matrix(self) -> np.ndarray:
        """3x3 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def project(self, points_optical: np.ndarray) -> np.ndarray:
        """Project (N, 3) points in the optical frame to distorted pixels (N, 2)."""
        pts = np.asarray(points_optical, np.float64).reshape(-1, 1, 3)
        d = np.asarray(self.dist, np.float64)
        if self.distortion_model == 'equidistant':
            px, _ = cv2.fisheye.projectPoints(pts, np.zeros((3, 1)), np.zeros((3, 1)),
                                              self.k_matrix(), d)
        else:
            px, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), self.k_matrix(), d)
        return px.reshape(-1, 2)

    def rays(self) -> np.ndarray:
        """Rays ``(x, y, 1)`` in the optical frame for every pixel, shape (H, W, 3); cached."""
        return _camera_rays(self)


def undistort_pixels(pixels: np.ndarray, k: np.ndarray, dist,
                     model: str = 'plumb_bob') -> np.ndarray:
    """Undistort (N, 2) pixels to normalised image coordinates with tight convergence."""
    pts = np.asarray(pixels, np.float64).reshape(-1, 1, 2)
    d = np.asarray(dist, np.float64)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    if model == 'equidistant':
        out = cv2.fisheye.undistortPoints(pts, k, d, criteria=crit)
    elif hasattr(cv2, 'undistortPointsIter'):  # OpenCV 4.x
        out = cv2.undistortPointsIter(pts, k, d, None, None, crit)
    else:  # OpenCV 5.x
        out = cv2.undistortPoints(pts, k, d, criteria=crit)
    return out.reshape(-1, 2)


@functools.lru_cache(maxsize=8)
def _camera_rays(cam: SynthCamera) -> np.ndarray:
    u, v = np.meshgrid(np.arange(cam.width, dtype=np.float64),
                       np.arange(cam.height, dtype=np.float64))
    xy = undistort_pixels(np.stack([u.ravel(), v.ravel()], 1), cam.k_matrix(), cam.dist,
                          cam.distortion_model)
    rays = np.concatenate([xy, np.ones((xy.shape[0], 1))], 1).reshape(cam.height, cam.width, 3)
    rays.setflags(write=False)
    return rays
