"""Property-based tests (hypothesis) of everything that takes input from outside.

Random image and CameraInfo messages, lens models and frame sequences: only the documented
error types escape, what is accepted is usable, outputs are finite, covariances symmetric
positive definite, and good frames after any bad input are estimated normally again.
Profiles (fixed seed, bounded examples) are in conftest.py.
"""

import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planar_vo.core.config import load_params_file
from planar_vo.core.geometry.camera import MAX_IMAGE_SIDE, CameraModel, CameraModelError
from planar_vo.core.odometry import VisualOdometry
from planar_vo.io import resources
from planar_vo.ros import messages
from planar_vo.ros.messages import SUPPORTED_ENCODINGS, ImageError

ROOT = resources.share_dir()
# The message and lens properties take about a millisecond per example: give them more.
CHEAP = settings(max_examples=5 * settings().max_examples)
BYTES_PER_PIXEL = {'mono8': 1, 'mono16': 2, 'bgr8': 3, 'rgb8': 3, 'bgra8': 4, 'rgba8': 4,
                   'bgr16': 6, 'rgb16': 6, 'bgra16': 8, 'rgba16': 8, 'yuv422': 2, 'uyvy': 2,
                   'yuyv': 2, 'yuv422_yuy2': 2}
HUGE = (2**16 - 1, 2**31 - 1, 2**32 - 1, MAX_IMAGE_SIDE + 1)


def bytes_per_pixel(encoding: str) -> int:
    if encoding.startswith('bayer'):
        return 2 if encoding.endswith('16') else 1
    return BYTES_PER_PIXEL.get(encoding, 1)


@st.composite
def image_messages(draw):
    """sensor_msgs/Image-like messages: mostly plausible layouts, some hostile numbers."""
    encoding = draw(st.sampled_from(SUPPORTED_ENCODINGS + ('32FC1', 'MONO8', '', '8UC3')))
    width = draw(st.integers(0, 24) | st.sampled_from(HUGE))
    height = draw(st.integers(0, 12) | st.sampled_from(HUGE))
    row = width * bytes_per_pixel(encoding)
    step = draw(st.just(row) | st.integers(row, row + 8) | st.integers(0, 64)
                | st.sampled_from(HUGE))
    exact = step * height
    size = draw(st.just(exact) | st.integers(0, 600)) if exact <= 4096 else draw(
        st.integers(0, 600))
    data = draw(st.binary(min_size=size, max_size=size))
    return SimpleNamespace(encoding=encoding, width=width, height=height, step=step,
                           is_bigendian=draw(st.booleans()), data=data)


def decodable(msg) -> bool:
    """What the documentation promises to decode (independent of the code's own checks)."""
    enc = msg.encoding.lower()
    row = msg.width * bytes_per_pixel(enc)
    return (enc in SUPPORTED_ENCODINGS and 0 < msg.width <= MAX_IMAGE_SIDE
            and 0 < msg.height <= MAX_IMAGE_SIDE and msg.step >= row
            and msg.step * (msg.height - 1) + row <= len(msg.data) <= msg.step * msg.height
            and not (enc in ('yuv422', 'uyvy', 'yuyv', 'yuv422_yuy2') and msg.width % 2)
            and not (enc.startswith('bayer') and min(msg.width, msg.height) < 2))


@CHEAP
@given(image_messages())
def test_any_image_message_is_grey_or_a_clear_image_error(msg):
    try:
        gray = messages.image_to_gray(msg)
    except ImageError as err:
        assert str(err)
        assert not decodable(msg), f'documented layout refused: {err}'
        return
    assert gray.dtype == np.uint8 and gray.shape == (msg.height, msg.width)
    if msg.encoding == 'mono8':  # the pixels are the data's rows, unchanged
        rows = np.frombuffer(msg.data, np.uint8)
        for r in range(msg.height):
            start = r * msg.step
            np.testing.assert_array_equal(gray[r], rows[start:start + msg.width])


finite_or_not = st.floats(allow_nan=True, allow_infinity=True, width=64)


@st.composite
def camera_infos(draw):
    """CameraInfo-like messages around a plausible calibration, with wild values mixed in."""
    w = draw(st.sampled_from([0, 1, 64, 640, 1920, 99999]))
    h = draw(st.sampled_from([0, 1, 48, 480, 1080]))
    k = [draw(st.floats(100, 2000)), 0.0, draw(st.floats(-100, 2000)), 0.0,
         draw(st.floats(100, 2000)), draw(st.floats(-100, 1200)), 0.0, 0.0, 1.0]
    for i in draw(st.lists(st.integers(0, 8), max_size=3)):
        k[i] = draw(finite_or_not)
    d = draw(st.lists(st.floats(-0.5, 0.5) | finite_or_not, max_size=14))
    model = draw(st.sampled_from(['plumb_bob', 'rational_polynomial', 'equidistant', '',
                                  'fisheye']))
    p = [k[0], 0.0, k[2], 0.0, 0.0, k[4], k[5], 0.0, 0.0, 0.0, 1.0, 0.0]
    if draw(st.booleans()):
        p[draw(st.integers(0, 11))] = draw(finite_or_not)
    return SimpleNamespace(width=w, height=h, k=k, d=d, distortion_model=model, p=p,
                           r=[1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0])


@CHEAP
@given(camera_infos())
def test_any_camera_info_is_a_usable_camera_or_a_clear_refusal(info):
    try:
        camera = messages.camera_info_to_model(info)
    except CameraModelError as err:
        assert str(err)
        return
    K = camera.K
    assert np.all(np.isfinite(K)) and np.all(np.isfinite(camera.D))
    assert np.all(np.isfinite(info.p))
    assert 0 < camera.width <= MAX_IMAGE_SIDE and 0 < camera.height <= MAX_IMAGE_SIDE
    assert K[0, 0] > 0 and K[1, 1] > 0
    # Accepted means usable: the image centre undistorts to a finite ray.
    centre = np.array([[camera.width / 2, camera.height / 2]])
    assert np.all(np.isfinite(camera.normalize(centre)))


@st.composite
def mild_lenses(draw):
    """Calibrations as real lenses have them (monotonic distortion within the view)."""
    fx = draw(st.floats(150, 1500))
    K = np.array([[fx, 0, draw(st.floats(200, 440))],
                  [0, fx * draw(st.floats(0.9, 1.1)), draw(st.floats(160, 320))], [0, 0, 1]])
    model = draw(st.sampled_from(['plumb_bob', 'rational_polynomial', 'equidistant']))
    small = st.floats(-1e-3, 1e-3)
    if model == 'equidistant':
        D = [draw(st.floats(-0.05, 0.05)) for _ in range(4)]
    else:
        D = [draw(st.floats(-0.3, 0.1)), draw(st.floats(-0.05, 0.05)), draw(small),
             draw(small), 0.0] + ([0.0] * 3 if model == 'rational_polynomial' else [])
    return CameraModel(K, np.array(D), model, 640, 480)


@CHEAP
@given(mild_lenses(), st.lists(st.tuples(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5)),
                               min_size=1, max_size=20))
def test_normalize_undoes_distort(camera, points):
    normalized = np.array(points)
    pixels = camera.distort(normalized)  # OpenCV's projection: the independent truth
    np.testing.assert_allclose(camera.normalize(pixels), normalized, atol=1e-6)
    assert np.all(camera.round_trip_px(pixels) < 1e-3)


@CHEAP
@given(st.lists(st.floats(0, 1000) | finite_or_not, min_size=9, max_size=9),
       st.lists(st.floats(-1, 1) | finite_or_not, max_size=14),
       st.sampled_from(['plumb_bob', 'rational_polynomial', 'equidistant', '', 'kannala']),
       st.integers(0, 100000), st.integers(0, 100000))
def test_camera_model_construction_raises_only_camera_model_error(k, d, model, width, height):
    try:
        camera = CameraModel(np.reshape(k, (3, 3)), np.array(d), model, width, height)
    except CameraModelError as err:
        assert str(err)
        return
    assert np.all(np.isfinite(camera.K)) and np.all(np.isfinite(camera.D))


# ---------------------------------------------------------------- odometry.process
class Frames:
    """The first frames of bags/default with their camera and true planar poses."""

    def __init__(self, count=8):
        from planar_vo.io.bag import open_reader
        images, self.truth, self.camera = [], {}, None
        with open_reader(ROOT / 'bags' / 'default') as reader:
            for conn, _, raw in reader.messages():
                msg = reader.deserialize(raw, conn.msgtype)
                stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
                if conn.topic == '/camera/camera_info' and self.camera is None:
                    self.camera = messages.camera_info_to_model(msg)
                elif conn.topic == '/camera/image_raw' and len(images) < count:
                    images.append((stamp, messages.image_to_gray(msg).copy()))
                elif conn.topic == '/ground_truth/odom':
                    self.truth[stamp] = messages.planar_pose(msg.pose.pose)
                if len(images) == count and self.camera is not None and all(
                        s in self.truth for s, _ in images):
                    break
        self.stamps = [s for s, _ in images]
        self.images = [g for _, g in images]
        self.period = self.stamps[1] - self.stamps[0]


@pytest.fixture(scope='module')
def frames():
    return Frames()


PARAMS = load_params_file(ROOT / 'config' / 'planar_vo.yaml')


def assert_sane(result):
    for value in (result.pose, result.twist):
        assert np.all(np.isfinite(value))
    for cov in (result.pose_covariance, result.twist_covariance):
        assert np.all(np.isfinite(cov)) and np.allclose(cov, cov.T)
        assert np.linalg.eigvalsh(0.5 * (cov + cov.T)).min() > 0


@st.composite
def bad_frames(draw):
    """(kind, shape, value, stamp offset from the last stamp in s) of one bad frame."""
    kind = draw(st.sampled_from(['noise', 'constant', 'wrong_size', 'repeat', 'tiny']))
    offset = draw(st.sampled_from([0.0, -1e-9, -5.0, 10.0, 1e6]) | st.floats(-3, 3))
    return kind, draw(st.integers(0, 255)), draw(st.integers(0, 2**32 - 1)), offset


def bad_image(kind: str, value: int, seed: int, good: np.ndarray) -> np.ndarray:
    rng = np.random.default_rng(seed)
    h, w = good.shape
    if kind == 'noise':
        return rng.integers(0, 256, (h, w), dtype=np.uint8)
    if kind == 'constant':
        return np.full((h, w), value, np.uint8)
    if kind == 'wrong_size':
        return rng.integers(0, 256, (h // 2, w + 3), dtype=np.uint8)
    if kind == 'tiny':
        return np.full((1, 1), value, np.uint8)
    return good  # the same picture again


@given(st.lists(bad_frames(), min_size=1, max_size=3))
def test_process_survives_any_frames_and_good_frames_are_estimated_again(frames, bad):
    vo = VisualOdometry.from_params(frames.camera, PARAMS)
    last = frames.stamps[1]
    for k in (0, 1):
        assert_sane(vo.process(frames.images[k], frames.stamps[k]))
    for kind, value, seed, offset in bad:
        image = bad_image(kind, value, seed, frames.images[1])
        stamp = last + offset
        assert math.isfinite(stamp)
        assert_sane(vo.process(image, stamp))
        last = max(last, stamp)
    # The bag's next frames, later than anything seen: estimated again within two frames,
    # and the motion between them is the true one.
    start = last + 2.0
    results = [vo.process(frames.images[k], start + (k - 2) * frames.period)
               for k in range(2, 6)]
    for r in results:
        assert_sane(r)
    assert results[-1].status == 'ok' and results[-2].status == 'ok', [
        (r.status, r.message) for r in results]
    true = frames.truth[frames.stamps[5]] - frames.truth[frames.stamps[4]]
    speed = np.hypot(*true[:2]) / frames.period
    assert abs(results[-1].twist[0] - speed) < 0.05 * speed
