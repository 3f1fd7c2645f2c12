"""The paper's Monte Carlo experiment (Choi et al., URAI 2010, section 4), and its future work.

A level camera (K of paper eq. 21) 1.5 m above the ground moves by ``[rho, phi, theta] =
[1.5, 0.39, 0.78]`` (eq. 20, a circular motion: ``theta = 2 phi``). Every trial draws random
ground points seen in both images, adds Gaussian pixel noise to both, and gives the *same*
correspondences to every solver:

- the paper's four: reduced essential matrix 1-point and 2-point, reduced ground
  homography 1-point and 2-point (:mod:`planar_vo.core.geometry.solvers`);
- what the paper leaves as future work: the 6-DoF baselines of OpenCV, five-point essential
  matrix (``findEssentialMat`` + ``recoverPose``) and four-point homography
  (``findHomography`` + ``decomposeHomographyMat``), on minimal sets and on 50 points, and
  the paper's homography in least squares over the same 50 points.

Point ``i`` of a trial is the same for every solver: 1-point solvers take point 0, 2-point
solvers points 0-1, and so on. Geometry and unit noise are drawn once per trial from the
seed and scaled by each sigma, so a given (seed, trial, sigma) always gives the same data,
whatever other sigmas are run. Numpy and OpenCV; matplotlib only for ``--plot``.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from planar_vo.core.geometry.solvers import (
    essential_1point,
    essential_2point,
    essential_select,
    homography_1point,
    homography_2point,
    homography_npoint,
)
from planar_vo.tools.cli import Parser, fail, non_negative_int, number_list, positive_int
from planar_vo.tools.plots import pyplot

__all__ = ['SETUP', 'SOLVERS', 'Trials', 'make_trials', 'estimate_all', 'run_experiment',
           'format_table', 'plot_fig5', 'main']

PROG = 'planar_vo_paper_experiment'
K = np.array([[100.0, 0.0, 320.0], [0.0, 100.0, 240.0], [0.0, 0.0, 1.0]])  # paper eq. 21
IMAGE_SIZE = (640, 480)
HEIGHT = 1.5  # d, metres
TRUE_MOTION = {'rho': 1.5, 'phi': 0.39, 'theta': 0.78}  # paper eq. 20
POINTS = 50  # correspondences per trial (the largest set any solver uses)
# Ground points are drawn uniformly in this rectangle of camera 1's ground (X right, Z
# forward, metres; the paper does not say): where a vehicle's camera tracks ground features.
# Farther points carry less translation and hurt the 2-, 4- and 5-point solvers most.
GROUND_X = (-5.0, 5.0)
GROUND_Z = (0.0, 10.0)
# Both OpenCV robust estimators see only inliers; a wide threshold keeps every noisy point in,
# so they end in (near) least squares on all 50 points.
CV_THRESHOLD_PX = 3.0
DEFAULT_SIGMAS = (0.0, 0.5, 1.0, 1.5, 2.0)
DEFAULT_TRIALS = 1000
DEFAULT_SEED = 0

SETUP = {
    'K': K.tolist(),
    'image_size': list(IMAGE_SIZE),
    'camera_height_m': HEIGHT,
    'motion': dict(TRUE_MOTION),
    'points_per_trial': POINTS,
    'ground_region_m': {'x': list(GROUND_X), 'z': list(GROUND_Z)},
    'cv_threshold_px': CV_THRESHOLD_PX,
}


def _r12_t2() -> tuple[np.ndarray, np.ndarray]:
    """True ``R12`` and ``T2`` (``x2 = R12 x1 + T2``), from the paper's eq. 1 and 4."""
    theta, phi, rho = TRUE_MOTION['theta'], TRUE_MOTION['phi'], TRUE_MOTION['rho']
    c, s = math.cos(theta), math.sin(theta)
    r21 = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    t1 = rho * np.array([math.sin(phi), 0.0, math.cos(phi)])
    r12 = r21.T
    return r12, -r12 @ t1


@dataclass(frozen=True)
class Trials:
    """Noise-free pixels of every trial and unit pixel noise to scale by sigma."""

    pixels1: np.ndarray  # (trials, POINTS, 2)
    pixels2: np.ndarray  # (trials, POINTS, 2)
    noise1: np.ndarray  # (trials, POINTS, 2), standard normal
    noise2: np.ndarray

    def rays(self, sigma: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Noisy pixels and their rays ``K^-1 [u, v, 1]`` for both images."""
        p1 = self.pixels1 + sigma * self.noise1
        p2 = self.pixels2 + sigma * self.noise2
        return p1, p2, _pixels_to_rays(p1), _pixels_to_rays(p2)


def _pixels_to_rays(pixels: np.ndarray) -> np.ndarray:
    rays = np.empty(pixels.shape[:-1] + (3,))
    rays[..., 0] = (pixels[..., 0] - K[0, 2]) / K[0, 0]
    rays[..., 1] = (pixels[..., 1] - K[1, 2]) / K[1, 1]
    rays[..., 2] = 1.0
    return rays


def _project(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of camera-frame points, and whether they are in front and inside the image."""
    z = points[..., 2]
    safe = np.where(z > 1e-9, z, 1.0)
    u = K[0, 0] * points[..., 0] / safe + K[0, 2]
    v = K[1, 1] * points[..., 1] / safe + K[1, 2]
    inside = (z > 1e-9) & (u >= 0) & (u < IMAGE_SIZE[0]) & (v >= 0) & (v < IMAGE_SIZE[1])
    return np.stack([u, v], axis=-1), inside


def make_trials(trials: int, seed: int) -> Trials:
    """Random ground points visible in both images, ``POINTS`` per trial, deterministic."""
    rng = np.random.default_rng(seed)
    r12, t2 = _r12_t2()
    chosen = np.empty((trials, POINTS, 3))
    for i in range(trials):
        found: list[np.ndarray] = []
        count = 0
        while count < POINTS:
            xz = rng.uniform((GROUND_X[0], GROUND_Z[0]), (GROUND_X[1], GROUND_Z[1]), (200, 2))
            pts = np.stack([xz[:, 0], np.full(len(xz), HEIGHT), xz[:, 1]], axis=1)
            ok = _project(pts)[1] & _project(pts @ r12.T + t2)[1]
            found.append(pts[ok])
            count += int(np.count_nonzero(ok))
        chosen[i] = np.concatenate(found)[:POINTS]
    pixels1 = _project(chosen)[0]
    pixels2 = _project(chosen @ r12.T + t2)[0]
    noise = rng.standard_normal((2, trials, POINTS, 2))
    return Trials(pixels1, pixels2, noise[0], noise[1])


# --- Solvers: each maps one trial's (pixels1, pixels2, rays1, rays2) to (theta, phi, rho).
# rho is NaN where the model has no scale. Only the solve is timed, not the conversion.

Estimate = tuple[float, float, float]
NAN = float('nan')


def _essential_1pt(p1: np.ndarray, p2: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> Estimate:
    """Paper eq. 16 on point 0; the root is chosen by cheirality over all the trial's points."""
    phi = essential_1point(x1[0], x2[0])
    theta, phi = essential_select(2.0 * phi, phi, x1, x2)
    return theta, phi, NAN


def _essential_2pt(p1: np.ndarray, p2: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> Estimate:
    """Paper eq. 12-15 on points 0-1; root and sign chosen over all the trial's points."""
    theta, phi = essential_2point(x1[:2], x2[:2])
    theta, phi = essential_select(theta, phi, x1, x2)
    return theta, phi, NAN


def _homography_1pt(p1: np.ndarray, p2: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> Estimate:
    m = homography_1point(x1[0], x2[0])
    return float(m.theta), float(m.phi), float(m.rho) * HEIGHT


def _homography_2pt(p1: np.ndarray, p2: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> Estimate:
    m = homography_2point(x1[:2], x2[:2])
    return float(m.theta), float(m.phi), float(m.rho) * HEIGHT


def _homography_npt(p1: np.ndarray, p2: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> Estimate:
    m = homography_npoint(x1, x2)
    return float(m.theta), float(m.phi), float(m.rho) * HEIGHT


def _from_cv_pose(r12: np.ndarray, t2: np.ndarray, scale: float) -> Estimate:
    """OpenCV's ``x2 = R x1 + t`` (R = R12, t = T2) → paper (theta, phi, rho).

    ``R12 = Ry(theta)^T``; for a 6-DoF estimate the closest rotation about y is taken.
    ``T1 = -R12^T T2`` is camera 2's position in camera 1.
    """
    theta = math.atan2(r12[2, 0] - r12[0, 2], r12[0, 0] + r12[2, 2])
    t1 = -r12.T @ np.asarray(t2, dtype=float).ravel() * scale
    return theta, math.atan2(t1[0], t1[2]), float(np.linalg.norm(t1))


def _sampson(E: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> float:
    Ex1, Etx2 = x1 @ E.T, x2 @ E
    num = np.einsum('ni,ni->n', x2, Ex1) ** 2
    den = Ex1[:, 0] ** 2 + Ex1[:, 1] ** 2 + Etx2[:, 0] ** 2 + Etx2[:, 1] ** 2
    return float(np.sum(num / np.maximum(den, 1e-300)))


def _recover(E: np.ndarray, p1: np.ndarray, p2: np.ndarray, x1: np.ndarray,
             x2: np.ndarray) -> Estimate:
    """Pick the root of the stacked ``E`` that fits all points best, then its cheiral pose."""
    roots = [E[i:i + 3] for i in range(0, E.shape[0] - 2, 3)]
    best = min(roots, key=lambda e: _sampson(e, x1, x2))
    _, R, t, _ = cv2.recoverPose(best, p1, p2, K)
    theta, phi, _ = _from_cv_pose(R, t, 1.0)
    return theta, phi, NAN


def _cv_essential_5pt(p1: np.ndarray, p2: np.ndarray, x1: np.ndarray,
                      x2: np.ndarray) -> Estimate:
    """Nister's 5-point on points 0-4; OpenCV returns every root, the other points choose.

    With exactly five points ``findEssentialMat``'s RANSAC runs the minimal solver once and
    returns all its roots stacked (3k x 3).
    """
    E, _ = cv2.findEssentialMat(p1[:5], p2[:5], K, method=cv2.RANSAC, prob=0.999,
                                threshold=CV_THRESHOLD_PX)
    if E is None or E.shape[0] < 3:
        return NAN, NAN, NAN
    return _recover(E, p1, p2, x1, x2)


def _cv_essential_usac(p1: np.ndarray, p2: np.ndarray, x1: np.ndarray,
                       x2: np.ndarray) -> Estimate:
    """5-point USAC (local optimisation and least-squares polish) on all 50 points."""
    E, _ = cv2.findEssentialMat(p1, p2, K, method=cv2.USAC_ACCURATE, prob=0.999,
                                threshold=CV_THRESHOLD_PX)
    if E is None or E.shape[0] < 3:
        return NAN, NAN, NAN
    return _recover(E, p1, p2, x1, x2)


def _decompose(H: np.ndarray | None, x1: np.ndarray) -> Estimate:
    """Keep the ground plane's decomposition of ``H``; its translation is ``T2 / d``.

    Of OpenCV's (up to four) solutions, those that put the points ``H`` was fitted to in
    front of the plane (``n . x1 > 0``, positive depth) come first, then the one whose
    normal is closest to the ground normal ``[0, 1, 0]``.
    """
    if H is None or not np.all(np.isfinite(H)):
        return NAN, NAN, NAN
    _, rotations, translations, normals = cv2.decomposeHomographyMat(H, K)
    best, best_key = None, None
    for R, t, n in zip(rotations, translations, normals, strict=True):
        n = n.ravel()
        key = (bool(np.all(x1 @ n > 0)), float(n[1]))
        if best_key is None or key > best_key:
            best, best_key = (R, t), key
    return _from_cv_pose(best[0], best[1], HEIGHT)


def _cv_homography_4pt(p1: np.ndarray, p2: np.ndarray, x1: np.ndarray,
                       x2: np.ndarray) -> Estimate:
    """Direct 4-point homography on points 0-3, decomposed (Malis-Vargas)."""
    H, _ = cv2.findHomography(p1[:4], p2[:4], 0)
    return _decompose(H, x1[:4])


def _cv_homography_lsq(p1: np.ndarray, p2: np.ndarray, x1: np.ndarray,
                       x2: np.ndarray) -> Estimate:
    """Least-squares homography (DLT + Levenberg-Marquardt) on all 50 points, decomposed."""
    H, _ = cv2.findHomography(p1, p2, 0)
    return _decompose(H, x1)


@dataclass(frozen=True)
class Solver:
    """A named solver, how many correspondences it uses, and whether it knows the scale."""

    name: str
    points: int
    scale: bool
    solve: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], Estimate]
    paper: bool = False


SOLVERS: tuple[Solver, ...] = (
    Solver('essential_1pt', 1, False, _essential_1pt, paper=True),
    Solver('essential_2pt', 2, False, _essential_2pt, paper=True),
    Solver('homography_1pt', 1, True, _homography_1pt, paper=True),
    Solver('homography_2pt', 2, True, _homography_2pt, paper=True),
    Solver('homography_npt', POINTS, True, _homography_npt),
    Solver('cv_essential_5pt', 5, False, _cv_essential_5pt),
    Solver('cv_essential_usac', POINTS, False, _cv_essential_usac),
    Solver('cv_homography_4pt', 4, True, _cv_homography_4pt),
    Solver('cv_homography_lsq', POINTS, True, _cv_homography_lsq),
)


def estimate_all(
    data: Trials, sigma: float, solvers: Sequence[Solver] = SOLVERS
) -> dict[str, np.ndarray]:
    """Run every solver on every trial at one noise level.

    Returns:
        solver name → (trials, 4) array of theta, phi, rho, time in seconds; a solver that
        fails (raises, or returns NaN angles) leaves NaN angles in its row.
    """
    p1s, p2s, x1s, x2s = data.rays(sigma)
    out = {s.name: np.full((len(p1s), 4), np.nan) for s in solvers}
    with np.errstate(all='ignore'):
        for i in range(len(p1s)):
            args = (p1s[i], p2s[i], x1s[i], x2s[i])
            for s in solvers:
                start = time.perf_counter()
                try:
                    est = s.solve(*args)
                except (np.linalg.LinAlgError, cv2.error):
                    est = (NAN, NAN, NAN)
                out[s.name][i] = (*est, time.perf_counter() - start)
    return out


def _angle_error(estimate: np.ndarray, truth: float) -> np.ndarray:
    return np.abs((estimate - truth + np.pi) % (2.0 * np.pi) - np.pi)


def summarize(solver: Solver, sigma: float, raw: np.ndarray) -> dict:
    """Median errors and time of one solver at one sigma (failed trials are counted apart)."""
    ok = np.isfinite(raw[:, 0]) & np.isfinite(raw[:, 1])
    if solver.scale:
        ok &= np.isfinite(raw[:, 2])
    good = raw[ok]

    def median(values: np.ndarray) -> float | None:
        return float(np.median(values)) if len(values) else None

    rho = None
    if solver.scale:
        rho = median(np.abs(good[:, 2] - TRUE_MOTION['rho']) / TRUE_MOTION['rho'])
    return {
        'solver': solver.name,
        'points': solver.points,
        'sigma': float(sigma),
        'phi_median_abs_err': median(_angle_error(good[:, 1], TRUE_MOTION['phi'])),
        'theta_median_abs_err': median(_angle_error(good[:, 0], TRUE_MOTION['theta'])),
        'rho_median_rel_err': rho,
        'time_us': float(np.median(raw[:, 3]) * 1e6),
        'failures': int(np.count_nonzero(~ok)),
    }


def _run(
    data: Trials, sigmas: Sequence[float], keep_sigma: float | None = None
) -> tuple[list[dict], dict[str, np.ndarray] | None]:
    """Summaries per (sigma, solver), and the raw estimates at ``keep_sigma`` if it was run."""
    results, kept = [], None
    for sigma in sigmas:
        raw = estimate_all(data, sigma)
        results.extend(summarize(s, sigma, raw[s.name]) for s in SOLVERS)
        if keep_sigma is not None and sigma == keep_sigma:
            kept = raw
    return results, kept


def run_experiment(trials: int, sigmas: Sequence[float], seed: int) -> list[dict]:
    """The whole experiment: one summary dict per (sigma, solver), sigma-major order."""
    return _run(make_trials(trials, seed), sigmas)[0]


def _fmt(value: float | None, spec: str) -> str:
    return 'n/a' if value is None else format(value, spec)


def format_table(results: Sequence[dict]) -> str:
    """Plain-text table, one block per sigma (also valid Markdown)."""
    header = ('| sigma [px] | solver | points | phi err [rad] | theta err [rad] '
              '| rho rel err | time [us] |')
    lines = [header, '|' + '---|' * 7]
    for r in results:
        fail = f' ({r["failures"]} failed)' if r.get('failures') else ''
        lines.append(
            f'| {r["sigma"]:g} | {r["solver"]}{fail} | {r["points"]} '
            f'| {_fmt(r["phi_median_abs_err"], ".2e")} '
            f'| {_fmt(r["theta_median_abs_err"], ".2e")} '
            f'| {_fmt(r["rho_median_rel_err"], ".2e")} | {r["time_us"]:.1f} |')
    return '\n'.join(lines)


def plot_fig5(phis: dict[str, np.ndarray], sigma: float, path: str) -> None:
    """Histograms of estimated phi like the paper's Fig. 5 (1-point vs 2-point per model)."""
    plt = pyplot()
    truth = TRUE_MOTION['phi']
    finite = np.concatenate([v[np.isfinite(v)] for v in phis.values()])
    half = float(np.clip(np.percentile(np.abs(finite - truth), 90), 0.02, 0.5))
    bins = np.linspace(truth - half, truth + half, 101)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    panels = (('(a) reduced essential matrix', 'essential'),
              ('(b) reduced ground homography', 'homography'))
    for ax, (title, model) in zip(axes, panels, strict=True):
        for pts, colour in (('1pt', 'tab:blue'), ('2pt', 'tab:orange')):
            values = phis[f'{model}_{pts}']
            values = np.clip(values[np.isfinite(values)], bins[0], bins[-1])
            ax.hist(values, bins=bins, alpha=0.6, color=colour,
                    label=f'{pts[0]}-point ({len(values)} trials)')
        ax.axvline(truth, color='k', linestyle='--', label=f'true phi = {truth}')
        ax.set_title(title)
        ax.set_xlabel('estimated phi [rad] (clipped to the range shown)')
        ax.legend()
    axes[0].set_ylabel('trials')
    fig.suptitle(f'Estimated phi, sigma = {sigma:g} px (cf. Choi et al. 2010, Fig. 5)')
    fig.tight_layout()
    try:
        fig.savefig(path, dpi=100)
    finally:
        plt.close(fig)


def _check_plot_path(path: str) -> str | None:
    """Why ``path`` cannot take the plot, or None; checked before the long run."""
    ext = os.path.splitext(path)[1].lower().lstrip('.')
    if ext != 'png':
        return f'--plot {path!r} must end in .png'
    if os.path.isdir(path):
        return f'--plot {path!r} is a directory; give a file name such as out/fig5.png'
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        return f'--plot {path!r}: directory {parent!r} does not exist'
    existed = os.path.exists(path)
    try:  # really try: access() says yes to root even where the file system says no
        with open(path, 'ab'):
            pass
        if not existed:
            os.remove(path)
    except OSError as exc:
        return f'--plot {path!r} is not writable: {exc.strerror}'
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        return '--plot needs matplotlib (pip install matplotlib)'
    return None


_SIGMAS = number_list(float, 'numbers', '0,0.5,1',
                      lambda values: all(math.isfinite(v) and v >= 0 for v in values),
                      'finite and non-negative (pixels)')


def _build_parser() -> Parser:
    parser = Parser(
        prog=PROG,
        description='Monte Carlo experiment of Choi et al. (URAI 2010, sec. 4): the paper\'s '
                    'four planar-motion solvers against OpenCV\'s 5-point and 4-point '
                    'baselines, on random ground points seen by a level camera.')
    parser.add_argument('--trials', type=positive_int, default=DEFAULT_TRIALS,
                        help='Monte Carlo trials per noise level (default %(default)s; '
                             'the paper used 1000)')
    parser.add_argument('--sigmas', type=_SIGMAS, default=list(DEFAULT_SIGMAS),
                        help='comma-separated pixel noise standard deviations, added to both '
                             'images (default 0,0.5,1,1.5,2 as in the paper)')
    parser.add_argument('--seed', type=non_negative_int, default=DEFAULT_SEED,
                        help='seed of the random points and noise; same seed, same errors '
                             '(default %(default)s)')
    parser.add_argument('--json', action='store_true',
                        help='print one JSON object {"setup": ..., "results": [...]} instead '
                             'of the table')
    parser.add_argument('--plot', metavar='OUT.png',
                        help='also write histograms of estimated phi at sigma = 1 px, 1-point '
                             'vs 2-point, like the paper\'s Fig. 5 (needs matplotlib)')
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Command line entry point; returns the exit code (2 on bad arguments)."""
    parser = _build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help (0) or a usage error, already printed in one line (2)
        return int(exc.code or 0)
    if args.plot is not None:
        problem = _check_plot_path(args.plot)
        if problem:
            return fail(PROG, problem)

    data = make_trials(args.trials, args.seed)
    plot_sigma = 1.0  # the paper's Fig. 5
    results, raw = _run(data, args.sigmas, plot_sigma if args.plot is not None else None)

    if args.json:
        setup = dict(SETUP, trials=args.trials, seed=args.seed, sigmas=args.sigmas)
        print(json.dumps({'setup': setup, 'results': results}))
    else:
        print(f'{PROG}: {args.trials} trials per sigma, seed {args.seed}; median errors and '
              f'median time per solve (essential solvers: with the choice among roots)')
        print(format_table(results))

    if args.plot is not None:
        paper = [s for s in SOLVERS if s.paper]
        if raw is None:  # sigma = 1 was not among --sigmas
            raw = estimate_all(data, plot_sigma, paper)
        paper_phis = {s.name: raw[s.name][:, 1] for s in paper}
        try:
            plot_fig5(paper_phis, plot_sigma, args.plot)
        except (OSError, ValueError) as exc:
            return fail(PROG, f'cannot write plot {args.plot!r}: {exc}')
        print(f'{PROG}: wrote plot to {os.path.abspath(args.plot)}',
              file=sys.stderr if args.json else sys.stdout)
    return 0


if __name__ == '__main__':
    sys.exit(main())
