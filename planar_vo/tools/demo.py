"""``planar_vo_demo``: the node on the bundled bag over DDS, scored against ground truth.

Starts ``planar_vo_node``, plays the bag into it at the bag's own rate (loopback DDS only;
slower if the node falls behind, so that no frame is dropped), collects ``odom``, and prints
the accuracy, the node's latency (image sent → odom received) and how the live odometry
compares with ``planar_vo_replay`` on the same bag.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from planar_vo.core.config import ConfigError, load_params_file
from planar_vo.core.metrics import associate, metrics
from planar_vo.io.errors import BagError
from planar_vo.ros.messages import planar_pose
from planar_vo.tools.cli import (
    Parser,
    add_bag_argument,
    add_node_params_argument,
    bag_or_default,
    node_params_or_default,
    run,
)
from planar_vo.tools.errors import LiveError
from planar_vo.tools.live_session import BagStream, LiveSession
from planar_vo.tools.plots import plot_trajectories
from planar_vo.tools.replay import replay

__all__ = ['main', 'run_demo']

PROG = 'planar_vo_demo'
# Frames the player may be ahead of the odometry that came back: on a loaded machine the
# playback slows down instead of the node dropping frames it cannot keep up with (its answer
# then still matches the offline replay's); whether it keeps the rate is planar_vo_bench's.
# One: with three, a frame that waited while a slow one (the first pair's ground search
# under load) was processed was dropped as stale when the next came (1 of 90, in 1 run of 5
# with three busy processes on the 2 cores; none in 6 with one); two leave the same race.
PLAY_WINDOW = 1


def run_demo(bag: Path, params_file: Path, *, plot: Path | None = None,
             log: Path | None = None) -> dict[str, Any]:
    """Play ``bag`` into the node; return accuracy, latency and the offline comparison."""
    params = load_params_file(params_file)
    stream = BagStream.read(bag)
    session = LiveSession(params_file, image_type=stream.image_type, log=log)
    try:
        session.wait_connected()
        session.handshake(stream.frames[0])
        played_s = session.play(stream.frames[1:], window=PLAY_WINDOW)
    finally:
        status = session.close()
    stamps = [f[0] for f in stream.frames]
    got = [s for s in stamps if s in session.received]
    live = np.array([planar_pose(session.odometry(s).pose.pose) for s in got]).reshape(-1, 3)
    latency = session.latencies_ms(stamps[1:])
    out: dict[str, Any] = {
        'bag': str(bag), 'frames_sent': len(stamps), 'odom_received': len(got),
        'played_s': played_s, 'bag_s': stamps[-1] - stamps[1],
        'node_exit_status': status,
        'latency_ms': {'median': float(np.median(latency)),
                       'p95': float(np.percentile(latency, 95))} if len(latency) else None,
    }
    offline = replay(bag, params)
    off_stamps, off_poses = offline.estimate.arrays()
    ia, ib = associate(np.array(got), off_stamps)
    if len(ia):
        out['live_vs_replay_max_position_difference_m'] = float(
            np.max(np.hypot(*(live[ia, :2] - off_poses[ib, :2]).T)))
    trajectories = {'planar_vo_node (live, DDS)': live, 'planar_vo_replay': off_poses}
    if stream.truth:
        truth_stamps = np.array(sorted(stream.truth))
        ia, ib = associate(np.array(got), truth_stamps)
        truth = np.array([stream.truth[s] for s in truth_stamps])
        if len(ia) > 1:
            out['accuracy'] = metrics(live[ia], truth[ib])
        trajectories = {'ground truth': truth, **trajectories}
    if plot:
        plot_trajectories(plot, trajectories, title=f'{bag.name}: node over DDS')
        out['plot'] = str(plot)
    return out


def main(argv: list[str] | None = None) -> int:
    """Console entry point; returns the exit code."""
    p = Parser(
        prog=PROG,
        description='Start planar_vo_node, play a bag into it over DDS (loopback only) at '
                    'its own rate, and report accuracy against the ground truth, latency, '
                    'and agreement with the offline planar_vo_replay.')
    add_bag_argument(p, 'rosbag2 bag with images, CameraInfo and optionally ground truth')
    add_node_params_argument(p)
    p.add_argument('--plot', metavar='OUT.png', help='plot the trajectories here')
    p.add_argument('--log', metavar='FILE', help="write the node's output here")
    p.add_argument('--json', action='store_true', help='print one JSON object')
    args = p.parse_args(argv)
    return run(PROG, lambda: _main(args), (BagError, ConfigError, LiveError, OSError))


def _main(args: argparse.Namespace) -> int:
    result = run_demo(bag_or_default(args.bag), node_params_or_default(args.params),
                      plot=Path(args.plot) if args.plot else None,
                      log=Path(args.log) if args.log else None)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f'{result["bag"]}: {result["frames_sent"]} frames sent over DDS, '
          f'{result["odom_received"]} odometry messages back')
    if result['played_s'] > 1.1 * result['bag_s'] + 0.1:
        print(f'the node fell behind the bag\'s rate (a busy machine?): the playback slowed '
              f'down to keep every frame, {result["played_s"]:.1f} s for the bag\'s '
              f'{result["bag_s"]:.1f} s')
    if result['latency_ms']:
        lat = result['latency_ms']
        print(f'latency image -> odom: median {lat["median"]:.1f} ms, '
              f'95th percentile {lat["p95"]:.1f} ms')
    acc = result.get('accuracy')
    if acc:
        print(f'accuracy vs ground truth over {acc["path_length_m"]:.1f} m: '
              f't_rel {acc["t_rel_percent"]:.3f} %, r_rel {acc["r_rel_deg_per_100m"]:.3f} '
              f'deg/100m, final drift {acc["final_drift_m"]:.3f} m, '
              f'scale ratio {acc["scale_ratio"]:.4f}')
    if 'live_vs_replay_max_position_difference_m' in result:
        print(f'live node vs planar_vo_replay: max position difference '
              f'{result["live_vs_replay_max_position_difference_m"]:.4f} m')
    if 'plot' in result:
        print(f'plot written to {result["plot"]}')
    if result['node_exit_status'] != 0:
        print(f'{PROG}: error: planar_vo_node exited with status {result["node_exit_status"]} '
              'when stopped (--log FILE keeps its output)', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
