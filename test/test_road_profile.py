"""The road's history tells a sprung body's tilt from a grade ahead (RoadProfile).

A vehicle with a wheelbase drives along a known road profile; each frame pair hands the
profile what the local ground model would measure: the camera's rotation between the frames
and the road's gradient ahead relative to the camera. The body's tilt read back from the
history is compared with the one the drive was given.
"""

import numpy as np

from planar_vo.core.odometry.road_profile import RoadProfile

WHEELBASE = 2.7
STEP = 0.25  # m per frame (5 m/s at 20 Hz)


def _road(s):
    """Height (m) along the path: flat, then a 4 % grade reached over a 10 m vertical curve."""
    s = np.asarray(s, dtype=float)
    ramp = np.clip((s - 15.0) / 10.0, 0.0, 1.0)
    return 0.04 * np.where(s < 15.0, 0.0, np.where(s < 25.0, 5.0 * ramp ** 2,
                                                   5.0 + (s - 25.0)))


def _slope(s):
    return (_road(s + 1e-4) - _road(s - 1e-4)) / 2e-4


def _drive(body_pitch, frames=160):
    """The pitch (rad, nose down) read back at each frame (NaN before the history covers the
    wheelbase), for a body pitched by ``body_pitch(k)`` on top of the road."""
    return np.array([np.nan if seen is None else seen[0][1]
                     for seen in _readings(body_pitch, frames, RoadProfile.camera_tilt,
                                           WHEELBASE, 1.0)])


def _readings(body_pitch, frames, read, *args):
    """``read(profile, *args)`` at each frame of the drive."""
    profile, readings = RoadProfile.empty(), []
    level = None
    for k in range(frames):
        s = k * STEP
        chord = (_road(s + WHEELBASE) - _road(s)) / WHEELBASE
        camera_level = chord - body_pitch(k)  # nose down lowers the camera's base plane
        if level is not None:
            ahead = WHEELBASE + np.array([0.5, 1.5, 2.5, 3.5])
            slopes = _slope(s - STEP + ahead) - level  # relative to the camera at frame 1
            k_fit, ep = np.polyfit(ahead - WHEELBASE, slopes, 1)
            surface = np.array([ep, 0.0, k_fit, 0.0, 0.0])
            rotation = np.array([0.0, -(camera_level - level)])
            profile = profile.with_pair(np.array([STEP, 0.0, 0.0]), rotation, surface,
                                        np.eye(5) * 1e-8, np.zeros(2), WHEELBASE, False)
        level = camera_level
        readings.append(read(profile, *args))
    return readings


def test_a_grade_ahead_is_not_taken_for_the_body_s_tilt():
    """A rigid vehicle drives onto a grade: from one pair the grade ahead looks like the
    camera pitched down; the history says the camera stands level on its wheels."""
    read = _drive(lambda k: 0.0)
    known = ~np.isnan(read)
    assert np.count_nonzero(known) > 120  # the history covers the wheels after ~4 m
    assert np.max(np.abs(read[known])) < np.radians(0.05), np.degrees(read[known]).max()


def test_a_sprung_body_s_pitch_is_read_back_over_a_grade_change():
    """The body pitches +-1 deg at 1.3 Hz while the vehicle drives onto the same grade."""
    def body(k):
        return np.radians(1.0) * np.sin(2 * np.pi * 1.3 * k / 20.0)
    read = _drive(body)
    truth = np.array([body(k) for k in range(len(read))])
    known = ~np.isnan(read)
    error = read[known] - truth[known]
    assert np.max(np.abs(error)) < np.radians(0.05), np.degrees(np.abs(error).max())


def test_the_pitch_a_grade_change_gives_the_wheels_is_predicted_from_the_road_seen():
    """Driving through the vertical curve, the chord between the axles pitches by up to
    0.06 deg a frame; the road seen earlier predicts it (the wheel-lift gate's reference)."""
    predicted = np.array([np.nan if p is None else p for p in _readings(
        lambda k: 0.0, 160, RoadProfile.pitch_change, WHEELBASE, 1.0, STEP)])
    s = np.arange(160) * STEP
    chord = (_road(s + WHEELBASE) - _road(s)) / WHEELBASE
    truth = -((_road(s + STEP + WHEELBASE) - _road(s + STEP)) / WHEELBASE - chord)
    known = ~np.isnan(predicted)
    assert np.count_nonzero(known) > 120
    error = predicted[known] - truth[known]
    # Measured: 0.011 deg at most (the history's 0.9 m windows where the curve begins and
    # ends), 0.003 rms of the pitch's 0.028.
    assert np.degrees(np.abs(truth).max()) > 0.05
    assert np.max(np.abs(error)) < 0.25 * np.abs(truth).max()
    assert np.sqrt(np.mean(error ** 2)) < 0.2 * np.sqrt(np.mean(truth[known] ** 2))


def test_nothing_is_read_until_the_wheels_stand_on_seen_ground_and_bumps_are_left_out():
    """A pair that saw a bump's face (a 10 % grade on the smooth surface) marked rough: once
    the wheels are there, the reading is the smooth road's. Not marked, it would not be."""
    def drive(rough):
        profile = RoadProfile.empty()
        assert profile.camera_tilt(WHEELBASE, 1.0) is None
        for k in range(43):
            face = k == 30
            surface = np.array([0.1 if face else 0.0, 0.0, 0.0, 0.0, 0.0])
            profile = profile.with_pair(np.array([STEP, 0.0, 0.0]), np.zeros(2), surface,
                                        np.eye(5) * 1e-8, np.zeros(2), WHEELBASE,
                                        face and rough)
        return profile.camera_tilt(WHEELBASE, 1.0)[0]
    np.testing.assert_allclose(drive(rough=True), 0.0, atol=1e-12)
    assert abs(drive(rough=False)[1]) > np.radians(0.1)  # measured 0.16 deg


def test_a_view_that_begins_past_the_wheels_is_sampled_where_it_was_seen():
    """A camera that sees the road from 1 m past its front wheels: the pair's surface (a
    grade and a curvature, hinged at the front axle) is sampled from 0.5 m into the view,
    each sample the quadratic's own slope there (z = ep u + k u^2 / 2, u past the hinge);
    from a view that begins before the wheels, from 0.5 m past the hinge as before."""
    ep, k = 0.01, 0.02
    surface = np.array([ep, 0.0, k, 0.0, 0.0])
    for seen_from, first in ((1.0, WHEELBASE + 1.5), (0.0, WHEELBASE + 0.5)):
        profile = RoadProfile.empty().with_pair(
            np.zeros(3), np.zeros(2), surface, np.eye(5) * 1e-8, np.zeros(2), WHEELBASE,
            False, seen_from=seen_from)
        x = profile.points[:, 0]
        np.testing.assert_allclose(x, first + np.arange(4.0), atol=1e-12)
        np.testing.assert_allclose(profile.gradients[:, 0], ep + k * (x - WHEELBASE),
                                   atol=1e-12)
