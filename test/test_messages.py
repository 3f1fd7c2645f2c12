"""Image/CameraInfo/Odometry conversions (no DDS: message classes only)."""

import math
import os

os.environ.setdefault('ROS_PYTHON_CHECK_FIELDS', '1')  # before the message modules load

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from sensor_msgs.msg import CameraInfo, CompressedImage, Image  # noqa: E402

from planar_vo.core.geometry.camera import CameraModelError  # noqa: E402
from planar_vo.core.odometry import FrameResult  # noqa: E402
from planar_vo.ros import messages  # noqa: E402
from planar_vo.ros.messages import ImageError  # noqa: E402

H, W = 48, 64


@pytest.fixture
def gray():
    rng = np.random.default_rng(1)
    img = cv2.GaussianBlur(rng.integers(0, 256, (H, W)).astype(np.uint8), (5, 5), 2.0)
    return cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX)


def make_image(pixels: np.ndarray, encoding: str, pad: int = 0, bigendian: bool = False):
    """An Image from (H, W[, C]) pixels (uint8/uint16), rows padded by ``pad`` bytes."""
    rows = pixels.reshape(pixels.shape[0], -1)
    if pixels.dtype == np.uint16:
        rows = rows.astype('>u2' if bigendian else '<u2')
    raw = rows.view(np.uint8).reshape(pixels.shape[0], -1)
    raw = np.concatenate([raw, np.full((raw.shape[0], pad), 0xAB, np.uint8)], axis=1)
    msg = Image(height=pixels.shape[0], width=pixels.shape[1], encoding=encoding,
                is_bigendian=int(bigendian), step=raw.shape[1])
    msg.data = raw.tobytes()
    return msg


def test_mono8_is_a_view_without_copy(gray):
    msg = make_image(gray, 'mono8')
    out = messages.image_to_gray(msg)
    assert out.dtype == np.uint8 and out.shape == (H, W)
    assert np.array_equal(out, gray)
    assert np.shares_memory(out, np.frombuffer(msg.data, np.uint8))


@pytest.mark.parametrize('pad', [0, 3, 64])
def test_mono8_step_padding(gray, pad):
    out = messages.image_to_gray(make_image(gray, 'mono8', pad))
    assert np.array_equal(out, gray) and out.flags.c_contiguous


@pytest.mark.parametrize('bigendian', [False, True])
@pytest.mark.parametrize('pad', [0, 6])
def test_mono16_scaled_to_8_bits_in_either_byte_order(gray, bigendian, pad):
    wide = gray.astype(np.uint16) * 256 + 77
    out = messages.image_to_gray(make_image(wide, 'mono16', pad, bigendian))
    assert out.dtype == np.uint8 and np.array_equal(out, gray)


@pytest.mark.parametrize('encoding, to_color', [
    ('bgr8', cv2.COLOR_GRAY2BGR), ('rgb8', cv2.COLOR_GRAY2RGB),
    ('bgra8', cv2.COLOR_GRAY2BGRA), ('rgba8', cv2.COLOR_GRAY2RGBA)])
@pytest.mark.parametrize('pad', [0, 5])
def test_color_encodings(gray, encoding, to_color, pad):
    color = cv2.cvtColor(gray, to_color)
    out = messages.image_to_gray(make_image(color, encoding, pad))
    assert np.abs(out.astype(int) - gray).max() <= 1


def test_color_channel_order_matters():
    bgr = np.zeros((H, W, 3), np.uint8)
    bgr[..., 2] = 200  # pure red
    as_bgr = messages.image_to_gray(make_image(bgr, 'bgr8'))
    as_rgb = messages.image_to_gray(make_image(bgr, 'rgb8'))
    assert abs(int(as_bgr[0, 0]) - round(0.299 * 200)) <= 1
    assert abs(int(as_rgb[0, 0]) - round(0.114 * 200)) <= 1


def test_rgb16_big_endian(gray):
    color = cv2.cvtColor(gray, cv2.COLOR_GRAY2RGB).astype(np.uint16) * 256
    out = messages.image_to_gray(make_image(color, 'rgb16', 2, bigendian=True))
    assert np.abs(out.astype(int) - gray).max() <= 1


@pytest.mark.parametrize('encoding, y_first', [('yuv422', False), ('uyvy', False),
                                               ('yuyv', True), ('yuv422_yuy2', True)])
def test_yuv422_packings(gray, encoding, y_first):
    packed = np.empty((H, W, 2), np.uint8)
    packed[..., 0 if y_first else 1] = gray
    packed[..., 1 if y_first else 0] = 128
    out = messages.image_to_gray(make_image(packed, encoding, 4))
    assert np.array_equal(out, gray)


@pytest.mark.parametrize('encoding', ['bayer_rggb8', 'bayer_bggr8', 'bayer_gbrg8',
                                      'bayer_grbg8'])
def test_bayer_of_a_grey_scene(gray, encoding):
    gray = cv2.GaussianBlur(gray, (0, 0), 3.0)  # demosaicing blurs fine texture
    out = messages.image_to_gray(make_image(gray, encoding, 2))
    inner = (slice(2, -2), slice(2, -2))
    assert np.abs(out[inner].astype(int) - gray[inner]).mean() < 3.0


def test_bayer_pattern_mapping():
    """A pure red scene through each ROS pattern: grey ≈ 0.299 * red everywhere."""
    red = 200
    for encoding, red_at in [('bayer_rggb8', (0, 0)), ('bayer_bggr8', (1, 1)),
                             ('bayer_gbrg8', (1, 0)), ('bayer_grbg8', (0, 1))]:
        mosaic = np.zeros((H, W), np.uint8)
        mosaic[red_at[0]::2, red_at[1]::2] = red
        out = messages.image_to_gray(make_image(mosaic, encoding))
        assert abs(float(np.median(out)) - 0.299 * red) < 3, encoding


@pytest.mark.parametrize('encoding', ['32FC1', '16SC1', 'jpeg', ''])
def test_unsupported_encoding_is_a_clear_error(encoding):
    msg = make_image(np.zeros((4, 4), np.uint8), 'mono8')
    msg.encoding = encoding
    with pytest.raises(ImageError, match='not supported'):
        messages.image_to_gray(msg)


def test_inconsistent_sizes_are_clear_errors(gray):
    msg = make_image(gray, 'mono8')
    msg.step = W - 1
    with pytest.raises(ImageError, match='step'):
        messages.image_to_gray(msg)
    msg = make_image(gray, 'mono8')
    msg.data = bytes(10)
    with pytest.raises(ImageError, match='10 bytes'):
        messages.image_to_gray(msg)
    msg = make_image(gray, 'mono8')
    msg.width = 0
    with pytest.raises(ImageError, match='empty'):
        messages.image_to_gray(msg)


@pytest.mark.parametrize('ext, fmt', [('.png', 'mono8; png compressed '),
                                      ('.jpg', 'bgr8; jpeg compressed bgr8'), ('.jpg', 'jpeg')])
def test_compressed(gray, ext, fmt):
    img = gray if 'mono' in fmt else cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)
    msg = CompressedImage(format=fmt)
    msg.data = cv2.imencode(ext, img)[1].tobytes()
    out = messages.compressed_to_gray(msg)
    assert out.shape == (H, W) and out.dtype == np.uint8
    assert np.abs(out.astype(int) - gray).mean() < (0.01 if ext == '.png' else 4.0)


def test_compressed_depth_and_garbage_are_refused(gray):
    msg = CompressedImage(format='16UC1; compressedDepth png')
    msg.data = cv2.imencode('.png', gray)[1].tobytes()
    with pytest.raises(ImageError, match='depth'):
        messages.compressed_to_gray(msg)
    msg = CompressedImage(format='jpeg')
    msg.data = bytes(range(200))
    with pytest.raises(ImageError, match='cannot decode'):
        messages.compressed_to_gray(msg)
    msg = CompressedImage(format='jpeg')
    with pytest.raises(ImageError, match='no data'):
        messages.compressed_to_gray(msg)


def test_camera_info():
    info = CameraInfo(width=640, height=480, distortion_model='plumb_bob')
    info.k = [460.0, 0.0, 320.0, 0.0, 461.0, 240.0, 0.0, 0.0, 1.0]
    info.d = [-0.25, 0.07, 0.0005, -0.0005, 0.0]
    cam = messages.camera_info_to_model(info)
    assert cam.K[1, 1] == 461.0 and cam.width == 640 and cam.height == 480
    assert np.allclose(cam.D, info.d)
    info.k = [0.0] * 9
    with pytest.raises(CameraModelError, match='uncalibrated'):
        messages.camera_info_to_model(info)


def _calibrated_info():
    info = CameraInfo(width=640, height=480, distortion_model='plumb_bob')
    info.k = [460.0, 0.0, 318.0, 0.0, 461.0, 243.0, 0.0, 0.0, 1.0]
    info.d = [-0.25, 0.07, 0.0005, -0.0005, 0.0]
    return info


def _rays_and_pixels(info, rng):
    """Normalized points and their full-resolution pixels, projected by OpenCV."""
    normalized = rng.uniform(-0.5, 0.5, (50, 2))
    obj = np.c_[normalized, np.ones(50)].reshape(-1, 1, 3)
    K = np.array(info.k).reshape(3, 3)
    pixels = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), K, np.array(info.d))[0]
    return normalized, pixels.reshape(-1, 2)


@pytest.mark.parametrize('binning, roi', [
    ((2, 2), (0, 0, 0, 0)),  # binned full image
    ((1, 1), (100, 60, 400, 300)),  # region of interest
    ((2, 4), (40, 20, 560, 440)),  # both, unequal binning
    ((0, 0), (0, 0, 0, 0)),  # 0 means no binning
])
def test_camera_info_binning_and_roi_as_image_geometry(binning, roi):
    """A pixel of the binned ROI image undistorts to the ray of its full-resolution pixel."""
    info = _calibrated_info()
    info.binning_x, info.binning_y = binning
    info.roi.x_offset, info.roi.y_offset, info.roi.width, info.roi.height = roi
    normalized, pixels = _rays_and_pixels(info, np.random.default_rng(1))
    bx, by = max(binning[0], 1), max(binning[1], 1)
    x0, y0 = roi[:2]
    reduced = np.c_[(pixels[:, 0] - x0) / bx, (pixels[:, 1] - y0) / by]
    cam = messages.camera_info_to_model(info)
    np.testing.assert_allclose(cam.normalize(reduced), normalized, atol=1e-6)
    width, height = roi[2:] if roi[2] else (640, 480)
    assert (cam.width, cam.height) == (width // bx, height // by)


def test_camera_info_roi_outside_the_image_is_refused():
    info = _calibrated_info()
    info.roi.x_offset, info.roi.width, info.roi.height = 400, 400, 100
    with pytest.raises(CameraModelError, match='roi 400x100 at \\(400, 0\\)'):
        messages.camera_info_to_model(info)


def test_rectified_input_uses_p_and_no_distortion():
    info = _calibrated_info()
    info.p = [400.0, 0.0, 330.0, 0.0, 0.0, 400.0, 235.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    rng = np.random.default_rng(2)
    normalized = rng.uniform(-0.5, 0.5, (20, 2))
    rect_pixels = normalized * 400.0 + [330.0, 235.0]  # what image_proc's image_rect shows
    cam = messages.camera_info_to_model(info, rectified=True)
    assert cam.D.size == 0
    np.testing.assert_allclose(cam.normalize(rect_pixels), normalized, atol=1e-9)
    assert not np.allclose(messages.camera_info_to_model(info).normalize(rect_pixels),
                           normalized, atol=1e-3)  # the raw model would be wrong here
    info.p = [0.0] * 12
    with pytest.raises(CameraModelError, match='uncalibrated'):
        messages.camera_info_to_model(info, rectified=True)


def result(**kw):
    base = dict(stamp=1.5, pose=np.array([1.0, -2.0, 0.5]),
                pose_covariance=np.diag([0.01, 0.02, 0.003]),
                twist=np.array([3.0, 0.1, -0.2]), twist_covariance=np.diag([0.1, 0.2, 0.03]),
                status='ok')
    base.update(kw)
    return FrameResult(**base)


def test_odometry_layout_and_covariance_convention():
    from builtin_interfaces.msg import Time
    from rclpy.serialization import deserialize_message, serialize_message
    r = result(pose_covariance=np.array([[0.01, 0.001, 0.002], [0.001, 0.02, 0.0],
                                         [0.002, 0.0, 0.003]]))
    msg = messages.odometry_from_result(r, Time(sec=1, nanosec=500_000_000), 'odom', 'base')
    msg = deserialize_message(serialize_message(msg), Odometry)  # valid field types
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1, 500_000_000)
    assert msg.header.frame_id == 'odom' and msg.child_frame_id == 'base'
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    assert (p.x, p.y, p.z) == (1.0, -2.0, 0.0)
    assert math.isclose(2 * math.atan2(q.z, q.w), 0.5) and q.x == q.y == 0.0
    assert math.isclose(q.x**2 + q.y**2 + q.z**2 + q.w**2, 1.0)
    t = msg.twist.twist
    assert (t.linear.x, t.linear.y, t.angular.z) == (3.0, 0.1, -0.2)
    pc = np.array(msg.pose.covariance).reshape(6, 6)
    assert pc[0, 0] == 0.01 and pc[1, 1] == 0.02 and pc[5, 5] == 0.003
    assert pc[0, 1] == pc[1, 0] == 0.001 and pc[0, 5] == pc[5, 0] == 0.002
    assert np.all(np.diag(pc)[2:5] == messages.UNOBSERVED_VARIANCE)
    assert np.count_nonzero(pc[2:5, :] - np.diag(np.diag(pc))[2:5, :]) == 0
    tc = np.array(msg.twist.covariance).reshape(6, 6)
    assert tc[0, 0] == 0.1 and tc[1, 1] == 0.2 and tc[5, 5] == 0.03


def test_covariance_never_zero_nan_or_inf():
    cov = messages.covariance_6x6(np.array([[0.0, 0, 0], [0, np.inf, 0], [0, 0, np.nan]]))
    c = cov.reshape(6, 6)
    assert np.all(np.isfinite(c)) and np.all(np.diag(c) > 0)
    assert np.all(np.diag(c) <= messages.UNOBSERVED_VARIANCE)


def test_transform_from_result():
    from builtin_interfaces.msg import Time
    tf = messages.transform_from_result(result(), Time(sec=2), 'odom', 'base_link')
    assert tf.header.frame_id == 'odom' and tf.child_frame_id == 'base_link'
    assert tf.transform.translation.x == 1.0
    assert math.isclose(2 * math.atan2(tf.transform.rotation.z, tf.transform.rotation.w), 0.5)


def test_gray_to_image_round_trip(gray):
    msg = messages.gray_to_image(gray)
    assert msg.encoding == 'mono8' and msg.step == W
    assert np.array_equal(messages.image_to_gray(msg), gray)


def test_debug_image_colours(gray):
    r = result(inlier_points=np.array([[10.0, 20.0]]), outlier_points=np.array([[40.0, 30.0]]))
    msg = messages.debug_image(np.zeros((H, W), np.uint8), r)
    assert msg.encoding == 'bgr8' and (msg.height, msg.width) == (H, W)
    bgr = np.frombuffer(msg.data, np.uint8).reshape(H, W, 3)
    assert bgr[20, 13, 1] > 100 and bgr[20, 13, 2] < 50  # green ring around the inlier
    assert bgr[30, 43, 2] > 100 and bgr[30, 43, 1] < 50  # red ring around the outlier


def test_a_hostile_step_allocates_nothing_the_message_does_not_hold(gray):
    import tracemalloc
    # One row and a 2 GB step: the row is all the data there is (the last row's padding
    # may be left out), so it decodes; before, the missing padding was allocated.
    msg = Image(height=1, width=W, encoding='mono8', step=2**31 - 1)
    msg.data = gray[0].tobytes()
    tracemalloc.start()
    out = messages.image_to_gray(msg)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 1_000_000
    np.testing.assert_array_equal(out[0], gray[0])
    msg.height = 2  # now the data cannot hold it: refused, also without allocating
    with pytest.raises(ImageError, match=f'image data has {W} bytes'):
        messages.image_to_gray(msg)


@pytest.mark.parametrize('width, height, encoding, data, reason', [
    (0, 240, 'mono8', b'', 'empty'),
    (65535, 1, 'mono8', bytes(65535), 'over the limit of 16384'),
    (640, 480, 'mono8', bytes(640 * 480 + 1), 'width, height, step or encoding is wrong'),
    (5, 2, 'yuv422', bytes(20), 'width must be even'),
])
def test_image_limits(width, height, encoding, data, reason):
    row = {'mono8': 1, 'yuv422': 2}[encoding] * width
    msg = Image(height=height, width=width, encoding=encoding, step=row)
    msg.data = data
    with pytest.raises(ImageError, match=reason):
        messages.image_to_gray(msg)


def test_camera_info_needs_its_size_and_finite_matrices():
    info = CameraInfo(width=640, height=480, distortion_model='plumb_bob')
    info.k = [460.0, 0.0, 320.0, 0.0, 461.0, 240.0, 0.0, 0.0, 1.0]
    info.p = [460.0, 0.0, 320.0, 0.0, 0.0, 461.0, 240.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    assert messages.camera_info_to_model(info).width == 640
    info.p[0] = math.nan
    with pytest.raises(CameraModelError, match='P = .* not all finite'):
        messages.camera_info_to_model(info)
    info.p[0], info.width, info.height = 460.0, 0, 0
    with pytest.raises(CameraModelError, match='no image size'):
        messages.camera_info_to_model(info)
