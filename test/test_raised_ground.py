"""Raised ground remembered under the front wheels: a bump crossed at an angle.

Closed-form views of a flat road with a raised band (the geometry written out in
test_terrain._observe, independently of the code under test).
"""

import numpy as np

from planar_vo.core.estimation.local_ground import Hinge
from planar_vo.core.odometry.raised_ground import RaisedGround
from planar_vo.core.odometry.surface_bands import (
    flow_excess,
    wheel_plane_distance,
    wheel_plane_lateral,
)
from test.test_bumps_ahead import STEP, _road, _view
from test.test_terrain import HINGE, MOUNT

WHEELS = np.array([[HINGE, 0.8], [HINGE, -0.8]])  # the front wheels, left and right
HEIGHT = 0.08


def _diagonal_bump(x, y, centre=4.9):
    """8 cm across the road at 45 deg: 0.7 m wide along x - y = ``centre``."""
    return np.where(np.abs(x - y - centre) < 0.35, HEIGHT, 0.0)


def _seen(ground: RaisedGround, rng, z) -> RaisedGround:
    """``ground`` with the samples of one pair over the road ``z`` (no motion yet)."""
    v1, m1, m2 = _view(_road(rng, z))
    excess, usable, _ = flow_excess(STEP, np.zeros(3), np.zeros(5), v1, m1, m2, MOUNT,
                                    Hinge(HINGE))
    at = np.c_[wheel_plane_distance(MOUNT, v1), wheel_plane_lateral(MOUNT, v1)]
    return ground.seen(MOUNT.position, at[usable], excess[usable], HINGE)


def _driven(ground: RaisedGround, metres: float) -> RaisedGround:
    for _ in range(int(round(metres / STEP[0]))):
        ground = ground.moved(STEP, HINGE)
    return ground


def test_a_bump_crossed_at_an_angle_is_under_one_front_wheel_when_the_wheels_get_there():
    """Seen 4-6 m ahead over two pairs, then driven 3 m: the left wheel stands on it (8 cm
    within 1 cm, from the flow alone: 8.5 here), the right one on the road."""
    rng = np.random.default_rng(5)
    ground = _seen(_seen(RaisedGround(), rng, _diagonal_bump), rng, _diagonal_bump)
    under = _driven(ground, 3.0).height_at(WHEELS, MOUNT.position[2])
    assert abs(under[0] - HEIGHT) < 0.01
    assert under[1] == 0.0


def test_the_flat_road_one_pair_or_reversing_raise_nothing():
    """A flat road reads no height anywhere; one pair's samples are not enough; reversing
    forgets what was seen on the way forward."""
    rng = np.random.default_rng(6)
    flat = _seen(_seen(RaisedGround(), rng, lambda x, y: 0.0 * x), rng, lambda x, y: 0.0 * x)
    grid = np.stack(np.meshgrid(np.arange(3.5, 6.5, 0.1), np.arange(-2, 2, 0.1)), -1)
    assert not flat.height_at(grid.reshape(-1, 2), MOUNT.position[2]).any()
    once = _driven(_seen(RaisedGround(), rng, _diagonal_bump), 3.0)
    assert not once.height_at(WHEELS, MOUNT.position[2]).any()
    bump = _seen(_seen(RaisedGround(), rng, _diagonal_bump), rng, _diagonal_bump)
    back = _driven(bump, 3.0).moved(np.array([-0.1, 0.0, 0.0]), HINGE)
    assert not back.height_at(WHEELS, MOUNT.position[2]).any()


def test_the_samples_turn_with_the_vehicle():
    """Seen straight ahead, then the car turns 90 deg left on the spot over six steps: the
    bump 4.9 m ahead now lies 4.9 m to its right."""
    rng = np.random.default_rng(7)
    band = lambda x, y: np.where(np.abs(x - 4.9) < 0.35, HEIGHT, 0.0)  # noqa: E731
    ground = _seen(_seen(RaisedGround(), rng, band), rng, band)
    turn = np.array([0.0, 0.0, np.pi / 12])
    for _ in range(6):
        ground = ground.moved(turn, -10.0)
    under = ground.height_at(np.array([[0.1, -4.9], [4.9, 0.1]]), MOUNT.position[2])
    assert abs(under[0] - HEIGHT) < 0.01 and under[1] == 0.0
