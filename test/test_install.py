"""The apt-ROS install path, as a user takes it: colcon build, source local_setup.bash, run.

One ``colcon build`` per session (the ``colcon_install`` fixture); every test then runs the
installed package from a directory unrelated to the source tree, with only the workspace's
``local_setup.bash`` sourced and the venv's ``bin`` off PATH, so nothing is found by accident.
The interpreter stays this venv's Python (the executables' shebang), which is where the ROS 2
wheels are on this machine; on a robot it is /usr/bin/python3 with ROS from apt.
"""

import ast
import os
import re
import subprocess
import sys
from pathlib import Path

from test.conftest import domain_id

EXECUTABLES = ('planar_vo_node', 'planar_vo_replay', 'planar_vo_synth', 'planar_vo_demo',
               'planar_vo_bench', 'planar_vo_paper_experiment', 'planar_vo_soak',
               'planar_vo_calibrate', 'planar_vo_mounting_experiment')


def _clean_path() -> str:
    """PATH without this venv's bin: the installed tools must not come from there."""
    venv_bin = str(Path(sys.prefix) / 'bin')
    return os.pathsep.join(p for p in os.environ.get('PATH', '/usr/bin:/bin').split(os.pathsep)
                           if p and Path(p) != Path(venv_bin))


def run_sourced(workspace: Path, command: str, *, cwd: Path, timeout: float = 120.0):
    """Run ``command`` in bash after ``source install/local_setup.bash``."""
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(('AMENT_', 'COLCON_', 'PYTHONPATH', 'VIRTUAL_ENV'))}
    env.update(PATH=_clean_path(), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               ROS_DOMAIN_ID=domain_id(3), PYTHONUNBUFFERED='1')
    env.pop('ROS_LOCALHOST_ONLY', None)
    script = f'source {workspace / "install" / "local_setup.bash"} && {command}'
    return subprocess.run(['bash', '-c', script], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=timeout)


def test_installed_layout(colcon_install):
    install = colcon_install / 'install' / 'planar_vo'
    for name in EXECUTABLES:
        exe = install / 'lib' / 'planar_vo' / name
        assert exe.is_file() and os.access(exe, os.X_OK), exe
    share = install / 'share' / 'planar_vo'
    for name in ('package.xml', 'config/planar_vo.yaml', 'launch/planar_vo.launch.py',
                 'bags/default/metadata.yaml', 'bags/default/default.mcap'):
        assert (share / name).is_file(), name
    assert (install / 'share' / 'ament_index' / 'resource_index' / 'packages'
            / 'planar_vo').is_file()


def test_installed_package_finds_its_files_and_executables(colcon_install, tmp_path):
    code = ('from planar_vo.io import resources as r; '
            'print(r.__file__); print(r.default_params()); print(r.default_bag()); '
            f'print(r.launch_file()); print(*map(r.executable, {EXECUTABLES!r}))')
    out = run_sourced(colcon_install, f'{sys.executable} -c {code!r}', cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    install = colcon_install / 'install' / 'planar_vo'
    module, params, bag, launch, *exes = (Path(line) for line in out.stdout.split())
    assert module.is_relative_to(install / 'lib')  # the installed copy, not the checkout
    assert params == install / 'share' / 'planar_vo' / 'config' / 'planar_vo.yaml'
    assert bag == install / 'share' / 'planar_vo' / 'bags' / 'default'
    assert launch.is_file() and launch.is_relative_to(install / 'share')
    assert exes == [install / 'lib' / 'planar_vo' / name for name in EXECUTABLES]


def test_installed_demo_without_arguments(colcon_install, tmp_path):
    """What the issue's user ran: the installed planar_vo_demo, from another directory."""
    demo = colcon_install / 'install' / 'planar_vo' / 'lib' / 'planar_vo' / 'planar_vo_demo'
    out = run_sourced(colcon_install, str(demo), cwd=tmp_path, timeout=180)
    assert out.returncode == 0, out.stdout + out.stderr
    share = colcon_install / 'install' / 'planar_vo' / 'share' / 'planar_vo'
    sent = re.search(r'^(\S+): (\d+) frames sent over DDS, (\d+) odometry messages back',
                     out.stdout, re.M)
    assert sent, out.stdout
    assert Path(sent[1]) == share / 'bags' / 'default'
    assert int(sent[2]) == int(sent[3]) > 50
    t_rel = float(re.search(r't_rel ([\d.]+) %', out.stdout)[1])
    assert t_rel < 0.07  # against the bag's ground truth; measured 0.027 %
    diff = float(re.search(r'max position difference ([\d.]+) m', out.stdout)[1])
    assert diff < 1e-4  # the installed node and the offline replay agree (printed 0.0000)


def test_tests_run_against_the_install_find_every_executable(colcon_install):
    """``colcon test`` style: pytest with the installed package, no venv bin on PATH."""
    src = colcon_install / 'src' / 'planar_vo'
    tests = ['test/test_node.py::test_invalid_startup_parameter_is_one_clear_line',
             'test/test_paper_experiment.py::test_console_script_bad_args_and_help',
             'test/test_replay.py::test_cli_writes_odom_bag_tum_and_plot']
    out = run_sourced(colcon_install, f'{sys.executable} -m pytest -q -p no:cacheprovider '
                      + ' '.join(tests), cwd=src, timeout=180)
    assert out.returncode == 0, out.stdout + out.stderr
    assert re.search(r'\b5 passed', out.stdout), out.stdout


def test_launch_file_names_what_is_installed(colcon_install):
    """launch is not on the package index: check what can be checked without importing it."""
    share = colcon_install / 'install' / 'planar_vo' / 'share' / 'planar_vo'
    tree = ast.parse((share / 'launch' / 'planar_vo.launch.py').read_text())
    calls = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
            calls.setdefault(node.func.id, []).append(node)
    arguments = {c.args[0].value for c in calls['DeclareLaunchArgument']}
    assert arguments == {'params_file', 'namespace', 'image', 'camera_info', 'image_transport',
                         'use_sim_time'}
    (node_call,) = calls['Node']
    keywords = {k.arg: k.value for k in node_call.keywords}
    assert keywords['package'].value == 'planar_vo'
    exe = keywords['executable'].value
    assert (colcon_install / 'install' / 'planar_vo' / 'lib' / 'planar_vo' / exe).is_file()
    (share_call,) = calls['PathJoinSubstitution']
    parts = [e.value for e in share_call.args[0].elts if isinstance(e, ast.Constant)]
    assert (share.joinpath(*parts)).is_file()  # the default params file
    remapped = {e.elts[0].value for e in keywords['remappings'].elts}
    assert remapped == {'image', 'camera_info'}  # the node's own topic names

