"""Standing still: zero motion while the vehicle waits, whatever crosses in front of it.

Drives of planar_vo_synth with full stops (the renderer's truth holds the vehicle exactly
still) at 320x240, scored against the renderer's truth: `stop_and_go` (starts standing, stops
of 2-4 s, reverses, cars and people cross ahead at every stop; 811 frames at 20 Hz), `creep`
(3, 2 and 5 cm/s; 491 frames at 20 Hz) and `red_light` (a 60.5 s stop with 20 cars and a
person crossing; 701 frames at 10 Hz).

Measured (deterministic): every stop 0.000 mm and 0.0000 deg in total (before: 4-41 mm and
0.04-0.65 deg per stop of stop_and_go); creeping never taken for a stop (0 of 293 frames at
2, 3 and 5 cm/s), reported at 0.0194, 0.0291 and 0.0488 m/s; no stationary frame on normal
driving; twist NEES 4.0 over stop_and_go (5.8 over its moving frames; 9.6 before). A sprung car
pulling away from rest: its first 2.5 m within 0.5 % of the renderer's at 640x480 (its squat).
"""

import dataclasses
import functools

import numpy as np
import pytest

from planar_vo import synth
from planar_vo.core import config
from planar_vo.core.odometry import VisualOdometry
from planar_vo.core.odometry.standstill import (
    ENTER_CHI2,
    EXIT_CHI2,
    MAX_STILL_STEP,
    TWIST_SIGMA,
    Standstill,
    zero_motion_chi2,
)
from planar_vo.synth.scene import stops_of
from test.conftest import drive, synth_camera_model
from test.test_consistency import measured, nees


@functools.cache
def stop_frames(scenario, rate):
    """(renderer, trajectory, images) of ``scenario`` at 320x240."""
    frames = synth.SCENARIOS[scenario].frames(rate)
    renderer, traj = synth.render_scenario(scenario, frames, 0, rate=rate,
                                           camera=synth.SynthCamera.scaled(320, 240))
    return renderer, traj, [renderer.render_frame(traj, k) for k in range(frames)]


@functools.cache
def stop_drive(scenario, rate, odometry=VisualOdometry):
    """(results, truth poses (N, 3), true twist (N, 3), trajectory, renderer, diagnostics)
    of ``odometry`` (the class) with the shipped defaults at 320x240."""
    renderer, traj, images = stop_frames(scenario, rate)
    params = config.validate(config.mounting_params(renderer.mounting))
    vo = odometry.from_params(synth_camera_model(renderer), params)
    diagnostics = []
    results = []
    for k, image in enumerate(images):
        results.append(vo.process(image, k / rate))
        diagnostics.append(vo.diagnostics())
    truth = np.c_[traj.x, traj.y, traj.yaw]
    twist = np.c_[traj.v, np.zeros_like(traj.v), traj.omega]
    return results, truth, twist, traj, renderer, diagnostics


def pose_change(results, first, last):
    """(mm, deg) the published pose moved in total over frames first..last."""
    poses = np.array([r.pose for r in results[first:last + 1]])
    steps = np.diff(poses, axis=0)
    return (1e3 * np.hypot(steps[:, 0], steps[:, 1]).sum(),
            np.degrees(np.abs(np.angle(np.exp(1j * steps[:, 2]))).sum()))


def test_the_synthetic_stops_hold_the_vehicle_exactly_still():
    _, _, twist, traj, renderer, _ = stop_drive('stop_and_go', 20.0)
    stops = stops_of(traj)
    assert [round((b - a) / 20.0, 2) for a, b in stops] == [1.45, 2.5, 4.0, 2.5, 2.0]
    for a, b in stops:
        assert np.all(traj.x[a:b + 1] == traj.x[a]) and np.all(traj.yaw[a:b + 1] == traj.yaw[a])
        assert np.all(twist[a + 1:b + 1] == 0.0)
    assert np.any(traj.v < -1.0)  # it reverses
    # Crossing traffic: moving boxes in the scene during every stop.
    for a, b in stops[1:4]:
        assert any(len(renderer.boxes_at(k)) > len(renderer.boxes) for k in range(a, b + 1))


def test_every_stop_holds_the_pose_with_traffic_crossing():
    results, _, twist, traj, _, _ = stop_drive('stop_and_go', 20.0)
    for a, b in stops_of(traj):
        mm, deg = pose_change(results, a, b)
        assert mm < 1.0 and deg < 0.01, (a, b, mm, deg)
        # Found still from the second frame of the stop (from the start's second frame).
        assert all(r.stationary for r in results[a + 1:b + 1]), (a, b)
        for r in results[a + 1:b + 1]:
            assert np.all(r.twist == 0.0)
            assert np.allclose(np.sqrt(r.twist_covariance.diagonal()), TWIST_SIGMA)
        covariances = [r.pose_covariance for r in results[a + 1:b + 1]]
        assert all(np.array_equal(c, covariances[0]) for c in covariances)
    # No stop while moving faster than 10 cm/s.
    fast = np.abs(twist[:, 0]) > 0.1
    assert not any(r.stationary for r, f in zip(results, fast) if f)


def test_a_sixty_second_stop_at_a_red_light_with_crossing_traffic():
    results, _, _, traj, renderer, diagnostics = stop_drive('red_light', 10.0)
    (a, b), = stops_of(traj)
    assert (b - a) / 10.0 >= 60.0
    crossing = sum(len(renderer.boxes_at(k)) > len(renderer.boxes) for k in range(a, b + 1))
    assert crossing > 0.5 * (b - a)
    mm, deg = pose_change(results, a, b)
    assert mm < 1.0 and deg < 0.01, (mm, deg)
    assert sum(r.stationary for r in results[a:b + 1]) >= (b - a)
    # /diagnostics values: the state and for how long.
    assert diagnostics[b]['motion state'] == 'stationary'
    assert float(diagnostics[b]['stationary for (s)']) >= 60.0
    assert diagnostics[a - 10]['motion state'] == 'moving'
    assert diagnostics[a - 10]['stationary for (s)'] == '0.00'
    assert results[b].stationary_s >= 60.0


def test_pulling_away_from_a_stop_has_no_jump():
    """One second after each stop the pose is as good as before it (no restart, no jump).

    A restart's lost frame alone would be 5 cm at 1 m/s. The error the pose gains in the
    first second is what a second of driving gains: measured 2-12 mm over the four stops,
    while one second of driving at speed gains 7-9 mm (median) and up to 23-34 mm on this
    drive, which moves by some millimetres with any change to the estimator (8.6, 8.8 and
    12.3 mm at the first stop with the static tilt shrunk at 4, 2 and 3 sigmas)."""
    results, truth, _, traj, _, _ = stop_drive('stop_and_go', 20.0)
    statuses = {r.status for r in results}
    assert statuses <= {'first', 'ok'}, statuses
    for _, b in stops_of(traj)[:-1]:
        before = np.array(results[b].pose) - truth[b]
        after = np.array(results[b + 20].pose) - truth[b + 20]
        assert np.hypot(*(after - before)[:2]) < 0.02  # < 2 cm in the first second
        assert not results[b + 20].stationary


class RigidBlind(VisualOdometry):
    """The rigid planar fit's covariance 30x looser, as on a car stopping on a bump's slope
    (tilted, no rigid motion fits its tracks well): its zero-motion test sees 30x less."""

    def _planar_at_inlier_threshold(self, *args, **kwargs):
        planar = super()._planar_at_inlier_threshold(*args, **kwargs)
        return dataclasses.replace(planar, covariance=planar.covariance * 900.0)


def test_pulling_away_is_seen_when_the_rigid_fit_cannot_see_it():
    """On a rendered stop-and-go drive over speed bumps the rigid fit read 4 mm for an
    11 mm step, so a stop began while the car still rolled, and held until 116 mm had gone
    by (a 0.37 % drive; 0.16 % since). Here the rigid fit is made blind: the local ground's
    own test must see the car pull away. The error the pose gains from a second before each
    stop to a second after it, measured: 20, 15, 11, 11 mm (the rigid test alone: 538, 169,
    55, 28 mm). The drive's start, standing from its first frame, is not among them: no
    surface is learned there yet, and the local ground's covariance is as loose (its test
    read 175 at 191 mm)."""
    results, truth, _, traj, _, _ = stop_drive('stop_and_go', 20.0, RigidBlind)
    for a, b in stops_of(traj)[1:]:
        before = np.array(results[a - 20].pose) - truth[a - 20]
        worst = max(np.hypot(*(np.array(results[k].pose) - truth[k] - before)[:2])
                    for k in range(a - 20, min(b + 21, len(results))))
        assert worst < 0.04, (a, b, worst)


@pytest.mark.parametrize('speed', [0.02, 0.03, 0.05])
def test_creeping_is_motion_at_its_speed(speed):
    results, _, twist, _, _, _ = stop_drive('creep', 20.0)
    creeping = np.flatnonzero(twist[:, 0] == speed)
    assert len(creeping) > 80
    assert not any(results[k].stationary for k in creeping)
    reported = np.mean([results[k].twist[0] for k in creeping])
    assert abs(reported - speed) < 0.1 * speed, reported


def test_reversing_keeps_its_tracks_and_its_distance():
    """Reversing, the image's tracks drift above the horizon margin; they go, so the track
    budget refills below (at 376x240 30 Hz 13 of 362 tracks were usable and tracking
    restarted). Against the renderer's truth over the reversing stretch (5.2 m)."""
    results, truth, _, traj, _, _ = stop_drive('stop_and_go', 20.0)
    reverse = np.flatnonzero(traj.v < -0.1)
    assert len(reverse) > 80
    assert all(results[k].status == 'ok' for k in reverse)
    # Measured: 232 inliers at the least (122 when the tracks above the margin stayed).
    assert min(results[k].inliers for k in reverse) > 180
    first, last = reverse[0] - 1, reverse[-1]
    est = np.array([r.pose for r in results])
    length = np.hypot(*np.diff(est[first:last + 1, :2], axis=0).T).sum()
    true = np.hypot(*np.diff(truth[first:last + 1, :2], axis=0).T).sum()
    assert abs(length / true - 1.0) < 0.01, (length, true)  # measured 0.45 %
    turned = (est[last, 2] - est[first, 2]) - (truth[last, 2] - truth[first, 2])
    assert abs(np.degrees(turned)) < 0.1  # measured 0.005 deg


def test_twist_is_consistent_over_a_stop_and_go_drive():
    results, _, twist, _, _, _ = stop_drive('stop_and_go', 20.0)
    values = [nees(r.twist - twist[k], r.twist_covariance)
              for k, r in enumerate(results) if measured(r)]
    assert len(values) >= 0.95 * len(results)
    assert 1.0 <= np.mean(values) <= 6.0, np.mean(values)


def test_normal_driving_is_never_a_stop():
    results, _, _ = drive('default', 90, 15.0)  # shared with test_consistency
    assert not any(r.stationary for r in results)


def test_the_zero_motion_test_and_its_hysteresis():
    cov = np.diag([1e-8, 1e-8, 1e-8])  # 0.1 mm, 0.1 mrad
    assert zero_motion_chi2(np.zeros(3), cov) == 0.0
    assert zero_motion_chi2(np.array([1e-3, 0.0, 0.0]), cov) == pytest.approx(100.0)
    assert zero_motion_chi2(np.ones(3), np.zeros((3, 3))) == float('inf')
    s = Standstill()
    assert not s.stationary and s.seconds(5.0) == 0.0
    enter = np.sqrt(ENTER_CHI2) * 1e-4
    assert s.quiet(np.array([0.9 * enter, 0, 0]), cov)
    assert not s.quiet(np.array([1.1 * enter, 0, 0]), cov)
    exit_ = np.sqrt(EXIT_CHI2) * 1e-4
    assert not s.moved(np.array([0.9 * exit_, 0, 0]), cov)  # between the two: stays put
    assert s.moved(np.array([1.1 * exit_, 0, 0]), cov)


def test_a_jolt_s_loose_fit_is_not_a_stop():
    """A wheel on a speed bump shakes the tracks off any rigid motion: the fit's step is
    long and its covariance loose enough to pass the chi-square test. Not a stop."""
    loose = np.diag([0.05 ** 2, 0.05 ** 2, 0.01 ** 2])
    step = np.array([0.3, 0.0, 0.0])  # 6 m/s at 20 Hz
    assert zero_motion_chi2(step, loose) < ENTER_CHI2
    assert not Standstill().quiet(step, loose)
    assert Standstill().quiet(np.array([0.5 * MAX_STILL_STEP, 0, 0]), loose)


def test_a_jolt_that_stills_the_rigid_motion_is_not_a_stop_when_the_local_ground_moves():
    """A front wheel on a bump at 6.3 m/s (the issue's camera over all four terrains, sprung,
    seed 25, frame 28): the rigid motion came out 7 mm within its test, the local ground's
    0.32 m (the truth's 0.317). Held as a stop, the drive lost its tracks: t_rel 1.54 %,
    0.14 % since."""
    rigid, tight = np.array([0.006, 0.0034, 0.005]), np.diag([1e-6, 1e-6, 1e-6])
    assert Standstill().quiet(rigid, tight)  # the rigid test alone
    assert not Standstill().quiet(rigid, tight, refined=np.array([0.319, 0.0012, -0.0032]))
    assert Standstill().quiet(rigid, tight, refined=np.array([0.002, 0.0, 0.0]))


@pytest.mark.parametrize('seed', [0, 1])
def test_a_sprung_car_pulling_away_from_rest_squats_and_keeps_its_distance(seed):
    """A sprung car (the `car`'s body) pulls away from its first stop on a flat road: over its
    first 2.5 m the road's history has nothing under the wheels to read the body's squat from.
    Its distance against the renderer's (640x480; seeds 0-3: -0.97 to -1.23 % before the
    pair's turn was taken as the squat, +0.02 to +0.28 % since)."""
    frames, rate = 75, 20.0
    renderer, traj = synth.render_scenario(
        'stop_and_go', frames, seed, rate=rate, camera=synth.SynthCamera.scaled(640, 480),
        suspension=synth.Suspension.degrees(1.0, 0.6, 0.015))
    params = config.validate(config.mounting_params(renderer.mounting))
    vo = VisualOdometry.from_params(synth_camera_model(renderer), params)
    poses = np.array([vo.process(renderer.render_frame(traj, k), k / rate).pose
                      for k in range(frames)])
    truth = np.c_[traj.x, traj.y]
    _, start = stops_of(traj)[0]
    travelled = np.r_[0.0, np.cumsum(np.hypot(*np.diff(truth[start:], axis=0).T))]
    end = start + int(np.searchsorted(travelled, 2.5))
    assert end < frames - 1 and np.min(traj.body.pitch[start:end]) < -np.radians(0.5)

    def length(p):
        return np.hypot(*np.diff(p[start:end + 1], axis=0).T).sum()

    assert abs(length(poses[:, :2]) / length(truth) - 1.0) < 0.005


def test_planar_vo_synth_writes_a_stop_scenario_whole(tmp_path, capsys):
    """--frames defaults to the scenario's whole schedule; the bag's truth stands still."""
    from rosbags.highlevel import AnyReader
    with pytest.raises(SystemExit):
        synth.main(['--help'])
    text = capsys.readouterr().out
    assert all(name in text for name in ('stop_and_go', 'creep', 'red_light'))
    rc = synth.main([str(tmp_path / 'b'), '--scenario', 'red_light', '--rate', '1', '--width',
                     '160', '--height', '120', '--quiet'])
    assert rc == 0
    with AnyReader([tmp_path / 'b']) as reader:
        odom = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()
                if c.topic == synth.ODOM_TOPIC]
    assert len(odom) == 71  # 70 s at 1 Hz
    x = np.array([m.pose.pose.position.x for m in odom])
    assert np.all(x[6:64] == x[6]) and x[-1] > x[6] + 5.0
