"""The first motion of a start or a restart, from aligning the images through the ground.

Truth: the renderer's path (planar_vo.synth builds its camera on its own path)."""

import numpy as np
import pytest

from planar_vo import synth
from planar_vo.core import config
from planar_vo.core.config import mounting_from_params
from planar_vo.core.estimation.ransac import TransferModel
from planar_vo.core.frontend.motion_search import GroundMotionSearch
from planar_vo.core.odometry import VisualOdometry
from test.conftest import synth_camera_model


def _true_motions(traj):
    """Motion (x, y, yaw) of base_link k in base_link k-1, for every k >= 1."""
    d = np.diff(np.c_[traj.x, traj.y], axis=0)
    c, s = np.cos(traj.yaw[:-1]), np.sin(traj.yaw[:-1])
    return np.c_[c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], np.diff(traj.yaw)]


def _params(renderer, **overrides):
    m = renderer.mounting
    return config.validate({**config.mounting_params(m), **overrides})


@pytest.fixture(scope='module')
def car_at_10_hz():
    """The sprung `car` at 10 Hz: 0.3-0.8 m between frames, the body tilting as it goes."""
    renderer, traj = synth.render_scenario('car', 12, 3, rate=10.0)
    return renderer, traj, [renderer.render_frame(traj, k) for k in range(12)]


# Measured, worst step: `default` 2.6 mm / 0.67 mrad, `tight` 1.0 mm / 0.59 mrad, `car`
# 24.9 mm / 0.82 mrad.
@pytest.mark.parametrize('scenario, rate, position_m, yaw_mrad', [
    ('default', 10.0, 0.006, 1.5),  # rigid mount: only the search's own error
    ('tight', 15.0, 0.003, 1.5),  # turning hard
    ('car', 10.0, 0.05, 2.5),  # the body's tilt is not searched
])
def test_search_finds_the_true_motion(scenario, rate, position_m, yaw_mrad):
    renderer, traj = synth.render_scenario(scenario, 8, 3, rate=rate)
    images = [renderer.render_frame(traj, k) for k in range(8)]
    params = _params(renderer)
    model = TransferModel.from_camera(mounting_from_params(params),
                                      synth_camera_model(renderer))
    search = GroundMotionSearch(synth_camera_model(renderer))
    for k, truth in enumerate(_true_motions(traj), start=1):
        found = search.search(images[k - 1], images[k], 1 / rate, model,
                              params['horizon_margin'])
        assert np.linalg.norm(found[:2] - truth[:2]) < position_m, (k, found, truth)
        assert abs(found[2] - truth[2]) < yaw_mrad * 1e-3, (k, found, truth)


def test_search_is_not_moved_by_a_gain_change_and_finds_nothing_in_a_blank_image(
        car_at_10_hz):
    renderer, traj, images = car_at_10_hz
    params = _params(renderer)
    model = TransferModel.from_camera(mounting_from_params(params),
                                      synth_camera_model(renderer))
    search = GroundMotionSearch(synth_camera_model(renderer))
    args = (0.1, model, params['horizon_margin'])
    found = search.search(images[0], images[1], *args)
    brighter = np.clip(images[1].astype(float) * 1.25, 0, 255).astype(np.uint8)
    # Measured: the same motion exactly with the gain changed; 0.62 mm (or mrad) standing.
    np.testing.assert_allclose(search.search(images[0], brighter, *args), found, atol=0.001)
    still = search.search(images[1], images[1], *args)
    assert np.abs(still).max() < 0.0015, still
    assert search.search(np.full_like(images[0], 128), images[1], *args) is None


def test_first_pair_at_10_hz_keeps_its_tracks(car_at_10_hz):
    """0.5 m between the first two frames: KLT unaided kept 263 tracks, 59 of them fitting
    the motion (on a longer drive of this body at 7.5 m/s, 13 of 81, and the first pair's
    pitch came out 2 deg off); started from the search's motion, in the warped image, 421,
    416 fitting, the step within 6 mm of the truth."""
    renderer, traj, images = car_at_10_hz
    truth = _true_motions(traj)[0]
    runs = {}
    for search in (True, False):
        vo = VisualOdometry.from_params(synth_camera_model(renderer), _params(
            renderer, ground_model='plane', estimate_attitude=True, self_calibrate=False,
                max_features=700,
            klt_first_search=search))
        vo.process(images[0], 0.0)
        runs[search] = vo.process(images[1], 0.1)
    found = runs[True]
    assert found.status == 'ok' and found.inliers > 0.9 * found.correspondences > 250, found
    assert np.linalg.norm(found.pose[:2] - truth[:2]) < 0.01, (found.pose, truth)
    unaided = runs[False]
    assert unaided.inliers < 0.3 * found.inliers, unaided


def test_a_long_gap_scores_a_bounded_grid_and_gives_no_wrong_motion():
    """Frames 1 s apart (max_frame_gap; the node's fuzz test sends 0.35 and 0.62 s after a
    restart): the motions searched would span 30 m and 3 rad, 56 000 of them at the coarse
    steps (gigabytes, a minute). The first grid is capped at about 600 and the steps grow. On this
    drive (5.3 m in that second) the best match is 0.57, under the 0.8 that counts: no
    prediction, rather than a wrong one."""
    renderer, traj = synth.render_scenario('default', 3, 1, rate=1.0)
    images = [renderer.render_frame(traj, k) for k in range(2)]
    params = _params(renderer)
    model = TransferModel.from_camera(mounting_from_params(params),
                                      synth_camera_model(renderer))
    search = GroundMotionSearch(synth_camera_model(renderer))
    scored = []
    original = search._scores
    search._scores = lambda *args: scored.append(len(args[3])) or original(*args)
    assert search.search(images[0], images[1], 1.0, model, params['horizon_margin']) is None
    assert sum(scored) < 1000, sum(scored)  # about 600, then three grids of 49
