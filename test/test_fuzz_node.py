"""A seeded fuzz run over DDS: random Image and CameraInfo messages between good frames.

What a broken driver could send (any encoding, size, step, byte order, data length, stamp;
any K, D, model, size, binning, ROI, P), each followed by good frames of the bundled bag.
The node must stay alive, answer every good frame with odometry, estimate motion again
within RECOVERY good frames, never print a traceback and never hit an unexpected error.
"""

import numpy as np
import pytest

from test.test_node import (  # noqa: F401 - fixtures
    DEFAULT_BAG,
    BagFrames,
    NodeProcess,
    ros,
    ros_env,
    send_lockstep,
    wait_for,
    warm_up,
)

SEED, RANDOM_MESSAGES, RECOVERY = 10, 100, 2
ENCODINGS = ('mono8', 'mono16', 'bgr8', 'rgba16', 'yuv422', 'yuyv', 'bayer_rggb8',
             'bayer_gbrg16', '32FC1', '', 'jpeg', 'MONO8', '8UC1')
SIZES = (0, 1, 2, 3, 17, 320, 479, 480, 640, 641, 65535, 2**31 - 1, 2**32 - 1)
BYTES = {'mono8': 1, 'mono16': 2, 'bgr8': 3, 'rgba16': 8, 'yuv422': 2, 'yuyv': 2,
         'bayer_gbrg16': 2, '32FC1': 4}
WILD = (np.nan, np.inf, -np.inf, 1e308, -1e308, 1e-12, 0.0, -1.0)
LOST_TWIST_VARIANCE = 1e3  # the README: a frame without an estimate has twist variance 1e3


def stamp(msg, stamp_ns):
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), 10**9)


def random_image(rng, good, stamp_ns_now, kinds=6):
    """An Image message a broken driver might send, stamped around ``stamp_ns_now``.

    ``kinds=1``: only a plausible frame of random pixels or blank.
    """
    from sensor_msgs.msg import Image
    msg = Image()
    kind = rng.integers(kinds)
    if kind == 0:  # a plausible frame with random pixels (decodable) or blank
        msg.height, msg.width, msg.encoding, msg.step = 480, 640, 'mono8', 640
        msg.data = (rng.integers(0, 256, 640 * 480, dtype=np.uint8) if rng.random() < 0.5
                    else np.full(640 * 480, rng.integers(256), np.uint8)).tobytes()
    elif kind == 1:  # the good frame again (duplicate or stale stamp)
        msg = good
    else:
        msg.encoding = str(rng.choice(ENCODINGS))
        msg.height, msg.width = int(rng.choice(SIZES)), int(rng.choice(SIZES))
        row = msg.width * BYTES.get(msg.encoding, 1)
        msg.step = min(int(rng.choice([row, row + rng.integers(1, 9), 0, 2**31 - 1])),
                       2**32 - 1)
        size = msg.step * msg.height
        length = int(size if 0 < size <= 1_500_000 and rng.random() < 0.5
                     else rng.integers(0, 5000))
        msg.data = rng.integers(0, 256, length, dtype=np.uint8).tobytes()
        msg.is_bigendian = int(rng.integers(2))
    offset = rng.choice([0, -1, 10**7, -5 * 10**9, 10 * 10**9, 10**14, int(rng.integers(
        -10**9, 10**9))])
    sec, nanosec = divmod(max(stamp_ns_now + int(offset), 0), 10**9)
    msg.header.stamp.sec = int(min(sec, 2**31 - 1))
    msg.header.stamp.nanosec = int(nanosec if rng.random() < 0.9 else rng.integers(2**32))
    return msg


def random_camera_info(rng, good):
    """A CameraInfo with one or more wild fields.

    Not a plausible camera of another size: switching to it is a real camera change, and
    which of two messages published together the node sees first is up to DDS (pairing
    images with their CameraInfo by stamp is what makes that deterministic).
    """
    from sensor_msgs.msg import CameraInfo, RegionOfInterest
    msg = CameraInfo(header=good.header, width=good.width, height=good.height,
                     distortion_model=good.distortion_model, d=list(good.d), k=good.k,
                     r=good.r, p=good.p)
    k, p = np.array(good.k), np.array(good.p)
    for _ in range(rng.integers(1, 4)):
        field = rng.integers(6)
        if field == 0:
            k[rng.integers(9)] = rng.choice(WILD) if rng.random() < 0.7 else rng.normal(0, 1e3)
        elif field == 1:
            msg.d = (rng.normal(0, 1, rng.integers(0, 15)) if rng.random() < 0.7
                     else np.full(5, np.nan)).tolist()
        elif field == 2:
            msg.distortion_model = str(rng.choice(['plumb_bob', 'rational_polynomial',
                                                   'equidistant', 'fisheye', '']))
        elif field == 3:
            msg.width, msg.height = int(rng.choice(SIZES)), int(rng.choice(SIZES))
        elif field == 4:
            p[rng.integers(12)] = rng.choice(WILD)
        else:
            msg.binning_x, msg.binning_y = int(rng.integers(0, 5)), int(rng.integers(0, 5))
            msg.roi = RegionOfInterest(x_offset=int(rng.integers(0, 700)),
                                       y_offset=int(rng.integers(0, 500)),
                                       width=int(rng.integers(0, 700)),
                                       height=int(rng.integers(0, 500)))
    msg.k, msg.p = k, p
    return msg


@pytest.fixture(scope='module')
def node(ros_env):  # noqa: F811 - the fixture imported above
    node = NodeProcess(ros_env, '-r', '__ns:=/fuzz', '-p', 'image_reliability:=reliable')
    yield node
    node.stop()


def test_random_messages_between_good_frames(ros, node):  # noqa: F811
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import CameraInfo, Image
    bag = BagFrames(DEFAULT_BAG)
    image_pub = ros.publisher(Image, '/fuzz/image')
    info_pub = ros.publisher(CameraInfo, '/fuzz/camera_info')
    odom_sub, odoms = ros.collector(Odometry, '/fuzz/odom')
    wait_for(lambda: image_pub.get_subscription_count() and info_pub.get_subscription_count()
             and odom_sub.get_publisher_count(), 20, 'discovery of /fuzz/planar_vo')
    warm_up(ros, image_pub, info_pub, bag.info, bag.images[0], odoms)
    good_info = bag.info_msg()
    rng = np.random.default_rng(SEED)
    now, frame = bag.stamps[0] + 10**10, 0

    def next_good():
        nonlocal now, frame
        frame += 1
        now += bag.stamps[1] - bag.stamps[0]
        stamp(good_info, now)  # a driver stamps its CameraInfo as the image
        return send_lockstep(image_pub, info_pub, good_info, bag.image_msg(frame, now), odoms)

    def rewind():
        """Back to the bag's start, 2 s later: tracking restarts (a time jump), then moves."""
        nonlocal now, frame
        frame, now = -1, now + 2 * 10**9
        for _ in range(3):
            next_good()

    rewind()
    not_recovered = []
    for i in range(RANDOM_MESSAGES):
        if frame + RECOVERY + 1 > len(bag.images):
            rewind()
        if rng.random() < 0.6:
            junk = random_image(rng, bag.image_msg(frame, now), now)
            image_pub.publish(junk)
            what = f'image {junk.encoding!r} {junk.width}x{junk.height} step {junk.step}'
        else:  # with a stamp of its own, and half the time an image that uses it
            junk = random_camera_info(rng, good_info)
            stamp(junk, now + 10**6)
            info_pub.publish(junk)
            what = (f'camera_info {junk.width}x{junk.height} {junk.distortion_model} binning '
                    f'{junk.binning_x}x{junk.binning_y} roi {junk.roi.width}x{junk.roi.height}')
            if rng.random() < 0.5:
                image = random_image(rng, bag.image_msg(frame, now), now, kinds=1)
                stamp(image, now + 10**6)
                image_pub.publish(image)
                what += ' with an image'
        # Every good frame is answered (or send_lockstep fails); motion is estimated again
        # within RECOVERY frames.
        odoms_after = [next_good() for _ in range(RECOVERY)]
        if not any(o.twist.covariance[0] < LOST_TWIST_VARIANCE for o in odoms_after):
            not_recovered.append(f'{i}: {what}')
        assert node.alive(), node.output
    assert not not_recovered, '\n'.join(not_recovered) + '\n' + node.output
    assert 'Traceback' not in node.output, node.output
    assert 'unexpected' not in node.output, node.output
