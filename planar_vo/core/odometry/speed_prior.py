"""A vehicle's speed cannot jump between frames: each step weighed against the one predicted.

On uneven road a pair can be poorly held: at car speeds a speed bump leaving the bottom of
the view takes the near tracks with it, every track left lies beyond it, and the fit trades
the road's grade there against the step (rendered all-four drives at 8-14 m/s: steps 10-25 %
long, +73 to +130 mm in a pair, while the car's speed changed by 0.3 %). The fit's own
variance rises there, 10-20 times, so each step along the path is fused with the step the
last speed and acceleration predict, by their variances; a well-held pair keeps about 96 %
of its own step. Only the step along base_link x: sideways and in yaw a car's motion is
not as smooth (a steering wheel turns faster than a car speeds up). Numpy only; no ROS.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ['SpeedPrior']

# How far the acceleration may change unpredicted over a pair, m/s^2 (one sigma): a car's
# jerk is a few m/s^3. The rendered drives change it by up to 3 m/s^2 over 2-3 s. Six
# rendered drives at 8-14 m/s summed 1.239 -> 0.916 % t_rel at 2 (3: 0.884, 5: 0.980; 2 was
# chosen on four more at 3-8 m/s, rigid ones among them); at 3-8 m/s, 80 drives 18.690 ->
# 18.603 (within +-0.02 each but six).
_ACCEL_CHANGE = 2.0
# The fit's own step variance is taken _FIT_SPREAD times larger, and at least _STEP_FLOOR_M:
# on rendered rigid drives a pair's error is 1.7 times the fit's sigma (0.2 mm), on sprung
# bodies 10-14 times (2 mm: the body's bounce changes the scale), on the poorly held pairs at
# speed 7-16 times (4.5-11 mm of sigma for +73 to +130 mm).
_FIT_SPREAD = 3.0
_STEP_FLOOR_M = 0.001
# s: the acceleration followed over this long (the speed's change between pairs, averaged).
# Without it a car speeding up lags its prediction, and the steps held back cost the flat
# rigid drives 0.021 -> 0.034 % t_rel.
_ACCEL_MEMORY_S = 0.25


@dataclass(frozen=True)
class SpeedPrior:
    """The speed along base_link x (m/s) after the last step, its variance and acceleration.

    ``stamp``: when that step ended (None: no step yet). Replaced, never changed in place.
    """

    stamp: float | None = None
    speed: float = 0.0
    speed_var: float = 0.0
    accel: float = 0.0

    def fuse(self, start: float, stamp: float, step: float,
             fit_var: float) -> tuple[SpeedPrior, float]:
        """Self after the step from ``start`` to ``stamp`` (s), and the step to take (m).

        ``step``: the pair's along base_link x (m), ``fit_var``: its fit's variance (m^2).
        Only a step that follows the last one (it starts where that ended) is predicted.
        """
        dt = stamp - start
        measured_var = _FIT_SPREAD ** 2 * fit_var + _STEP_FLOOR_M ** 2
        if dt <= 0.0:
            return self, step
        if self.stamp is None or self.stamp != start:
            return SpeedPrior(stamp, step / dt, measured_var / dt ** 2, 0.0), step
        predicted = (self.speed + self.accel * dt) * dt
        predicted_var = (_ACCEL_CHANGE * dt * dt) ** 2 + self.speed_var * dt * dt
        gain = predicted_var / (predicted_var + measured_var)
        fused = predicted + gain * (step - predicted)
        fused_var = gain * measured_var
        speed = fused / dt
        alpha = min(dt / _ACCEL_MEMORY_S, 1.0)
        accel = self.accel + alpha * ((speed - self.speed) / dt - self.accel)
        return SpeedPrior(stamp, speed, fused_var / dt ** 2, accel), fused
