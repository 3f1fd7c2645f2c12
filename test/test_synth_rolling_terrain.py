"""A rolling-shutter camera over terrain: every row rendered from the vehicle's 3D pose at its
own time, riding the height field. Pinned against the global-shutter terrain frame, the flat
rolling-shutter renderer and a closed form on a constant grade."""

import json
import math
import subprocess

import numpy as np
import yaml

from planar_vo import synth
from planar_vo.io import resources
from planar_vo.io.bag import open_reader
from planar_vo.synth.ride import FINE_STEP, ride_grid, ride_over
from planar_vo.synth.shutter import RollingShutter, world_row_poses

SMALL = synth.SynthCamera.scaled(160, 120)


def test_readout_zero_rows_are_the_global_shutter_terrain_frame():
    """Every row at its frame's stamp (readout 0): the row poses are the frame's 3D pose and
    camera pose bit for bit, and the per-row renderer draws the global-shutter frame exactly:
    all four terrains under a sprung body (road) and bumps with a rigid mount, boxes in view."""
    for scenario, kind, frames in (('road', 'all', 5), ('default', 'bumps', 5)):
        sc = synth.SCENARIOS[scenario]
        renderer, _ = synth.render_scenario(scenario, frames, 0, rate=20.0, camera=SMALL,
                                            terrain=kind, noise_sigma=0.0)
        # the ride one grid step longer (a sprung body's twist at the last row needs it)
        grid = ride_grid(sc.drive, renderer.terrain, frames, 20.0, 0, margin=FINE_STEP)
        traj = synth.mount_camera(ride_over(sc.drive, renderer.terrain, frames, 20.0, 0,
                                            grid=grid), renderer.mounting, sc.suspension, 0)
        rows = world_row_poses(grid, traj, sc.drive, 20.0, 0, RollingShutter(0.0),
                               SMALL.height, renderer.mounting, sc.suspension)
        np.testing.assert_array_equal(rows.position, np.repeat(
            traj.pose3d.position[:, None], SMALL.height, 1))
        np.testing.assert_array_equal(rows.rotation, np.repeat(
            traj.pose3d.rotation[:, None], SMALL.height, 1))
        if not sc.suspension.rigid:
            np.testing.assert_array_equal(rows.camera_position, np.repeat(
                traj.camera.position[:, None], SMALL.height, 1))
            np.testing.assert_array_equal(rows.camera_rotation, np.repeat(
                traj.camera.rotation[:, None], SMALL.height, 1))
        want = [renderer.render_frame(traj, k) for k in (0, frames - 1)]
        assert renderer.boxes
        renderer.rows = rows
        for k, image in zip((0, frames - 1), want, strict=True):
            np.testing.assert_array_equal(renderer.render_frame(traj, k), image)


def test_a_terrain_of_height_zero_is_the_flat_rolling_shutter():
    """On the plane z = 0 ridden as a terrain, each row's pose is the flat renderer's (the
    bicycle model integrated row by row, RK4) within 0.2 um and 1e-8 rad, the sprung body's
    camera within 1e-8 (the rows differ from their frame's pose by up to 0.29 m and 2e-3);
    the rigid drive's frames are the flat rolling-shutter frames (measured: identical)."""
    for scenario, stamp in (('car', 'start'), ('default', 'end')):
        shutter = RollingShutter(0.05, stamp)
        flat, _ = synth.render_scenario(scenario, 6, 0, rate=20.0, camera=SMALL,
                                        rolling_shutter=shutter, noise_sigma=0.0)
        zero, tz = synth.render_scenario(scenario, 6, 0, rate=20.0, camera=SMALL,
                                         rolling_shutter=shutter, noise_sigma=0.0,
                                         terrain=synth.Plane())
        f, w = flat.rows, zero.rows
        np.testing.assert_allclose(w.position[..., 0], f.x, atol=2e-7)
        np.testing.assert_allclose(w.position[..., 1], f.y, atol=2e-7)
        np.testing.assert_array_equal(w.position[..., 2], 0.0)
        yaw = np.arctan2(w.rotation[..., 1, 0], w.rotation[..., 0, 0])
        np.testing.assert_allclose(yaw, f.yaw, atol=1e-8)
        np.testing.assert_array_equal(w.rotation[..., 2, 2], 1.0)  # level
        assert np.abs(w.position[..., 0] - tz.pose3d.position[:, None, 0]).max() > 0.1
        if scenario == 'car':
            np.testing.assert_allclose(w.camera_position, f.camera_position, atol=1e-8)
            np.testing.assert_allclose(w.camera_rotation, f.camera_rotation, atol=1e-8)
            moved = np.abs(w.camera_rotation - tz.camera.rotation[:, None]).max()
            assert moved > 1e-3, moved
        else:
            for k in (1, 5):
                np.testing.assert_array_equal(zero.render_frame(tz, k),
                                              flat.render_frame(tz, k))


def _rotation_y(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def test_a_dot_on_a_grade_is_where_the_pose_at_its_rows_time_projects_it():
    """Closed form: straight up a constant 5 % grade at 5 m/s, base_link is at
    (v cos(a) t, 0, v sin(a) t) pitched a = atan(0.05) nose up; row v of H is exposed at
    stamp + (v / H) T (stamp at the start). A bright dot on the road is rendered at the pixel
    (u, v) where the pinhole camera at the time of row v sees it (within 0.15 px, measured
    0.04); the frame's pose would put it 2.5 px higher."""
    grade, speed, readout, height = 0.05, 5.0, 0.06, 240
    camera = synth.SynthCamera(width=320, height=height, fx=230.0, fy=230.0, cx=160.0,
                               cy=120.0, dist=(0.0, 0.0, 0.0, 0.0, 0.0))
    mount = synth.CameraMount(x=1.2, height=1.1, pitch=math.radians(8.0))
    k, rate = 2, 20.0
    renderer, traj = synth.render_scenario(
        'straight', 3, 0, rate=rate, camera=camera, mounting=mount,
        terrain=synth.Plane(grade), obstacles=False, noise_sigma=0.0, max_range=8.0,
        rolling_shutter=RollingShutter(readout, 'start'))
    texel, size, centre = 0.01, 1024, 600  # the dot at world x = 6.005 m (every 10.24 m)
    yy, xx = np.mgrid[0:size, 0:size]
    dot = 250 * np.exp(-((xx - centre) ** 2 + (yy - 0) ** 2) / (2 * 5.0 ** 2))
    dot += 250 * np.exp(-((xx - centre) ** 2 + (yy - size) ** 2) / (2 * 5.0 ** 2))
    images = []
    for texture in (synth.Texture(dot, texel), synth.Texture(np.zeros_like(dot), texel)):
        renderer.texture, renderer.illumination, renderer.haze = texture, False, False
        renderer.vignette[:] = 1
        images.append(renderer.render_frame(traj, k).astype(float))
    w = np.clip(images[0] - images[1], 0, None)
    w[w < 20] = 0
    vs, us = np.mgrid[0:w.shape[0], 0:w.shape[1]]
    got = np.array([(w * us).sum() / w.sum(), (w * vs).sum() / w.sum()])

    a = math.atan(grade)
    point = np.array([(centre + 0.5) * texel, 0.5 * texel, grade * (centre + 0.5) * texel])
    to_optical = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    body = _rotation_y(-a)  # world <- base_link: nose up
    camera_rotation = body @ _rotation_y(mount.pitch)  # world <- camera body frame

    def pixel(t):
        base = speed * t * np.array([math.cos(a), 0.0, math.sin(a)])
        centre_world = base + body @ np.array([mount.x, 0.0, mount.height])
        p = to_optical @ camera_rotation.T @ (point - centre_world)
        return np.array([230.0 * p[0] / p[2] + 160.0, 230.0 * p[1] / p[2] + 120.0])

    stamp = k / rate
    frame_pose = pixel(stamp)
    uv = frame_pose
    for _ in range(20):  # the row whose time sees the dot in that row
        uv = pixel(stamp + uv[1] / height * readout)
    assert 120 < uv[1] < 230 and abs(uv[0] - 160) < 1, uv
    assert uv[1] - frame_pose[1] > 2.0, (uv, frame_pose)
    np.testing.assert_allclose(got, uv, atol=0.15)  # measured 0.04 px


def test_cli_writes_a_replayable_rolling_shutter_bag_on_terrain(tmp_path):
    """``--rolling-shutter 0.03 --terrain bumps``: the bag has the 3D truth, its metadata
    records the terrain and the readout, its truth is at the stamps (that of the
    global-shutter bag of the same drive), and planar_vo_replay runs it."""
    bag, params = tmp_path / 'bag', tmp_path / 'p.yaml'
    args = ['--terrain', 'bumps', '--frames', '8', '--width', '160', '--height', '120',
            '--rate', '20', '--quiet']
    assert synth.main([str(bag), *args, '--rolling-shutter', '0.03', '--params-out',
                       str(params)]) == 0
    assert synth.main([str(tmp_path / 'gs'), *args]) == 0
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())
    record = json.loads(meta['rosbag2_bagfile_information']['custom_data']['planar_vo_synth'])
    assert record['terrain']['kind'] == 'bumps'
    assert record['rolling_shutter'] == {'readout_s': 0.03, 'stamp': 'middle'}

    def truth(path):
        with open_reader(path) as reader:
            msgs = [(c.topic, t, reader.deserialize(raw, c.msgtype))
                    for c, t, raw in reader.messages()]
        return {topic: [(t, m.pose.pose.position.x, m.pose.pose.position.y,
                         m.pose.pose.position.z, m.twist.twist.linear.x)
                        for top, t, m in msgs if top == topic]
                for topic in (synth.ODOM_TOPIC, synth.POSE3D_TOPIC)}

    rolling, global_ = truth(bag), truth(tmp_path / 'gs')
    for topic in (synth.ODOM_TOPIC, synth.POSE3D_TOPIC):
        assert len(rolling[topic]) == 8
        np.testing.assert_allclose(rolling[topic], global_[topic], rtol=0, atol=1e-6)
    run = subprocess.run([resources.executable('planar_vo_replay'), str(bag), '--params',
                          str(params), '--json'], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert summary['images'] == 8 and summary['accuracy']['frames'] == 8, summary
