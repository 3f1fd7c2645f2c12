"""ROS messages ↔ numpy: images to grey, CameraInfo to CameraModel, results to Odometry.

No rclpy here: image decoding works on any object with the fields of sensor_msgs/Image
(rclpy messages, rosbags messages, simple namespaces), so it is unit-testable without DDS.
Message classes for the outputs are imported lazily from the ROS message packages
(``nav_msgs``, ``sensor_msgs``, ``geometry_msgs``), which do not need rclpy either.

Covariance convention of the published nav_msgs/Odometry (6x6, row-major over
x, y, z, roll, pitch, yaw): the 3x3 planar covariances of the core fill the (x, y, yaw)
rows/columns of the pose covariance and the (vx, vy, vyaw) rows/columns of the twist
covariance. The unobserved z, roll and pitch (and vz, vroll, vpitch) get a large finite
variance, :data:`UNOBSERVED_VARIANCE` = 1e6, never 0 or inf. Diagonal entries we do observe
are kept strictly positive. For robot_localization use ``two_d_mode: true`` or fuse only
x, y, yaw, vx, vy, vyaw from this source.
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np

from planar_vo.core.geometry.camera import MAX_IMAGE_SIDE, CameraModel, CameraModelError
from planar_vo.ros.errors import ImageError

__all__ = ['ImageError', 'UNOBSERVED_VARIANCE', 'SUPPORTED_ENCODINGS', 'image_to_gray',
           'compressed_to_gray', 'camera_info_to_model', 'stamp_to_seconds', 'covariance_6x6',
           'yaw_to_quaternion', 'planar_pose', 'odometry_from_result', 'transform_from_result',
           'debug_image', 'gray_to_image']

UNOBSERVED_VARIANCE = 1e6  # z, roll, pitch (and their rates): unobserved by a planar model
_MIN_VARIANCE = 1e-12  # observed variances never reach 0
_PLANAR_INDEX = (0, 1, 5)  # x, y, yaw within (x, y, z, roll, pitch, yaw)


# encoding -> (channels, bytes per channel, cv2 conversion code to grey or None)
_ENCODINGS: dict[str, tuple[int, int, int | None]] = {
    'mono8': (1, 1, None), '8uc1': (1, 1, None),
    'mono16': (1, 2, None), '16uc1': (1, 2, None),
    'bgr8': (3, 1, cv2.COLOR_BGR2GRAY), 'rgb8': (3, 1, cv2.COLOR_RGB2GRAY),
    'bgra8': (4, 1, cv2.COLOR_BGRA2GRAY), 'rgba8': (4, 1, cv2.COLOR_RGBA2GRAY),
    'bgr16': (3, 2, cv2.COLOR_BGR2GRAY), 'rgb16': (3, 2, cv2.COLOR_RGB2GRAY),
    'bgra16': (4, 2, cv2.COLOR_BGRA2GRAY), 'rgba16': (4, 2, cv2.COLOR_RGBA2GRAY),
    # ROS 'yuv422' is UYVY; 'yuyv' / 'yuv422_yuy2' are YUYV.
    'yuv422': (2, 1, cv2.COLOR_YUV2GRAY_UYVY), 'uyvy': (2, 1, cv2.COLOR_YUV2GRAY_UYVY),
    'yuyv': (2, 1, cv2.COLOR_YUV2GRAY_YUY2), 'yuv422_yuy2': (2, 1, cv2.COLOR_YUV2GRAY_YUY2),
    # ROS names the pattern from the top-left 2x2 block, OpenCV from the second row/column.
    'bayer_rggb8': (1, 1, cv2.COLOR_BayerBG2GRAY), 'bayer_bggr8': (1, 1, cv2.COLOR_BayerRG2GRAY),
    'bayer_gbrg8': (1, 1, cv2.COLOR_BayerGR2GRAY), 'bayer_grbg8': (1, 1, cv2.COLOR_BayerGB2GRAY),
    'bayer_rggb16': (1, 2, cv2.COLOR_BayerBG2GRAY),
    'bayer_bggr16': (1, 2, cv2.COLOR_BayerRG2GRAY),
    'bayer_gbrg16': (1, 2, cv2.COLOR_BayerGR2GRAY),
    'bayer_grbg16': (1, 2, cv2.COLOR_BayerGB2GRAY),
}
SUPPORTED_ENCODINGS = tuple(e for e in _ENCODINGS if not e[0].isdigit())
_PAIRED_ENCODINGS = ('yuv422', 'uyvy', 'yuyv', 'yuv422_yuy2')  # 2 pixels in 4 bytes


def image_to_gray(msg: Any) -> np.ndarray:
    """sensor_msgs/Image → grey uint8 (H, W), honouring ``step`` and ``is_bigendian``.

    mono8 without row padding is a view on ``msg.data`` (no copy). 16-bit images are scaled
    to 8 bits (divided by 256, as cv_bridge does). Raises :class:`ImageError`.
    """
    encoding = str(msg.encoding)
    spec = _ENCODINGS.get(encoding.lower())
    if spec is None:
        raise ImageError(
            f'image encoding {encoding!r} is not supported (expected one of '
            f'{", ".join(SUPPORTED_ENCODINGS)})')
    channels, depth, code = spec
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    rows = _pixel_rows(np.frombuffer(msg.data, dtype=np.uint8), encoding, height, width, step,
                       width * channels * depth)
    if depth == 2:
        dtype = np.dtype('>u2' if msg.is_bigendian else '<u2')
        rows = np.ascontiguousarray(rows).view(dtype)
        rows = (rows >> 8).astype(np.uint8)  # native order, 8 bits
    if code is None:
        return np.ascontiguousarray(rows)  # a view unless rows are padded
    pixels = np.ascontiguousarray(rows).reshape(height, width, channels) if channels > 1 \
        else np.ascontiguousarray(rows)
    try:
        return cv2.cvtColor(pixels, code)
    except cv2.error as err:
        raise ImageError(f'cannot convert {encoding} {width}x{height} to grey: '
                         f'{str(err).strip().splitlines()[-1]}') from err


def _pixel_rows(buf: np.ndarray, encoding: str, height: int, width: int, step: int,
                row_bytes: int) -> np.ndarray:
    """The (height, row_bytes) pixel bytes of an image buffer, as a view (no copy).

    Every size is checked against the data before anything is allocated, so a hostile
    ``step`` or size cannot make us allocate what the message does not hold.
    """
    if height <= 0 or width <= 0:
        raise ImageError(f'image is empty ({width}x{height}): the driver sent no pixels')
    if height > MAX_IMAGE_SIDE or width > MAX_IMAGE_SIDE:
        raise ImageError(f'image size {width}x{height} is over the limit of {MAX_IMAGE_SIDE} '
                         'per side: check the width and height the driver sends')
    if encoding.lower() in _PAIRED_ENCODINGS and width % 2:
        raise ImageError(f'{encoding} packs two pixels in four bytes, so the width must be '
                         f'even, not {width}')
    if step < row_bytes:
        raise ImageError(f'image step {step} is smaller than a row of {width} {encoding} '
                         f'pixels ({row_bytes} bytes): the driver must send step >= that')
    need = step * (height - 1) + row_bytes  # the last row's padding may be left out
    if not need <= buf.size <= step * height:
        raise ImageError(f'image data has {buf.size} bytes, {encoding} {width}x{height} with '
                         f'step {step} needs {step * height}: width, height, step or '
                         'encoding is wrong')
    return np.lib.stride_tricks.as_strided(buf, (height, row_bytes), (step, 1),
                                           writeable=False)


def compressed_to_gray(msg: Any) -> np.ndarray:
    """sensor_msgs/CompressedImage (JPEG, PNG, ...) → grey uint8 (H, W). Raises ImageError."""
    fmt = str(msg.format)
    if 'compresseddepth' in fmt.lower().replace(' ', ''):
        raise ImageError(f'compressed image format {fmt!r} is a depth image, not a camera '
                         'image: subscribe to the camera image topic')
    buf = np.frombuffer(msg.data, dtype=np.uint8)
    if buf.size == 0:
        raise ImageError('compressed image has no data')
    gray = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)
    if gray is None or gray.size == 0:
        raise ImageError(f'cannot decode compressed image (format {fmt!r}, {buf.size} bytes)')
    if max(gray.shape) > MAX_IMAGE_SIDE:
        raise ImageError(f'compressed image is {gray.shape[1]}x{gray.shape[0]}, over the '
                         f'limit of {MAX_IMAGE_SIDE} per side')
    if gray.dtype != np.uint8:  # 16-bit PNG
        gray = (gray >> 8).astype(np.uint8)
    return gray


def camera_info_to_model(msg: Any, *, rectified: bool = False) -> CameraModel:
    """sensor_msgs/CameraInfo → CameraModel of the images that come with it.

    ``binning_x/y`` and ``roi`` scale and shift the intrinsics as image_geometry does (binning
    0 is 1; an all-zero ROI is the full image); the model's size is the ROI's, binned.
    ``rectified``: the images are rectified (image_proc's ``image_rect``), so the projection
    P is used, without distortion. Beyond the checks of CameraModel (finite, plausible K and
    D), the image size must be given and R and P must be finite. Raises CameraModelError.
    """
    width, height = int(msg.width), int(msg.height)
    if width <= 0 or height <= 0:
        raise CameraModelError(f'CameraInfo gives no image size ({width}x{height}): publish '
                               'the width and height the camera was calibrated at')
    for name in ('r', 'p'):
        values = np.asarray(getattr(msg, name), dtype=float)
        if not np.all(np.isfinite(values)):
            raise CameraModelError(f'CameraInfo {name.upper()} = {values.tolist()} is not all '
                                   'finite: publish the calibration\'s real matrices')
    if rectified:
        K = np.asarray(msg.p, dtype=float).reshape(3, 4)[:, :3].copy()
        D, model = np.zeros(0), 'plumb_bob'
    else:
        K = np.asarray(msg.k, dtype=float).reshape(3, 3).copy()
        D, model = np.asarray(msg.d, dtype=float), str(msg.distortion_model)
    # Objects with only the calibration fields (tests, other bag readers): no binning, no ROI.
    bx, by = int(getattr(msg, 'binning_x', 0)) or 1, int(getattr(msg, 'binning_y', 0)) or 1
    roi = getattr(msg, 'roi', None)
    x0, y0, roi_w, roi_h = (0, 0, 0, 0) if roi is None else (
        int(roi.x_offset), int(roi.y_offset), int(roi.width), int(roi.height))
    if (x0, y0, roi_w, roi_h) == (0, 0, 0, 0):
        roi_w, roi_h = width, height
    elif roi_w <= 0 or roi_h <= 0 or x0 + roi_w > width or y0 + roi_h > height:
        raise CameraModelError(
            f'CameraInfo roi {roi_w}x{roi_h} at ({x0}, {y0}) does not fit in the '
            f'{width}x{height} image: fix the driver\'s roi (all zero for the full image)')
    if roi_w // bx < 1 or roi_h // by < 1:
        raise CameraModelError(f'CameraInfo binning {bx}x{by} leaves no pixel of the '
                               f'{roi_w}x{roi_h} image')
    K[0, 2] -= x0
    K[1, 2] -= y0
    K[0] /= bx
    K[1] /= by
    return CameraModel(K=K, D=D, distortion_model=model, width=roi_w // bx,
                       height=roi_h // by)


def stamp_to_seconds(stamp: Any) -> float:
    """builtin_interfaces/Time → seconds."""
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


def covariance_6x6(cov3: np.ndarray) -> np.ndarray:
    """A 3x3 covariance over (x, y, yaw) → 36 row-major values over (x, y, z, r, p, yaw).

    z, roll, pitch get :data:`UNOBSERVED_VARIANCE`; non-finite values become that variance
    too; observed diagonal entries are at least 1e-12.
    """
    cov3 = np.asarray(cov3, dtype=float).reshape(3, 3)
    cov3 = np.nan_to_num(cov3, nan=UNOBSERVED_VARIANCE, posinf=UNOBSERVED_VARIANCE,
                         neginf=-UNOBSERVED_VARIANCE)
    out = np.zeros((6, 6))
    np.fill_diagonal(out, UNOBSERVED_VARIANCE)
    idx = np.array(_PLANAR_INDEX)
    out[np.ix_(idx, idx)] = 0.5 * (cov3 + cov3.T)
    for i in idx:
        out[i, i] = min(max(out[i, i], _MIN_VARIANCE), UNOBSERVED_VARIANCE)
    return out.ravel()


def yaw_to_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation by ``yaw`` about z."""
    return 0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw)


def planar_pose(pose: Any) -> np.ndarray:
    """geometry_msgs/Pose → ``[x, y, yaw]`` (yaw of the quaternion's rotation about z)."""
    q = pose.orientation
    yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
    return np.array([pose.position.x, pose.position.y, yaw])


def odometry_from_result(result: Any, header_stamp: Any, odom_frame: str, base_frame: str,
                         odometry_cls: Any = None) -> Any:
    """nav_msgs/Odometry of base_link in ``odom_frame`` from a FrameResult.

    ``header_stamp`` (the image's stamp message) is copied; twist is in ``base_frame``.
    """
    if odometry_cls is None:
        from nav_msgs.msg import Odometry
        odometry_cls = Odometry
    msg = odometry_cls()
    msg.header.stamp = header_stamp
    msg.header.frame_id = odom_frame
    msg.child_frame_id = base_frame
    x, y, yaw = (float(v) for v in result.pose)
    p = msg.pose.pose
    p.position.x, p.position.y, p.position.z = x, y, 0.0
    q = yaw_to_quaternion(yaw)
    p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w = q
    msg.pose.covariance = covariance_6x6(result.pose_covariance)
    vx, vy, wz = (float(v) for v in result.twist)
    t = msg.twist.twist
    t.linear.x, t.linear.y, t.linear.z = vx, vy, 0.0
    t.angular.x, t.angular.y, t.angular.z = 0.0, 0.0, wz
    msg.twist.covariance = covariance_6x6(result.twist_covariance)
    return msg


def transform_from_result(result: Any, header_stamp: Any, odom_frame: str,
                          base_frame: str) -> Any:
    """geometry_msgs/TransformStamped odom → base_link for /tf."""
    from geometry_msgs.msg import TransformStamped
    msg = TransformStamped()
    msg.header.stamp = header_stamp
    msg.header.frame_id = odom_frame
    msg.child_frame_id = base_frame
    x, y, yaw = (float(v) for v in result.pose)
    tr = msg.transform
    tr.translation.x, tr.translation.y, tr.translation.z = x, y, 0.0
    tr.rotation.x, tr.rotation.y, tr.rotation.z, tr.rotation.w = yaw_to_quaternion(yaw)
    return msg


def gray_to_image(img: np.ndarray, header: Any = None, image_cls: Any = None) -> Any:
    """uint8 (H, W) mono8 or (H, W, 3) bgr8 numpy → sensor_msgs/Image."""
    if image_cls is None:
        from sensor_msgs.msg import Image
        image_cls = Image
    img = np.ascontiguousarray(img, dtype=np.uint8)
    msg = image_cls()
    if header is not None:
        msg.header = header
    msg.height, msg.width = int(img.shape[0]), int(img.shape[1])
    msg.encoding = 'bgr8' if img.ndim == 3 else 'mono8'
    msg.is_bigendian = 0
    msg.step = int(img.strides[0])
    msg.data = img.tobytes()  # ~30x faster than assigning the array
    return msg


def debug_image(gray: np.ndarray, result: Any, header: Any = None, image_cls: Any = None) -> Any:
    """bgr8 sensor_msgs/Image of ``gray`` with inlier tracks green and outliers red."""
    bgr = cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)
    for points, color in ((result.outlier_points, (0, 0, 255)),
                          (result.inlier_points, (0, 255, 0))):
        for u, v in np.asarray(points, dtype=float).reshape(-1, 2):
            if np.isfinite(u) and np.isfinite(v):
                cv2.circle(bgr, (int(round(u)), int(round(v))), 3, color, 1, cv2.LINE_AA)
    text = f'{result.status} tracks {result.tracks} inliers {result.inliers}'
    cv2.putText(bgr, text, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 255, 255), 1,
                cv2.LINE_AA)
    return gray_to_image(bgr, header, image_cls)
