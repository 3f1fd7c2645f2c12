"""The plain-OpenCV ways to get the same motion, for comparison (accuracy and speed).

- 4-point: ``cv2.findHomography`` (RANSAC) + ``cv2.decomposeHomographyMat``, keeping the
  decomposition whose plane normal is the known ground normal; metric from the known height.
- 5-point: ``cv2.findEssentialMat`` (RANSAC) + ``cv2.recoverPose``; no scale.

Both take normalized image coordinates of the real (tilted) camera, so they see exactly what
the planar solvers see. :class:`OpenCVReference` is the whole textbook pipeline around the
4-point way (detect, track, check, estimate), the yardstick for planar_vo's cost per frame.
"""

from __future__ import annotations

import cv2
import numpy as np

from planar_vo.core.estimation.ransac import PoseEstimationError
from planar_vo.core.geometry.camera import CameraModel, Mounting

__all__ = ['homography_motion', 'essential_motion', 'OpenCVReference']


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


class OpenCVReference:
    """The plain OpenCV visual odometry a user would write first, as a yardstick for speed.

    goodFeaturesToTrack over the whole image, 21x21 3-level pyramidal LK forward and back
    (the classic monocular VO settings), tracks whose round trip misses by more than
    ``fb_threshold`` dropped, then findHomography + decomposeHomographyMat on the undistorted
    survivors. It keeps the same feature budget as planar_vo's tracker and tops it up by the
    same rule (when 10 % or more are missing), so both do the same amount of work per frame.
    """

    _LK = {'winSize': (21, 21), 'maxLevel': 3,
           'criteria': (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)}

    def __init__(self, camera: CameraModel, mounting: Mounting, *, max_features: int = 400,
                 quality_level: float = 0.005, min_distance: float = 8.0,
                 fb_threshold: float = 0.5, inlier_threshold_px: float = 1.0) -> None:
        self.camera, self.mounting = camera, mounting
        self.max_features, self.quality_level = max_features, quality_level
        self.min_distance, self.fb_threshold = min_distance, fb_threshold
        self.threshold = inlier_threshold_px / camera.focal_px
        self._previous: np.ndarray | None = None
        self.points = np.zeros((0, 1, 2), np.float32)

    @classmethod
    def from_params(cls, camera: CameraModel, mounting: Mounting,
                    params: dict) -> OpenCVReference:
        """The reference with planar_vo's own settings (validated node parameters).

        The same feature budget, detector, round-trip check and inlier threshold, so only
        the method differs.
        """
        return cls(camera, mounting, max_features=params['max_features'],
                   quality_level=params['quality_level'], min_distance=params['min_distance'],
                   fb_threshold=params['fb_threshold'],
                   inlier_threshold_px=params['inlier_threshold'])

    def process(self, gray: np.ndarray) -> np.ndarray | None:
        """Motion ``[x, y, yaw]`` of base_link since the previous image, None if none."""
        motion = None
        if self._previous is not None and len(self.points):
            cur, ok, _ = cv2.calcOpticalFlowPyrLK(self._previous, gray, self.points, None,
                                                  **self._LK)
            back, ok_back, _ = cv2.calcOpticalFlowPyrLK(gray, self._previous, cur, None,
                                                        **self._LK)
            keep = ((ok.ravel() == 1) & (ok_back.ravel() == 1)
                    & (np.linalg.norm((back - self.points).reshape(-1, 2), axis=1)
                       < self.fb_threshold))
            try:
                motion, _ = homography_motion(
                    self.camera.normalize(self.points[keep]), self.camera.normalize(cur[keep]),
                    self.mounting, threshold=self.threshold)
            except PoseEstimationError:
                motion = None
            self.points = cur[keep]
        if len(self.points) <= 0.9 * self.max_features:
            free = np.full(gray.shape, 255, np.uint8)
            for x, y in self.points.reshape(-1, 2):
                cv2.circle(free, (int(x), int(y)), int(self.min_distance), 0, -1)
            new = cv2.goodFeaturesToTrack(gray, self.max_features - len(self.points),
                                          self.quality_level, self.min_distance, mask=free)
            if new is not None:
                self.points = np.concatenate([self.points, new.astype(np.float32)])
        self._previous = gray
        return motion
