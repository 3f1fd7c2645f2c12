"""OpenCV's 6-DoF estimates turned into a planar base motion (accuracy and speed yardsticks).

- 4-point: ``cv2.findHomography`` (RANSAC) + ``cv2.decomposeHomographyMat``, keeping the
  decomposition whose plane normal is the known ground normal; metric from the known height.
- 5-point: ``cv2.findEssentialMat`` (RANSAC) + ``cv2.recoverPose``; no scale.

Both take normalized image coordinates of the real (tilted) camera, so they see exactly what
the planar solvers see. The odometry uses the 4-point way as its ``opencv_homography``
``ransac_method``; the whole textbook pipeline around it (detect, track, check, estimate) is
:class:`planar_vo.tools.experiments.opencv_pipeline.OpenCVReference`.
"""

from __future__ import annotations

import cv2
import numpy as np

from planar_vo.core.estimation.ransac import PoseEstimationError
from planar_vo.core.geometry.camera import Mounting

__all__ = ['homography_motion', 'essential_motion']


def _planar_base_motion(R: np.ndarray, t: np.ndarray, mounting: Mounting) -> np.ndarray:
    """Camera motion ``X2 = R X1 + t`` (optical frames, metres) → base_link ``[x, y, yaw]``."""
    cam = np.eye(4)  # pose of camera 2 in camera 1
    cam[:3, :3], cam[:3, 3] = R.T, -R.T @ t
    mount = np.eye(4)
    mount[:3, :3], mount[:3, 3] = mounting.base_from_optical, mounting.position
    base = mount @ cam @ np.linalg.inv(mount)
    return np.array([base[0, 3], base[1, 3], np.arctan2(base[1, 0], base[0, 0])])


def homography_motion(m1: np.ndarray, m2: np.ndarray, mounting: Mounting, *,
                      threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """4-point RANSAC homography, decomposed with the known ground normal and height.

    Args:
        m1, m2: (N, 2) normalized image coordinates in frames 1 and 2.
        threshold: RANSAC threshold in normalized units (pixels / focal length).

    Returns:
        (motion [x, y, yaw] of base_link, inlier mask (N,)).
    """
    if len(m1) < 4:
        raise PoseEstimationError(f'{len(m1)} correspondences; the homography needs 4')
    H, mask = cv2.findHomography(m1, m2, cv2.RANSAC, threshold, maxIters=2000,
                                 confidence=0.999)
    if H is None:
        raise PoseEstimationError('findHomography found no homography')
    _, Rs, ts, normals = cv2.decomposeHomographyMat(H, np.eye(3))
    ground_normal = mounting.base_from_optical.T @ np.array([0.0, 0.0, -1.0])
    best = int(np.argmax([float(n.ravel() @ ground_normal) for n in normals]))
    t = ts[best].ravel() * mounting.height  # OpenCV's t is divided by the plane distance
    return _planar_base_motion(Rs[best], t, mounting), mask.ravel().astype(bool)


def essential_motion(m1: np.ndarray, m2: np.ndarray, mounting: Mounting, *,
                     threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """5-point RANSAC essential matrix + recoverPose; translation has unit length (no scale)."""
    if len(m1) < 5:
        raise PoseEstimationError(f'{len(m1)} correspondences; the essential matrix needs 5')
    E, mask = cv2.findEssentialMat(m1, m2, np.eye(3), cv2.RANSAC, 0.999, threshold)
    if E is None:
        raise PoseEstimationError('findEssentialMat found no essential matrix')
    _, R, t, mask = cv2.recoverPose(E[:3], m1, m2, np.eye(3), mask=mask)
    return _planar_base_motion(R, t.ravel(), mounting), mask.ravel().astype(bool)
