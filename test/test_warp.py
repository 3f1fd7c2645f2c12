"""The ground warp KLT can match against, checked against the ground's own geometry."""

import numpy as np

from planar_vo.camera import CameraModel, Mounting
from planar_vo.ransac import TransferModel
from planar_vo.warp import GroundWarp
from test.conftest import move_points, observe

MOUNTING = Mounting(x=1.2, y=0.1, height=1.25, pitch=np.radians(8.0), roll=0.01, yaw=0.02)
CAMERA = CameraModel(np.array([[460.0, 0, 320.0], [0, 460.0, 240.0], [0, 0, 1]]),
                     np.array([-0.28, 0.07, 0.0005, -0.0005, 0.0]), 'plumb_bob', 640, 480)


def _bilinear(grid, pixels):
    from planar_vo.tracker import _bilinear
    return _bilinear(grid, pixels.astype(np.float32))


def test_the_maps_take_each_ground_pixel_back_to_where_it_was():
    """Ground points seen in two frames (closed form: the ground-to-image projection and the
    planar motion): the maps at a point's pixel in the second frame give its pixel in the
    first within 0.03 px (they are interpolated from an 8 px grid)."""
    rng = np.random.default_rng(2)
    motion = np.array([0.45, 0.02, 0.03])  # 0.45 m and 1.7 deg: a car at 15 Hz, turning
    points = np.c_[rng.uniform(3.5, 12.0, 300), rng.uniform(-3.0, 3.0, 300)]
    first = CAMERA.distort(observe(MOUNTING, points))
    second = CAMERA.distort(observe(MOUNTING, move_points(points, motion)))
    inside = np.all((second > 20) & (second < [620, 460]), axis=1)
    map_x, map_y = GroundWarp(CAMERA).maps(TransferModel.from_camera(MOUNTING, CAMERA), motion)
    back = np.c_[_bilinear(map_x, second[inside]), _bilinear(map_y, second[inside])]
    error = np.linalg.norm(back - first[inside], axis=1)
    assert inside.sum() > 100 and error.max() < 0.03, error.max()  # measured 0.011
    # Above the horizon there is no ground: the maps point far outside the image.
    assert map_y[0].max() < -1000
