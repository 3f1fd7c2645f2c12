"""planar_vo_synth: deterministic bags whose geometry agrees with the pipeline's camera model."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from planar_vo import synth
from planar_vo.bag import open_reader
from test.conftest import synth_camera_model

SYNTH = str(Path(sys.executable).parent / 'planar_vo_synth')


def small_bag(path, **kw):
    camera = synth.SynthCamera.scaled(320, 240)
    return synth.generate_bag(path, 'default', 8, seed=3, rate=15.0, camera=camera, **kw)


def read(path):
    with open_reader(path) as reader:
        return [(c.topic, c.msgtype, t, reader.deserialize(raw, c.msgtype))
                for c, t, raw in reader.messages()]


def test_same_seed_same_images(tmp_path):
    small_bag(tmp_path / 'a')
    small_bag(tmp_path / 'b')
    images = [[m.data.tobytes() for topic, _, _, m in read(tmp_path / name)
               if topic == synth.IMAGE_TOPIC] for name in ('a', 'b')]
    assert len(images[0]) == 8 and images[0] == images[1]


def test_topics_types_stamps_and_order(tmp_path):
    small_bag(tmp_path / 'bag')
    msgs = read(tmp_path / 'bag')
    topics = [m[0] for m in msgs]
    assert topics[:3] == [synth.INFO_TOPIC, synth.IMAGE_TOPIC, synth.ODOM_TOPIC]
    assert topics.count(synth.IMAGE_TOPIC) == topics.count(synth.INFO_TOPIC) == 8
    image = next(m for t, _, _, m in msgs if t == synth.IMAGE_TOPIC)
    info = next(m for t, _, _, m in msgs if t == synth.INFO_TOPIC)
    assert (image.encoding, image.width, image.height, image.step) == ('mono8', 320, 240, 320)
    assert info.distortion_model == 'plumb_bob' and len(info.d) == 5
    assert info.header.frame_id == image.header.frame_id == synth.OPTICAL_FRAME
    stamps = sorted({m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
                     for t, _, _, m in msgs if t == synth.IMAGE_TOPIC})
    np.testing.assert_allclose(np.diff(stamps), 1 / 15.0, atol=1e-6)
    odom = [m for t, _, _, m in msgs if t == synth.ODOM_TOPIC]
    assert (odom[0].header.frame_id, odom[0].child_frame_id) == ('odom', 'base_link')
    assert odom[0].pose.pose.position.x == 0.0 and odom[0].pose.pose.orientation.w == 1.0


def test_ground_truth_follows_the_bicycle_model():
    traj = synth.make_trajectory(synth.SCENARIOS['tight'], 300, 30.0, seed=1)
    assert (traj.x[0], traj.y[0], traj.yaw[0]) == (0.0, 0.0, 0.0)
    dt = np.diff(traj.t)
    heading = np.arctan2(np.diff(traj.y), np.diff(traj.x))
    # nonholonomic: the rear axle moves along its heading (chord at the mean yaw)
    mid_yaw = 0.5 * (traj.yaw[1:] + traj.yaw[:-1])
    assert np.max(np.abs(np.angle(np.exp(1j * (heading - mid_yaw))))) < 1e-3
    yaw_rate = np.diff(traj.yaw) / dt
    np.testing.assert_allclose(yaw_rate, 0.5 * (traj.omega[1:] + traj.omega[:-1]), atol=2e-3)
    np.testing.assert_allclose(traj.omega, traj.v * np.tan(traj.steer) / synth.WHEELBASE)
    assert np.ptp(traj.v) > 0.3 and np.ptp(traj.steer) > 0.1  # speed and steering change


def test_rendered_ground_agrees_with_the_pipeline_camera_model():
    """The renderer's own undistortion and ray casting agree with the pipeline's CameraModel."""
    renderer, _ = synth.render_scenario('default', 2, seed=0)
    mounting = renderer.mounting
    camera = synth_camera_model(renderer)
    truth = renderer.ground_points_base()
    rng = np.random.default_rng(0)
    pixels = np.c_[rng.integers(0, 640, 400), rng.integers(300, 480, 400)]
    expected = truth[pixels[:, 1], pixels[:, 0]]
    got, valid = mounting.ground_points(camera.rays(pixels.astype(float)))
    assert valid.all()
    np.testing.assert_allclose(got, expected, atol=1e-6)


def test_sky_has_no_texture_and_ground_has():
    renderer, traj = synth.render_scenario('straight', 1, seed=0, noise_sigma=0.0,
                                           obstacles=False)
    image = renderer.render(traj.x[0], traj.y[0], traj.yaw[0], 0).astype(float)
    sky = ~renderer.ground_mask
    gradient = np.abs(np.diff(image, axis=1))
    assert np.median(gradient[sky[:, 1:]]) < 0.5
    assert np.median(gradient[~sky[:, 1:] & (np.arange(480)[:, None] > 400)]) > 2.0


@pytest.mark.parametrize('args, message', [
    (['--scenario', 'moon'], 'unknown scenario'),
    (['--frames', '0'], 'must be > 0'),
    (['--camera-pitch', '2.0'], 'out of range'),
])
def test_cli_errors_are_one_line(tmp_path, args, message):
    result = subprocess.run([SYNTH, str(tmp_path / 'x'), *args], capture_output=True, text=True)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert message in lines[-1] and 'Traceback' not in result.stderr


def test_cli_refuses_an_existing_output(tmp_path):
    result = subprocess.run([SYNTH, str(tmp_path)], capture_output=True, text=True)
    assert result.returncode == 2 and 'already exists' in result.stderr
