"""The paper's Monte Carlo experiment (section 4, Fig. 5) and its OpenCV extension."""

import json

import pytest

from planar_vo import paper_experiment as pe

OURS = {'essential_1pt', 'essential_2pt', 'homography_1pt', 'homography_2pt', 'homography_npt'}


def by_solver(results, sigma):
    return {r['solver']: r for r in results if r['sigma'] == sigma}


def test_every_solver_is_exact_without_noise():
    rows = by_solver(pe.run_experiment(20, [0.0], seed=1), 0.0)
    assert set(rows) == {s.name for s in pe.SOLVERS}
    for name, row in rows.items():
        tol = 1e-6 if name in OURS else 1e-4
        assert row['phi_median_abs_err'] < tol, row
        assert row['theta_median_abs_err'] < tol, row
        if row['rho_median_rel_err'] is not None:
            assert row['rho_median_rel_err'] < tol, row


def test_one_point_beats_two_points_at_one_pixel_as_in_the_paper():
    rows = by_solver(pe.run_experiment(300, [1.0], seed=0), 1.0)
    one, two = rows['homography_1pt'], rows['homography_2pt']
    # the design notes measured 0.006 vs 0.11 rad: a margin of more than 5x
    assert 5 * one['phi_median_abs_err'] < two['phi_median_abs_err']
    assert rows['essential_1pt']['phi_median_abs_err'] < rows['essential_2pt'][
        'phi_median_abs_err']
    # only the homography solvers know the scale (from the camera height)
    assert rows['essential_1pt']['rho_median_rel_err'] is None
    assert rows['homography_npt']['rho_median_rel_err'] < 0.05


def test_json_and_plot(tmp_path, capsys):
    plot = tmp_path / 'fig5.png'
    assert pe.main(['--trials', '10', '--sigmas', '0,1', '--json', '--plot', str(plot)]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data['setup']['camera_height_m'] == 1.5
    assert {r['solver'] for r in data['results']} == {s.name for s in pe.SOLVERS}
    assert {r['sigma'] for r in data['results']} == {0.0, 1.0}
    assert plot.read_bytes()[:4] == b'\x89PNG'


@pytest.mark.parametrize('args', [['--trials', '-3'], ['--sigmas', 'a,b'],
                                  ['--plot', '/nonexistent/dir/p.png']])
def test_bad_arguments_exit_2_with_one_line(capsys, args):
    assert pe.main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith('planar_vo_paper_experiment: error:')
