"""A planar constant-velocity EKF, as a user would fuse planar_vo's twist (tests only).

State: pose (x, y, yaw) in odom and body twist (vx, vy, yaw rate). The twist is a random
walk driven by white acceleration noise; measurements are body twists with a covariance.
"""

import numpy as np

from planar_vo.core.geometry.se2 import compose, twist_motion


class PlanarEkf:
    def __init__(self, acceleration_psd, twist, twist_covariance):
        """``acceleration_psd`` (3,): white-noise spectral density of d(twist)/dt."""
        self.q = np.asarray(acceleration_psd, dtype=float)
        self.x = np.r_[np.zeros(3), twist]
        self.P = np.zeros((6, 6))
        self.P[:3, :3] = np.eye(3) * 1e-12
        self.P[3:, 3:] = twist_covariance

    def predict(self, dt):
        """Move on by ``dt`` at the twist at the middle of the step."""
        twist = self.x[3:]
        motion = twist_motion(twist, dt)
        # d motion / d twist, numerically (a test helper: clarity over speed)
        J = np.empty((3, 3))
        for i in range(3):
            h = np.zeros(3)
            h[i] = 1e-6
            J[:, i] = (twist_motion(twist + h, dt) - twist_motion(twist - h, dt)) / 2e-6
        pose, _ = compose(self.x[:3], np.zeros((3, 3)), motion, np.zeros((3, 3)))
        c, s = np.cos(self.x[2]), np.sin(self.x[2])
        F = np.eye(6)
        F[0, 2], F[1, 2] = -s * motion[0] - c * motion[1], c * motion[0] - s * motion[1]
        F[:3, 3:] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ J
        Q = np.zeros((6, 6))
        # white acceleration over dt: the twist walks, the pose integrates it
        R = F[:3, 3:]
        Qa = np.diag(self.q)
        Q[3:, 3:] = Qa * dt
        Q[:3, 3:] = R @ Qa * dt / 2
        Q[3:, :3] = Q[:3, 3:].T
        Q[:3, :3] = R @ Qa @ R.T * dt / 3
        self.x = np.r_[pose, twist]
        self.P = F @ self.P @ F.T + Q

    def update_twist(self, z, R, axes=(0, 1, 2)):
        """Fuse a measurement of the twist components ``axes`` with covariance ``R``."""
        axes = list(axes)
        H = np.zeros((len(axes), 6))
        H[np.arange(len(axes)), 3 + np.array(axes)] = 1.0
        S = H @ self.P @ H.T + R
        K = self.P @ H.T @ np.linalg.inv(S)
        self.x = self.x + K @ (np.asarray(z) - H @ self.x)
        self.x[2] = (self.x[2] + np.pi) % (2 * np.pi) - np.pi
        I_KH = np.eye(6) - K @ H
        self.P = I_KH @ self.P @ I_KH.T + K @ R @ K.T
