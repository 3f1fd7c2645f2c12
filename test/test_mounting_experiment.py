"""planar_vo_mounting_experiment, the README's sprung-body tables as a command (short drives)."""

import json
import subprocess

import numpy as np

from planar_vo.io import resources
from planar_vo.tools.experiments.mounting_experiment import (
    OPENCV,
    OURS,
    PLAIN_OPENCV,
    RIGID,
    VARIANTS,
)


def _run(*args):
    exe = resources.executable('planar_vo_mounting_experiment')
    return subprocess.run([exe, *args], capture_output=True, text=True, timeout=300)


def test_experiment_reports_every_variant_and_the_ratios():
    """One 40-frame `car` drive, rendered with 2 x 2 rays a pixel: every variant scored
    against the renderer's path, the rigid mount as accurate as on any rigid drive, and the
    ratios those means give."""
    run = _run('--frames', '40', '--seeds', '3', '--supersample', '2', '--rate', '20', '--json')
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    assert out['supersample'] == 2 and out['rate'] == 20
    drive = out['drives']['3']
    assert set(drive) == set(VARIANTS)
    assert all(np.isfinite(v['t_rel_percent']) and v['path_length_m'] > 4 for v in drive.values())
    assert drive[RIGID]['t_rel_percent'] < 0.05, drive  # measured 0.0201 %
    assert abs(drive[RIGID]['scale_ratio'] - 1) < 0.0005, drive  # measured 0.99981
    summary = out['summary']
    assert np.isclose(summary['sprung_over_rigid_mount'],
                      drive[OURS]['t_rel_percent'] / drive[RIGID]['t_rel_percent'])
    assert np.isclose(summary['opencv_over_ours'],
                      drive[OPENCV]['t_rel_percent'] / drive[OURS]['t_rel_percent'])
    assert np.isclose(summary['plain_opencv_over_ours'],
                      drive[PLAIN_OPENCV]['t_rel_percent'] / drive[OURS]['t_rel_percent'])


def test_experiment_bad_arguments_are_one_line_and_exit_2():
    for args, message in ((('--frames', '10'), 'at least 30'),
                          (('--seeds', '1,x'), 'comma-separated integers'),
                          (('--seeds', '1,1'), 'distinct'),
                          (('--supersample', '0'), 'must be 1 to 4'),
                          (('--rate', 'fast'), 'number of Hz'), (('--rate', '1'), '5 to 120'),
                          (('--scenario', 'default'), 'invalid choice')):
        run = _run(*args)
        err = run.stderr.strip().splitlines()
        assert run.returncode == 2 and len(err) == 1 and message in err[0], (args, run.stderr)
