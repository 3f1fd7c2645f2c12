"""The one parameter schema: names, defaults, ranges and descriptions.

The node declares every parameter from it; ``planar_vo_replay`` reads the same YAML
(``planar_vo: ros__parameters: ...``) through :func:`load_params_file`. No ROS imports.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import asdict, dataclass, make_dataclass, replace
from pathlib import Path
from typing import Any

import yaml

from planar_vo.core.errors import ConfigError
from planar_vo.core.geometry.camera import Mounting

__all__ = ['Param', 'SCHEMA', 'Params', 'make_params', 'ConfigError', 'defaults', 'validate',
           'load_params_file', 'read_params_yaml', 'params_section', 'MOUNTING_PARAMS',
           'schema_markdown', 'mounting_from_params', 'mounting_params']

NODE_NAME = 'planar_vo'


@dataclass(frozen=True)
class Param:
    """One parameter: its default fixes the type; numbers have an inclusive range."""

    name: str
    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] = ()
    read_only: bool = False

    def check(self, value: Any) -> Any:
        """Return ``value`` converted to this parameter's type, or raise ConfigError."""
        kind = type(self.default)
        if kind is bool:
            if not isinstance(value, bool):
                raise ConfigError(f'{self.name} must be true or false, got {value!r}')
            return value
        if kind in (int, float):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ConfigError(f'{self.name} must be a number, got {value!r}')
            if kind is int and not float(value).is_integer():
                raise ConfigError(f'{self.name} must be a whole number, got {value!r}')
            value = kind(value)
            if not math.isfinite(value) or (self.low is not None and value < self.low) or (
                    self.high is not None and value > self.high):
                raise ConfigError(
                    f'{self.name} = {value} is outside its range [{self.low}, {self.high}]')
            return value
        if not isinstance(value, str):
            raise ConfigError(f'{self.name} must be a string, got {value!r}')
        if self.choices and value not in self.choices:
            raise ConfigError(f'{self.name} must be one of {", ".join(self.choices)}, '
                              f'got {value!r}')
        if not self.choices and not value:
            raise ConfigError(f'{self.name} must not be empty')
        return value


_PI = math.pi
SCHEMA: tuple[Param, ...] = (
    # Mounting: the camera body frame (x forward) in base_link, as a static transform says.
    Param('camera_height', 1.25, 'Height of the camera above the ground, m (sets the scale).',
          0.02, 20.0),
    Param('camera_x', 1.2, 'Camera position ahead of base_link (rear axle), m.', -20.0, 20.0),
    Param('camera_y', 0.0, 'Camera position left of base_link, m.', -20.0, 20.0),
    Param('camera_roll', 0.0, 'Camera roll, rad.', -_PI / 2, _PI / 2),
    Param('camera_pitch', math.radians(8.0), 'Camera pitch, rad; positive looks down.',
          -_PI / 2, _PI / 2),
    Param('camera_yaw', 0.0, 'Camera yaw, rad; positive looks left.', -_PI, _PI),
    # Frames and outputs.
    Param('odom_frame', 'odom', 'Frame of the published pose (REP-105).'),
    Param('base_frame', 'base_link', 'Frame of the vehicle; the twist is expressed in it.'),
    Param('publish_tf', True, 'Broadcast odom -> base_link on /tf (needs tf2_ros).'),
    Param('publish_path', False, 'Publish ~/path (nav_msgs/Path) of the recent trajectory.'),
    Param('path_max_poses', 1000, 'Poses kept in ~/path (about 5 cm or 3 deg apart); the '
          'oldest are dropped.', 2, 100000),
    Param('publish_debug_image', False, 'Publish ~/debug_image with inlier/outlier tracks.'),
    Param('image_transport', 'raw', "'raw' subscribes image, 'compressed' image/compressed.",
          choices=('raw', 'compressed'), read_only=True),
    Param('image_reliability', 'auto',
          "QoS of the image subscription: 'best_effort' connects to every publisher; "
          "'reliable' avoids losing large frames but only connects to reliable publishers; "
          "'auto' is best effort, reliable while the images are over 512 kB and every "
          "publisher of the topic is reliable.",
          choices=('auto', 'best_effort', 'reliable'), read_only=True),
    Param('rectified_input', False, 'The images are rectified (e.g. image_proc image_rect): '
          'use the CameraInfo projection P and no distortion.', read_only=True),
    # Tracking.
    Param('image_binning', 0, 'Average the images over this many pixels square before '
          'tracking (the camera model follows); 0: 1 up to 1.5 megapixels, above it the '
          'least that brings them there (1920x1080: 2, 960x540), so a 1080p camera keeps up '
          'at 30 Hz (2x2 cost 0.118 -> 0.152 % t_rel on a rendered 1080p drive).', 0, 4),
    Param('max_features', 600, 'Features kept tracked; replenished on a grid. More hold the '
          'local ground on terrain (600 against 400: -24 % t_rel over 60 rendered drives, '
          'about 0.75 ms a frame per 100); 700 with estimate_attitude on a sprung body.',
          20, 5000),
    Param('quality_level', 0.005, 'Shi-Tomasi quality relative to the best corner.',
          1e-5, 0.5),
    Param('min_distance', 0.0, 'Minimum distance between features, px; 0: 8 px, more on '
          'images larger than 752x480 (by the square root of the area: 13 px at 1280x720, '
          '19 at 1920x1080), which keeps the features spread over the road.', 0.0, 100.0),
    Param('klt_window', 25, 'Lucas-Kanade window size, px (odd). Larger averages more pixels '
          'but costs more; without klt_prewarp 15 is better (the window deforms).', 5, 101),
    Param('klt_levels', 3, 'Pyramid levels above the full image for KLT when no motion '
          'predicts where tracks went (from a prediction it uses at most 1).', 0, 8),
    Param('fb_threshold', 0.5, 'Forward-backward KLT check: max round-trip error, px.',
          0.05, 10.0),
    Param('klt_prewarp', True, 'Warp the last image through the ground by the motion the '
          'last twist predicts before KLT, so its windows do not deform (less bias in scale, '
          'yaw and attitude; about 0.5 ms a frame). Off: use inlier_threshold 1.0.'),
    Param('klt_first_search', True, 'With no twist to predict the tracks (the first frame '
          'pair after a start or a restart), search the planar motion that aligns the two '
          'images through the ground and track from it, warped: at 10-15 Hz and 7.5 m/s KLT '
          'alone keeps a few tracks of that pair (20-70 ms, once).'),
    Param('learn_vignetting', True, "Learn the lens's vignetting from the drive (the ground's "
          'mean look over the last 20 m) and divide it out before KLT: its part symmetric about '
          "the image's centre once 3 m are driven, the whole once 10 m are (the road's stains "
          'averaged out). The darker corners otherwise hold the tracks back (a rendered road '
          'of a third of the usual contrast, 17 % less light in the corners: 0.34 % t_rel, '
          '0.05 with it). '
          'Off for images already flat-fielded, if you like: it learns a flat field there.'),
    Param('horizon_margin', math.radians(12.0),
          'Use only rays at least this far below the horizon, rad: points just below it are '
          'often not ground yet move like it.', 0.0, 1.4),
    # Pose estimation.
    Param('ransac_method', '1point', 'Hypotheses from 1 point (circular motion at the axle), '
          '2 points (planar) or histogram voting; opencv_homography is the plain OpenCV '
          '4-point way, for comparison only.',
          choices=('1point', '2point', 'histogram', 'opencv_homography')),
    Param('inlier_threshold', 0.5, 'RANSAC inlier threshold on the transfer error, px; keep '
          'it about 3x the inlier rms error /diagnostics report (1.0 without klt_prewarp).',
          0.1, 20.0),
    Param('ransac_confidence', 0.999, 'Probability of drawing an all-inlier sample.',
          0.5, 0.999999),
    Param('circular_refine', False, 'Keep the circular-motion constraint while refining.'),
    Param('min_inliers', 12, 'Fewest inliers for a frame to count as estimated.', 3, 1000),
    # The ground and real mountings: terrain, attitude and self-calibration.
    Param('ground_model', 'local', "What the tracks lie on. 'local': the road ahead as a "
          'smooth surface (grade, cross-slope, curvature and twist relative to the wheels, '
          'learned frame to frame) and the vehicle rotating between frames as it follows the '
          'road; holds on grades, crests, bumps, cambered roads and sprung bodies, and learns '
          "the static mounting (self_calibrate). 'plane': the paper's model, one ground plane "
          'under the wheels and a rigid, exact mounting (a calibrated rig on a flat floor; '
          'with estimate_attitude, a sprung body on flat ground).',
          choices=('local', 'plane')),
    Param('wheelbase', 2.7, 'With ground_model local: how far ahead of base_link the wheels '
          'stand on the ground (the front axle; a differential-drive robot: its front caster, '
          'or 0 when its drive wheels lead and the caster trails), m. The road is free to bend '
          'from there, also where the camera sees it from behind them (set beyond the middle '
          'of the camera\'s view of the ground: from where the view begins, with advice in '
          '/diagnostics).',
          0.0, 20.0),
    Param('track_width', 1.6, 'With ground_model local: how far apart the wheels at wheelbase '
          'stand, centre to centre of their contact patches, m (a car\'s front track; a '
          'differential-drive robot with wheelbase 0: its drive wheels; a front caster: 0). '
          'The road ahead meets the wheels there, not under the centre line, which a crowned '
          'road or a hill crossed at an angle holds lower or higher.',
          0.0, 5.0),
    Param('surface_half_width', 1.4, 'With ground_model local: how far to either side of '
          'base_link the road is surely one smooth surface, m. While the road beyond it on a '
          'side bends away (a crowned road at its crown, 1.5-2 m left of a car in its lane), '
          'the tracks beyond it are left out of the surface\'s fit. 100: every track, always.',
          0.3, 100.0),
    Param('estimate_attitude', False, "With ground_model plane: estimate the camera's pitch, "
          'roll and height change to the ground plane every frame, jointly with the motion (a '
          'sprung body on flat ground; a mounting known to about a degree). Off: the mounting '
          'is taken as rigid and exact.'),
    Param('attitude_sigma', math.radians(2.0), 'How far the body tilts (pitch, roll) from its '
          'mean attitude, rad (1 sigma).', 1e-4, 0.5),
    Param('attitude_rate', 0.5, 'How fast the body tilts at most, rad/s (1 sigma); the actual '
          'rate is learned.', 1e-4, 20.0),
    Param('body_pivot_below_camera', 0.0, 'With estimate_attitude: how far below the camera the '
          'body tilts about (its centre of mass; about 0.6 m on a car), m. 0: the camera '
          'tilts in place.', -5.0, 20.0),
    Param('body_pivot_behind_camera', 0.0, 'With estimate_attitude: how far behind the camera '
          'the body tilts about (negative: ahead of it), m.', -20.0, 20.0),
    Param('estimate_height', True, "Also estimate the camera height's change between frames "
          '(body bounce); each frame pair starts from the height those changes summed to, '
          'about camera_height, which stays the mean and the scale.'),
    Param('bounce_sigma', 0.03, 'With estimate_height: how far the camera height moves from '
          'its mean, m (1 sigma).', 1e-5, 1.0),
    Param('bounce_rate', 0.3, 'With estimate_height: how fast the camera height moves at '
          'most, m/s (1 sigma).', 1e-5, 10.0),
    Param('self_calibrate', True, 'Learn the static camera_pitch, camera_roll, camera_yaw and '
          'camera_x from the drive, starting from the configured values (with ground_model '
          'local, or plane with estimate_attitude).'),
    # Rolling-shutter cameras (DESIGN.md section 7).
    Param('rolling_shutter_readout', 0.0, 'Rolling shutter: time from reading the first image '
          'row to the last, s; 0 is a global shutter. Most webcams and the Raspberry Pi '
          'cameras read 10-35 ms: the datasheet gives it as the line time (row period) times '
          'the rows read (e.g. 1/frame rate minus the vertical blanking), or learn it from a '
          'drive with turns (learn_rolling_shutter, planar_vo_calibrate). Each track is then '
          'moved to its own row\'s time (the frame motion stretched by the twist).', 0.0, 0.2),
    Param('rolling_shutter_stamp', 'middle', 'Where in the readout the driver stamps the '
          "image: 'start' (first row), 'middle' or 'end' (last row); the published pose is "
          'the pose of that row. Only matters with rolling_shutter_readout over 0.',
          choices=('start', 'middle', 'end')),
    Param('learn_rolling_shutter', False, 'Learn rolling_shutter_readout from the drive '
          '(turns and speed tell it), starting from the configured value: reported with its '
          'standard deviation in /diagnostics, a warning once when it differs from the '
          'configured value by over 2 ms, and used once known to 1 ms; until then the '
          'mounting\'s self-calibration waits (an unmodelled readout looks like a grade). '
          'For a rolling-shutter camera only: a global shutter on rough road learns 1-15 ms '
          'that are not there.'),
    Param('detect_rolling_shutter', True, 'With rolling_shutter_readout 0 and '
          'learn_rolling_shutter off (ground_model local): watch the first seconds of the drive '
          'for a rolling shutter\'s shear and, once its readout reads surely over 8 ms two ways '
          '(after 40 frame pairs and 15 m of road or 3 s: a bend in the road reads as a '
          'readout while it is in view), learn it as learn_rolling_shutter does, with a '
          'warning to set it. A global shutter is left as it is (43 rendered drives, rough '
          'road and terrain too: one found, a level camera; the watch ends after 40-55 pairs '
          'on most and costs about 10 ms a pair meanwhile); a readout under about 10 ms is not '
          'found.'),
    Param('max_frame_gap', 1.0, 'A larger gap between image stamps, or one backwards, restarts '
          'tracking (the pose is kept, its covariance inflated), s.', 0.01, 3600.0),
)

MOUNTING_PARAMS = ('camera_height', 'camera_x', 'camera_y', 'camera_roll', 'camera_pitch',
                   'camera_yaw')
_BY_NAME = {p.name: p for p in SCHEMA}


class _ParamsMethods:
    """What every :data:`Params` object can do besides holding the values."""

    def __getitem__(self, name: str) -> Any:
        """``params['camera_x']``, as from the dict of a params file."""
        return getattr(self, name)

    def replace(self, **changes: Any) -> Any:
        """A copy with ``changes`` checked against the schema (ConfigError if invalid)."""
        unknown = sorted(set(changes) - set(_BY_NAME))
        if unknown:
            raise ConfigError(f'unknown parameter(s): {", ".join(unknown)}')
        return replace(self, **{name: _BY_NAME[name].check(v) for name, v in changes.items()})

    def as_dict(self) -> dict[str, Any]:
        """Every value by name."""
        return asdict(self)


#: Frozen, typed values of every parameter in :data:`SCHEMA` (attributes by name; also
#: ``params['name']``); build one with :func:`make_params`.
Params = make_dataclass('Params', [(p.name, type(p.default)) for p in SCHEMA],
                        bases=(_ParamsMethods,), frozen=True)
Params.__module__ = __name__


def make_params(values: Mapping[str, Any] | None = None) -> Any:
    """:data:`Params` from the defaults overlaid with checked ``values`` (see validate)."""
    if isinstance(values, Params):
        return values
    return Params(**validate(dict(values or {})))


def defaults() -> dict[str, Any]:
    """Every parameter at its default."""
    return {p.name: p.default for p in SCHEMA}


def validate(values: dict[str, Any]) -> dict[str, Any]:
    """Defaults overlaid with checked ``values``; unknown names are an error (typos)."""
    unknown = sorted(set(values) - set(_BY_NAME))
    if unknown:
        raise ConfigError(f'unknown parameter(s): {", ".join(unknown)}')
    out = defaults()
    for name, value in values.items():
        out[name] = _BY_NAME[name].check(value)
    return out


_ANGLE = re.compile(r'\brad\b(?!/)')  # a description giving its unit as rad (not rad/s)


def _markdown_value(param: Param, value: Any) -> str:
    """One value as docs/parameters.md shows it: YAML spelling, angles also in degrees."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        return f'`{value}`'
    text = f'{value:.6g}'
    if isinstance(value, float) and _ANGLE.search(param.description):
        text += f' ({math.degrees(value):.4g}°)'
    return text


def schema_markdown() -> str:
    """docs/parameters.md: every parameter of :data:`SCHEMA` as a Markdown table.

    Regenerate the file with
    ``python -c 'from planar_vo.core import config; print(config.schema_markdown(), end="")'
    > docs/parameters.md``; ``test/test_docs.py`` checks that it is up to date.
    """
    lines = [
        '# Parameters',
        '',
        '<!-- Generated from planar_vo.core.config.SCHEMA; do not edit. Regenerate with:',
        "python -c 'from planar_vo.core import config; print(config.schema_markdown(), end=\"\")'"
        ' > docs/parameters.md -->',
        '',
        'Every parameter of `planar_vo_node`, in the order of `config/planar_vo.yaml`. The node',
        'declares each with this description and range (`ros2 param describe /planar_vo NAME`);',
        '`planar_vo_replay`, `planar_vo_calibrate` and the other tools read the same params file.',
        'Ranges are inclusive; integers are accepted for float parameters. Read-only parameters',
        'are set at start-up only; the others can be changed at run time (`ros2 param set`): a',
        'mounting change applies at once, a tracking or estimation change restarts tracking',
        '(the pose is kept). An invalid value is refused with the reason; at start-up the node',
        'prints one line and exits with status 2.',
        '',
        '| name | type | default | range / choices | read-only | description |',
        '|---|---|---|---|---|---|',
    ]
    for param in SCHEMA:
        if param.choices:
            allowed = ', '.join(f'`{c}`' for c in param.choices)
        elif param.low is not None or param.high is not None:
            allowed = (f'{_markdown_value(param, param.low)} .. '
                       f'{_markdown_value(param, param.high)}')
        else:
            allowed = ''
        cells = [f'`{param.name}`', type(param.default).__name__,
                 _markdown_value(param, param.default), allowed,
                 'yes' if param.read_only else 'no', param.description.replace('|', '\\|')]
        lines.append('| ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines) + '\n'


def params_section(data: Any, node_name: str = NODE_NAME) -> Any:
    """The ``ros__parameters`` of ``node_name`` (or a wildcard) in a loaded params YAML."""
    if isinstance(data, dict):
        for key in (node_name, f'/{node_name}', '/**', '**'):
            if isinstance(data.get(key), dict) and 'ros__parameters' in data[key]:
                return data[key]['ros__parameters']
    return None


class _UniqueKeyLoader(yaml.SafeLoader):
    """A YAML loader that refuses a key given twice in one mapping.

    PyYAML keeps the last of them without a word, so a parameter set near the top of a long
    file and again further down silently takes the second value.
    """

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen: dict[Any, int] = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            line = key_node.start_mark.line + 1
            try:
                hash(key)
            except TypeError:  # SafeLoader says what is wrong with it
                continue
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f'"{key}" is given twice (lines {seen[key]} and {line}); '
                    'keep one', key_node.start_mark)
            seen[key] = line
        return super().construct_mapping(node, deep=deep)


def read_params_yaml(path: str | Path) -> Any:
    """The YAML document of a params file, or a ConfigError saying what is wrong with it."""
    path = Path(path)
    try:
        return yaml.load(path.read_text(), Loader=_UniqueKeyLoader)
    except OSError as err:
        raise ConfigError(f'cannot read params file {path}: {err.strerror}') from err
    except yaml.YAMLError as err:
        mark = getattr(err, 'problem_mark', None)
        where = f' (line {mark.line + 1}: {getattr(err, "problem", "")})' if mark else ''
        raise ConfigError(f'params file {path} is not valid YAML{where}') from err


def load_params_file(path: str | Path, node_name: str = NODE_NAME) -> dict[str, Any]:
    """Read a ROS 2 params YAML (``<node>: ros__parameters: {...}``) and validate it."""
    path = Path(path)
    data = read_params_yaml(path)
    if data is None:
        return defaults()
    section = params_section(data, node_name)
    if not isinstance(section, dict):
        raise ConfigError(f'params file {path} has no "{node_name}: ros__parameters:" section')
    return validate(section)


def mounting_params(mounting: Any) -> dict[str, float]:
    """The ``camera_*`` parameters of ``mounting``: the inverse of mounting_from_params.

    ``mounting``: anything with x, y, height, roll, pitch and yaw (a Mounting, the renderer's).
    """
    return {'camera_x': mounting.x, 'camera_y': mounting.y, 'camera_height': mounting.height,
            'camera_roll': mounting.roll, 'camera_pitch': mounting.pitch,
            'camera_yaw': mounting.yaw}


def mounting_from_params(params: Any) -> Mounting:
    """The Mounting the ``camera_*`` parameters describe."""
    return Mounting(x=params['camera_x'], y=params['camera_y'], height=params['camera_height'],
                    roll=params['camera_roll'], pitch=params['camera_pitch'],
                    yaw=params['camera_yaw'])
