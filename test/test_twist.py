"""The twist at the image stamp: SE(2) log/exp, extrapolation, its covariance, restarts."""

import numpy as np
import pytest

from planar_vo.core.estimation.twist import TwistAtStamp
from planar_vo.core.geometry.se2 import mean_twist, twist_motion
from planar_vo.core.odometry import VisualOdometry


def arc(v, rate, dt):
    """Closed-form pose after driving a circle at speed v and yaw rate ``rate`` for dt."""
    yaw = rate * dt
    return np.array([v / rate * np.sin(yaw), v / rate * (1 - np.cos(yaw)), yaw])


def integrate(twist_of_t, t0, t1, substeps=2000):
    """Motion (x, y, yaw) from t0 to t1 of a time-varying body twist, by fine Euler steps."""
    pose = np.zeros(3)
    h = (t1 - t0) / substeps
    for i in range(substeps):
        vx, vy, w = twist_of_t(t0 + (i + 0.5) * h)
        c, s = np.cos(pose[2] + 0.5 * w * h), np.sin(pose[2] + 0.5 * w * h)
        pose += [(c * vx - s * vy) * h, (s * vx + c * vy) * h, w * h]
    return pose


def test_exp_and_log_match_the_closed_form_circle():
    motion = arc(6.0, 0.4, 0.1)
    np.testing.assert_allclose(twist_motion(np.array([6.0, 0.0, 0.4]), 0.1), motion, atol=1e-12)
    twist, _ = mean_twist(motion, 0.1)
    np.testing.assert_allclose(twist, [6.0, 0.0, 0.4], atol=1e-12)
    # Straight: the small-angle branches.
    np.testing.assert_allclose(mean_twist(np.array([0.5, 0.01, 0.0]), 0.1)[0], [5.0, 0.1, 0.0])


def test_log_jacobian_matches_finite_differences():
    for motion in (np.array([0.4, 0.03, 0.08]), np.array([0.3, -0.01, 1e-6])):
        _, jac = mean_twist(motion, 0.05)
        numeric = np.empty((3, 3))
        for i in range(3):
            h = np.zeros(3)
            h[i] = 1e-7
            numeric[:, i] = (mean_twist(motion + h, 0.05)[0]
                             - mean_twist(motion - h, 0.05)[0]) / 2e-7
        np.testing.assert_allclose(jac, numeric, rtol=1e-6, atol=1e-6)


def test_extrapolation_is_exact_under_constant_acceleration_with_uneven_intervals():
    """Speed and yaw rate ramp linearly; the middle interval spans two frames (a frame
    without an estimate). The twist at each interval's end is the true one at that time."""
    def twist_of_t(t):
        return np.array([3.0 + 2.0 * t, 0.0, 0.1 - 0.3 * t])

    estimator = TwistAtStamp()
    stamps = [0.0, 0.05, 0.15, 0.2]
    for t0, t1 in zip(stamps, stamps[1:]):
        estimator = estimator.add(t0, t1, integrate(twist_of_t, t0, t1), np.eye(3) * 1e-8)
    twist, _ = estimator.estimate()
    np.testing.assert_allclose(twist, twist_of_t(0.2), atol=2e-5)


def test_at_30_hz_three_intervals_are_fitted_and_carry_the_noise_less_far():
    """Three 1/30 s intervals: the least-squares line through their midpoints, at the stamp,
    weighs them -5/12, 1/3 and 13/12 (worked out by hand), so independent noise C in each
    comes out as 35/24 C where the line through the last two gives 5/2 C. Checked by
    sampling; exact under constant acceleration."""
    def ramp(t):
        return np.array([3.0 + 2.0 * t, 0.0, 0.1 - 0.3 * t])

    stamps = [0.0, 1 / 30, 2 / 30, 3 / 30]
    estimator = TwistAtStamp()
    for t0, t1 in zip(stamps, stamps[1:]):
        estimator = estimator.add(t0, t1, integrate(ramp, t0, t1), np.eye(3) * 1e-8)
    twist, _ = estimator.estimate()
    # Sideways, each interval's mean of an arc whose curvature changes is 0.1 mm/s off.
    assert np.all(np.abs(twist - ramp(0.1)) < [2e-5, 2e-4, 2e-5]), twist - ramp(0.1)

    rng = np.random.default_rng(5)
    motion_cov = np.diag([4e-6, 1e-6, 2e-7])
    truth = np.array([5.0, 0.0, 0.2])
    errors = []
    for _ in range(2000):
        estimator = TwistAtStamp(jerk=(0.0, 0.0, 0.0))
        for t0 in stamps[:2]:
            estimator = estimator.add(t0, t0 + 1 / 30, twist_motion(truth, 1 / 30)
                                      + rng.multivariate_normal(np.zeros(3), motion_cov),
                                      motion_cov)
        two = estimator.estimate()[1]
        estimator = estimator.add(stamps[2], stamps[3], twist_motion(truth, 1 / 30)
                                  + rng.multivariate_normal(np.zeros(3), motion_cov),
                                  motion_cov)
        twist, cov = estimator.estimate()
        errors.append(twist - truth)
    np.testing.assert_allclose(cov.diagonal() / two.diagonal(), (35 / 24) / (5 / 2), rtol=0.02)
    ratio = np.cov(np.array(errors).T).diagonal() / cov.diagonal()
    assert np.all((ratio > 0.85) & (ratio < 1.15)), ratio


def test_a_jolt_s_twist_is_covered_where_a_line_through_the_means_misses_it():
    """A rear wheel climbing a bump jolts the body sideways within a frame (rendered, 20 Hz:
    0.09, 0.03, -0.08 m/s in three frames, none before or after). With the pairs flagged as
    jolts the covariance holds the miss of the line through the means (the sideways error
    under 3 sigma); without, the same errors are 10-100 sigma off."""
    def jolted(t):
        pulse = 0.1 * np.sin(2 * np.pi * (t - 0.5) / 0.15) if 0.5 <= t <= 0.65 else 0.0
        return np.array([5.0, pulse, 0.02])

    stamps = np.arange(0.0, 1.0, 0.05)
    flagged, unflagged = TwistAtStamp(), TwistAtStamp()
    sigmas = []
    for t0, t1 in zip(stamps, stamps[1:]):
        motion, noise = integrate(jolted, t0, t1), np.diag([1e-8, 1e-8, 1e-9])
        jolt = t1 > 0.5 + 1e-9 and t0 < 0.65 - 1e-9  # the intervals the pulse is in
        flagged = flagged.add(t0, t1, motion, noise, jolt=jolt)
        unflagged = unflagged.add(t0, t1, motion, noise)
        if jolt:
            estimates = [estimator.estimate() for estimator in (flagged, unflagged)]
            sigmas.append([abs(twist[1] - jolted(t1)[1]) / np.sqrt(cov[1, 1])
                           for twist, cov in estimates])
    sigmas = np.array(sigmas)
    assert len(sigmas) == 3
    assert np.all(sigmas[:, 0] < 3.0), sigmas
    assert np.max(sigmas[:, 1]) > 10.0, sigmas


def test_jerk_term_is_the_extrapolation_error_of_a_quadratic_speed():
    """With speed t^2/2 (unit jerk) the extrapolation misses by -h^2/3 for equal intervals h
    (worked out by hand); the covariance carries exactly that for the configured jerk."""
    h = 0.1
    estimator = TwistAtStamp(jerk=(2.0, 0.0, 0.0))
    for t0 in (-2 * h, -h):
        motion = integrate(lambda t: np.array([10.0 + t * t, 0.0, 0.0]), t0, t0 + h)
        estimator = estimator.add(t0, t0 + h, motion, np.eye(3) * 1e-12)
    twist, cov = estimator.estimate()
    assert twist[0] - 10.0 == pytest.approx(-2.0 * h * h / 3, rel=1e-3)
    assert np.sqrt(cov[0, 0]) == pytest.approx(2.0 * h * h / 3, rel=1e-3)


def test_covariance_matches_the_spread_of_noisy_extrapolations():
    rng = np.random.default_rng(3)
    motion_cov = np.array([[4e-6, 1e-7, 2e-7], [1e-7, 1e-6, 0.0], [2e-7, 0.0, 2e-7]])
    truth = np.array([5.0, 0.0, 0.2])
    errors = []
    for _ in range(2000):
        estimator = TwistAtStamp(jerk=(0.0, 0.0, 0.0))
        for t0 in (0.0, 1 / 30):
            motion = twist_motion(truth, 1 / 30) + rng.multivariate_normal(np.zeros(3),
                                                                           motion_cov)
            estimator = estimator.add(t0, t0 + 1 / 30, motion, motion_cov)
        twist, cov = estimator.estimate()
        errors.append(twist - truth)
    ratio = np.cov(np.array(errors).T).diagonal() / cov.diagonal()
    assert np.all((ratio > 0.85) & (ratio < 1.15)), ratio


def test_a_gap_in_the_intervals_restarts_the_history():
    estimator = TwistAtStamp().add(0.0, 0.1, twist_motion(np.array([2.0, 0.0, 0.0]), 0.1),
                                   np.eye(3) * 1e-8)
    twist, cov = estimator.add(0.5, 0.6, twist_motion(np.array([4.0, 0.0, 0.0]), 0.1),
                               np.eye(3) * 1e-8).estimate()
    assert twist[0] == pytest.approx(4.0)  # not a line through 2 m/s half a second ago
    assert cov[0, 0] > (4.0 * 0.05) ** 2 * 0.99  # the unknown acceleration over half a step


def test_lost_tracking_extrapolates_along_the_arc_without_a_sideways_twist(car_camera):
    """The unseen motion is the last twist held over the gap (a circle), and the twist is
    kept as it was: no sideways velocity appears."""
    camera, mounting = car_camera
    vo = VisualOdometry(camera, mounting)
    vo.integrator.twist = np.array([5.0, 0.0, 0.3])
    vo.integrator.restart(0.5, extrapolate=True)
    np.testing.assert_allclose(vo.pose, arc(5.0, 0.3, 0.5), atol=1e-12)
    np.testing.assert_allclose(vo.twist, [5.0, 0.0, 0.3], atol=1e-12)
    assert vo.twist_covariance[0, 0] >= 1.0  # published as unmeasured
