"""Speed bumps seen ahead: found by their faster flow, remembered, and the front wheels on one.

Closed-form views of a flat road with a bump band (the geometry written out in
test_terrain._observe, independently of the code under test).
"""

import numpy as np

from planar_vo.core.estimation.local_ground import GroundPrior, Hinge, refine_on_local_ground
from planar_vo.core.estimation.ransac import RansacResult, TransferModel
from planar_vo.core.odometry.bumps_ahead import BumpsAhead
from planar_vo.core.odometry.ground_filter import LocalGroundFilter
from planar_vo.core.odometry.surface_bands import (
    faster_bands,
    track_noise,
    wheel_plane_distance,
)
from test.test_terrain import HINGE, MOUNT, _observe

STEP = np.array([0.3, 0.0, 0.0])
FOCAL_PX = 300.0  # a 376x240 image's
NOISE = track_noise(0.3, FOCAL_PX)  # a fit's residual of 0.3 px


def _view(points, motion=STEP):
    """(v1 in base_link, m1, m2) of ``points`` (base-1 coordinates) over ``motion``."""
    m1, m2 = _observe(points, MOUNT, motion, np.zeros(2))
    v1 = np.c_[m1, np.ones(len(m1))] @ MOUNT.base_from_optical.T
    return v1, m1, m2


def _road(rng, z, count=800):
    x, y = rng.uniform(3.1, 6.5, count), rng.uniform(-2.0, 2.0, count)
    return np.c_[x, y, z(x, y)]


def test_a_bump_s_band_moves_faster_than_the_road_around_it_and_a_hill_s_does_not():
    """An 8 cm bump 5.0-5.5 m ahead: a band its rays meet the wheel plane in is found, nearly
    all of it on the bump, and remembered, it hides the bump's tracks. The flat road and a
    hill of the drives' largest curvature (0.03 /m) over the surface before: nothing."""
    rng = np.random.default_rng(2)
    points = _road(rng, lambda x, y: np.where((x > 5.0) & (x < 5.5), 0.08, 0.0))
    on_bump = points[:, 2] > 0
    v1, m1, m2 = _view(points)
    found = faster_bands(STEP, np.zeros(3), np.zeros(5), v1, m1, m2, MOUNT, Hinge(HINGE),
                         NOISE)
    assert found.any() and np.mean(on_bump[found]) > 0.8
    distance = wheel_plane_distance(MOUNT, v1)
    hidden = BumpsAhead().seen(distance[found], 0.5).hides(distance, 0.75)
    assert np.mean(hidden[on_bump]) > 0.9
    assert np.mean(hidden[~on_bump]) < 0.3
    hill = np.array([0.0, 0.0, 0.03, 0.0, 0.0])
    for surface in (np.zeros(5), hill):
        v1, m1, m2 = _view(_road(rng, lambda x, y, k=surface[2]: 0.5 * k * (x - HINGE) ** 2))
        assert not faster_bands(STEP, np.zeros(3), surface, v1, m1, m2, MOUNT,
                                Hinge(HINGE), NOISE).any()


def test_a_band_is_a_bump_only_out_of_its_tracks_noise():
    """Noisy views (0.2 px at 300 px focal) of a road with few tracks at the far edge, as a
    small image has: a flat road's far band, faster by 2 % or more by chance on one view in
    five, is not a bump; an 8 cm bump 5.0-5.5 m ahead under the same noise is on two thirds
    of them (a bump shows on pair after pair as it comes closer)."""
    sigma = 0.2 / FOCAL_PX

    def found(seed, bump):
        rng = np.random.default_rng(seed)
        x = np.r_[rng.uniform(3.0, 6.0, 240), rng.uniform(6.0, 7.0, 16)]
        y = rng.uniform(-2.0, 2.0, len(x))
        points = np.c_[x, y, np.where(bump & (x > 5.0) & (x < 5.5), 0.08, 0.0)]
        m1, m2 = _observe(points, MOUNT, STEP, np.zeros(2))
        m1, m2 = (m + rng.normal(0.0, sigma, m.shape) for m in (m1, m2))
        v1 = np.c_[m1, np.ones(len(m1))] @ MOUNT.base_from_optical.T
        bands = faster_bands(STEP, np.zeros(3), np.zeros(5), v1, m1, m2, MOUNT, Hinge(HINGE),
                             sigma)
        return bands.any()

    assert sum(found(seed, False) for seed in range(100)) == 0
    assert sum(found(seed, True) for seed in range(100)) > 50


def test_the_front_wheels_on_a_bump_need_the_road_s_height_at_the_hinge():
    """The front wheels 7 cm up on a long bump: the road past the front axle is 7 cm below
    the wheels' plane there and falls away from it. Given that height, the step comes out
    exact; without it, centimetres off (no surface through the hinge holds that road)."""
    rng = np.random.default_rng(4)
    lift = 0.07
    points = _road(rng, lambda x, y: -lift * x / HINGE)
    v1, _, m2 = _view(points)
    prior = GroundPrior(np.diag([0.02, 0.02, 0.01]) ** 2, np.zeros(5),
                        np.diag([0.05, 0.05, 0.03, 0.03, 0.03]) ** 2)

    def step(hinge_height):
        return refine_on_local_ground(STEP + [0.01, 0.0, 0.0], v1, m2, MOUNT, prior,
                                      focal_px=500.0, threshold_px=2.0,
                                      start_threshold_px=20.0, iterations=20,
                                      hinge=Hinge(HINGE, height=hinge_height)).motion

    np.testing.assert_allclose(step(-lift), STEP, atol=1e-5)
    assert abs(step(0.0)[0] - STEP[0]) > 0.005


def test_a_bump_is_remembered_until_it_has_passed_and_found_once():
    """Bands near a remembered bump are that bump, which stands at their mean; moving on
    shifts it; it is forgotten once past the camera's view, or when reversing. Its tracks are
    hidden, from a little before it to ``reach``."""
    bumps = BumpsAhead().seen(np.array([6.1, 6.2, 6.3]), 0.5)
    assert bumps.ahead == (6.2,)
    again = bumps.seen(np.array([7.0, 7.2]), 0.5)  # one band at 7.1: the bump seen again
    np.testing.assert_allclose(again.ahead, [(6.2 + 7.1) / 2])
    np.testing.assert_allclose(again.seen(np.array([6.3]), 0.5).ahead, [(6.2 + 7.1 + 6.3) / 3])
    np.testing.assert_allclose(bumps.seen(np.array([5.0, 7.9]), 0.5).ahead, [(6.2 + 5 + 7.9) / 3])
    assert bumps.seen(np.array([9.0]), 0.5).ahead == (6.2, 9.0)
    hidden = bumps.hides(np.array([5.0, 5.8, 6.2, 6.9, 7.1]), 0.75)
    np.testing.assert_array_equal(hidden, [False, True, True, True, False])
    moved = bumps.moved(1.0, camera_x=1.2)
    np.testing.assert_allclose(moved.ahead, [5.2])
    assert moved.moved(3.0, camera_x=1.2).ahead == ()
    assert bumps.moved(-0.1, camera_x=1.2).ahead == ()  # reversing: it was seen going forward


def test_where_the_road_curves_a_band_is_a_bump_once_a_later_pair_shows_it_again():
    """A hill's bend can make one band: where the road curves a band is only a candidate,
    moved on with the vehicle; a band of a later pair within 0.6 m of it makes it a bump at
    their mean. Two bands of one pair do not confirm each other; a candidate past the camera's
    view, or when reversing, is forgotten. A band near a known bump still moves it."""
    once = BumpsAhead().seen(np.array([6.1, 6.2, 6.3]), 0.5, confirm=True)
    assert once.ahead == () and once.candidates == (6.2,)
    assert BumpsAhead().seen(np.array([6.2, 6.6]), 0.5, confirm=True).ahead == ()
    moved = once.moved(0.3, camera_x=1.2)
    np.testing.assert_allclose(moved.candidates, [5.9])
    twice = moved.seen(np.array([6.2, 6.4]), 0.5, confirm=True)  # a band at 6.3
    np.testing.assert_allclose(twice.ahead, [(5.9 + 6.3) / 2])
    assert twice.sightings == (2,) and twice.candidates == ()
    elsewhere = moved.seen(np.array([7.0, 7.1]), 0.5, confirm=True)  # 1.15 m from it
    assert elsewhere.ahead == ()
    np.testing.assert_allclose(elsewhere.candidates, [5.9, 7.05])
    assert once.moved(4.1, camera_x=1.2).candidates == ()  # 2.1 m ahead: past the view
    assert once.moved(-0.1, camera_x=1.2).candidates == ()
    known = BumpsAhead((6.0,)).seen(np.array([6.5]), 0.5, confirm=True)
    np.testing.assert_allclose(known.ahead, [6.25])


def test_a_candidate_s_tracks_are_left_out_only_when_asked():
    """A bump hides its tracks from 0.6 m before it to ``reach`` past it; a band waiting for its
    confirmation does too when the caller asks (the ground filter does unless a road hump's
    heights are in use), and a bump's tracks are hidden either way."""
    distance = np.linspace(3.0, 7.0, 41)
    waiting = BumpsAhead(candidates=(5.0,))
    assert not waiting.hides(distance, 0.4).any()
    hidden = distance[waiting.hides(distance, 0.4, candidates=True)]
    assert hidden.min() > 4.4 - 1e-9 and hidden.max() < 5.4 + 1e-9 and len(hidden) == 9
    bump = BumpsAhead((5.0,))
    np.testing.assert_array_equal(bump.hides(distance, 0.4),
                                  bump.hides(distance, 0.4, candidates=True))
    assert distance[bump.hides(distance, 0.4)].tolist() == hidden.tolist()


def test_the_front_wheels_height_is_summed_only_on_a_remembered_bump():
    """A lift sums into the front wheels' height while a bump is at the front axle; elsewhere
    (a hill's pitch) it does not, and the height fades once the wheels are off."""
    on = BumpsAhead((HINGE + 0.2,)).lifted(0.06, HINGE)
    assert on.front_height == 0.06
    assert BumpsAhead((HINGE + 3.0,)).lifted(0.06, HINGE).front_height == 0.0
    assert on.lifted(None, HINGE).front_height < 0.02


def test_a_bump_coming_into_view_is_found_where_it_is():
    """Driving a flat road towards an 8 cm bump: once it comes into the far tracks the filter
    remembers it within half a metre of where it is, and keeps it there as it comes closer."""
    rng = np.random.default_rng(9)
    ground = LocalGroundFilter(MOUNT, rates=np.array([0.5, 0.5, 0.3]), wheelbase=HINGE,
                               self_calibrate=False)
    model = TransferModel(*MOUNT.ground_to_optical(), 500.0, MOUNT)
    bump_x = 12.0
    for k in range(26):
        position = 0.3 * k
        points = _road(rng, lambda x, y, p=position: np.where(np.abs(x + p - bump_x) < 0.35,
                                                               0.08, 0.0))
        v1, m1, m2 = _view(points)
        m2 = m2 + rng.normal(0.0, 0.1 / 500.0, m2.shape)
        start = RansacResult(STEP.copy(), np.eye(3) * 1e-4, np.ones(len(m1), bool), 1, 0.2)
        result, _ = ground.refine(start, np.c_[m1, np.ones(len(m1))], m2, MOUNT, model,
                                  dt=0.05, inlier_threshold=2.0, start_threshold=8.0,
                                  min_inliers=10)
        ground.advance(result.motion)
        ahead = bump_x - (position + 0.3)
        if ahead < 6.0:
            assert len(ground.ahead.bumps.ahead) == 1
            assert abs(ground.ahead.bumps.ahead[0] - ahead) < 0.5
    assert wheel_plane_distance(MOUNT, v1).max() > 6.0
