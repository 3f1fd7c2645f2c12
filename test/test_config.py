import math
import re
import subprocess
import sys
from pathlib import Path

import pytest

from planar_vo.core import config

ROOT = Path(__file__).resolve().parents[1]

CORE = sorted('.'.join(p.relative_to(ROOT).with_suffix('').parts)
              for p in (ROOT / 'planar_vo' / 'core').rglob('*.py'))


def test_defaults_are_valid_and_described():
    values = config.validate({})
    assert values == config.defaults()
    for p in config.SCHEMA:
        assert p.description.endswith('.'), p.name
        if isinstance(p.default, (int, float)) and not isinstance(p.default, bool):
            assert p.low is not None and p.high is not None and p.low <= p.default <= p.high


def test_ints_are_accepted_for_floats_and_ranges_enforced():
    assert config.validate({'camera_height': 1})['camera_height'] == 1.0
    with pytest.raises(config.ConfigError, match='outside its range'):
        config.validate({'camera_height': 0.0})
    with pytest.raises(config.ConfigError, match='whole number'):
        config.validate({'max_features': 10.5})
    with pytest.raises(config.ConfigError, match='one of'):
        config.validate({'ransac_method': '5point'})
    with pytest.raises(config.ConfigError, match='unknown parameter'):
        config.validate({'camera_hieght': 1.0})
    with pytest.raises(config.ConfigError, match='true or false'):
        config.validate({'publish_tf': 'yes'})
    with pytest.raises(config.ConfigError, match='range'):
        config.validate({'camera_pitch': math.nan})


def test_params_file_round_trip_and_errors(tmp_path):
    good = tmp_path / 'p.yaml'
    good.write_text('planar_vo:\n  ros__parameters:\n    camera_height: 1.5\n')
    assert config.load_params_file(good)['camera_height'] == 1.5
    wildcard = tmp_path / 'w.yaml'
    wildcard.write_text('/**:\n  ros__parameters:\n    camera_x: 0.5\n')
    assert config.load_params_file(wildcard)['camera_x'] == 0.5
    with pytest.raises(config.ConfigError, match='cannot read'):
        config.load_params_file(tmp_path / 'missing.yaml')
    bad = tmp_path / 'bad.yaml'
    bad.write_text('planar_vo: [unclosed\n')
    with pytest.raises(config.ConfigError, match='not valid YAML'):
        config.load_params_file(bad)
    twice = tmp_path / 'twice.yaml'
    twice.write_text('planar_vo:\n  ros__parameters:\n    camera_x: 0.5\n    camera_y: 0.0\n'
                     '    camera_x: 0.7\n')
    with pytest.raises(config.ConfigError, match=r'"camera_x" is given twice \(lines 3 and 5\)'):
        config.load_params_file(twice)
    other = tmp_path / 'other.yaml'
    other.write_text('some_node:\n  ros__parameters:\n    x: 1\n')
    with pytest.raises(config.ConfigError, match='no "planar_vo: ros__parameters:"'):
        config.load_params_file(other)


def test_shipped_params_file_matches_the_schema():
    assert config.load_params_file('config/planar_vo.yaml') == config.defaults()


def test_shipped_params_file_lists_every_parameter():
    """Users copy it and edit it: a parameter it leaves out is one they never see (the ground
    model, the wheelbase and the rolling shutter once were)."""
    text = Path('config/planar_vo.yaml').read_text()
    listed = set(re.findall(r'^    ([a-z_0-9]+):', text, re.MULTILINE))
    assert listed == set(config.defaults())


def test_core_imports_no_ros_and_no_bag_library():
    code = ('import sys\n'
            + ''.join(f'import {m}\n' for m in CORE)
            + 'bad = [m for m in sys.modules if m.split(".")[0] in '
              '("rclpy", "rosbags", "mcap", "sensor_msgs", "nav_msgs", "matplotlib")]\n'
              'print(",".join(bad))\n')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == ''
