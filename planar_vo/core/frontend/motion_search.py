"""A first motion when no twist predicts one: the two images aligned through the ground.

Every pair but the first after a start or a restart is tracked from where the last twist
predicts the tracks, in the last image warped by that motion. The first is not, and KLT from
where a track was reaches some tens of pixels on its pyramid: a car at 7.5 m/s filmed at 10 Hz
moves the bottom of the image by over 100 px between frames and the ground there grows by a
third. On the rendered `car` drives that first pair kept 13 of 81 tracks at 10 Hz (its pitch
then 2 deg off) and 16-60 of 270 at 15 Hz. :class:`GroundMotionSearch` finds a prediction
for it: of the planar motions circular at the rear axle, the one whose ground warp makes the
last image most like the new one (normalized cross-correlation, which an exposure change does
not move, over ground pixels at a quarter of the resolution), coarse to fine. Numpy and
OpenCV only; no ROS.
"""

from __future__ import annotations

import cv2
import numpy as np

from planar_vo.core.estimation.ransac import TransferModel
from planar_vo.core.geometry.camera import CameraModel, rays_through
from planar_vo.core.geometry.se2 import circular_motion, inverse_motion

__all__ = ['GroundMotionSearch']

_LEVELS = 2  # pyrDown twice: a quarter of the resolution, and blurred (a wider basin)
_SCALE = 2 ** _LEVELS
_SAMPLE_STEP = 2  # every second pixel of the small image, both ways
# The motions searched: up to this fast forward, backward, and turning (per second).
_MAX_SPEED, _MAX_REVERSE, _MAX_YAW_RATE = 25.0, 5.0, 1.5  # m/s, m/s, rad/s
_COARSE_STEP = (0.08, 0.02)  # m, rad: the first grid (found the motion on every tried pair)
# The first grid's size is capped (its steps then grow): frames up to max_frame_gap (1 s)
# apart would ask for 56 000 motions. Motions are scored this many at a time (memory).
_MAX_COARSE, _CHUNK = 600, 64
_REFINEMENTS, _SHRINK = 3, 2.5  # then 7 x 7 grids, each this much finer, about the best
_MIN_CORRELATION = 0.8  # below, the images do not match (0.94-0.99 where they did)
_MIN_SHARED = 0.25  # of the ground samples, seen in both images


class GroundMotionSearch:
    """Searches the planar motion between two images of the ground, for one camera.

    Both images are looked at through a pinhole camera with the same matrix K (at a quarter
    of the resolution), so a candidate motion moves a sample by a homography alone and no
    distortion is evaluated per candidate.
    """

    def __init__(self, camera: CameraModel) -> None:
        self.camera = camera
        h, w = camera.height, camera.width
        for _ in range(_LEVELS):
            h, w = (h + 1) // 2, (w + 1) // 2  # pyrDown's size
        K = camera.K
        self._fx, self._fy, self._cx, self._cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        # Small pixel (i, j) is full-resolution pixel (SCALE j, SCALE i) after pyrDown.
        vv, uu = np.mgrid[0:h, 0:w].astype(np.float64) * _SCALE
        normalized = np.c_[(uu.ravel() - self._cx) / self._fx, (vv.ravel() - self._cy) / self._fy]
        with np.errstate(all='ignore'):
            pixels = camera.distort(normalized)
        inside = (np.all(np.isfinite(pixels), axis=1) & (pixels[:, 0] >= 0)
                  & (pixels[:, 1] >= 0) & (pixels[:, 0] <= camera.width - 1)
                  & (pixels[:, 1] <= camera.height - 1))
        pixels[~inside] = -1e4  # outside the real image: the border value, never used
        self._undistort = (pixels / _SCALE).reshape(h, w, 2).astype(np.float32)
        keep = np.zeros((h, w), bool)
        keep[::_SAMPLE_STEP, ::_SAMPLE_STEP] = True
        keep &= inside.reshape(h, w)
        self._rows, self._cols = np.nonzero(keep)
        self._normalized = normalized.reshape(h, w, 2)[self._rows, self._cols]

    def _small(self, gray: np.ndarray) -> np.ndarray:
        """The image at a quarter of the resolution, seen through the pinhole camera."""
        small = gray
        for _ in range(_LEVELS):
            small = cv2.pyrDown(small)
        return cv2.remap(small.astype(np.float32), self._undistort, None, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0)

    def search(self, last: np.ndarray, gray: np.ndarray, dt: float, model: TransferModel,
               horizon_margin: float) -> np.ndarray | None:
        """Motion ``[x, y, yaw]`` of base_link from ``last`` to ``gray`` (uint8 images).

        ``dt`` (s) bounds the motions searched; ``model`` is the ground as seen now (its
        mounting); only rays ``horizon_margin`` below the horizon are ground. None when the
        images do not match anywhere (a blank or changed scene): KLT then goes on unaided.
        """
        ground, valid = model.mounting.ground_points(rays_through(self._normalized),
                                                     horizon_margin)
        if np.count_nonzero(valid) < 50:
            return None
        new = self._small(gray)[self._rows[valid], self._cols[valid]]
        ground = ground[valid]
        seen = new >= 0.0
        ground, new = ground[seen], new[seen]
        old = self._small(last)
        rho_step, yaw_step = _COARSE_STEP
        spans = ((_MAX_SPEED + _MAX_REVERSE) * dt, 2 * _MAX_YAW_RATE * dt)
        size = (spans[0] / rho_step + 1) * (spans[1] / yaw_step + 1)
        if size > _MAX_COARSE:
            grow = np.sqrt(size / _MAX_COARSE)
            rho_step, yaw_step = rho_step * grow, yaw_step * grow
        rho = np.arange(-_MAX_REVERSE * dt, _MAX_SPEED * dt + rho_step, rho_step)
        yaw = np.arange(-_MAX_YAW_RATE * dt, _MAX_YAW_RATE * dt + yaw_step, yaw_step)
        for _ in range(_REFINEMENTS + 1):
            rr, yy = np.meshgrid(rho, yaw)
            candidates = np.c_[rr.ravel(), yy.ravel()]
            motions = circular_motion(candidates[:, 1], candidates[:, 0])
            scores = np.concatenate([self._scores(old, new, ground, motions[i:i + _CHUNK], model)
                                     for i in range(0, len(motions), _CHUNK)])
            i = int(np.argmax(scores))
            best, score = tuple(candidates[i]), float(scores[i])
            rho_step, yaw_step = rho_step / _SHRINK, yaw_step / _SHRINK
            rho = best[0] + rho_step * np.arange(-3, 4)
            yaw = best[1] + yaw_step * np.arange(-3, 4)
        if score < _MIN_CORRELATION:
            return None
        return circular_motion(np.array([best[1]]), np.array([best[0]]))[0]

    def _scores(self, old: np.ndarray, new: np.ndarray, ground: np.ndarray,
                motions: np.ndarray, model: TransferModel) -> np.ndarray:
        """Normalized cross-correlation (K,) of the new samples with the old image.

        One per motion (K, 3); -2 where too few samples are seen in both images.
        """
        # Where the new frame's ground points were in the old one, (K, N, 2) normalized.
        was = model.transfer(inverse_motion(motions), ground)
        maps = np.empty(was.shape, np.float32)
        maps[..., 0] = (self._fx * was[..., 0] + self._cx) / _SCALE
        maps[..., 1] = (self._fy * was[..., 1] + self._cy) / _SCALE
        maps[~np.isfinite(maps)] = -1e4  # behind the old camera
        values = cv2.remap(old, maps, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                           borderValue=-1.0)
        shared = values >= 0.0
        n = shared.sum(axis=1)
        count = np.maximum(n, 1)
        a = np.where(shared, values, 0.0)
        b_ = np.where(shared, new, 0.0)
        a = np.where(shared, a - (a.sum(axis=1) / count)[:, None], 0.0)
        b_ = np.where(shared, b_ - (b_.sum(axis=1) / count)[:, None], 0.0)
        ncc = (a * b_).sum(axis=1) / np.sqrt((a * a).sum(axis=1) * (b_ * b_).sum(axis=1) + 1e-9)
        return np.where(n >= _MIN_SHARED * len(new), ncc, -2.0)
