"""The plain OpenCV visual odometry pipeline: the yardstick of the bench and the experiments.

Used by ``planar_vo_bench`` (cost per frame) and the mounting experiment (accuracy on a sprung
body); the odometry itself never runs it. Its pose step is
:func:`planar_vo.core.estimation.opencv_motion.homography_motion`.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from planar_vo.core.estimation.opencv_motion import homography_motion
from planar_vo.core.estimation.ransac import PoseEstimationError
from planar_vo.core.frontend.ground_mask import ground_mask
from planar_vo.core.frontend.tracker import feature_spacing
from planar_vo.core.geometry.camera import CameraModel, Mounting

__all__ = ['OpenCVReference']


class OpenCVReference:
    """The plain OpenCV visual odometry a user would write first, as a yardstick for speed.

    goodFeaturesToTrack on the ground (the pixels whose rays hit it at least
    ``horizon_margin`` below the horizon, from the known mounting), 21x21 3-level pyramidal
    LK forward and back (the classic monocular VO settings), tracks whose round trip misses
    by more than ``fb_threshold`` dropped, then findHomography + decomposeHomographyMat on the
    undistorted survivors. It keeps the same feature budget and detection region as
    planar_vo's tracker and tops it up by the same rule (when 10 % or more are missing), so
    both do the same amount of work per frame.

    The homography it decomposes is the ground's, so it detects only where the ground is:
    over the whole image, tracks on obstacles and on the far field near the horizon (which
    fit a homography of almost no motion) outvoted the ground's on the frames where a box
    passed close (terrain drives, 752x480 at 20 Hz: 20 frames of 300 gave almost no motion;
    t_rel 11.2 % and scale 0.92 on the flat one, 1.06 % on the same drive without the boxes).
    """

    _LK = {'winSize': (21, 21), 'maxLevel': 3,
           'criteria': (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)}

    def __init__(self, camera: CameraModel, mounting: Mounting, *, max_features: int = 400,
                 quality_level: float = 0.005, min_distance: float = 8.0,
                 fb_threshold: float = 0.5, inlier_threshold_px: float = 1.0,
                 horizon_margin: float = math.radians(12.0)) -> None:
        self.camera, self.mounting = camera, mounting
        self.max_features, self.quality_level = max_features, quality_level
        self.min_distance, self.fb_threshold = min_distance, fb_threshold
        self.threshold = inlier_threshold_px / camera.focal_px
        self.horizon_margin = horizon_margin
        self._ground: np.ndarray | None = None
        self._previous: np.ndarray | None = None
        self.points = np.zeros((0, 1, 2), np.float32)

    @classmethod
    def from_params(cls, camera: CameraModel, mounting: Mounting,
                    params: dict) -> OpenCVReference:
        """The reference with planar_vo's own settings (validated node parameters).

        The same feature budget, detector and its region (``horizon_margin``), round-trip
        check and inlier threshold, so only the method differs.
        """
        return cls(camera, mounting, max_features=params['max_features'],
                   quality_level=params['quality_level'],
                   min_distance=feature_spacing(params['min_distance'], camera.width,
                                                camera.height),
                   fb_threshold=params['fb_threshold'],
                   inlier_threshold_px=params['inlier_threshold'],
                   horizon_margin=params['horizon_margin'])

    def _ground_region(self, shape: tuple[int, ...]) -> np.ndarray:
        """uint8 mask of the ground in images of ``shape`` (computed once)."""
        if self._ground is None or self._ground.shape != shape:
            camera = self.camera
            if (camera.height, camera.width) != shape:
                camera = dataclasses.replace(camera, width=shape[1], height=shape[0])
            self._ground = ground_mask(camera, self.mounting, self.horizon_margin)
        return self._ground

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
            free = self._ground_region(gray.shape).copy()
            for x, y in self.points.reshape(-1, 2):
                cv2.circle(free, (int(x), int(y)), int(self.min_distance), 0, -1)
            new = cv2.goodFeaturesToTrack(gray, self.max_features - len(self.points),
                                          self.quality_level, self.min_distance, mask=free)
            if new is not None:
                self.points = np.concatenate([self.points, new.astype(np.float32)])
        self._previous = gray
        return motion
