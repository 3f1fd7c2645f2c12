"""package.xml declares what the code imports, with keys rosdep resolves on Noble + Jazzy."""

import ast
import subprocess
import sys
import xml.etree.ElementTree as ET

from planar_vo.io import resources

ROOT = resources.share_dir()

# Keys read from ros/rosdistro (commit 8468e88, 2026-08): ROS packages released for Jazzy in
# jazzy/distribution.yaml, system keys with an `ubuntu` entry in rosdep/python.yaml.
JAZZY_PACKAGES = {'rclpy', 'rcl_interfaces', 'builtin_interfaces', 'std_msgs', 'sensor_msgs',
                  'nav_msgs', 'geometry_msgs', 'std_srvs', 'diagnostic_msgs',
                  'ament_index_python', 'tf2_ros_py', 'launch', 'launch_ros'}
ROSDEP_PYTHON_KEYS = {'python3-opencv', 'python3-numpy', 'python3-yaml', 'python3-matplotlib',
                      'python3-pytest', 'python3-rosbags-pip', 'python3-tqdm'}
# Import name -> rosdep key, where they differ.
KEY_OF_IMPORT = {'cv2': 'python3-opencv', 'numpy': 'python3-numpy', 'yaml': 'python3-yaml',
                 'matplotlib': 'python3-matplotlib', 'rosbags': 'python3-rosbags-pip',
                 'tf2_ros': 'tf2_ros_py', 'pytest': 'python3-pytest', 'tqdm': 'python3-tqdm'}


def _depends(*tags):
    root = ET.parse(ROOT / 'package.xml').getroot()
    return {e.text.strip() for tag in tags for e in root.iter(tag)}


def _imports(paths):
    names = set()
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names.update(a.name.split('.')[0] for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names.add(node.module.split('.')[0])
    return names - set(sys.stdlib_module_names) - {'planar_vo', '__future__'}


def test_every_import_is_a_declared_run_dependency():
    code = [*(ROOT / 'planar_vo').rglob('*.py'), *(ROOT / 'launch').glob('*.py')]
    needed = {KEY_OF_IMPORT.get(name, name) for name in _imports(code)}
    assert needed - {'setuptools'} <= _depends('exec_depend', 'depend'), needed


def test_every_key_resolves_with_rosdep_on_noble_jazzy():
    keys = _depends('exec_depend', 'depend', 'test_depend', 'build_depend')
    assert keys <= JAZZY_PACKAGES | ROSDEP_PYTHON_KEYS, keys - JAZZY_PACKAGES - ROSDEP_PYTHON_KEYS
    assert 'tf2_ros' not in keys  # the C++ library; the Python module is tf2_ros_py


def test_the_node_needs_no_bag_library():
    """python3-rosbags-pip (a pip key, PEP 668 on Noble) is only for the offline tools."""
    code = ('import sys, planar_vo.ros.node\n'
            'print(sorted(m for m in sys.modules if m.split(".")[0] in ("rosbags", '
            '"matplotlib")))\n')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == '[]'
