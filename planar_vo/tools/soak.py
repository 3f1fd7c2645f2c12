"""``planar_vo_soak``: a long run of the node over DDS, watching answers and memory.

The bag's frames are played forward, then backward, again and again, restamped at a fixed
rate so stamps always increase, into a ``planar_vo_node`` subprocess. Every few thousand
frames it prints how many were answered with odometry and the node's resident memory; at
the end, the memory growth after the warm-up and the node's CPU time per frame (all its
threads). ``--busy N`` keeps N cores busy with other processes meanwhile. Run by
``make soak`` (not part of make test).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from planar_vo.io.errors import BagError, ResourceError
from planar_vo.tools.benchmark import BusyCore, cpu_seconds
from planar_vo.tools.cli import (
    Parser,
    add_bag_argument,
    add_node_params_argument,
    bag_or_default,
    node_params_or_default,
    non_negative_int,
    positive_float,
    positive_int,
    run,
)
from planar_vo.tools.errors import LiveError
from planar_vo.tools.live_session import BagStream, LiveSession

__all__ = ['main']

PROG = 'planar_vo_soak'

def resident_mb(pid: int) -> float:
    """Resident memory (VmRSS) of process ``pid``, MB."""
    for line in Path(f'/proc/{pid}/status').read_text().splitlines():
        if line.startswith('VmRSS:'):
            return int(line.split()[1]) / 1024
    raise LiveError(f'no VmRSS for process {pid}')


def _parser() -> Parser:
    p = Parser(
        prog=PROG, description='Play a bag forward and backward into '
        'planar_vo_node over loopback DDS for a long time; print frames answered and the '
        "node's resident memory over time.")
    add_bag_argument(p)
    p.add_argument('--frames', type=positive_int, default=20000,
                   help='frames to send (default 20000)')
    p.add_argument('--rate', type=positive_float, default=60.0,
                   help='frames per second (default 60)')
    p.add_argument('--warm-up', type=non_negative_int, default=2000,
                   help='frames after which memory growth is measured (default 2000)')
    p.add_argument('--every', type=positive_int, default=2000, help='report every N frames')
    p.add_argument('--busy', type=non_negative_int, default=0,
                   help='cores kept busy by other processes during the run (default 0)')
    p.add_argument('--min-answered', type=positive_float, default=99.0,
                   help='the exit status is 0 when at least this %% of the frames were '
                        'answered (default 99)')
    add_node_params_argument(p)
    return p


def main(argv: list[str] | None = None) -> int:
    """Console entry point; returns 0 when at least ``--min-answered`` % were answered."""
    parser = _parser()
    args = parser.parse_args(argv)
    if args.frames <= args.warm_up:
        parser.error('--frames must exceed --warm-up')
    return run(PROG, lambda: _main(args), (BagError, ResourceError, LiveError))


def _main(args: argparse.Namespace) -> int:
    stream = BagStream.read(bag_or_default(args.bag))
    params = node_params_or_default(args.params)
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import CameraInfo, Image
    images = [deserialize_message(raw, Image) for _, raw, _ in stream.frames]
    info = deserialize_message(stream.frames[0][2], CameraInfo)
    order = list(range(len(images))) + list(range(len(images) - 2, 0, -1))  # ping-pong
    session = LiveSession(params, image_type=stream.image_type)
    busy = [BusyCore() for _ in range(args.busy)]
    try:
        session.wait_connected()
        session.handshake(stream.frames[0])
        session.reset()
        for core in busy:
            core.__enter__()
        cpu = cpu_seconds(session.proc.pid)
        start_ns = int(time.time()) * 10**9
        period_ns = int(round(1e9 / args.rate))
        t0, rows, warm_mb = time.perf_counter(), [], None
        print(f'{"frames":>7} {"answered":>9} {"resident MB":>12} {"elapsed s":>10}')
        for i in range(args.frames):
            due = t0 + i / args.rate
            while time.perf_counter() < due:
                time.sleep(min(0.001, max(due - time.perf_counter(), 0.0)))
            msg = images[order[i % len(order)]]
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(
                start_ns + i * period_ns, 10**9)
            info.header.stamp = msg.header.stamp
            session.info_pub.publish(info)
            session.image_pub.publish(msg)
            done = i + 1
            if done % args.every == 0 or done == args.frames:
                if done == args.frames:
                    session.wait_for((start_ns + i * period_ns) / 1e9, 5.0)
                mb = resident_mb(session.proc.pid)
                if done >= args.warm_up and warm_mb is None:
                    warm_mb = mb
                rows.append((done, len(session.received), mb))
                print(f'{done:7d} {len(session.received):9d} {mb:12.1f} '
                      f'{time.perf_counter() - t0:10.1f}', flush=True)
        answered = len(session.received)
        cpu = cpu_seconds(session.proc.pid) - cpu
    finally:
        for core in busy:
            if hasattr(core, 'proc'):
                core.__exit__()
        status = session.close()
    share = answered / args.frames
    growth = rows[-1][2] - warm_mb
    print(f'{args.frames} frames at {args.rate:g} Hz'
          f'{f" ({args.busy} core(s) kept busy)" if args.busy else ""}: {answered} answered '
          f'({100 * share:.2f} %); the node\'s CPU {1e3 * cpu / max(answered, 1):.1f} ms a '
          f'frame answered (all its threads); resident memory {rows[0][2]:.1f} MB at '
          f'{rows[0][0]} frames, {warm_mb:.1f} MB after the warm-up, {rows[-1][2]:.1f} MB at the '
          f'end (growth {growth:+.1f} MB); node exit status {status}')
    return 0 if 100 * share >= args.min_answered and status == 0 else 1


if __name__ == '__main__':
    sys.exit(main())
