"""Online self-calibration of the static camera mounting from the drive (DESIGN.md §6).

What a nonholonomic vehicle's drive tells about where its camera sits:

- pitch, roll: the mean of the camera's tracked tilt to the ground (the body moves around it);
- yaw: the rear axle moves along base_link x, so a mounting yaw off by ``eta`` shows as a
  sideways slip of ``rho * eta`` per step of length ``rho``;
- camera_x: a camera placed ``dx`` wrong slips sideways by ``-yaw * dx`` per step that turns
  by ``yaw`` (only turns tell);
- camera_height: not from vision alone (it is the scale); see ``planar_vo_calibrate
  --known-distance``.

Sideways slip is measured against the circular motion of the axle: the component of each
step's translation across its chord (the direction at half its yaw). The slip is linear in
(eta, dx), so they come from a weighted least-squares line fit whose normal equations are kept
as they accumulate; a correction applied to the working mounting is subtracted from them, so
the fit keeps all the drive's evidence. Numpy only; no ROS.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planar_vo.core.estimation.attitude import tilted_mounting
from planar_vo.core.geometry.camera import Mounting

__all__ = ['MountingCalibrator', 'MountingEstimate', 'mounting_advice', 'calibrated_params']

# Body tilt samples are correlated over about this long (suspension and road), s: the
# standard deviation of the mean tilt counts one independent sample per interval.
_TILT_CORRELATION_S = 1.0
# A yaw or camera_x correction is applied to the working mounting once known this well.
_APPLY_YAW_STD, _APPLY_X_STD = np.radians(0.15), 0.03
_SIGNIFICANT = 3.0  # ... and this many standard deviations from none
# The slip fit counts its steps as independent, but a body swaying on its springs (its roll
# moves the camera sideways) keeps the slip off one way for a second or more: in the first
# seconds of a drive the fit was surer of a yaw than it was (a rendered sprung car: -0.2 deg
# applied at 0.8 s, the camera's yaw exact; it stayed at -0.05 deg, -1 mm a metre sideways).
# So a correction must stand out from none by _SIGNIFICANT standard deviations taken
# sqrt(1 + _SLIP_SETTLE_S / t) times larger, t the fit's seconds of steps (a camera 1 deg off
# still stands out at once). Stop 56, 80 rendered drives 19.058 -> 18.690 % t_rel summed (flat
# sprung seed 60 0.136 -> 0.085, seed 1 0.088 -> 0.052, grades sprung 0.102 -> 0.058; a rigid
# mounting 1 deg off over all four terrains 0.137 -> 0.163, sprung 0.248 -> 0.264); eight
# rendered after the choice 1.298 -> 1.245 (flat sprung seed 77 0.117 -> 0.073, all four
# sprung 0.261 -> 0.234; three mountings 1 deg off 0.116 / 0.142 / 0.239 -> 0.147 / 0.154 /
# 0.260).
_SLIP_SETTLE_S = 2.0
# Users are told to change a parameter once the drive says it is this far off, and knows
# it to a third of that (rad, m).
_ADVICE = {'camera_pitch': np.radians(0.5), 'camera_roll': np.radians(0.5),
           'camera_yaw': np.radians(0.5), 'camera_x': 0.1}


def calibrated_params(mounting: Mounting) -> dict[str, float]:
    """The ``camera_*`` parameters self-calibration learns, as ``mounting`` has them."""
    return {'camera_roll': mounting.roll, 'camera_pitch': mounting.pitch,
            'camera_yaw': mounting.yaw, 'camera_x': mounting.x}


@dataclass(frozen=True)
class MountingEstimate:
    """The mounting learned so far, each value with its standard deviation.

    A standard deviation of ``inf`` means the drive has not determined that value yet (no
    turn: camera_x); the configured value is then kept.
    """

    mounting: Mounting
    std: dict[str, float]  # camera_roll, camera_pitch, camera_yaw (rad), camera_x (m)
    seconds: float  # driving time that went into it

    def as_params(self) -> dict[str, float]:
        """The estimate as ``camera_*`` parameter values."""
        return calibrated_params(self.mounting)


class MountingCalibrator:
    """Accumulates the evidence of one drive about the static mounting."""

    def __init__(self, configured: Mounting) -> None:
        self.configured = configured
        self.working = configured  # configured, with the yaw and x corrections applied
        self._tilt_sum = np.zeros(2)
        self._tilt_sq = np.zeros(2)
        self._tilt_time = 0.0
        self._normal = np.zeros((2, 2))  # slip fit: sum phi phi^T / var
        self._rhs = np.zeros(2)
        self._chi2, self._samples = 0.0, 0
        self._slip_time = 0.0  # s of steps in the slip fit

    def tilt_std(self, correlation_s: float = 1.0) -> np.ndarray:
        """Standard deviation (2,) of :attr:`mean_tilt`; inf before any sample.

        The samples are taken as correlated over ``correlation_s`` (one independent sample
        per interval).
        """
        if self._tilt_time <= 0:
            return np.full(2, np.inf)
        spread = np.sqrt(np.maximum(self._tilt_sq / self._tilt_time - self.mean_tilt ** 2, 0.0))
        return spread / np.sqrt(max(self._tilt_time / correlation_s, 1.0))

    @property
    def mean_tilt(self) -> np.ndarray:
        """Mean (roll, pitch) of the camera's tilt to the ground so far, rad."""
        return self._tilt_sum / self._tilt_time if self._tilt_time > 0 else np.zeros(2)

    def add(self, motion: np.ndarray, motion_cov: np.ndarray, tilt: np.ndarray | None,
            dt: float) -> None:
        """One estimated step: base_link motion (through :attr:`working`), frame-2 tilt.

        ``motion_cov``: the step's covariance as one of a run of steps whose errors are
        correlated (consecutive pairs share their tracks): taken as independent, the fit was
        sure of a yaw that was noise. ``tilt`` None: the step says nothing about the tilt
        (only about yaw and camera_x).
        """
        # Arrays are replaced, never changed in place: VisualOdometry.process restores the
        # attributes when a frame fails half-way.
        if tilt is not None:
            self._tilt_sum = self._tilt_sum + tilt[:2] * dt
            self._tilt_sq = self._tilt_sq + tilt[:2] ** 2 * dt
            self._tilt_time += dt
        x, y, yaw = motion
        c, s = np.cos(yaw / 2), np.sin(yaw / 2)
        rho, slip = c * x + s * y, -s * x + c * y
        if abs(rho) < 1e-3:
            return
        grad = np.array([-s, c, -0.5 * rho])
        variance = max(float(grad @ motion_cov @ grad), 1e-12)
        phi = np.array([rho, -yaw])
        self._normal = self._normal + np.outer(phi, phi) / variance
        self._rhs = self._rhs + phi * slip / variance
        self._chi2 += slip * slip / variance
        self._samples += 1
        self._slip_time += dt

    def _slip_fit(self) -> tuple[np.ndarray, np.ndarray]:
        """(eta, dx) and their covariance; inf where the drive does not determine them."""
        normal = self._normal
        if self._samples < 3 or np.linalg.cond(normal) > 1e12:
            std = np.sqrt(1.0 / np.maximum(np.diag(normal), 1e-300))
            if normal[0, 0] > 0:  # yaw alone (a straight drive)
                eta = self._rhs[0] / normal[0, 0]
                return np.array([eta, 0.0]), np.diag([std[0] ** 2, np.inf])
            return np.zeros(2), np.diag([np.inf, np.inf])
        cov = np.linalg.inv(normal)
        theta = cov @ self._rhs
        # Body motion and road make the slip noisier than the pixel noise alone says:
        # scale the covariance by the fit's own dispersion when it is larger.
        dof = max(self._samples - 2, 1)
        chi2 = max(self._chi2 - float(theta @ self._rhs), 0.0)
        return theta, cov * max(1.0, chi2 / dof)

    def apply(self) -> bool:
        """Move what is well determined into :attr:`working`; True if it changed."""
        theta, cov = self._slip_fit()
        std = np.sqrt(np.diag(cov))
        settled = std * np.sqrt(1.0 + _SLIP_SETTLE_S / max(self._slip_time, 1e-3))
        applied = np.zeros(2)
        # Known well enough, and told apart from no correction at all: a mounting that is
        # right is left alone (applying its noise cost 0.032 -> 0.040 % t_rel on a flat drive).
        if std[0] < _APPLY_YAW_STD and abs(theta[0]) > _SIGNIFICANT * settled[0]:
            applied[0] = theta[0]
        if std[1] < _APPLY_X_STD and abs(theta[1]) > _SIGNIFICANT * settled[1]:
            applied[1] = theta[1]
        if not np.any(np.abs(applied) > 1e-6):
            return False
        m = self.working
        self.working = Mounting(x=m.x - applied[1], y=m.y, height=m.height, roll=m.roll,
                                pitch=m.pitch, yaw=m.yaw - applied[0])
        self._rhs = self._rhs - self._normal @ applied
        # The slips already seen, had the new mounting been used, fit it by construction.
        self._chi2 = max(self._chi2 - 2 * float(applied @ (self._rhs + self._normal @ applied))
                         + float(applied @ self._normal @ applied), 0.0)
        return True

    def applied_covariance(self) -> np.ndarray:
        """Covariance (2, 2) of the working yaw (rad) and camera_x (m) where they were applied.

        The fit's spread and what it still finds off, not yet applied (its mean square: on
        rendered drives with the mounting 1 deg off, 0.1 deg of yaw stayed for 7 s, the
        sideways speed 0.01 m/s off for a spread of 0.004). Zero for what is still the
        configured value (taken as exact, as everywhere else).
        """
        theta, cov = self._slip_fit()
        applied = np.array([self.working.yaw != self.configured.yaw,
                            self.working.x != self.configured.x])
        if not np.any(applied):
            return np.zeros((2, 2))
        cov = np.where(np.outer(applied, applied), cov + np.outer(theta, theta), 0.0)
        return np.where(np.isfinite(cov), cov, 0.0)

    def step(self, motion: np.ndarray, motion_cov: np.ndarray, tilt: np.ndarray | None,
             dt: float) -> tuple[Mounting | None, np.ndarray]:
        """:meth:`add` then :meth:`apply`; (new working mounting or None, covariance (3, 3)).

        The covariance is what the corrections applied so far add to ``motion``.

        What self-calibration applied is known only so well: a yaw off by eta moves the step
        sideways by x * eta (and rotates it), a camera_x off by dx by -yaw * dx. Right for one
        step (the twist); the pose, which adds the steps as if their errors were nearly
        independent, still undercounts this persistent one.
        """
        self.add(motion, motion_cov, tilt, dt)
        working = self.working if self.apply() else None
        x, y, yaw = motion
        J = np.array([[-y, 0.0], [x, -yaw], [0.0, 0.0]])
        return working, J @ self.applied_covariance() @ J.T

    def estimate(self) -> MountingEstimate:
        """The static mounting learned so far."""
        theta, cov = self._slip_fit()
        m = self.working
        with_slip = Mounting(x=m.x - theta[1], y=m.y, height=m.height, roll=m.roll,
                             pitch=m.pitch, yaw=m.yaw - theta[0])
        tilt = self.mean_tilt
        mounting = tilted_mounting(with_slip, np.array([tilt[0], tilt[1], 0.0]))
        tilt_std = self.tilt_std(_TILT_CORRELATION_S) + np.radians(0.01)
        std = {'camera_roll': float(tilt_std[0]), 'camera_pitch': float(tilt_std[1]),
               'camera_yaw': float(np.sqrt(cov[0, 0])), 'camera_x': float(np.sqrt(cov[1, 1]))}
        if not np.isfinite(std['camera_x']):
            mounting = Mounting(x=self.configured.x, y=mounting.y, height=mounting.height,
                                roll=mounting.roll, pitch=mounting.pitch, yaw=mounting.yaw)
        return MountingEstimate(mounting, std, self._tilt_time)


def mounting_advice(configured: Mounting, estimate: MountingEstimate) -> dict[str, str]:
    """One line per parameter the drive says is off (> 0.5 deg, > 0.1 m): what to set."""
    advice = {}
    now = calibrated_params(configured)
    for name, value in estimate.as_params().items():
        off, std = value - now[name], estimate.std[name]
        if abs(off) <= _ADVICE[name] or not std < _ADVICE[name] / 3:
            continue
        if name == 'camera_x':
            detail = f'{now[name]:.3f} m but the drive says {value:.3f} +- {std:.3f} m'
        else:
            detail = (f'{np.degrees(now[name]):.2f} deg but the drive says '
                      f'{np.degrees(value):.2f} +- {np.degrees(std):.2f} deg')
        advice[name] = (f'{name} is configured as {detail}: set {name}: {value:.4f} '
                        '(or run planar_vo_calibrate on a recorded drive)')
    return advice
