"""The motion over a local ground surface: the road ahead is not the plane under the wheels.

The wheels stand on the ground under the vehicle; the camera sees the ground 2-7 m ahead. On a
grade change, a crest, a bump or a crowned road these differ, and a track taken to lie on the
plane under the wheels biases the motion (DESIGN.md §7). Measured on rendered drives (before
this model): 93 % of the step error on grades was the vehicle's pitch *change* between the
frames (-0.39 of the step per degree), which the planar 3-DoF motion cannot hold; most of the
rest was the surface ahead bending away from the wheel plane.

So the frame pair is explained by (all in base_link of frame 1, whose x-y plane is the plane
through the wheel contacts):

- the planar motion (x, y, yaw) of base_link, as the paper's model;
- the rotation of the vehicle between the frames (roll, pitch), about the wheel contacts
  (a pivot on the ground under base_link: the camera also moves), and the camera's height
  change: the wheels follow the road;
- the road ahead as a quadratic surface hinged at the front axle, ``z = ep u + er y +
  k u^2 / 2 + kxy u y + kyy y^2 / 2`` with ``u = x - hinge``: its grade (ep) and cross-slope
  (er) relative to the wheels, its curvature along (k) and across (kyy) and its twist (kxy).
  The wheels at the hinge stand on it: where the road sags or rises between them (a crown,
  a hill crossed at an angle), the centre line lies ``kyy track^2 / 8`` off the wheel plane.

Each track's ray from camera 1 meets the surface; the point is carried into camera 2 and
compared with where it was seen (the transfer error, normalized coordinates). The metric
scale is still the camera height above the wheel plane: the surface passes through the
wheel contacts' plane at the hinge. Gauss-Newton with analytic derivatives, priors on the
rotation (the body's rate) and on the surface (the last frame pair's, moved on by the travel),
and Cauchy weights: tracks off the smooth surface (a bump's faces, the far side of a crown)
weigh less. Numpy only; no ROS.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from planar_vo.core.errors import PoseEstimationError
from planar_vo.core.geometry.camera import Mounting

__all__ = ['SURFACE_TERMS', 'GroundPrior', 'Hinge', 'LocalGroundResult', 'ray_coefficients',
           'refine_on_local_ground', 'relief_on_rays', 'surface_residuals']

SURFACE_TERMS = ('grade', 'cross_slope', 'curvature', 'twist', 'cross_curvature')
_N = 11  # x, y, yaw, roll, pitch, dh of frame 2, then the five surface terms
_RELIEF_STEPS = 2  # fixed-point steps to where a ray meets a relief (relief_on_rays)
_MIN_SIGMA_PX = 0.05  # residuals below this (px) are not believed: KLT is never better
# Gauss-Newton stops when no term moves more than this (m, rad, 1/m): the reweighting makes
# it converge linearly (halving the step each time), and the last steps below 1e-5 moved the
# 34 rendered drives' t_rel by 0.4 % in sum (none by 0.02) and took 13 evaluations a pair
# instead of about 9.
_CONVERGED = 1e-5


@dataclass(frozen=True)
class Hinge:
    """Where the surface ahead meets the wheels: the front axle, in base_link.

    The body rests on its wheels, not on its centre line. Where the road between the wheels
    sags or rises (a crowned road, a hill crossed at an angle) the surface passes through
    their contacts, ``track`` apart; its height under the centre line is then off the wheel
    plane, which read as a scale error of the step (0.2 % per 0.006 /m of curvature across
    on rendered drives over hills, grades and a crown together).
    """

    x: float  # m ahead of base_link
    track: float = 0.0  # m between the wheels' contacts there (0: a single caster)
    height: float = 0.0  # m the road there lies above the wheel plane (below: a wheel on a bump)
    # The road's height (m) off the surface at base_link points (N, 2): a remembered hump
    # (planar_vo.core.odometry.road_heights), None where the surface holds the road.
    relief: Callable[[np.ndarray], np.ndarray] | None = field(default=None, compare=False)


@dataclass(frozen=True)
class GroundPrior:
    """What is known before the pair: the rotation's spread, the surface's mean and spread."""

    rotation_cov: np.ndarray  # (3, 3) over frame 2's roll, pitch (rad) and height change (m)
    surface: np.ndarray  # (5,) SURFACE_TERMS
    surface_cov: np.ndarray  # (5, 5)


@dataclass
class LocalGroundResult:
    """Motion, rotation and surface after the refinement."""

    motion: np.ndarray  # (3,) x, y, yaw of base_link 2 in base_link 1
    covariance: np.ndarray  # (3, 3) marginal over (x, y, yaw)
    rotation: np.ndarray  # (3,) roll, pitch (rad), height change (m) of frame 2
    measured_rotation: np.ndarray  # (3,) the same without its prior: unbiased, noisier
    surface: np.ndarray  # (5,) SURFACE_TERMS
    surface_cov: np.ndarray  # (5, 5)
    inliers: np.ndarray  # (N,) bool
    weights: np.ndarray  # (N,) the Cauchy weight of each inlier (0 for outliers)
    rms_px: float


# d lifted / d yaw as a map of lifted itself: (q1, -q0, 0).
_YAW_T = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])


class _Transfer:
    """The transfer over the surface for one frame pair, its per-pair terms computed once.

    The ray's quadratic on the surface is linear in the surface terms with coefficients that
    depend on the rays only, and the point in camera 2 and its derivatives are fixed 3x3 maps
    of the ground point ``c1 + s v1``: an evaluation is one (12, 3) @ (3, N) product and a
    few elementwise passes. Gauss-Newton's evaluations were most of the local ground's cost.
    """

    def __init__(self, v1: np.ndarray, m2: np.ndarray, mounting: Mounting, hinge: Hinge):
        """``v1``: (3, N) frame-1 rays in base_link; ``m2``: (2, N) seen in frame 2."""
        self.v1, self.m2 = v1, m2
        self.c1 = mounting.position
        self.above_hinge = self.c1[2] - hinge.height  # the camera's height over the road there
        # A relief off the surface: its height where each ray meets the road, found again
        # from the last evaluation's point at each evaluation (constant in the derivatives).
        self.relief = hinge.relief
        self.relief_height = (None if hinge.relief is None
                              else relief_on_rays(self.c1, v1, hinge.relief))
        self.optical_from_base = mounting.base_from_optical.T
        self.offset = np.zeros(12)  # o = G lifted - optical_from_base c1
        self.offset[:3] = -self.optical_from_base @ self.c1
        self.dA, self.dB, self.dC = ray_coefficients(self.c1, v1, hinge)
        # Buffers every evaluation fills (allocating them was a tenth of its time).
        self.maps = np.empty((12, 3))
        self.do = np.empty((_N, 3, v1.shape[1]))

    def __call__(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Residuals (2, N), Jacobian (11, 2, N) and validity (N,) at ``params``."""
        x, y, yaw, roll, pitch, dh = params[:6].tolist()
        surface = params[6:]
        v1 = self.v1
        A = surface @ self.dA
        B = surface @ self.dB
        B -= v1[2]
        C = surface @ self.dC - self.above_hinge
        s, hit = _ray_roots(A, B, C if self.relief is None else C + self.relief_height)
        if self.relief is not None:
            for _ in range(_RELIEF_STEPS):
                reach = self.c1[:2, None] + np.where(hit, s, 0.0) * v1[:2]
                self.relief_height = np.where(hit, self.relief(reach.T), self.relief_height)
                s, hit = _ray_roots(A, B, C + self.relief_height)
            C = C + self.relief_height
        # ds/dtheta = -(s^2 dA + s dB + dC) / (2 A s + B), theta the surface terms
        ds = self.dA * s
        ds += self.dB
        ds *= s
        ds += self.dC[:, None]
        ds /= -np.where(hit, 2.0 * A * s + B, 1.0)
        # The ground point P = c1 + s v1 in base_link 2 before its rotation is lifted =
        # Y (P - (x, y, dh)), Y the yaw; camera 2 sees o = G lifted - rot c1, G = rot R^T, rot
        # optical_from_base and R = body_tilt(roll, pitch) = Ry Rx, about the contacts.
        c, sn = math.cos(yaw), math.sin(yaw)
        cp, sp, cr, sr = math.cos(pitch), math.sin(pitch), math.cos(roll), math.sin(roll)
        ry_t = np.array([[cp, 0.0, -sp], [0.0, 1.0, 0.0], [sp, 0.0, cp]])
        rx_t = np.array([[1.0, 0.0, 0.0], [0.0, cr, sr], [0.0, -sr, cr]])
        d_ry_t = np.array([[-sp, 0.0, -cp], [0.0, 0.0, 0.0], [cp, 0.0, -sp]])
        d_rx_t = np.array([[0.0, 0.0, 0.0], [0.0, -sr, cr], [0.0, -cr, -sr]])
        yaw_t = np.array([[c, sn, 0.0], [-sn, c, 0.0], [0.0, 0.0, 1.0]])
        rot = self.optical_from_base
        rot_rx = rot @ rx_t
        G = rot_rx @ ry_t
        # Rows: o, then its derivatives by yaw, roll and pitch, each a map of P.
        maps = self.maps
        maps[0:3] = G
        np.matmul(G, _YAW_T, out=maps[3:6])
        np.matmul(rot @ d_rx_t, ry_t, out=maps[6:9])
        np.matmul(rot_rx, d_ry_t, out=maps[9:12])
        maps = maps @ yaw_t
        along = maps @ v1
        out = along * s
        out += (maps @ (self.c1 - np.array([x, y, dh])) + self.offset)[:, None]
        o = out[:3]
        front = (o[2] > 1e-9) & hit
        iz = np.divide(1.0, o[2], out=np.zeros_like(o[2]), where=front)
        m = o[:2] * iz
        do = self.do
        d_point = maps[:3]  # d o / d P: x and y move P by minus one, dh lifts it
        do[0] = -d_point[:, 0:1]
        do[1] = -d_point[:, 1:2]
        do[2:5] = out[3:].reshape(3, 3, -1)
        do[5] = -d_point[:, 2:3]
        np.multiply(ds[:, None, :], along[:3], out=do[6:])
        J = np.multiply(do[:, 2:3], m)
        np.subtract(do[:, :2], J, out=J)
        J *= iz
        return m - self.m2, J, front


def _arc_terms(params: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Information (11, 11) and gradient (11,) that hold base_link to its circular arc.

    Within ``sigma`` m: the constraint ``y = x tan(yaw / 2)`` (:func:`~planar_vo.core.
    geometry.se2.off_arc`), linearized at ``params``.
    """
    x, y, yaw = params[:3]
    half = math.tan(yaw / 2.0)
    jac = np.zeros(_N)
    jac[:3] = (-half, 1.0, -x * (1.0 + half * half) / 2.0)
    return np.outer(jac, jac) / sigma ** 2, jac * (y - x * half) / sigma ** 2


def _ray_roots(A: np.ndarray, B: np.ndarray, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The near root ``s`` (N,) of ``A s^2 + B s + C = 0`` in front of the ray, and where any."""
    disc = B * B
    disc -= 4.0 * A * C
    hit = (disc > 0.0) & (B > 1e-9)
    root = np.sqrt(np.where(hit, disc, 1.0))
    s = np.where(hit, -2.0 * C / np.where(hit, B + root, 1.0), 0.0)
    return s, hit & (s > 0.0)


def relief_on_rays(origin: np.ndarray, directions: np.ndarray,
                    relief: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """The ``relief`` (N,) where each ray (3, N) from ``origin`` meets the road it describes.

    Found by fixed-point steps from the wheel plane (the relief is centimetres, the rays
    meet the road at 10-40 deg: the point moves by centimetres a step).
    """
    down = np.maximum(-directions[2], 1e-6)
    height = np.zeros(directions.shape[1])
    for _ in range(_RELIEF_STEPS):
        reach = (origin[2] - height) / down
        height = relief((origin[:2, None] + reach * directions[:2]).T)
    return height


def ray_coefficients(origin: np.ndarray, directions: np.ndarray,
                     hinge: Hinge) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the rays ``origin + s directions`` ((3,), (3, N)) meet the surface.

    ``A s^2 + B s + C = 0`` with A, B and C (dA (5, N), dB (5, N), dC (5,)) dotted with the
    surface terms (B less the directions' z, C less the origin's height). The curvature
    across is ``kyy (y^2 - track^2 / 4) / 2``: naught at the wheels' contacts.
    """
    a, cy = origin[0] - hinge.x, origin[1]
    dx, dy = directions[0], directions[1]
    zero = np.zeros_like(dx)
    return (np.stack([zero, zero, 0.5 * dx * dx, dx * dy, 0.5 * dy * dy]),
            np.stack([dx, dy, a * dx, a * dy + cy * dx, cy * dy]),
            np.array([a, cy, 0.5 * a * a, a * cy, 0.5 * cy * cy - hinge.track ** 2 / 8]))


def surface_residuals(params: np.ndarray, v1: np.ndarray, m2: np.ndarray, mounting: Mounting,
                      hinge: Hinge) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residuals (2, N), Jacobian (11, 2, N) and validity (N,) of the transfer over the surface.

    Args:
        params: (11,) x, y, yaw; roll, pitch, height change of frame 2; SURFACE_TERMS.
        v1: (3, N) frame-1 ray directions in base_link.
        m2: (2, N) observed frame-2 normalized image coordinates.
        mounting: camera 1 in base_link 1 (camera 2 is it after the motion and rotation).
        hinge: where the surface leaves the wheel plane (the front axle).
    """
    return _Transfer(v1, m2, mounting, hinge)(params)


def refine_on_local_ground(
    motion: np.ndarray, v1: np.ndarray, m2: np.ndarray, mounting: Mounting,
    prior: GroundPrior, *, focal_px: float, threshold_px: float, hinge: Hinge,
    start_threshold_px: float | None = None, cauchy: float = 1.0, iterations: int = 8,
    arc_sigma: float | None = None,
) -> LocalGroundResult:
    """Gauss-Newton over (motion, frame-2 rotation, surface) with priors and Cauchy weights.

    The inliers are chosen again at every step, the threshold halving from
    ``start_threshold_px`` (a jolt moves every point off the start) down to ``threshold_px``.
    Each inlier weighs ``1 / (1 + (r / (cauchy sigma))^2)``, sigma the inliers' noise.

    Args:
        motion: (3,) starting motion (RANSAC's).
        v1: (N, 3) frame-1 ray directions in base_link.
        m2: (N, 2) observed frame-2 normalized coordinates.
        arc_sigma: if given, base_link is held to the circular arc of its x and yaw within
            this many metres (a prior: wheels roll, they do not slide); None: free.

    Raises:
        PoseEstimationError: fewer than 3 correspondences fit.
    """
    v1_t = np.ascontiguousarray(v1.T, dtype=float)
    m2_t = np.ascontiguousarray(m2.T, dtype=float)
    params = np.concatenate([motion, np.zeros(3), prior.surface])
    info = np.zeros((_N, _N))
    info[3:6, 3:6] = np.linalg.inv(prior.rotation_cov)
    info[6:, 6:] = np.linalg.inv(prior.surface_cov)
    mean = np.concatenate([np.zeros(6), prior.surface])
    floor2 = (_MIN_SIGMA_PX / focal_px) ** 2
    wide = max(threshold_px, start_threshold_px or threshold_px)
    iterations += int(np.ceil(np.log2(wide / threshold_px)))
    inliers = np.zeros(len(v1), bool)
    arc_info = np.zeros((_N, _N))
    transfer = _Transfer(v1_t, m2_t, mounting, hinge)
    for i in range(iterations + 1):
        threshold = max(threshold_px, wide * 0.5 ** i)
        r, J, front = transfer(params)
        squared = r[0] * r[0] + r[1] * r[1]
        selected = front & (squared < (threshold / focal_px) ** 2)
        changed = not np.array_equal(selected, inliers)
        inliers = selected
        count = int(np.count_nonzero(inliers))
        if count < 3:
            raise PoseEstimationError(f'only {count} correspondences fit the local ground')
        sigma2 = max(float(squared[inliers].sum()) / max(2 * count - _N, 1), floor2)
        weights = inliers / (1.0 + squared / (cauchy * cauchy * sigma2))
        J_w = (J * weights).reshape(_N, -1)
        H = J_w @ J.reshape(_N, -1).T / sigma2 + info
        g = J_w @ r.reshape(-1) / sigma2 + info @ (params - mean)
        if arc_sigma is not None:
            arc_info, arc_gradient = _arc_terms(params, arc_sigma)
            H = H + arc_info
            g = g + arc_gradient
        if i == iterations:
            break
        step = -np.linalg.solve(H, g)
        params = params + step
        if np.max(np.abs(step)) < _CONVERGED and not changed and threshold == threshold_px:
            break
    # The weighted fit's covariance, the sandwich of an M-estimator: the weights lower the
    # information the data give, and lower the noise that reaches the estimate as much.
    bread = np.linalg.inv(H)
    J_ww = (J * weights * weights).reshape(_N, -1)
    covariance = bread @ (J_ww @ J.reshape(_N, -1).T / sigma2 + info + arc_info) @ bread
    rms = focal_px * float(np.sqrt(squared[inliers].mean()))
    # The rotation's prior (the body's rate) pulls every rotation towards none: summed over a
    # second of a hill it comes up short by 5-20 %. One Newton step without it undoes that.
    rotation_prior = np.zeros((_N, _N))
    rotation_prior[3:6, 3:6] = info[3:6, 3:6]
    measured = params + np.linalg.solve(H - rotation_prior, rotation_prior @ (params - mean))
    return LocalGroundResult(params[:3].copy(), covariance[:3, :3].copy(), params[3:6].copy(),
                             measured[3:6], params[6:].copy(), covariance[6:, 6:].copy(),
                             inliers, weights, rms)
