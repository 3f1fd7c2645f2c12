"""The speed prior: a poorly held step pulled to the speed, a well-held one kept, no lag."""

import numpy as np

from planar_vo.core.odometry.speed_prior import SpeedPrior

DT = 0.05
WELL_HELD = 0.0003 ** 2  # m^2: a pair's fit variance on a smooth road (0.3 mm)


def _drive(steps: np.ndarray, fit_var: np.ndarray) -> np.ndarray:
    prior, fused = SpeedPrior(), []
    for k, (step, var) in enumerate(zip(steps, fit_var, strict=True)):
        prior, along = prior.fuse(k * DT, (k + 1) * DT, float(step), float(var))
        fused.append(along)
    return np.array(fused)


def _speeding_up_and_braking() -> np.ndarray:
    """True steps (m) of a car from 3 to 8 m/s and back (up to 1.3 m/s^2) over 12 s."""
    t = np.arange(241) * DT
    return np.diff(5.5 * t - 2.5 * 12.0 / (2 * np.pi) * np.sin(2 * np.pi * t / 12.0))


def test_a_car_speeding_up_is_not_held_back():
    steps = _speeding_up_and_braking()
    rng = np.random.default_rng(0)
    measured = steps + rng.normal(0.0, 0.0003, steps.shape)
    fused = _drive(measured, np.full(steps.shape, WELL_HELD))
    # The distance measured over the first 6 s (3 -> 8 m/s): a prior that held the speed
    # (no acceleration followed) takes 17 mm off it; this one 0.2 mm.
    half = len(steps) // 2
    assert abs(np.sum(fused[:half]) - np.sum(measured[:half])) < 0.001
    assert abs(np.sum(fused) - np.sum(measured)) < 0.001
    # Each well-held step keeps nearly all of its own measurement.
    assert np.max(np.abs(fused - measured)) < 0.001


def test_a_poorly_held_step_is_pulled_to_the_speed():
    steps = _speeding_up_and_braking()
    rng = np.random.default_rng(1)
    measured = steps + rng.normal(0.0, 0.0003, steps.shape)
    fit_var = np.full(steps.shape, WELL_HELD)
    # A bump leaving the view at speed: the step 120 mm long, the fit's sigma 10 mm.
    measured[100] += 0.12
    fit_var[100] = 0.01 ** 2
    fused = _drive(measured, fit_var)
    assert abs(fused[100] - steps[100]) < 0.02
    # The steps after it are not carried off by it.
    assert np.max(np.abs(fused[101:] - steps[101:])) < 0.003
    assert abs(np.sum(fused) - np.sum(steps)) < 0.02


def test_after_a_gap_the_step_is_taken_as_measured():
    prior, _ = SpeedPrior().fuse(0.0, DT, 0.25, WELL_HELD)
    # The next step starts later (a stop or a restart between): nothing is predicted.
    prior, along = prior.fuse(2.0, 2.0 + DT, 0.40, 0.01 ** 2)
    assert along == 0.40
    assert prior.stamp == 2.0 + DT and prior.accel == 0.0
