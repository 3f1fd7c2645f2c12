"""``planar_vo_synth``: the command line."""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

from planar_vo.io.errors import BagError
from planar_vo.synth.bagfile import generate_bag
from planar_vo.synth.lens import DISTORTION_DEFAULTS, SynthCamera
from planar_vo.synth.mount import MountingError
from planar_vo.synth.scenarios import SCENARIOS, VEHICLES
from planar_vo.synth.shutter import STAMPS, RollingShutter
from planar_vo.synth.terrain import TERRAIN_KINDS, TerrainShape
from planar_vo.synth.vehicle import Suspension
from planar_vo.tools.cli import (
    Parser,
    finite_float,
    integer,
    non_negative_float,
    positive_float,
    positive_int,
    run,
)

PROG = 'planar_vo_synth'


def _mounting_error(s):
    try:
        return MountingError.parse(s)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def _terrain_shape(s):
    try:
        return TerrainShape.parse(s)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def build_parser() -> argparse.ArgumentParser:
    """Command-line interface of ``planar_vo_synth``."""
    scen = '; '.join(f'{k}: {v.description}' for k, v in SCENARIOS.items())
    p = Parser(
        prog=PROG,
        description='Render a monocular camera on a car driving over textured ground and write '
                    'a rosbag2 bag (MCAP, Jazzy) with /camera/image_raw, /camera/camera_info '
                    'and /ground_truth/odom (base_link on the rear axle, in odom; on terrain '
                    'the planar truth, distance along the surface, plus /ground_truth/pose3d: '
                    'the full 3D base_link pose in world).')
    p.add_argument('out_bag', metavar='OUT_BAG', help='output bag directory (must not exist)')
    p.add_argument('--scenario', default='default', metavar='NAME',
                   help=f'driving scenario (default: default). {scen}')
    p.add_argument('--frames', type=positive_int,
                   help='number of frames (default: the whole drive of a scenario with stops, '
                        'stop_and_go, creep and red_light; 300 otherwise)')
    p.add_argument('--seed', type=integer, default=0, help='random seed (default: 0)')
    p.add_argument('--rate', type=positive_float, default=30.0,
                   help='frame rate in Hz (default: 30)')
    p.add_argument('--width', type=positive_int, default=640, help='image width (default 640)')
    p.add_argument('--height', type=positive_int, default=480,
                   help='image height (default 480)')
    p.add_argument('--fx', type=positive_float, help='focal length x in px (default 460*W/640)')
    p.add_argument('--fy', type=positive_float, help='focal length y in px (default = fx)')
    p.add_argument('--cx', type=finite_float, help='principal point x (default W/2)')
    p.add_argument('--cy', type=finite_float, help='principal point y (default H/2)')
    p.add_argument('--distortion-model', choices=sorted(DISTORTION_DEFAULTS),
                   default='plumb_bob', help='lens model, as CameraInfo names it '
                   '(default plumb_bob; equidistant is the OpenCV fisheye model)')
    p.add_argument('--dist', type=finite_float, nargs='+', metavar='D',
                   help='distortion coefficients in CameraInfo order: 5 for plumb_bob '
                        '(default -0.25 0.07 0.0005 -0.0005 0), 8 for rational_polynomial, '
                        '4 for equidistant')
    p.add_argument('--camera-x', type=finite_float,
                   help='camera x ahead of the rear axle, m (default 1.2)')
    p.add_argument('--camera-y', type=finite_float, help='camera y (left), m (default 0)')
    p.add_argument('--camera-height', type=positive_float,
                   help='camera height above the ground, m (default 1.25)')
    p.add_argument('--camera-roll', type=finite_float,
                   help="rad (default: the scenario's, 0 except car 0.5 deg, rough -0.6 deg)")
    p.add_argument('--camera-pitch', type=finite_float,
                   help='rad, positive looks down (default 0.13963 = 8 deg)')
    p.add_argument('--camera-yaw', type=finite_float,
                   help="rad, positive looks left (default: the scenario's, 0 except "
                        'car -0.7 deg, rough 0.8 deg)')
    p.add_argument('--body-pitch', type=non_negative_float, metavar='DEG',
                   help='sprung body: largest |pitch|, degrees (a drive reaches 60-90 %% of '
                        'it); 60 %% follows the longitudinal '
                        'acceleration (dive when braking, squat when accelerating), 40 %% is '
                        "road vibration up to 3 Hz while rolling (default: the scenario's, "
                        '0 except car 1, rough 2)')
    p.add_argument('--body-roll', type=non_negative_float, metavar='DEG',
                   help='sprung body: largest |roll|, degrees; 60 %% follows the lateral '
                        'acceleration v*omega (lean out of turns), 40 %% is road vibration '
                        "(default: the scenario's, 0 except car 0.6, rough 1.2)")
    p.add_argument('--bounce', type=non_negative_float, metavar='M',
                   help="sprung body: largest height change, m (default: the scenario's, 0 "
                        'except car 0.015, rough 0.03)')
    p.add_argument('--body-pivot', type=finite_float, nargs=2, metavar=('X', 'Z'),
                   help='sprung body: the point it pitches and rolls about, in base_link, m '
                        '(default 1.35 0.55: its centre of mass, mid-car; 0 0 tilts the '
                        'vehicle about its rear axle on the ground)')
    kinds = '; '.join(f'{k}: {v}' for k, v in TERRAIN_KINDS.items()).replace('%', '%%')
    p.add_argument('--terrain', choices=list(TERRAIN_KINDS), metavar='KIND',
                   help="ground height field (default: the scenario's, flat except road: "
                        f'all). {kinds}. Grades, bumps and hills are laid out in world x, y '
                        '(the drive starts at the origin heading +x); the crown follows the '
                        'path. Off flat ground the bag also has /ground_truth/pose3d')
    shape = TerrainShape()
    sizes = ', '.join(f'{name} {getattr(shape, name):g} ({low:g}-{high:g})'
                      for name, (low, high) in TerrainShape.RANGES.items())
    p.add_argument('--terrain-shape', type=_terrain_shape, metavar='NAME=VALUE,...',
                   help='other sizes of the terrain kinds\' features, e.g. '
                        'bump_height=0.1,bump_length=0.5 (metres; grades and camber as '
                        f'fractions). Default (range): {sizes}')
    vehicles = '; '.join(f'{k}: {v}' for k, v in VEHICLES.items())
    p.add_argument('--vehicle', choices=list(VEHICLES), default='car', metavar='KIND',
                   help=f'what rides the terrain on its wheels (default car). {vehicles}. '
                        'Both drive the same speed and yaw-rate profile')
    p.add_argument('--configured-error', type=_mounting_error, metavar='NAME=VALUE,...',
                   help='write to --params-out a mounting that is off the rendered one by '
                        'this much, to test calibration: roll, pitch, yaw in degrees, x, y, '
                        'height in metres, e.g. pitch=1.0,roll=-1.0,yaw=1.0,x=0.15 (the '
                        'images still use the true mounting, noted in a comment)')
    p.add_argument('--exposure', type=non_negative_float, default=0.0, metavar='FRACTION',
                   help='auto-exposure gain changes within +-FRACTION (e.g. 0.2): half a '
                        'smooth drift, half steps every 1.5-4 s (default 0: off)')
    p.add_argument('--texture-contrast', type=positive_float, default=1.0, metavar='F',
                   help="the road's contrast: every grey level's distance from 120 times F "
                        '(default 1; 0.3: a worn, even road)')
    p.add_argument('--vignetting', type=non_negative_float, default=0.35, metavar='F',
                   help='light lost towards the edges of the image: 1 - F (u^2 + v^2), u and '
                        'v from -0.5 to 0.5 across it (default 0.35: 17.5 %% in the corners; '
                        '0: none)')
    p.add_argument('--noise', type=non_negative_float, default=1.5,
                   help='Gaussian image noise sigma, grey levels (default 1.5)')
    p.add_argument('--supersample', type=positive_int, default=1, metavar='S',
                   help='S x S rays per pixel, averaged, as a sensor integrates its pixel '
                        '(default 1: one ray per pixel, mip-mapped; 2 costs about 4x the time)')
    p.add_argument('--rolling-shutter', type=non_negative_float, default=0.0,
                   metavar='SECONDS',
                   help='rolling-shutter readout: row r of H exposed at stamp + (r/H - c) '
                        'SECONDS, each row rendered from the pose at its own time (on terrain '
                        'the 3D pose riding it; default 0: a global shutter). Recorded in the '
                        'bag metadata; the ground truth stays at the stamps')
    p.add_argument('--rolling-shutter-stamp', choices=list(STAMPS), default='middle',
                   help='where the stamp is in the readout: start (c = 0), middle (c = 0.5, '
                        'default) or end (c = 1)')
    p.add_argument('--max-range', type=positive_float, default=60.0,
                   help='ground beyond this distance (m) is haze/sky (default 60)')
    p.add_argument('--no-obstacles', action='store_true', help='no boxes')
    p.add_argument('--compressed', action='store_true',
                   help='write JPEG sensor_msgs/CompressedImage on /camera/image_raw/compressed '
                        'instead of raw Image')
    p.add_argument('--jpeg-quality', type=positive_int, default=90,
                   help='JPEG quality with --compressed (default 90)')
    p.add_argument('--no-storage-compression', action='store_true',
                   help='do not zstd-compress the MCAP chunks')
    p.add_argument('--params-out', metavar='YAML',
                   help='also write a planar_vo params file with this mounting and the '
                        "vehicle's wheelbase and track_width")
    p.add_argument('--quiet', action='store_true', help='no progress output')
    return p


def main(argv=None) -> int:
    """Entry point of ``planar_vo_synth``."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.scenario not in SCENARIOS:
        parser.error(f'unknown scenario {args.scenario!r} (choose from {", ".join(SCENARIOS)})')
    out = Path(args.out_bag)
    if out.exists():
        parser.error(f'output {out} already exists')
    if not out.parent.is_dir():
        parser.error(f'directory {out.parent} does not exist')
    if args.params_out and not Path(args.params_out).parent.is_dir():
        parser.error(f'directory of --params-out {args.params_out} does not exist')
    if args.jpeg_quality > 100:
        parser.error('--jpeg-quality must be in 1..100')
    scenario = SCENARIOS[args.scenario]
    mounting = scenario.mounting
    given = {name: getattr(args, f'camera_{name}') for name in
             ('x', 'y', 'height', 'roll', 'pitch', 'yaw')}
    mounting = dataclasses.replace(mounting, **{k: v for k, v in given.items() if v is not None})
    if not -1.2 < mounting.pitch < 1.5 or abs(mounting.roll) > 0.5:
        parser.error('camera pitch/roll out of range: the camera must see the ground')
    body = scenario.suspension
    suspension = Suspension.degrees(
        math.degrees(body.pitch) if args.body_pitch is None else args.body_pitch,
        math.degrees(body.roll) if args.body_roll is None else args.body_roll,
        body.bounce if args.bounce is None else args.bounce)
    if args.body_pivot:
        if args.body_pivot[1] < 0:
            parser.error('--body-pivot: Z must be >= 0 (the pivot is not under the ground)')
        suspension = dataclasses.replace(suspension, pivot_x=args.body_pivot[0],
                                         pivot_z=args.body_pivot[1])
    if max(suspension.pitch, suspension.roll) > math.radians(5.0):
        parser.error('--body-pitch/--body-roll must be at most 5 degrees')
    if suspension.bounce > 0.5 * mounting.height:
        parser.error('--bounce must be at most half the camera height')
    if args.exposure > 0.5:
        parser.error('--exposure must be at most 0.5 (a gain within +-50 %)')
    if args.vignetting > 1.0:
        parser.error('--vignetting must be at most 1 (half the light lost in the corners)')
    if args.texture_contrast > 3.0:
        parser.error('--texture-contrast must be at most 3 (beyond it the road is clipped)')
    if args.rolling_shutter > 0.2:
        parser.error('--rolling-shutter must be at most 0.2 s')
    if args.configured_error and not args.params_out:
        parser.error('--configured-error needs --params-out (it only changes that file)')
    if args.configured_error and args.configured_error.apply(mounting).height <= 0:
        parser.error('--configured-error: the configured camera height must stay > 0')
    expected = len(DISTORTION_DEFAULTS[args.distortion_model])
    if args.dist and len(args.dist) != expected:
        parser.error(f'--dist: {args.distortion_model} takes {expected} coefficients, '
                     f'not {len(args.dist)}')
    camera = SynthCamera.scaled(args.width, args.height, fx=args.fx,
                                fy=args.fy if args.fy is not None else args.fx,
                                cx=args.cx, cy=args.cy,
                                dist=tuple(args.dist) if args.dist else None,
                                distortion_model=args.distortion_model)

    frames = args.frames or scenario.frames(args.rate) or 300

    def generate() -> int:
        res = generate_bag(out, args.scenario, frames, args.seed, rate=args.rate,
                           camera=camera, mounting=mounting, suspension=suspension,
                           compressed=args.compressed,
                           jpeg_quality=args.jpeg_quality, noise_sigma=args.noise,
                           max_range=args.max_range, obstacles=not args.no_obstacles,
                           storage_compression=not args.no_storage_compression,
                           params_out=args.params_out, configured_error=args.configured_error,
                           exposure=args.exposure, supersample=args.supersample,
                           terrain=args.terrain, vehicle=args.vehicle,
                           terrain_shape=args.terrain_shape,
                           texture_contrast=args.texture_contrast, vignetting=args.vignetting,
                           rolling_shutter=RollingShutter(args.rolling_shutter,
                                                          args.rolling_shutter_stamp),
                           progress=not args.quiet)
        if not args.quiet:
            ground = '' if res.terrain.flat else \
                f', terrain {res.terrain.describe()["kind"]}, {res.vehicle}'
            if res.rolling_shutter is not None:
                ground += (f', rolling shutter {1e3 * res.rolling_shutter.readout:.1f} ms '
                           f'(stamp at the {res.rolling_shutter.stamp})')
            print(f'{PROG}: wrote {res.path} ({res.frames} frames, scenario {res.scenario}, '
                  f'path {res.trajectory.length:.1f} m, {res.obstacles} boxes{ground}, '
                  f'{res.seconds:.1f} s)', file=sys.stderr)
        return 0

    return run(PROG, generate, (BagError, OSError, ValueError))
