import json
import subprocess

import numpy as np
import pytest

from planar_vo.io import resources
from planar_vo.tools.experiments import paper_experiment as pe

SCRIPT = resources.executable('planar_vo_paper_experiment')


@pytest.fixture(scope='module')
def noiseless():
    return {r['solver']: r for r in pe.run_experiment(20, [0.0], seed=3)}


@pytest.fixture(scope='module')
def one_pixel():
    data = pe.make_trials(300, seed=0)
    paper = [s for s in pe.SOLVERS if s.paper]
    raw = pe.estimate_all(data, 1.0, paper)
    return {s.name: pe.summarize(s, 1.0, raw[s.name]) for s in paper}


def test_trials_are_visible_in_both_images_and_deterministic():
    a, b = pe.make_trials(5, seed=7), pe.make_trials(5, seed=7)
    np.testing.assert_array_equal(a.pixels1, b.pixels1)
    np.testing.assert_array_equal(a.noise2, b.noise2)
    for pix in (a.pixels1, a.pixels2):
        assert pix.shape == (5, pe.POINTS, 2)
        assert np.all(pix >= 0) and np.all(pix[..., 0] < 640) and np.all(pix[..., 1] < 480)
        assert np.all(pix[..., 1] > 240)  # ground: below the horizon of a level camera


def test_every_solver_is_exact_without_noise(noiseless):
    assert set(noiseless) == {s.name for s in pe.SOLVERS}
    for name, r in noiseless.items():
        tol = 1e-4 if name.startswith('cv_') else 1e-6
        assert r['failures'] == 0, name
        assert r['phi_median_abs_err'] < tol, name
        assert r['theta_median_abs_err'] < tol, name
        if name.startswith(('homography', 'cv_homography')):
            assert r['rho_median_rel_err'] < tol, name
        else:
            assert r['rho_median_rel_err'] is None, name


def test_one_point_beats_two_point_at_one_pixel(one_pixel):
    # The paper's Fig. 5: the circular prior makes the 1-point solvers far more accurate.
    h1, h2 = one_pixel['homography_1pt'], one_pixel['homography_2pt']
    e1, e2 = one_pixel['essential_1pt'], one_pixel['essential_2pt']
    assert h1['phi_median_abs_err'] * 5 < h2['phi_median_abs_err']
    assert e1['phi_median_abs_err'] * 5 < e2['phi_median_abs_err']
    assert 0.001 < h1['phi_median_abs_err'] < 0.05
    # only the homography solvers know the scale (from the camera height)
    assert h1['rho_median_rel_err'] is not None and e1['rho_median_rel_err'] is None


def test_results_do_not_depend_on_the_other_sigmas():
    alone = pe.run_experiment(10, [1.0], seed=1)
    both = pe.run_experiment(10, [0.0, 1.0], seed=1)[len(pe.SOLVERS):]
    for a, b in zip(alone, both, strict=True):
        assert a['phi_median_abs_err'] == b['phi_median_abs_err']


def test_json_output_has_every_solver(capsys):
    assert pe.main(['--trials', '3', '--sigmas', '0,1', '--seed', '2', '--json']) == 0
    out = json.loads(capsys.readouterr().out)
    assert out['setup']['trials'] == 3
    assert out['setup']['K'] == pe.K.tolist()
    results = out['results']
    assert len(results) == 2 * len(pe.SOLVERS)
    assert {r['solver'] for r in results} == {s.name for s in pe.SOLVERS}
    for r in results:
        assert set(r) >= {'solver', 'points', 'sigma', 'phi_median_abs_err',
                          'theta_median_abs_err', 'rho_median_rel_err', 'time_us'}
        assert r['time_us'] > 0


def test_json_with_plot_keeps_stdout_pure_json(tmp_path, capsys):
    plot = tmp_path / 'fig5.png'
    assert pe.main(['--trials', '10', '--sigmas', '0,1', '--json', '--plot', str(plot)]) == 0
    captured = capsys.readouterr()
    data = json.loads(captured.out)
    assert data['setup']['camera_height_m'] == 1.5
    assert {r['sigma'] for r in data['results']} == {0.0, 1.0}
    assert str(plot) in captured.err
    assert plot.read_bytes()[:4] == b'\x89PNG'


def test_table_output(capsys):
    assert pe.main(['--trials', '2', '--sigmas', '0.5']) == 0
    out = capsys.readouterr().out
    for s in pe.SOLVERS:
        assert s.name in out


def test_plot_writes_a_png(tmp_path, capsys):
    path = tmp_path / 'fig5.png'
    assert pe.main(['--trials', '5', '--sigmas', '0', '--plot', str(path)]) == 0
    assert path.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert str(path) in capsys.readouterr().out


@pytest.mark.parametrize('args', [
    ['--trials', '-1'],
    ['--trials', 'many'],
    ['--sigmas', '0,x,1'],
    ['--sigmas', '-1'],
    ['--seed', '-3'],
    ['--plot', '/nonexistent-dir/fig.png'],
    ['--plot', '.'],
    ['--plot', 'fig.jpg'],
    ['--plot', '/sys/fig.png'],  # unwritable even for root
    ['--bogus'],
])
def test_bad_arguments_exit_2_with_one_line(args, capsys):
    assert pe.main(args) == 2
    captured = capsys.readouterr()
    assert captured.out == ''
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('planar_vo_paper_experiment: error:')


def test_console_script_bad_args_and_help():
    bad = subprocess.run([SCRIPT, '--trials', '-5'], capture_output=True, text=True)
    assert bad.returncode == 2
    assert 'Traceback' not in bad.stderr and len(bad.stderr.strip().splitlines()) == 1
    helped = subprocess.run([SCRIPT, '--help'], capture_output=True, text=True)
    assert helped.returncode == 0
    for option in ('--trials', '--sigmas', '--seed', '--json', '--plot'):
        assert option in helped.stdout
