import numpy as np
import pytest

from planar_vo.core.geometry import solvers
from test.conftest import paper_motion_rays

CASES = 200


def random_motions(rng, n, circular):
    theta = rng.uniform(-0.8, 0.8, n)
    phi = theta / 2 if circular else rng.uniform(-0.8, 0.8, n)
    return theta, phi, rng.uniform(0.05, 3.0, n)


def test_models_hold_for_the_paper_setup():
    rng = np.random.default_rng(0)
    x1, x2 = paper_motion_rays(rng, 0.78, 0.39, 1.5)
    H = solvers.ground_homography(0.78, 0.39, 1.5 / 1.5)
    E = solvers.essential_matrix(0.78, 0.39)
    assert np.abs(np.cross(x1 @ H.T, x2)).max() < 1e-12
    assert np.abs(np.einsum('ni,ij,nj->n', x2, E, x1)).max() < 1e-12


def test_homography_1point_exact_on_circular_motion():
    rng = np.random.default_rng(1)
    for theta, phi, rho in zip(*random_motions(rng, CASES, circular=True)):
        x1, x2 = paper_motion_rays(rng, theta, phi, rho, n=1)
        m = solvers.homography_1point(x1[0], x2[0])
        assert m.theta == pytest.approx(theta, abs=1e-9)
        assert m.phi == pytest.approx(phi, abs=1e-9)
        assert m.rho * 1.5 == pytest.approx(rho, abs=1e-9)


def test_homography_2point_and_npoint_exact_on_planar_motion():
    rng = np.random.default_rng(2)
    for theta, phi, rho in zip(*random_motions(rng, CASES, circular=False)):
        x1, x2 = paper_motion_rays(rng, theta, phi, rho, n=8)
        for m in (solvers.homography_2point(x1[:2], x2[:2]),
                  solvers.homography_npoint(x1, x2)):
            assert m.theta == pytest.approx(theta, abs=1e-9)
            assert m.phi == pytest.approx(phi, abs=1e-9)
            assert m.rho * 1.5 == pytest.approx(rho, abs=1e-9)


def test_homography_solvers_are_vectorised():
    rng = np.random.default_rng(3)
    x1, x2 = paper_motion_rays(rng, 0.2, 0.1, 0.5, n=50)
    m = solvers.homography_1point(x1, x2)
    assert m.theta.shape == (50,)
    np.testing.assert_allclose(m.phi, 0.1, atol=1e-9)
    pairs = solvers.homography_2point(x1.reshape(25, 2, 3), x2.reshape(25, 2, 3))
    np.testing.assert_allclose(pairs.theta, 0.2, atol=1e-9)


def test_essential_1point_returns_both_roots_and_selection_finds_truth():
    rng = np.random.default_rng(4)
    for theta, phi, rho in zip(*random_motions(rng, CASES, circular=True)):
        x1, x2 = paper_motion_rays(rng, theta, phi, rho, n=6)
        roots = solvers.essential_1point(x1[0], x2[0])
        assert np.min(np.abs(roots - phi)) < 1e-9
        assert np.abs(np.angle(np.exp(1j * (roots[1] - roots[0])))) == pytest.approx(np.pi)
        sel = solvers.essential_select(2 * roots, roots, x1, x2)
        assert sel == pytest.approx((theta, phi), abs=1e-9)


def test_essential_2point_every_real_root_contains_truth():
    rng = np.random.default_rng(5)
    for theta, phi, rho in zip(*random_motions(rng, CASES, circular=False)):
        x1, x2 = paper_motion_rays(rng, theta, phi, rho, n=10)
        thetas, phis = solvers.essential_2point(x1[:2], x2[:2])
        assert thetas.shape == (4,)
        err = np.hypot(np.angle(np.exp(1j * (thetas - theta))),
                       np.angle(np.exp(1j * (phis - phi))))
        assert err.min() < 1e-9
        # every candidate satisfies the epipolar constraint of both points
        for t, p in zip(thetas, phis):
            E = solvers.essential_matrix(t, p)
            assert np.abs(np.einsum('ni,ij,nj->n', x2[:2], E, x1[:2])).max() < 1e-9
        assert solvers.essential_select(thetas, phis, x1, x2) == pytest.approx(
            (theta, phi), abs=1e-9)


def test_sign_conventions_match_ros():
    """A left turn is negative theta in the paper and positive yaw in REP-103."""
    planar = solvers.paper_to_planar(-0.2, -0.1, 1.0)
    assert planar[2] == pytest.approx(0.2)
    assert planar[1] > 0  # turning left moves the camera to its left (+y)
    assert planar[0] == pytest.approx(np.cos(0.1))
    back = solvers.planar_to_paper(*planar)
    assert (back.theta, back.phi, back.rho) == pytest.approx((-0.2, -0.1, 1.0))


def test_homography_1point_keeps_the_forward_root():
    """Of phi and phi + pi the solver keeps the one with non-negative distance."""
    rng = np.random.default_rng(6)
    x1, x2 = paper_motion_rays(rng, 0.1, 0.05, 0.3, n=1)
    forward = solvers.homography_1point(x1[0], x2[0])
    backward = solvers.homography_1point(x2[0], x1[0])
    assert forward.rho > 0 and backward.rho > 0
    assert forward.phi == pytest.approx(0.05)
    assert abs(backward.phi) > np.pi / 2  # driving backwards
