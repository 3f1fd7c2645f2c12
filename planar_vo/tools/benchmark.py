"""``planar_vo_bench``: speed of the pipeline against baselines measured in the same run.

Prints ratios, never absolute pass/fail timings (machines are shared and noisy):
- pose step (1-point RANSAC + refinement) vs OpenCV ``findEssentialMat + recoverPose``
  (5-point) and ``findHomography + decomposeHomographyMat`` (4-point), on the same
  correspondences of every frame of the bag;
- a whole offline frame (bag decode included) vs the time its tracker takes (KLT from the
  predicted positions, and detection), and vs the plain OpenCV pipeline
  (:class:`planar_vo.tools.experiments.opencv_pipeline.OpenCVReference`, decode-free);
- the whole frame also one pass at 30 Hz, idling between frames as the node does (wall and
  CPU of all threads), so the node's figures split into the machine's and its path's;
- with ``--live``, the node's median latency over DDS vs the whole frame and vs its own
  median compute on the same frames (as its /diagnostics report it), the CPU time of all its
  threads per frame vs the whole frame, and the highest frame rate with at least 99.5 % of
  the frames answered, on the machine as it is and with one core kept busy by another process;
- the accuracy of the run (planar_vo and the reference), so a speed gain that costs
  accuracy shows;
- with ``--curve``, the front end's cost against its accuracy: KLT window, pyramid levels in
  the prewarped image, iterations and track count, one at a time off the defaults.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from planar_vo.core.config import ConfigError, defaults, load_params_file
from planar_vo.core.estimation.opencv_motion import essential_motion, homography_motion
from planar_vo.core.estimation.ransac import PoseEstimationError, TransferModel, estimate_motion
from planar_vo.core.frontend.motion_search import GroundMotionSearch
from planar_vo.core.frontend.tracker import Tracker
from planar_vo.core.geometry.camera import bin_image, rays_through
from planar_vo.core.geometry.se2 import compose
from planar_vo.core.metrics import metrics
from planar_vo.core.odometry import VisualOdometry
from planar_vo.io.bag import (
    IMAGE_TYPES,
    INFO_TYPE,
    ODOM_TYPE,
    open_reader,
    read_messages,
    truth_connection,
    typestore,
)
from planar_vo.io.errors import BagError, ResourceError
from planar_vo.ros.health import RECENT_FRAMES
from planar_vo.ros.messages import (
    ImageError,
    camera_info_to_model,
    compressed_to_gray,
    image_to_gray,
    planar_pose,
    stamp_to_seconds,
)
from planar_vo.tools.cli import (
    Parser,
    add_bag_argument,
    add_node_params_argument,
    bag_or_default,
    node_params_or_default,
    run,
)
from planar_vo.tools.errors import LiveError
from planar_vo.tools.experiments.opencv_pipeline import OpenCVReference

__all__ = ['main', 'run_benchmark']

PROG = 'planar_vo_bench'
_ACCURACY_KEYS = ('path_length_m', 't_rel_percent', 'r_rel_deg_per_100m', 'ate_rmse_m',
                  'scale_ratio')
# max_features the README advises for a sprung body (estimate_attitude): its cost is timed.
SPRUNG_BODY_TRACKS = 700
# The front end's variants --curve measures, one change at a time off the defaults: params
# overrides and Tracker keywords (warped_levels: pyramid levels of KLT in the prewarped image).
CURVE = (
    ('defaults', {}, {}),
    ('klt_window 19', {'klt_window': 19}, {}),
    ('klt_window 15', {'klt_window': 15}, {}),
    ('klt_window 11', {'klt_window': 11}, {}),
    ('prewarped KLT on the full image only', {}, {'warped_levels': 0}),
    ('prewarped KLT on 2 pyramid levels', {}, {'warped_levels': 2}),
    ('KLT iterations 5 (30)', {}, {'iterations': 5}),
    ('KLT iterations 2', {}, {'iterations': 2}),
    ('max_features 300', {'max_features': 300}, {}),
    ('max_features 200', {'max_features': 200}, {}),
)
ANSWERED = 0.995  # the share of frames answered for a rate to count as sustained
PACED_HZ = 30.0  # the rate of the node's bars: the whole frame also timed one pass at it


def _read_raw(bag: Path) -> tuple[list[tuple[str, bytes]], Any, dict[float, np.ndarray]]:
    """Raw image messages (undecoded), the first CameraInfo and the ground truth.

    The truth maps stamp → (x, y, yaw) and is empty if the bag has none; all is read once.
    """
    images, info, truth = [], None, {}
    with open_reader(bag) as reader:
        truth_conn = truth_connection(reader.connections)
        wanted = [c for c in reader.connections if c.msgtype in (*IMAGE_TYPES, INFO_TYPE)]
        wanted += [truth_conn] if truth_conn is not None else []
        for conn, raw, msg in read_messages(reader, bag, wanted,
                                            decode=lambda c: c.msgtype not in IMAGE_TYPES):
            if conn.msgtype == INFO_TYPE:
                info = info or msg
            elif conn.msgtype == ODOM_TYPE:
                truth[stamp_to_seconds(msg.header.stamp)] = planar_pose(msg.pose.pose)
            else:
                images.append((conn.msgtype, bytes(raw)))
    if info is None or not images:
        raise BagError(f'{bag} has no images or no CameraInfo')
    return images, info, truth


def _decode(msgtype: str, raw: bytes) -> tuple[np.ndarray, float]:
    msg = typestore().deserialize_cdr(raw, msgtype)
    gray = compressed_to_gray(msg) if msgtype.endswith('CompressedImage') else image_to_gray(msg)
    return gray, stamp_to_seconds(msg.header.stamp)


def _time(fn: Any, *args: Any, repeat: int = 3, **kwargs: Any) -> float:
    """Best of ``repeat`` runs, in seconds: the least disturbed by other processes."""
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn(*args, **kwargs)
        best = min(best, time.perf_counter() - t)
    return best


def run_benchmark(bag: Path, params: dict[str, Any], *, progress: bool = False,
                  frames: int | None = None) -> dict[str, Any]:
    """Measure everything on ``bag``; return medians (ms), ratios and the run's accuracy."""
    images, info, truth = _read_raw(bag)
    images = images[:frames] if frames else images
    camera = camera_info_to_model(info)
    passes = 3
    bar = tqdm(total=(passes + 1) * len(images), desc='bench', unit='frame', disable=not progress)

    # 1-3. Whole frames (decode from CDR bytes + the full per-frame odometry), the time the
    # tracker spends inside them (KLT from the predicted positions, and detection) and the
    # plain OpenCV reference pipeline (on decoded images), interleaved frame by frame so all
    # see the same machine load; each frame's best of a few passes.
    decoded = [_decode(*m) for m in images]
    track_s, frame_s, reference_s, attitude_s, sprung_s = (
        np.full(len(images), np.inf) for _ in range(5))
    poses, reference_poses, tracks, attitude_poses = [], [], [], []
    for k in range(passes):
        vo = VisualOdometry.from_params(camera, params)
        # What estimating the camera's attitude (and self-calibrating) adds to a frame.
        # (the plane model with estimate_attitude; the default, local ground, is `vo`).
        attitude = {**params, 'ground_model': 'plane', 'estimate_attitude': True}
        tilted = VisualOdometry.from_params(camera, attitude)
        # The same with the tracks the README advises for a sprung body.
        sprung = VisualOdometry.from_params(camera, {**attitude,
                                                     'max_features': SPRUNG_BODY_TRACKS})
        in_tracker = _time_calls(vo.tracker, ('track', 'replenish'))
        reference = OpenCVReference.from_params(camera, vo.mounting, params)
        reference_pose = np.zeros(3)
        for i, message in enumerate(images):
            in_tracker[0] = 0.0
            t = time.perf_counter()
            result = vo.process(*_decode(*message))
            frame_s[i] = min(frame_s[i], time.perf_counter() - t)
            track_s[i] = min(track_s[i], in_tracker[0])
            t = time.perf_counter()
            motion = reference.process(decoded[i][0])
            reference_s[i] = min(reference_s[i], time.perf_counter() - t)
            t = time.perf_counter()
            tilted_result = tilted.process(*_decode(*message))
            attitude_s[i] = min(attitude_s[i], time.perf_counter() - t)
            t = time.perf_counter()
            sprung.process(*_decode(*message))
            sprung_s[i] = min(sprung_s[i], time.perf_counter() - t)
            if k == 0:
                attitude_poses.append(tilted_result.pose)
                if motion is not None:
                    reference_pose = compose(reference_pose, np.zeros((3, 3)), motion,
                                             np.zeros((3, 3)))[0]
                poses.append(result.pose)
                reference_poses.append(reference_pose)
                tracks.append((result.tracks, len(reference.points)))
            bar.update()

    paced_s, paced_cpu_s = _paced(camera, params, images, PACED_HZ)

    # Frame-to-frame correspondences (every frame a reference), as the pipeline forms them,
    # on the images as it tracks them (binned above 1.5 megapixels) and with its camera.
    tracked = [(bin_image(gray, vo.binning), stamp) for gray, stamp in decoded]
    camera = vo.camera
    tracker = Tracker.from_params(params, camera.width, camera.height)
    correspondences = []
    mask = vo.front.mask
    if mask is None:
        mask = np.full(tracked[0][0].shape, 255, np.uint8)
    for gray, _ in tracked:
        tracker.track(gray)
        correspondences.append(tracker.correspondences()[1:])
        tracker.replenish(mask, is_reference=True)
        tracker.set_reference()
    correspondences = [_ground_pairs(vo, *pair) for pair in correspondences]

    # 4. Pose step alone on the same correspondences, as tracked (the forward-backward check
    # leaves few outliers) and with 30 % of them mismatched (what RANSAC is for).
    model = TransferModel.from_camera(vo.mounting, camera)
    threshold = params['inlier_threshold']
    solvers = {
        'pose_1point_ransac_refine': lambda p1, p2, m1, m2, rng: estimate_motion(
            p1, p2, m2, model, threshold_px=threshold, rng=rng),
        'opencv_5point_essential_recoverpose': lambda p1, p2, m1, m2, rng: essential_motion(
            m1, m2, vo.mounting, threshold=threshold / camera.focal_px),
        'opencv_4point_homography_decompose': lambda p1, p2, m1, m2, rng: homography_motion(
            m1, m2, vo.mounting, threshold=threshold / camera.focal_px),
    }
    times: dict[str, list[float]] = {}
    # 5. The ground search that starts the first pair after a start or a restart
    # (klt_first_search), on every pair of the bag as if it were that one.
    search = GroundMotionSearch(vo.camera)
    times['first_pair_ground_search'] = [
        _time(search.search, tracked[i - 1][0], tracked[i][0],
              tracked[i][1] - tracked[i - 1][1], model, params['horizon_margin'])
        for i in range(1, len(tracked))]
    for i, pairs in enumerate(correspondences):
        bar.update()
        if pairs is None:
            continue
        for suffix, data in (('', pairs), (' (30% outliers)', _mismatch(pairs, 0.3, i))):
            try:
                row = {name + suffix: _time(solve, *data, np.random.default_rng(i))
                       for name, solve in solvers.items()}
            except PoseEstimationError:
                continue
            for name, value in row.items():
                times.setdefault(name, []).append(value)
    bar.close()

    def ms(values: list[float]) -> float:
        return 1e3 * float(np.median(values))

    median = {'opencv_reference_pipeline': ms(reference_s),
              'klt_tracking_in_pipeline': ms(track_s), 'whole_frame_with_decode': ms(frame_s),
              'whole_frame_with_attitude': ms(attitude_s),
              f'whole_frame_paced_{PACED_HZ:g}hz': ms(paced_s),
              f'whole_frame_paced_{PACED_HZ:g}hz_cpu_all_threads': ms(paced_cpu_s),
              f'whole_frame_with_attitude_{SPRUNG_BODY_TRACKS}_tracks': ms(sprung_s),
              **{name: ms(values) for name, values in times.items()}}
    ratios = {'whole_frame_over_reference': median['whole_frame_with_decode'] / median[
        'opencv_reference_pipeline'], 'whole_frame_over_klt': median[
        'whole_frame_with_decode'] / median['klt_tracking_in_pipeline'],
        'attitude_over_whole_frame': median['whole_frame_with_attitude'] / median[
        'whole_frame_with_decode'],
        f'attitude_{SPRUNG_BODY_TRACKS}_tracks_over_whole_frame': median[
            f'whole_frame_with_attitude_{SPRUNG_BODY_TRACKS}_tracks'] / median[
            'whole_frame_with_decode'],
        'first_pair_search_over_whole_frame': median['first_pair_ground_search'] / median[
            'whole_frame_with_decode']}
    bars = {'whole_frame_over_reference': '<= 0.3', 'whole_frame_over_klt': '<= 1.2',
            'attitude_over_whole_frame': 'reported (estimate_attitude: true)',
            f'attitude_{SPRUNG_BODY_TRACKS}_tracks_over_whole_frame':
                f'reported (a sprung body: max_features {SPRUNG_BODY_TRACKS})',
            'first_pair_search_over_whole_frame': 'reported (once a start or a restart)'}
    for suffix in ('', ' (30% outliers)'):
        pose = median['pose_1point_ransac_refine' + suffix]
        ratios['essential_5point_over_pose' + suffix] = median[
            'opencv_5point_essential_recoverpose' + suffix] / pose
        ratios['homography_4point_over_pose' + suffix] = median[
            'opencv_4point_homography_decompose' + suffix] / pose
        bars['essential_5point_over_pose' + suffix] = '>= 10'
        bars['homography_4point_over_pose' + suffix] = '>= 1'
    stamps = [stamp for _, stamp in decoded]
    accuracy = {}
    if all(stamp in truth for stamp in stamps):
        truth_poses = np.array([truth[stamp] for stamp in stamps])
        accuracy = {name: {key: value for key, value in metrics(
            np.array(estimate), truth_poses).items() if key in _ACCURACY_KEYS}
            for name, estimate in (('planar_vo', poses), ('opencv_reference', reference_poses),
                                   ('planar_vo_attitude', attitude_poses))}
    mean_tracks = np.mean(tracks, axis=0)
    return {'bag': str(bag), 'frames': len(images), 'image_size': list(decoded[0][0].shape[::-1]),
            'pose_frames': len(times.get('pose_1point_ransac_refine', [])),
            'tracks_per_frame': {'planar_vo': float(mean_tracks[0]),
                                 'opencv_reference': float(mean_tracks[1])},
            'median_ms': median, 'ratios': ratios, 'bars': bars, 'accuracy': accuracy}


def _odometry(camera: Any, params: dict[str, Any], tracker_kwargs: dict[str, Any]
              ) -> VisualOdometry:
    """The odometry of ``params``, its tracker built with ``tracker_kwargs`` added."""
    vo = VisualOdometry.from_params(camera, params)
    if tracker_kwargs:
        tracker = Tracker.from_params(params, vo.camera.width, vo.camera.height,
                                      **tracker_kwargs)
        tracker.set_normalize(vo.camera.normalize)
        vo.front.tracker = tracker
    return vo


def _paced(camera: Any, params: dict[str, Any], images: list[tuple[str, bytes]],
           rate: float) -> tuple[np.ndarray, np.ndarray]:
    """Wall and CPU (all the process's threads) seconds of each whole frame, one pass at ``rate``.

    What the node does at that rate, without the node: the process idles between frames, so
    each starts with caches and clocks another process used meanwhile (1.06-1.32x the back
    to back frame on this shared machine). The node's latency and CPU over these are what its
    own path (middleware, executor, hand-over, publishing) costs.
    """
    vo = VisualOdometry.from_params(camera, params)
    wall, cpu = np.empty(len(images)), np.empty(len(images))
    due = time.perf_counter()
    for i, message in enumerate(images):
        while (left := due - time.perf_counter()) > 0:
            time.sleep(left)
        due += 1.0 / rate
        t, c = time.perf_counter(), time.process_time()
        vo.process(*_decode(*message))
        wall[i], cpu[i] = time.perf_counter() - t, time.process_time() - c
    return wall[1:], cpu[1:]  # the first frame is the start (its ground search)


def run_curve(bag: Path, params: dict[str, Any], *, frames: int | None = None,
              passes: int = 2) -> list[dict[str, Any]]:
    """Whole frame (decode included) and accuracy of each :data:`CURVE` variant on ``bag``.

    The variants process each frame in turn (each frame's best of ``passes``), so all see
    the same machine load; times are also given over the defaults' (the first row).
    """
    images, info, truth = _read_raw(bag)
    images = images[:frames] if frames else images
    camera = camera_info_to_model(info)
    best = np.full((len(CURVE), len(images)), np.inf)
    poses: list[list[np.ndarray]] = [[] for _ in CURVE]
    for k in range(passes):
        vos = [_odometry(camera, {**params, **over}, kwargs) for _, over, kwargs in CURVE]
        for i, message in enumerate(images):
            for j, vo in enumerate(vos):
                t = time.perf_counter()
                result = vo.process(*_decode(*message))
                best[j, i] = min(best[j, i], time.perf_counter() - t)
                if k == 0:
                    poses[j].append(result.pose)
    stamps = [_decode(*m)[1] for m in images]
    truth_poses = (np.array([truth[s] for s in stamps]) if all(s in truth for s in stamps)
                   else None)
    rows = []
    for j, (name, _, _) in enumerate(CURVE):
        row = {'variant': name, 'whole_frame_ms': 1e3 * float(np.median(best[j]))}
        if truth_poses is not None:
            m = metrics(np.array(poses[j]), truth_poses)
            row.update(t_rel_percent=m['t_rel_percent'], r_rel=m['r_rel_deg_per_100m'])
        rows.append(row)
    for row in rows:
        row['time_over_defaults'] = row['whole_frame_ms'] / rows[0]['whole_frame_ms']
        if 't_rel_percent' in row:
            row['t_rel_over_defaults'] = row['t_rel_percent'] / rows[0]['t_rel_percent']
    return rows


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of process ``pid``, all its threads, s (Linux /proc)."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


class BusyCore:
    """Another process keeping one core busy (a spinning Python loop) while in the block."""

    def __enter__(self) -> BusyCore:
        self.proc = subprocess.Popen([sys.executable, '-c', 'while True: pass'])
        return self

    def __exit__(self, *exc: Any) -> None:
        self.proc.kill()
        self.proc.wait()


def run_live_benchmark(bag: Path, params_file: Path, *, frames: int = 150,
                       rates: tuple[float, ...] = (15.0, 30.0, 45.0, 60.0, 90.0, 120.0)
                       ) -> dict[str, Any]:
    """Node latency at each rate against its own compute; the highest rate sustained.

    A frame the node cannot keep up with is dropped for a newer one, so a missing odometry
    message is a frame the node missed; a rate is sustained when at least :data:`ANSWERED`
    of its frames are answered. Its compute (the odometry's time per frame) comes from its
    /diagnostics, over the same frames, so latency and compute see the same machine load;
    its CPU time per frame (all its threads: middleware, executor, odometry) from /proc.
    The rates are tried on the machine as it is, then again with one core kept busy by
    another process (:class:`BusyCore`).
    """
    from diagnostic_msgs.msg import DiagnosticArray

    from planar_vo.tools.live_session import BagStream, LiveSession

    stream = BagStream.read(bag, limit=frames)
    session = LiveSession(params_file, image_type=stream.image_type)
    # (frames, mean processing ms since start, median over the latest RECENT_FRAMES), as reported
    node_stats: list[tuple[int, float, float]] = []
    median_key = f'median processing time, last {RECENT_FRAMES} frames (ms)'

    def on_diagnostics(msg: Any) -> None:
        for status in msg.status:
            values = {v.key: v.value for v in status.values}
            if ('planar_vo' in status.name and 'mean processing time (ms)' in values
                    and 'frames processed' in values and median_key in values):
                node_stats.append((int(values['frames processed']),
                                   float(values['mean processing time (ms)']),
                                   float(values[median_key])))

    session.node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 10)
    rows = []
    try:
        session.wait_connected()
        before = _node_totals(node_stats, 0, 0.0)
        for busy, rate in [(False, r) for r in rates] + [(True, r) for r in rates]:
            session.reset()
            session.handshake(stream.frames[0])
            if busy:
                with BusyCore():
                    cpu = cpu_seconds(session.proc.pid)
                    session.play(stream.frames[1:], rate=rate)
                    cpu = cpu_seconds(session.proc.pid) - cpu
            else:
                cpu = cpu_seconds(session.proc.pid)
                session.play(stream.frames[1:], rate=rate)
                cpu = cpu_seconds(session.proc.pid) - cpu
            stamps = [f[0] for f in stream.frames[1:]]
            latency = session.latencies_ms(stamps)
            after = _node_totals(node_stats, before[0] + len(latency), 3.0)
            computed = after[0] - before[0]
            row = {'rate_hz': rate, 'busy_core': busy, 'sent': len(stamps),
                   'received': len(latency),
                   'cpu_ms_per_frame': 1e3 * cpu / len(latency) if len(latency) else None,
                   'median_ms': float(np.median(latency)) if len(latency) else None,
                   'p95_ms': float(np.percentile(latency, 95)) if len(latency) else None,
                   'mean_ms': float(np.mean(latency)) if len(latency) else None,
                   'node_compute_ms': (after[1] - before[1]) / computed if computed else None}
            if row['mean_ms'] is not None and row['node_compute_ms']:
                row['latency_over_compute'] = row['mean_ms'] / row['node_compute_ms']
            if computed >= RECENT_FRAMES and after[2] > 0:
                # Medians over the same frames: the node's median is over its latest ones.
                row['median_latency_recent_ms'] = float(np.median(latency[-RECENT_FRAMES:]))
                row['node_median_compute_ms'] = after[2]
                row['median_latency_over_median_compute'] = (
                    row['median_latency_recent_ms'] / after[2])
            rows.append(row)
            before = after
    finally:
        session.close()
    highest = {}  # the rates are increasing: the highest before the first not sustained
    for busy in (False, True):
        highest[busy] = None
        for row in (r for r in rows if r['busy_core'] == busy):
            if row['received'] < ANSWERED * row['sent']:
                break
            highest[busy] = row['rate_hz']
    return {'rates': rows, 'highest_rate_sustained_hz': highest[False],
            'highest_rate_sustained_one_core_busy_hz': highest[True]}


def _node_totals(stats: list[tuple[int, float, float]], frames: int,
                 timeout: float) -> tuple[int, float, float]:
    """(frames, total processing ms, median of the latest) from the node's latest /diagnostics.

    Waits up to ``timeout`` s for one that counts ``frames`` or more (the node reports about
    once a second).
    """
    end = time.monotonic() + timeout
    while time.monotonic() < end and not (stats and stats[-1][0] >= frames):
        time.sleep(0.05)
    if not stats:
        return 0, 0.0, 0.0
    count, mean, median = stats[-1]
    return count, count * mean, median


def _time_calls(obj: Any, names: tuple[str, ...]) -> list[float]:
    """Wrap methods of ``obj`` so the seconds spent in them add up in the returned [0]."""
    spent = [0.0]

    def timer(method: Any) -> Any:
        def timed(*args: Any, **kwargs: Any) -> Any:
            t = time.perf_counter()
            try:
                return method(*args, **kwargs)
            finally:
                spent[0] += time.perf_counter() - t
        return timed

    for name in names:
        setattr(obj, name, timer(getattr(obj, name)))
    return spent


def _mismatch(pairs: tuple[np.ndarray, ...], fraction: float,
              seed: int) -> tuple[np.ndarray, ...]:
    """The same correspondences with ``fraction`` of them paired with the wrong point."""
    p1, p2, m1, m2 = pairs
    rng = np.random.default_rng(seed)
    idx = rng.choice(len(p1), int(fraction * len(p1)), replace=False)
    shuffled = np.roll(idx, 1)
    p2, m2 = p2.copy(), m2.copy()
    p2[idx], m2[idx] = p2[shuffled], m2[shuffled]
    return p1, p2, m1, m2


def _ground_pairs(vo: VisualOdometry, ref_px: np.ndarray,
                  cur_px: np.ndarray) -> tuple[np.ndarray, ...] | None:
    """Ground correspondences exactly as the pipeline forms them."""
    if len(ref_px) < 8:
        return None
    m1, m2 = vo.camera.normalize(ref_px), vo.camera.normalize(cur_px)
    p1, v1 = vo.mounting.ground_points(rays_through(m1), vo.horizon_margin)
    p2, v2 = vo.mounting.ground_points(rays_through(m2), vo.horizon_margin)
    ok = v1 & v2
    if np.count_nonzero(ok) < 8:
        return None
    return p1[ok], p2[ok], m1[ok], m2[ok]


def main(argv: list[str] | None = None) -> int:
    """Console entry point; returns the exit code."""
    parser = Parser(
        prog=PROG,
        description='Time the planar_vo pipeline against OpenCV baselines and KLT tracking '
                    'on one bag, in one run; prints medians and the ratios the design bars '
                    'are about.')
    add_bag_argument(parser)
    parser.add_argument('--params', help='params YAML (default: built-in defaults)')
    parser.add_argument('--frames', type=int, help='use only the first N images')
    parser.add_argument('--live', action='store_true',
                        help='also start planar_vo_node and measure its latency and the '
                             'highest frame rate it sustains over DDS (loopback only)')
    add_node_params_argument(parser, '--node-params', when=' with --live')
    parser.add_argument('--curve', action='store_true',
                        help="also time the front end's variants (KLT window, pyramid "
                             'levels, iterations, track count) against their accuracy')
    parser.add_argument('--json', action='store_true', help='print one JSON object')
    args = parser.parse_args(argv)
    return run(PROG, lambda: _main(args),
               (BagError, ConfigError, ImageError, LiveError, ResourceError, OSError))


def _main(args: argparse.Namespace) -> int:
    params = load_params_file(args.params) if args.params else defaults()
    if args.frames is not None and args.frames < 2:
        raise ConfigError('--frames must be at least 2')
    bag = bag_or_default(args.bag)
    result = run_benchmark(bag, params, frames=args.frames,
                           progress=not args.json and sys.stderr.isatty())
    if args.curve:
        result['curve'] = run_curve(bag, params, frames=args.frames)
    if args.live:
        live = run_live_benchmark(
            bag, node_params_or_default(args.node_params))
        at_30 = next((r for r in live['rates'] if r['rate_hz'] == 30.0
                      and not r['busy_core']), None)
        whole = result['median_ms']['whole_frame_with_decode']
        if at_30 and at_30['median_ms'] is not None:
            result['ratios']['node_median_latency_at_30hz_over_whole_frame'] = (
                at_30['median_ms'] / whole)
            result['bars']['node_median_latency_at_30hz_over_whole_frame'] = '<= 1.2'
            result['ratios']['node_cpu_per_frame_at_30hz_over_whole_frame'] = (
                at_30['cpu_ms_per_frame'] / whole)
            result['bars']['node_cpu_per_frame_at_30hz_over_whole_frame'] = (
                '<= 1.5 (all the node\'s threads)')
        paced = result['median_ms'][f'whole_frame_paced_{PACED_HZ:g}hz']
        paced_cpu = result['median_ms'][f'whole_frame_paced_{PACED_HZ:g}hz_cpu_all_threads']
        if at_30 and at_30['median_ms'] is not None:
            result['ratios']['node_median_latency_at_30hz_over_paced_frame'] = (
                at_30['median_ms'] / paced)
            result['bars']['node_median_latency_at_30hz_over_paced_frame'] = (
                'no bar (what the node\'s path adds)')
            result['ratios']['node_cpu_per_frame_at_30hz_over_paced_frame_cpu'] = (
                at_30['cpu_ms_per_frame'] / paced_cpu)
            result['bars']['node_cpu_per_frame_at_30hz_over_paced_frame_cpu'] = (
                'no bar (what the node\'s path adds)')
        if at_30 and 'median_latency_over_median_compute' in at_30:
            result['ratios']['node_median_latency_at_30hz_over_its_compute'] = at_30[
                'median_latency_over_median_compute']
            result['bars']['node_median_latency_at_30hz_over_its_compute'] = 'no bar'
        if at_30 and 'latency_over_compute' in at_30:  # the tails of a busy machine too
            result['ratios']['node_mean_latency_at_30hz_over_its_compute'] = at_30[
                'latency_over_compute']
            result['bars']['node_mean_latency_at_30hz_over_its_compute'] = 'no bar'
        result['live'] = live
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    width, height = result['image_size']
    print(f'{result["frames"]} frames ({width}x{height}) of {result["bag"]} (pose step on '
          f'{result["pose_frames"]} frames); tracks per frame: planar_vo '
          f'{result["tracks_per_frame"]["planar_vo"]:.0f}, OpenCV reference '
          f'{result["tracks_per_frame"]["opencv_reference"]:.0f}')
    print('median per frame:')
    for name, value in result['median_ms'].items():
        print(f'  {name:52s} {value:8.3f} ms')
    print('ratios (bar):')
    for name, value in result['ratios'].items():
        print(f'  {name:52s} {value:8.2f}   ({result["bars"][name]})')
    if 'curve' in result:
        print('front end: cost against accuracy, one change at a time (whole frame, decode '
              'included; each frame timed in turn for every variant):')
        for row in result['curve']:
            accuracy = (f't_rel {row["t_rel_percent"]:.4f} % '
                        f'({row["t_rel_over_defaults"]:.2f}x), r_rel {row["r_rel"]:.2f} '
                        'deg/100m' if 't_rel_percent' in row else 'no ground truth')
            print(f'  {row["variant"]:36s} {row["whole_frame_ms"]:7.2f} ms '
                  f'({row["time_over_defaults"]:.2f}x)  {accuracy}')
    if 'live' in result:
        print('planar_vo_node over DDS (image sent -> odom received; CPU: all the node\'s '
              'threads):')
        for row in result['live']['rates']:
            print(f'  {row["rate_hz"]:5.0f} Hz{" one core busy" if row["busy_core"] else ""}: '
                  f'{row["received"]}/{row["sent"]} frames, '
                  f'latency median {row["median_ms"] or float("nan"):.1f} ms, '
                  f'95th percentile {row["p95_ms"] or float("nan"):.1f} ms, mean '
                  f'{row["mean_ms"] or float("nan"):.1f} ms; the node\'s compute '
                  f'{row["node_compute_ms"] or float("nan"):.1f} ms a frame (mean), CPU '
                  f'{row["cpu_ms_per_frame"] or float("nan"):.1f} ms a frame')
            if 'median_latency_over_median_compute' in row:
                print(f'         last {RECENT_FRAMES} frames: latency median '
                      f'{row["median_latency_recent_ms"]:.1f} ms, compute median '
                      f'{row["node_median_compute_ms"]:.1f} ms: '
                      f'{row["median_latency_over_median_compute"]:.2f}x')
        print(f'  highest rate with >= {100 * ANSWERED:g} % answered: '
              f'{result["live"]["highest_rate_sustained_hz"]} Hz; with one core busy: '
              f'{result["live"]["highest_rate_sustained_one_core_busy_hz"]} Hz')
    for name, acc in result['accuracy'].items():
        print(f'accuracy of this run, {name}: t_rel {acc["t_rel_percent"]:.3f} %, r_rel '
              f'{acc["r_rel_deg_per_100m"]:.2f} deg/100m, ATE {acc["ate_rmse_m"]:.3f} m, '
              f'scale ratio {acc["scale_ratio"]:.4f} over {acc["path_length_m"]:.1f} m')
    return 0


if __name__ == '__main__':
    sys.exit(main())
