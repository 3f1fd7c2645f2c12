"""``planar_vo_replay``: the odometry pipeline run offline over a rosbag2 bag (no DDS).

Reads images and CameraInfo with ``rosbags``, runs :class:`planar_vo.core.odometry.VisualOdometry`
with the node's parameter file, writes ``/odom`` (nav_msgs/Odometry) to a new bag, and
scores the trajectory when the bag has ground truth.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from planar_vo.core.config import ConfigError, defaults, load_params_file
from planar_vo.core.estimation.calibration import MountingEstimate
from planar_vo.core.estimation.rolling_shutter import ReadoutEstimate
from planar_vo.core.geometry.camera import CameraModelError
from planar_vo.core.metrics import associate, metrics
from planar_vo.core.odometry import FrameResult, VisualOdometry
from planar_vo.io.bag import (
    IMAGE_TYPES,
    INFO_TYPE,
    ODOM_TYPE,
    BagWriter,
    open_reader,
    read_messages,
    truth_connection,
)
from planar_vo.io.errors import BagError
from planar_vo.io.tum import write_tum
from planar_vo.ros.camera_frontend import CameraFrontend, Step
from planar_vo.ros.messages import (
    ImageError,
    camera_info_to_model,
    compressed_to_gray,
    image_to_gray,
    odometry_from_result,
    planar_pose,
    stamp_to_seconds,
)
from planar_vo.tools.cli import Parser, add_topic_arguments, run
from planar_vo.tools.errors import ReplayError
from planar_vo.tools.plots import plot_trajectories

__all__ = ['main', 'replay', 'Trajectory']

PROG = 'planar_vo_replay'


@dataclass
class Trajectory:
    """Stamped planar poses (N, 3): x, y, yaw."""

    stamps: list[float] = field(default_factory=list)
    poses: list[np.ndarray] = field(default_factory=list)

    def add(self, stamp: float, pose: np.ndarray) -> None:
        """Append one pose."""
        self.stamps.append(stamp)
        self.poses.append(np.asarray(pose, dtype=float))

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(stamps (N,), poses (N, 3))."""
        return np.asarray(self.stamps), np.asarray(self.poses).reshape(-1, 3)


@dataclass
class ReplayResult:
    """What a replay produced."""

    estimate: Trajectory
    truth: Trajectory
    counters: dict[str, int]
    warnings: list[str]
    frames: int
    mounting: MountingEstimate | None = None  # what self-calibration learned over the drive
    readout: ReadoutEstimate | None = None  # the rolling-shutter readout learned, if asked


def _pick_topic(connections: list, types: tuple[str, ...], wanted: str | None, what: str,
                flag: str, required: bool = True) -> Any:
    """The connection for ``wanted``, or the only one of ``types``; clear errors otherwise."""
    if wanted:
        found = [c for c in connections if c.topic == wanted]
        if not found:
            raise ReplayError(f'topic {wanted} is not in the bag (topics: '
                              f'{", ".join(sorted({c.topic for c in connections}))})')
        if found[0].msgtype not in types:
            raise ReplayError(f'{wanted} is {found[0].msgtype}, not {" or ".join(types)}')
        return found[0]
    found = [c for c in connections if c.msgtype in types]
    topics = sorted({c.topic for c in found})
    if len(topics) == 1:
        return found[0]
    if not topics:
        if required:
            raise ReplayError(f'the bag has no {what} topic ({" or ".join(types)})')
        return None
    if what == 'image' and sum(c.msgtype == IMAGE_TYPES[0] for c in found) == 1:
        return next(c for c in found if c.msgtype == IMAGE_TYPES[0])  # raw beats compressed
    truth = truth_connection(found) if what == 'ground truth' else None
    if truth is not None:  # the planar one of planar_vo_synth's terrain bags
        return truth
    raise ReplayError(f'several {what} topics ({", ".join(topics)}): choose one with {flag}')


def replay(bag: str | Path, params: dict[str, Any], *, output: str | Path | None = None,
           image_topic: str | None = None, camera_info_topic: str | None = None,
           ground_truth_topic: str | None = None, progress: bool = False) -> ReplayResult:
    """Run the odometry over ``bag``; write ``/odom`` to ``output`` if given."""
    estimate, truth, warnings = Trajectory(), Trajectory(), []
    with open_reader(bag) as reader:
        conns = list(reader.connections)
        image_conn = _pick_topic(conns, IMAGE_TYPES, image_topic, 'image', '--image-topic')
        info_conn = _pick_topic(conns, (INFO_TYPE,), camera_info_topic, 'CameraInfo',
                                '--camera-info-topic')
        truth_conn = _pick_topic(conns, (ODOM_TYPE,), ground_truth_topic, 'ground truth',
                                 '--ground-truth-topic', required=False)
        wanted = [c for c in (image_conn, info_conn, truth_conn) if c is not None]
        total = sum(c.msgcount for c in conns if c.topic == image_conn.topic)
        writer = BagWriter(output) if output else None
        frames, frontend = 0, CameraFrontend(params)

        def process(steps: list[Step]) -> None:
            for step in steps:
                for reason in step.reasons:
                    _warn_once(warnings, reason)
                if step.process:
                    _process(frontend.vo, step.image, estimate, writer, params, warnings)

        bar = tqdm(total=total, desc='replay', unit='image', disable=not progress)
        try:
            if writer:
                writer.open()
            for conn, _, msg in read_messages(reader, bag, wanted):
                stamp_ns = int(msg.header.stamp.sec) * 10**9 + int(msg.header.stamp.nanosec)
                if conn.topic == info_conn.topic:
                    try:
                        camera = camera_info_to_model(msg,
                                                      rectified=params['rectified_input'])
                    except CameraModelError as err:
                        _warn_once(warnings, f'CameraInfo refused: {err}')
                        continue
                    process(frontend.add_info(stamp_ns, camera))
                elif truth_conn is not None and conn.topic == truth_conn.topic:
                    truth.add(stamp_to_seconds(msg.header.stamp), planar_pose(msg.pose.pose))
                else:
                    frames += 1
                    bar.update()
                    process(frontend.add_image(stamp_ns, msg))
            process(frontend.flush())
        except BagError as err:
            if writer:  # closed below: what was read is kept
                raise BagError(f'{err}; what was read before is in {output}') from None
            raise
        finally:
            bar.close()
            if writer:
                writer.close()
    vo = frontend.vo
    if vo is None:
        raise ReplayError(f'no usable CameraInfo on {info_conn.topic}')
    return ReplayResult(estimate, truth, dict(vo.counters), warnings, frames,
                        vo.mounting_estimate(), vo.readout_estimate())


def _process(vo: VisualOdometry, msg: Any, estimate: Trajectory, writer: BagWriter | None,
             params: dict[str, Any], warnings: list[str]) -> None:
    try:
        gray = compressed_to_gray(msg) if hasattr(msg, 'format') else image_to_gray(msg)
    except ImageError as err:
        _warn_once(warnings, f'image skipped: {err}')
        return
    stamp = stamp_to_seconds(msg.header.stamp)
    try:
        result = vo.process(gray, stamp)
    except Exception as err:  # noqa: BLE001 - a bug: the odometry restored its state
        vo.counters['errors'] = vo.counters.get('errors', 0) + 1
        _warn_once(warnings, f'unexpected {type(err).__name__}: {err} (first at stamp '
                   f'{stamp:.6f}; image skipped, please report this line)')
        return
    if result.message:
        _warn_once(warnings, result.message)
    if result.status == 'duplicate':  # as the node: no second odometry for one stamp
        return
    estimate.add(result.stamp, result.pose)
    if writer:
        writer.write_raw('/odom', ODOM_TYPE, int(round(result.stamp * 1e9)),
                         _odometry_cdr(result, msg.header, params))


def _warn_once(warnings: list[str], message: str) -> None:
    # Per-frame messages carry numbers; one line per kind of problem is enough.
    kind = message.split(':')[0]
    if not any(w.split(':')[0] == kind for w in warnings):
        warnings.append(message)


def _odometry_cdr(result: FrameResult, header: Any, params: dict[str, Any]) -> bytes:
    """The node's Odometry message, serialized as the node would send it."""
    from builtin_interfaces.msg import Time
    from rclpy.serialization import serialize_message

    stamp = Time(sec=int(header.stamp.sec), nanosec=int(header.stamp.nanosec))
    return serialize_message(odometry_from_result(
        result, stamp, params['odom_frame'], params['base_frame']))


def _parser() -> Parser:
    p = Parser(
        prog=PROG,
        description='Run planar_vo offline over a rosbag2 bag (MCAP or sqlite3, Image or '
                    'CompressedImage), write /odom to a new bag, and score it against '
                    'ground truth when the bag has it.')
    p.add_argument('bag', help='rosbag2 directory or .mcap file')
    p.add_argument('--params', help='ROS 2 params YAML (planar_vo: ros__parameters:), the '
                   'same file the node takes; default: the built-in defaults')
    p.add_argument('--output', help='bag to write /odom (nav_msgs/Odometry) to; must not '
                   'exist')
    add_topic_arguments(p)
    p.add_argument('--ground-truth-topic', help='nav_msgs/Odometry ground truth (default: '
                   'the only Odometry topic, if any)')
    p.add_argument('--json', action='store_true', help='print one JSON object, no table')
    p.add_argument('--plot', metavar='OUT.png', help='plot estimated vs true path')
    p.add_argument('--tum', metavar='PREFIX', help='write PREFIX_estimate.txt and '
                   'PREFIX_truth.txt in TUM format (for evo)')
    return p


def report(result: ReplayResult) -> dict[str, Any]:
    """Summary: counters, and accuracy when ground truth matches the estimate's stamps."""
    out: dict[str, Any] = {'images': result.frames, 'counters': result.counters,
                           'warnings': result.warnings}
    stamps, poses = result.estimate.arrays()
    gt_stamps, gt_poses = result.truth.arrays()
    if len(gt_stamps) and len(stamps):
        ia, ib = associate(stamps, gt_stamps)
        if len(ia) > 1:
            out['accuracy'] = metrics(poses[ia], gt_poses[ib])
    learned = result.mounting
    if learned is not None and learned.seconds > 0:  # self-calibration ran
        out['mounting'] = {'seconds': learned.seconds, **{
            name: {'value': value, 'std': _finite_or_none(learned.std[name])}
            for name, value in learned.as_params().items()}}
    readout = result.readout
    if readout is not None and readout.pairs:  # the rolling-shutter readout was learned
        out['rolling_shutter_readout'] = {'seconds': readout.seconds, 'pairs': readout.pairs,
                                          'value': readout.readout,
                                          'std': _finite_or_none(readout.std)}
    return out


def _finite_or_none(value: float) -> float | None:
    """JSON has no infinity: a value the drive did not determine is null."""
    return float(value) if np.isfinite(value) else None


def main(argv: list[str] | None = None) -> int:
    """Console entry point; returns the exit code."""
    args = _parser().parse_args(argv)
    return run(PROG, lambda: _main(args), (BagError, ConfigError, ReplayError, OSError),
               internal=True)


def _main(args: argparse.Namespace) -> int:
    params = load_params_file(args.params) if args.params else defaults()
    if args.output and Path(args.output).exists():
        raise ReplayError(f'output {args.output} exists: choose a new path or remove it')
    result = replay(args.bag, params, output=args.output, image_topic=args.image_topic,
                    camera_info_topic=args.camera_info_topic,
                    ground_truth_topic=args.ground_truth_topic,
                    progress=not args.json and sys.stderr.isatty())
    summary = report(result)
    if args.tum:
        write_tum(f'{args.tum}_estimate.txt', *result.estimate.arrays())
        if len(result.truth.stamps):
            write_tum(f'{args.tum}_truth.txt', *result.truth.arrays())
    if args.plot:
        trajectories = {'estimate (planar_vo)': result.estimate.arrays()[1]}
        if len(result.truth.stamps):
            trajectories = {'ground truth': result.truth.arrays()[1], **trajectories}
        plot_trajectories(args.plot, trajectories, title=Path(args.bag).name)
        summary['plot'] = str(args.plot)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        _print_summary(summary, args)
    return 0


def _print_summary(summary: dict[str, Any], args: argparse.Namespace) -> None:
    c = summary['counters']
    print(f'{summary["images"]} images: {c["estimated"]} estimated, {c["no_estimate"]} not '
          f'estimated, {c["reinitialized"]} re-initialisations, {c["blank"]} blank, '
          f'{c["time_jumps"]} time jumps' + (f', {c["errors"]} unexpected errors (please '
                                             'report)' if c.get('errors') else ''))
    for w in summary['warnings']:
        print(f'warning: {w}')
    acc = summary.get('accuracy')
    if acc:
        print(f'path {acc["path_length_m"]:.2f} m over {acc["frames"]} frames')
        print(f't_rel {acc["t_rel_percent"]:.3f} %   r_rel {acc["r_rel_deg_per_100m"]:.3f} '
              f'deg/100m   ATE RMSE {acc["ate_rmse_m"]:.3f} m')
        print(f'final drift {acc["final_drift_m"]:.3f} m ({acc["final_drift_percent"]:.3f} %)'
              f'   yaw {acc["final_yaw_error_deg"]:.3f} deg   scale ratio '
              f'{acc["scale_ratio"]:.4f}')
    learned = summary.get('mounting')
    if learned:
        parts = []
        for name, item in learned.items():
            if name == 'seconds':
                continue
            scale, unit = (1.0, 'm') if name == 'camera_x' else (180.0 / np.pi, 'deg')
            std = 'not determined' if item['std'] is None else f'+- {item["std"] * scale:.3f}'
            parts.append(f'{name} {item["value"] * scale:.3f} {unit} ({std})')
        print(f'self-calibrated mounting over {learned["seconds"]:.1f} s: ' + ', '.join(parts))
    readout = summary.get('rolling_shutter_readout')
    if readout:
        std = ('not determined' if readout['std'] is None
               else f'+- {1e3 * readout["std"]:.1f} ms')
        print(f'rolling-shutter readout learned over {readout["seconds"]:.1f} s: '
              f'{1e3 * readout["value"]:.1f} ms ({std})')
    if args.output:
        print(f'odometry written to {args.output}')
    if args.plot:
        print(f'plot written to {args.plot}')


if __name__ == '__main__':
    sys.exit(main())
