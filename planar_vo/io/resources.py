"""Where the package's files and executables are: the source tree or an install.

Run from the source tree (a checkout, ``pip install -e``, ``colcon build --symlink-install``),
``config/``, ``launch/`` and ``bags/`` sit next to the ``planar_vo`` package. Installed
(``colcon build``), they are in ``share/planar_vo``, found through ``ament_index_python``
(or, for a pip wheel, under the environment's prefix).
Executables are found on ``PATH`` (a pip install) or in the package's ``lib/planar_vo``, where
``ros2 run`` looks; never next to ``sys.executable``, which after a colcon install is
``/usr/bin/python3``.
"""

from __future__ import annotations

import os
import shutil
import sysconfig
from pathlib import Path

from planar_vo.io.errors import ResourceError

__all__ = ['PACKAGE', 'share_dir', 'default_params', 'default_bag',
           'launch_file', 'executable', 'from_source_tree', 'installed_prefix']

PACKAGE = 'planar_vo'
_SOURCE_ROOT = Path(__file__).resolve().parents[2]


def from_source_tree() -> bool:
    """True when this code runs from a checkout of the package (not from an install)."""
    return (_SOURCE_ROOT / 'package.xml').is_file() and (_SOURCE_ROOT / 'config').is_dir()


def installed_prefix() -> Path | None:
    """The install prefix the ament index gives for planar_vo, or None (not sourced)."""
    try:
        from ament_index_python.packages import get_package_prefix
        return Path(get_package_prefix(PACKAGE))
    except (ImportError, LookupError, ValueError, OSError):  # OSError: AMENT_PREFIX_PATH unset
        return None


def share_dir() -> Path:
    """The directory holding ``config/``, ``launch/`` and ``bags/``."""
    if from_source_tree():
        return _SOURCE_ROOT
    for prefix in (installed_prefix(), Path(sysconfig.get_path('data'))):  # colcon, pip
        if prefix is not None and (prefix / 'share' / PACKAGE).is_dir():
            return prefix / 'share' / PACKAGE
    raise ResourceError(
        f'cannot find the {PACKAGE} share directory: source the workspace '
        '(source install/setup.bash) or run from the source tree')


def default_params() -> Path:
    """The shipped parameter file, ``config/planar_vo.yaml``."""
    return share_dir() / 'config' / 'planar_vo.yaml'


def default_bag() -> Path:
    """The bundled synthetic bag, ``bags/default``."""
    return share_dir() / 'bags' / 'default'


def launch_file() -> Path:
    """``launch/planar_vo.launch.py``."""
    return share_dir() / 'launch' / 'planar_vo.launch.py'


def executable(name: str) -> str:
    """Path of one of the package's executables: on PATH, else in ``lib/planar_vo``."""
    found = shutil.which(name)
    if found:
        return found
    prefix = installed_prefix()
    if prefix is not None:
        candidate = prefix / 'lib' / PACKAGE / name
        if candidate.is_file() and os.access(candidate, os.X_OK):
            return str(candidate)
    raise ResourceError(
        f'{name} is neither on PATH nor in the lib/{PACKAGE} directory of a sourced ROS '
        'workspace: source install/setup.bash (colcon) or activate the environment where '
        f'{PACKAGE} was pip-installed')
