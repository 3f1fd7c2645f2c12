"""The ground warp KLT can match against, checked against the ground's own geometry."""

import numpy as np

from planar_vo.core.estimation.ransac import TransferModel
from planar_vo.core.frontend.warp import GroundWarp
from planar_vo.core.geometry.camera import CameraModel, Mounting
from test.conftest import move_points, observe

MOUNTING = Mounting(x=1.2, y=0.1, height=1.25, pitch=np.radians(8.0), roll=0.01, yaw=0.02)
CAMERA = CameraModel(np.array([[460.0, 0, 320.0], [0, 460.0, 240.0], [0, 0, 1]]),
                     np.array([-0.28, 0.07, 0.0005, -0.0005, 0.0]), 'plumb_bob', 640, 480)


def _bilinear(grid, pixels):
    from planar_vo.core.frontend.tracker import _bilinear
    return _bilinear(grid, pixels.astype(np.float32))


def test_the_maps_take_each_ground_pixel_back_to_where_it_was():
    """Ground points seen in two frames (closed form: the ground-to-image projection and the
    planar motion): the maps at a point's pixel in the second frame give its pixel in the
    first within 0.06 px (they are interpolated from a 16 px grid), up to the image's edges
    (the outer half cells are extrapolated, not held: held, they were up to 8 px off)."""
    rng = np.random.default_rng(2)
    motion = np.array([0.45, 0.02, 0.03])  # 0.45 m and 1.7 deg: a car at 15 Hz, turning
    points = np.c_[rng.uniform(3.5, 12.0, 3000), rng.uniform(-6.0, 6.0, 3000)]
    first = CAMERA.distort(observe(MOUNTING, points))
    second = CAMERA.distort(observe(MOUNTING, move_points(points, motion)))
    inside = np.all((second > 0) & (second < [639, 479]), axis=1)
    edge = inside & np.any((second < 8) | (second > [631, 471]), axis=1)
    warp = GroundWarp(CAMERA).pixel_map(TransferModel.from_camera(MOUNTING, CAMERA), motion)
    back = _bilinear(warp, second)
    error = np.linalg.norm(back - first, axis=1)
    assert inside.sum() > 1000 and edge.sum() > 20
    assert error[inside].max() < 0.06, error[inside].max()  # 0.042 (0.011 on an 8 px grid)
    # Above the horizon there is no ground: the maps point far outside the image.
    assert warp[0, :, 1].max() < -1000
