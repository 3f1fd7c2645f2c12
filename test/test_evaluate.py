import numpy as np
import pytest

from planar_vo.core.metrics import associate, metrics
from planar_vo.io.tum import write_tum
from planar_vo.tools.plots import plot_trajectories


def circle(n=400, radius=20.0, scale=1.0, yaw_bias=0.0):
    a = np.linspace(0, np.pi, n)
    xy = scale * radius * np.c_[np.sin(a), 1 - np.cos(a)]
    return np.c_[xy, a + yaw_bias * a]


def test_perfect_estimate_has_zero_error():
    m = metrics(circle(), circle())
    assert m['t_rel_percent'] == pytest.approx(0, abs=1e-9)
    assert m['r_rel_deg_per_100m'] == pytest.approx(0, abs=1e-9)
    assert m['scale_ratio'] == pytest.approx(1)
    assert m['path_length_m'] == pytest.approx(np.pi * 20, rel=1e-4)


def test_scale_error_shows_in_t_rel_and_scale_ratio():
    line = np.c_[np.linspace(0, 50, 200), np.zeros(200), np.zeros(200)]
    m = metrics(line * [1.02, 1, 1], line)
    assert m['scale_ratio'] == pytest.approx(1.02, rel=1e-6)
    assert m['t_rel_percent'] == pytest.approx(2.0, rel=1e-2)  # segments end past their length
    assert m['final_drift_m'] == pytest.approx(1.0)
    # On a curve the error of a segment is its chord's, shorter than its length.
    curved = metrics(circle(scale=1.02), circle())
    assert 1.0 < curved['t_rel_percent'] < 2.0
    assert curved['r_rel_deg_per_100m'] == pytest.approx(0, abs=1e-9)


def test_yaw_drift_shows_in_r_rel():
    m = metrics(circle(yaw_bias=0.01), circle())
    assert m['r_rel_deg_per_100m'] > 0.5
    assert m['final_yaw_error_deg'] == pytest.approx(np.degrees(0.01 * np.pi), rel=1e-6)


def test_association_by_stamp():
    ia, ib = associate(np.array([0.0, 0.1, 0.2, 5.0]), np.array([0.2, 0.1, 0.0]))
    assert ia.tolist() == [0, 1, 2] and ib.tolist() == [2, 1, 0]


def test_tum_export(tmp_path):
    path = tmp_path / 't.txt'
    write_tum(path, np.array([1.0, 2.0]), np.array([[0, 0, 0], [1, 2, np.pi / 2]]))
    rows = np.loadtxt(path)
    assert rows.shape == (2, 8)
    np.testing.assert_allclose(rows[1, 6:], [np.sin(np.pi / 4), np.cos(np.pi / 4)])


def test_plot_is_written(tmp_path):
    out = tmp_path / 'p.png'
    plot_trajectories(out, {'truth': circle(), 'estimate': circle(scale=1.01)})
    assert out.read_bytes()[:4] == b'\x89PNG'
