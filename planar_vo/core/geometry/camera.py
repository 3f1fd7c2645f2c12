"""Camera model (pixels → rays) and camera mounting (rays → ground points, and back).

Frames: base_link is REP-103 (x forward, y left, z up) on the rear axle *on the ground*
(the ground is ``z = 0``). The camera body frame (x forward) sits at ``(x, y, height)`` in
base_link with roll, pitch, yaw (positive pitch looks down), like a
``static_transform_publisher base_link camera_link``. Rays are in the optical frame
(x right, y down, z forward). Numpy and OpenCV only; no ROS.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from planar_vo.core.errors import CameraModelError

__all__ = ['CameraModel', 'CameraModelError', 'MAX_IMAGE_SIDE', 'Mounting', 'bin_image',
           'level_to_base', 'rays_through', 'BODY_FROM_OPTICAL']

# Columns: optical x = body -y, optical y = body -z, optical z = body x (REP-103 optical frame).
BODY_FROM_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
DISTORTION_MODELS = {'plumb_bob': (4, 5, 8, 12, 14), 'rational_polynomial': (8, 12, 14),
                     'equidistant': (4,)}
MAX_IMAGE_SIDE = 16384  # px: larger "images" are corrupt messages, not cameras
# fx from 0.05 to 50 image widths: fields of view from about 170 to 1 degree.
MIN_FOCAL_PER_WIDTH, MAX_FOCAL_PER_WIDTH = 0.05, 50.0
_PRINCIPAL_MARGIN = 0.25  # the principal point may lie this fraction of the size outside
MAX_ROUND_TRIP_PX = 1.0  # undistort/distort over the ground region must agree this well
# OpenCV's iterative undistortion stops per point once it reprojects within a millionth of a
# pixel (its default of 5 iterations leaves 0.06 px at this bag's corners); the fisheye
# solver is Newton's method on the angle, so its tolerance, in radians, costs nothing.
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-6)
_FISHEYE_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)


def rays_through(normalized: np.ndarray) -> np.ndarray:
    """Unnormalized rays ``[x, y, 1]`` (N, 3) through normalized image points (N, 2)."""
    return np.concatenate([normalized, np.ones((len(normalized), 1))], axis=1)


def _rotation_rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """``Rz(yaw) Ry(pitch) Rx(roll)``, the fixed-axis convention of tf2 and URDF."""
    cr, sr, cp, sp, cy, sy = (np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch),
                              np.cos(yaw), np.sin(yaw))
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return rz @ ry @ rx


def level_to_base(points_xy: np.ndarray, height: float) -> np.ndarray:
    """Rays of a virtual *level* camera on the rear axle at ``height`` seeing ground points.

    The paper's solvers assume a level camera at the centre of circular motion; for a car
    that is the rear axle. Any ground point ``(x, y)`` in base_link is seen by that virtual
    camera along ``[-y, height, x]`` (optical convention), whatever camera really saw it.

    Args:
        points_xy: ground points in base_link, shape (N, 2), metres.

    Returns:
        rays, shape (N, 3).
    """
    x, y = points_xy[..., 0], points_xy[..., 1]
    return np.stack([-y, np.full_like(x, height), x], axis=-1)


def bin_image(gray: np.ndarray, factor: int) -> np.ndarray:
    """``gray`` averaged over ``factor`` x ``factor`` blocks (a last partial block dropped).

    The image :meth:`CameraModel.binned` describes.
    """
    if factor == 1:
        return gray
    h, w = gray.shape[0] // factor, gray.shape[1] // factor
    return cv2.resize(gray[:h * factor, :w * factor], (w, h), interpolation=cv2.INTER_AREA)


@dataclass(frozen=True)
class CameraModel:
    """Pinhole intrinsics and lens distortion as a sensor_msgs/CameraInfo describes them."""

    K: np.ndarray  # 3x3
    D: np.ndarray = field(default_factory=lambda: np.zeros(0))
    distortion_model: str = 'plumb_bob'
    width: int = 0
    height: int = 0

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=float).reshape(3, 3)
        D = np.asarray(self.D, dtype=float).ravel()
        if not np.all(np.isfinite(K)) or not (K[0, 0] > 0 and K[1, 1] > 0):
            raise CameraModelError(
                'camera is uncalibrated (K has a zero or invalid focal length): '
                'calibrate it and publish a CameraInfo with a real K')
        _check_intrinsics(K, int(self.width), int(self.height))
        if not np.all(np.isfinite(D)):
            raise CameraModelError(f'distortion coefficients D = {D.tolist()} are not all '
                                   'finite: publish the calibration\'s real D')
        model = self.distortion_model or 'plumb_bob'
        if np.allclose(D, 0.0):
            D = np.zeros(0)
        elif model not in DISTORTION_MODELS:
            raise CameraModelError(
                f'distortion model {model!r} is not supported; use one of '
                f'{", ".join(DISTORTION_MODELS)}')
        elif len(D) not in DISTORTION_MODELS[model]:
            raise CameraModelError(
                f'distortion model {model!r} takes {DISTORTION_MODELS[model]} '
                f'coefficients, got {len(D)}')
        object.__setattr__(self, 'K', K)
        object.__setattr__(self, 'D', D)
        object.__setattr__(self, 'distortion_model', model)
        if D.size and self.width > 0 and self.height > 0:
            self._check_rays()

    def _check_rays(self) -> None:
        """Refuse a lens model whose undistortion gives no ray somewhere in the image.

        A coarse 5x5 grid is enough for coefficients that blow up; the finer check, the
        undistort/distort round trip over the ground region, needs the mounting and is done
        by the odometry.
        """
        u, v = np.meshgrid(np.linspace(0, self.width - 1, 5), np.linspace(0, self.height - 1, 5))
        grid = np.stack([u.ravel(), v.ravel()], axis=1)
        with np.errstate(all='ignore'):
            bad = ~np.all(np.isfinite(self.normalize(grid)), axis=1)
        if bad.any():
            x, y = grid[np.argmax(bad)]
            raise CameraModelError(
                f'undistortion gives no ray at pixel ({x:.0f}, {y:.0f}) with '
                f'{self.distortion_model} D = {np.round(self.D, 6).tolist()}: check the '
                'distortion coefficients')

    def binned(self, factor: int) -> CameraModel:
        """The camera of its images averaged over ``factor`` x ``factor`` pixel blocks.

        A binned pixel u' covers the full pixels factor u' .. factor u' + factor - 1, whose
        centre is factor u' + (factor - 1) / 2: u' = (u - (factor - 1) / 2) / factor. The lens
        (D, on normalized coordinates) is the same.
        """
        if factor == 1:
            return self
        K = self.K.copy()
        K[:2] /= factor
        K[:2, 2] = (self.K[:2, 2] - 0.5 * (factor - 1)) / factor
        return CameraModel(K, self.D, self.distortion_model, self.width // factor,
                           self.height // factor)

    @property
    def focal_px(self) -> float:
        """Mean focal length in pixels: converts normalized errors to pixel errors."""
        return 0.5 * float(self.K[0, 0] + self.K[1, 1])

    def normalize(self, pixels: np.ndarray) -> np.ndarray:
        """Undistort pixel positions to normalized image coordinates ``(x/z, y/z)``.

        Args:
            pixels: shape (N, 2).

        Returns:
            shape (N, 2), float64.
        """
        pts = np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
        if len(pts) == 0:
            return np.zeros((0, 2))
        if self.D.size == 0:
            out = cv2.undistortPoints(pts, self.K, None)
        elif self.distortion_model == 'equidistant':
            out = cv2.fisheye.undistortPoints(pts, self.K, self.D,
                                              criteria=_FISHEYE_CRITERIA)
        elif hasattr(cv2, 'undistortPointsIter'):  # OpenCV 4.x (Ubuntu's python3-opencv)
            out = cv2.undistortPointsIter(pts, self.K, self.D, None, None, _UNDISTORT_CRITERIA)
        else:  # OpenCV 5.x
            out = cv2.undistortPoints(pts, self.K, self.D, criteria=_UNDISTORT_CRITERIA)
        return out.reshape(-1, 2)

    def distort(self, normalized: np.ndarray) -> np.ndarray:
        """Project normalized coordinates (N, 2) to pixels (N, 2): the inverse of normalize."""
        pts = np.asarray(normalized, dtype=np.float64).reshape(-1, 1, 2)
        if len(pts) == 0:
            return np.zeros((0, 2))
        obj = np.concatenate([pts, np.ones((len(pts), 1, 1))], axis=-1)
        zero = np.zeros(3)
        if self.distortion_model == 'equidistant' and self.D.size:
            out = cv2.fisheye.projectPoints(obj, zero, zero, self.K, self.D)[0]
        else:
            out = cv2.projectPoints(obj, zero, zero, self.K, self.D if self.D.size else None)[0]
        return out.reshape(-1, 2)

    def round_trip_px(self, pixels: np.ndarray) -> np.ndarray:
        """Pixel error (N,) of ``distort(normalize(pixels))``; inf where it is not finite.

        Iterative undistortion of a model that folds over (or of absurd coefficients) does
        not converge: this is how a calibration that cannot be inverted shows itself.
        """
        pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        with np.errstate(all='ignore'):
            back = self.distort(self.normalize(pixels))
            error = np.linalg.norm(back - pixels, axis=1)
        return np.where(np.isfinite(error), error, np.inf)

    def rays(self, pixels: np.ndarray) -> np.ndarray:
        """Unnormalized rays ``[x, y, 1]`` (N, 3) in the optical frame."""
        return rays_through(self.normalize(pixels))


def _check_intrinsics(K: np.ndarray, width: int, height: int) -> None:
    """Refuse a K no real camera has, saying which value is wrong (see MAX_IMAGE_SIDE)."""
    fx, fy = K[0, 0], K[1, 1]
    if not np.allclose(K[2], [0.0, 0.0, 1.0]) or K[1, 0] != 0.0:
        raise CameraModelError(f'K = {K.ravel().tolist()} is not an upper-triangular camera '
                               'matrix with last row [0, 0, 1]: publish K row-major')
    if not 0.25 <= fy / fx <= 4.0:
        raise CameraModelError(f'focal lengths fx = {fx:g}, fy = {fy:g} give an aspect ratio '
                               'outside 0.25..4: check K[0] and K[4]')
    if abs(K[0, 1]) > 0.1 * fx:
        raise CameraModelError(f'skew K[1] = {K[0, 1]:g} is more than a tenth of fx = {fx:g}: '
                               'check K')
    if width == 0 and height == 0:
        return  # size unknown yet (core use): the image will give it
    if not (0 < width <= MAX_IMAGE_SIDE and 0 < height <= MAX_IMAGE_SIDE):
        raise CameraModelError(f'image size {width}x{height} is outside 1..{MAX_IMAGE_SIDE} '
                               'per side: publish the width and height of the images')
    if not (MIN_FOCAL_PER_WIDTH * width <= fx <= MAX_FOCAL_PER_WIDTH * width):
        raise CameraModelError(
            f'fx = {fx:g} px is implausible for an image {width} px wide (expected '
            f'{MIN_FOCAL_PER_WIDTH:g}..{MAX_FOCAL_PER_WIDTH:g} times the width): check K')
    cx, cy = K[0, 2], K[1, 2]
    if not (-_PRINCIPAL_MARGIN * width <= cx <= (1 + _PRINCIPAL_MARGIN) * width
            and -_PRINCIPAL_MARGIN * height <= cy <= (1 + _PRINCIPAL_MARGIN) * height):
        raise CameraModelError(f'principal point ({cx:g}, {cy:g}) is far outside the '
                               f'{width}x{height} image: check K[2] and K[5]')


@dataclass(frozen=True)
class Mounting:
    """Where the camera sits on the vehicle (camera body frame in base_link; m and rad)."""

    x: float = 0.0
    y: float = 0.0
    height: float = 1.0
    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0

    @property
    def base_from_optical(self) -> np.ndarray:
        """Rotation taking optical-frame vectors into base_link, 3x3."""
        return _rotation_rpy(self.roll, self.pitch, self.yaw) @ BODY_FROM_OPTICAL

    @property
    def position(self) -> np.ndarray:
        """Camera position in base_link, (3,)."""
        return np.array([self.x, self.y, self.height])

    def level_rays(self, rays: np.ndarray) -> np.ndarray:
        """Rotate optical rays (N, 3) into the virtual level camera looking along base x.

        The level camera has the optical convention with its y axis straight down, so the
        ground is ``Y = height`` and the paper's reduced models apply.
        """
        return rays @ (BODY_FROM_OPTICAL.T @ self.base_from_optical).T

    def ground_points(
        self, rays: np.ndarray, min_depression: float = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Intersect optical rays (N, 3) with the ground.

        Only rays at least ``min_depression`` rad below the horizon count: points just below
        the horizon are often not ground but move almost like it, and bias the yaw.

        Returns:
            (points (N, 2) in base_link metres, valid (N,) bool); invalid points are NaN.
        """
        d = rays @ self.base_from_optical.T
        norm = np.linalg.norm(d, axis=1)
        valid = -d[:, 2] > np.sin(min_depression) * norm + 1e-12
        scale = np.where(valid, self.height / np.where(valid, -d[:, 2], 1.0), np.nan)
        points = self.position[:2] + scale[:, None] * d[:, :2]
        return points, valid

    def ground_to_optical(self) -> tuple[np.ndarray, np.ndarray]:
        """Affine map of ground points to optical-frame points: ``P = A @ [x, y] + b``.

        Returns:
            (A (3, 2), b (3,)); normalized image coordinates are ``P[:2] / P[2]``.
        """
        optical_from_base = self.base_from_optical.T
        return optical_from_base[:, :2].copy(), -optical_from_base @ self.position
