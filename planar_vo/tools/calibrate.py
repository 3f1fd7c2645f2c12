"""``planar_vo_calibrate``: the camera mounting from a recorded drive.

Runs the odometry over the bag with self-calibration on (see
:mod:`planar_vo.core.estimation.calibration`),
then writes the parameter file back with the learned ``camera_pitch``, ``camera_roll``,
``camera_yaw`` and ``camera_x``. With ``--known-distance`` (the drive's true length) a second
pass, from the calibrated mounting, measures the path and scales ``camera_height`` to it:
the one thing vision alone cannot tell. With ``--rolling-shutter`` the camera's readout
time (``rolling_shutter_readout``) is learned over the same drive and written too.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from planar_vo.core.config import (
    NODE_NAME,
    ConfigError,
    load_params_file,
    params_section,
    read_params_yaml,
    validate,
)
from planar_vo.core.estimation.calibration import MountingEstimate
from planar_vo.io.errors import BagError
from planar_vo.tools.cli import Parser, add_topic_arguments, positive_float, run
from planar_vo.tools.errors import CalibrationError, ReplayError
from planar_vo.tools.replay import replay

__all__ = ['main', 'calibrate']

PROG = 'planar_vo_calibrate'
_ANGLES = ('camera_pitch', 'camera_roll', 'camera_yaw')
# A value whose standard deviation is above this was not determined by the drive.
_UNDETERMINED = {'camera_pitch': math.radians(1.0), 'camera_roll': math.radians(1.0),
                 'camera_yaw': math.radians(1.0), 'camera_x': 0.2,
                 'rolling_shutter_readout': 0.003}


def calibrate(bag: str | Path, params: dict[str, Any], *, image_topic: str | None = None,
              camera_info_topic: str | None = None, known_distance: float | None = None,
              rolling_shutter: bool = False, progress: bool = False) -> dict[str, Any]:
    """Estimate the mounting from ``bag``; returns values, deviations and what was kept.

    With ``rolling_shutter`` also the readout (s), learned from the configured one.
    """
    params = dict(params, estimate_attitude=True, self_calibrate=True,
                  learn_rolling_shutter=rolling_shutter)
    first = replay(bag, params, image_topic=image_topic, camera_info_topic=camera_info_topic,
                   progress=progress)
    estimate = first.mounting
    if estimate is None or first.counters.get('estimated', 0) < 10:
        raise CalibrationError(f'only {first.counters.get("estimated", 0)} frames of the drive '
                               'could be estimated: record a longer drive over textured ground')
    values, kept = _determined(estimate, params)
    result: dict[str, Any] = {'values': values, 'std': dict(estimate.std), 'kept': kept,
                              'seconds': estimate.seconds}
    if rolling_shutter:
        readout = first.readout
        if readout is not None and readout.std <= _UNDETERMINED['rolling_shutter_readout']:
            values['rolling_shutter_readout'] = float(readout.readout)
        else:
            values['rolling_shutter_readout'] = float(params['rolling_shutter_readout'])
            kept.append('rolling_shutter_readout')
        result['std']['rolling_shutter_readout'] = (
            math.inf if readout is None else float(readout.std))
    if known_distance is not None:
        second = replay(bag, dict(params, **values), image_topic=image_topic,
                        camera_info_topic=camera_info_topic, progress=progress)
        _, poses = second.estimate.arrays()
        length = float(np.hypot(*np.diff(poses[:, :2], axis=0).T).sum())
        if length < 1.0:
            raise CalibrationError(f'the drive is only {length:.2f} m long: the camera height '
                                   'needs a drive of known length of at least a few metres')
        values['camera_height'] = params['camera_height'] * known_distance / length
        result['measured_distance'] = length
        # The height is as good as the path length's scale: about the per-frame scale noise
        # averaged over the drive; 0.1 % is what the rendered drives reach.
        result['std']['camera_height'] = 1e-3 * values['camera_height']
    return result


def _determined(estimate: MountingEstimate,
                params: dict[str, Any]) -> tuple[dict[str, float], list[str]]:
    values, kept = {}, []
    for name, value in estimate.as_params().items():
        if estimate.std[name] <= _UNDETERMINED[name]:
            values[name] = float(value)
        else:
            values[name] = float(params[name])
            kept.append(name)
    return values, kept


def _raw_section(path: Path) -> dict[str, Any]:
    """IN's own parameters, as written (validated by :func:`load_params_file` first)."""
    return dict(params_section(read_params_yaml(path)) or {})


def _parser() -> Parser:
    p = Parser(
        prog=PROG,
        description='Estimate the camera mounting (camera_pitch, camera_roll, camera_yaw, '
                    'camera_x; camera_height with --known-distance) from a recorded drive '
                    'and write it to a new params file. Drive straight and through turns: '
                    'turns are what tell camera_x.')
    p.add_argument('bag', help='rosbag2 directory or .mcap file of the drive')
    p.add_argument('--params', required=True, metavar='IN.yaml',
                   help='the params file to start from (planar_vo: ros__parameters:)')
    p.add_argument('--output', required=True, metavar='OUT.yaml',
                   help="where to write IN's parameters with the calibrated mounting")
    add_topic_arguments(p)
    p.add_argument('--known-distance', type=positive_float, metavar='METRES',
                   help='true length of the drive: also calibrates camera_height')
    p.add_argument('--rolling-shutter', action='store_true',
                   help="also learn the camera's rolling-shutter readout time "
                        '(rolling_shutter_readout, s) from the drive; it needs turns')
    p.add_argument('--json', action='store_true', help='print one JSON object, no table')
    return p


def main(argv: list[str] | None = None) -> int:
    """Console entry point; returns the exit code."""
    args = _parser().parse_args(argv)
    return run(PROG, lambda: _main(args),
               (BagError, ConfigError, ReplayError, CalibrationError, OSError))


def _main(args: argparse.Namespace) -> int:
    params = load_params_file(args.params)
    output = Path(args.output)
    if output.exists():
        raise ConfigError(f'output {output} exists: choose a new path or remove it')
    result = calibrate(args.bag, params, image_topic=args.image_topic,
                       camera_info_topic=args.camera_info_topic,
                       known_distance=args.known_distance,
                       rolling_shutter=args.rolling_shutter,
                       progress=not args.json and sys.stderr.isatty())
    section = {**_raw_section(Path(args.params)), **result['values']}
    validate(section)
    output.write_text(yaml.safe_dump({NODE_NAME: {'ros__parameters': section}},
                                     sort_keys=False))
    result['changes'] = {name: value - params[name] for name, value in result['values'].items()}
    result['output'] = str(output)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        _print_table(result)
    return 0


def _print_table(result: dict[str, Any]) -> None:
    print(f'mounting from {result["seconds"]:.1f} s of driving:')
    for name, value in result['values'].items():
        std, change = result['std'].get(name, math.inf), result['changes'][name]
        if name == 'rolling_shutter_readout':
            line = (f'  {name:14s} {1e3 * value:.2f} ms  +- {1e3 * std:.2f} ms  change '
                    f'{1e3 * change:+.2f} ms')
        elif name in _ANGLES:
            line = (f'  {name:14s} {value:+.5f} rad ({math.degrees(value):+.3f} deg)  '
                    f'+- {math.degrees(std):.3f} deg  change {math.degrees(change):+.3f} deg')
        else:
            line = (f'  {name:14s} {value:+.4f} m  +- {std:.4f} m  change {change:+.4f} m')
        if name in result['kept']:
            line = f'  {name:14s} kept at {value:+.4f}: the drive does not determine it ' + (
                '(no turns)' if name in ('camera_x', 'rolling_shutter_readout')
                else '(too short)')
        print(line)
    if 'measured_distance' in result:
        print(f'  the drive measured {result["measured_distance"]:.3f} m with the calibrated '
              'mounting; camera_height scaled to the known distance')
    print(f'written to {result["output"]}')


if __name__ == '__main__':
    sys.exit(main())
