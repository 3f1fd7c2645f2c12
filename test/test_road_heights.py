"""A long road hump remembered as heights: the transfer over them, the memory, a rendered drive.

The closed-form views are written out in test_terrain._observe (through test_bumps_ahead's
view of a road 3.1-6.5 m ahead), independently of the code under test; the rendered drive
is scored against the renderer's truth.
"""

import numpy as np
import pytest

from planar_vo import synth
from planar_vo.core import config
from planar_vo.core.estimation.local_ground import GroundPrior, Hinge, refine_on_local_ground
from planar_vo.core.metrics import metrics
from planar_vo.core.odometry import VisualOdometry
from planar_vo.core.odometry.road_heights import RoadHeights, chord_grade
from planar_vo.synth.terrain import TerrainShape
from planar_vo.tools.experiments.mounting_experiment import plain_opencv_path
from test.conftest import synth_camera_model
from test.test_bumps_ahead import STEP, _road, _view
from test.test_terrain import CAR_MOUNT, HINGE, MOUNT

HUMP_LENGTH, HUMP_HEIGHT = 3.0, 0.08


def _hump(x, centre):
    """The renderer's road hump: ``HUMP_HEIGHT cos^2`` over ``HUMP_LENGTH``."""
    u = np.asarray(x) - centre
    return np.where(np.abs(u) < HUMP_LENGTH / 2,
                    HUMP_HEIGHT * np.cos(np.pi * u / HUMP_LENGTH) ** 2, 0.0)


def test_the_front_wheels_on_a_long_hump_need_its_heights_not_a_hinge_height():
    """The front wheels 0.5 m short of a 3 m hump's crest, the rear ones on flat road: the
    road ahead, in the wheels' plane, is the hump less the front wheels' height, tilted with
    the wheels. Given those heights the step comes out exact; with the front wheels' height
    at the hinge alone (a short bump's model) or nothing, centimetres off."""
    rng = np.random.default_rng(5)
    centre = HINGE + 0.5
    front = float(_hump(HINGE, centre))
    v1, _, m2 = _view(_road(rng, lambda x, y: _hump(x, centre) - front * x / HINGE))
    loose = np.diag([0.05, 0.05, 0.03, 0.03, 0.03]) ** 2
    prior = GroundPrior(np.diag([0.02, 0.02, 0.01]) ** 2, np.zeros(5), loose)

    def step(hinge):
        start = STEP + [0.01, 0.0, 0.0]
        return refine_on_local_ground(start, v1, m2, MOUNT, prior, focal_px=500.0,
                                      threshold_px=2.0, start_threshold_px=20.0,
                                      iterations=20, hinge=hinge).motion

    relief = Hinge(HINGE, relief=lambda p: _hump(p[:, 0], centre) - front)
    np.testing.assert_allclose(step(relief), STEP, atol=1e-5)
    assert abs(step(Hinge(HINGE, height=-front))[0] - STEP[0]) > 0.005
    assert abs(step(Hinge(HINGE))[0] - STEP[0]) > 0.005


def _seen_over(heights, centre, length, pairs=6, step=0.25):
    """``heights`` after ``pairs`` pairs driving ``step`` m each, every one measuring a bump
    of ``length`` (8 cm cos^2) ``centre`` m ahead of the first frame's base_link."""
    rng = np.random.default_rng(0)
    for k in range(pairs):
        points = np.c_[rng.uniform(3.0, 8.0, 600), rng.uniform(-1.0, 1.0, 600)]
        u = points[:, 0] + k * step - centre
        bump = np.where(np.abs(u) < length / 2, 0.08 * np.cos(np.pi * u / length) ** 2, 0.0)
        heights = heights.seen(points, bump).moved(np.array([step, 0.0, 0.0]))
    return heights


def test_a_long_hump_s_heights_are_remembered_where_it_lies_and_a_short_bump_s_are_not_used():
    """Measured over several pairs, a 3 m hump's heights are read back where it lies after
    the vehicle moved on (its crest 8 cm, its feet none); a 0.7 m bump's are left to the
    bands and lifts (none in use). Reversing forgets them."""
    pairs, step, centre = 6, 0.25, 6.0
    heights = _seen_over(RoadHeights(), centre, 3.0, pairs, step)
    assert heights.in_use
    ahead = centre - pairs * step
    x = np.array([ahead - 1.6, ahead - 0.75, ahead, ahead + 0.75, ahead + 1.6])
    read = heights.at(np.c_[x, np.zeros_like(x)])
    np.testing.assert_allclose(read, [0.0, 0.04, 0.08, 0.04, 0.0], atol=0.012)
    short = _seen_over(RoadHeights(), centre, 0.7, pairs, step)
    assert not short.in_use
    assert not heights.moved(np.array([-0.1, 0.0, 0.0])).in_use


def test_the_wheels_chord_rises_with_the_front_wheels_on_a_remembered_hump():
    """The front wheels at the crest, the rear on the road: the chord's grade is the crest's
    height over the wheelbase; with the hump under the rear wheels it falls."""
    heights = _seen_over(RoadHeights(), HINGE + 1.5, 3.0, 6, 0.25)  # crest at the front axle
    assert chord_grade(heights, HINGE, 0.8) == pytest.approx(0.08 / HINGE, abs=0.005)
    crest_at_rear = heights.moved(np.array([HINGE, 0.0, 0.0]))
    assert chord_grade(crest_at_rear, HINGE, 0.8) == pytest.approx(-0.08 / HINGE, abs=0.005)


# Measured (752x480, 150 frames): seed 1 0.22 % (stop 67 0.31, stop 66 0.45, before it 1.39),
# seeds 3 and 4 0.79 and 0.14 (stop 67 0.71 and 0.31, stop 66 0.79 and 0.78); plain OpenCV on
# the same frames 1.47, 2.00, 1.51.
def test_3_m_road_humps_are_remembered_as_heights_and_hold_better():
    """The issue's camera over 8 cm x 3 m road humps (a rigid car), against the renderer's
    truth: the humps' heights are in use while they are near, and the drive holds within
    a fifth of the error it had without them (1.39 %) and 3x better than plain OpenCV."""
    camera = synth.SynthCamera.scaled(752, 480)
    renderer, traj = synth.render_scenario('default', 150, 1, rate=20.0, camera=camera,
                                           mounting=CAR_MOUNT, terrain='bumps',
                                           terrain_shape=TerrainShape.parse('bump_length=3.0'))
    model = synth_camera_model(renderer)
    params = config.validate(config.mounting_params(CAR_MOUNT))
    vo = VisualOdometry.from_params(model, params)
    images = [renderer.render_frame(traj, k) for k in range(150)]
    poses, reported = [], []
    for k, image in enumerate(images):
        poses.append(vo.process(image, k / 20.0).pose)
        reported.append((k, vo.ground.heights.extent(),
                         vo.ground.diagnostics()['road hump remembered']))
    truth = np.c_[traj.x, traj.y, traj.yaw]
    t_rel = metrics(np.array(poses), truth)['t_rel_percent']
    opencv = metrics(plain_opencv_path(model, params, images), truth)['t_rel_percent']
    assert t_rel < 0.3 and 3 * t_rel < opencv, (t_rel, opencv)
    # Where /diagnostics says the hump is, the renderer has one (base_link x of its centres,
    # 1.5 m either side; the remembered extent may reach a cell past it).
    pose, centres = traj.pose3d, np.asarray(renderer.terrain.centres)
    shown = [(k, extent) for k, extent, text in reported if text != 'none']
    assert len(shown) >= 20, len(shown)
    for k, (start, end, top) in shown:
        offsets = np.c_[centres, np.zeros((len(centres), 2))] - pose.position[k]
        ahead = (offsets @ pose.rotation[k])[:, 0]
        assert np.any((ahead - 1.5 < end + 0.25) & (ahead + 1.5 > start - 0.25)), (
            k, start, end, ahead)
        assert 0.01 < top < 0.12
