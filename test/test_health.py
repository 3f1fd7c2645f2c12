"""Diagnostics levels from image arrival times and frame results (no ROS, explicit clock)."""

from types import SimpleNamespace

from planar_vo.ros.health import ERROR, OK, WARN, Health


def result(status, message=''):
    return SimpleNamespace(status=status, message=message, tracks=200, inliers=150,
                           rms_px=0.125, timing_ms={'total': 12.5})


def feed(health, start, stop, rate, status='ok'):
    """Images at ``rate`` Hz from ``start`` to ``stop`` s, each giving ``status``."""
    n = int(round((stop - start) * rate))
    for k in range(n):
        health.image_received(start + k / rate)
        health.frame_done(result(status))
    return start + n / rate


def test_ok_while_tracking_at_a_steady_rate():
    health = Health()
    t = feed(health, 0.0, 3.0, 30.0)
    level, message, values = health.report(t, calibrated=True)
    assert (level, message) == (OK, 'tracking')
    assert abs(float(values['image rate (Hz)']) - 30.0) < 0.5
    assert values['tracks'] == '200' and values['processing time (ms)'] == '12.50'
    assert values['inlier rms error (px)'] == '0.125'
    assert values['last failure'] == 'none'


def test_warn_before_any_image_and_when_images_stop():
    health = Health()
    level, message, _ = health.report(0.5, calibrated=False)
    assert level == WARN and 'no image received yet' in message
    t = feed(health, 0.0, 2.0, 20.0)
    assert health.report(t + 0.5, calibrated=True)[0] == OK
    level, message, values = health.report(t + 1.7, calibrated=True)
    assert level == WARN and 'no image for 1.' in message


def test_warn_when_the_rate_drops_below_half_then_it_becomes_usual():
    health = Health()
    t = 0.0
    for _ in range(5):  # 30 Hz, reported every second
        t = feed(health, t, t + 1.0, 30.0)
        assert health.report(t, calibrated=True)[0] == OK
    levels = []
    for _ in range(40):  # 10 Hz from now on
        t = feed(health, t, t + 1.0, 10.0)
        level, message, _ = health.report(t, calibrated=True)
        levels.append(level)
        if level == WARN:
            assert 'below half of the usual' in message
    assert WARN in levels[:3]  # noticed at once (the window still holds some 30 Hz images)
    assert levels[-5:] == [OK] * 5  # a lasting new rate is the new normal
    t = feed(health, t, t + 1.0, 8.0)  # within half of the usual rate: fine
    assert health.report(t, calibrated=True)[0] == OK


def test_error_while_tracking_is_lost_until_a_frame_is_estimated():
    health = Health()
    t = feed(health, 0.0, 1.0, 30.0)
    health.frame_done(result('no_estimate', '5 inliers, fewer than 12'))
    level, message, values = health.report(t, calibrated=True)
    assert level == WARN and '5 inliers' in message  # one bad frame is not lost tracking
    health.frame_done(result('reinitialized', 'tracking lost (3 inliers): restarted'))
    level, message, values = health.report(t, calibrated=True)
    assert level == ERROR and message.startswith('tracking lost')
    assert 'reinitialized' in values['last failure']
    health.frame_done(result('first'))  # neutral: still lost
    assert health.report(t, calibrated=True)[0] == ERROR
    health.frame_done(result('ok'))
    assert health.report(t, calibrated=True)[0] == OK


def test_error_after_many_frames_without_estimate_and_worst_level_wins():
    health = Health()
    t = feed(health, 0.0, 1.0, 30.0)
    for _ in range(4):
        health.frame_failed('image skipped: cannot decode')
    level, message, _ = health.report(t + 2.0, calibrated=True)  # also stale
    assert level == ERROR
    assert 'tracking lost (image skipped: cannot decode)' in message and 'no image for' in message


def test_images_dated_out_of_order_or_in_a_burst_give_no_absurd_rate():
    """Images queued while the node was busy are dated when received, so they can come out
    of order; two of a burst alone say nothing about the rate."""
    health = Health()
    health.image_received(10.0)
    health.image_received(10.00001)
    health.report(10.1, calibrated=True)  # 100 kHz for a moment: shown, not learned
    for t in (10.4, 10.2, 10.3, 10.1, 10.6, 10.5):  # 10 Hz, handed over out of order
        health.image_received(t)
    assert abs(health.rate(10.7) - 7 / 0.6) < 1e-6  # 8 images over 0.6 s
    assert health.report(10.7, calibrated=True)[0] == OK


def test_median_processing_time_is_over_the_latest_frames_only():
    from planar_vo.ros.health import RECENT_FRAMES
    health = Health()
    slow = SimpleNamespace(status='ok', message='', tracks=200, inliers=150, rms_px=0.1,
                           timing_ms={'total': 50.0})
    for _ in range(3 * RECENT_FRAMES):  # a slow start-up, then a steady 12.5 ms
        health.frame_done(slow)
    for k in range(RECENT_FRAMES):
        health.image_received(k / 30.0)
        health.frame_done(result('ok'))
    _, _, values = health.report(RECENT_FRAMES / 30.0, calibrated=True)
    assert values[f'median processing time, last {RECENT_FRAMES} frames (ms)'] == '12.50'
    assert float(values['mean processing time (ms)']) > 40.0  # the mean still has the start


def feed_numbered(health, start, rate, sequences, size_bytes):
    """One image at ``rate`` Hz per publisher sequence number in ``sequences``."""
    for k, sequence in enumerate(sequences):
        health.image_received(start + k / rate, sequence=sequence, size_bytes=size_bytes)
        health.frame_done(result('ok'))
    return start + len(sequences) / rate


def test_images_lost_on_the_way_warn_and_say_why_when_qos_and_size_explain_it():
    """Gaps in the publisher's sequence numbers are images the node never saw: a 720p mono8
    image (900 kB) over best effort, which Fast DDS loses, gets the advice; the same loss of
    small images, or over reliable QoS, is reported without it."""
    every_other = list(range(1, 120, 2))  # half of them lost
    health = Health(best_effort=True)
    t = feed_numbered(health, 0.0, 15.0, every_other, 1280 * 720)
    level, message, values = health.report(t, calibrated=True)
    assert level == WARN and '50 % of the images lost on the way (900 kB' in message, message
    assert 'image_reliability' in message and values['images lost on the way'] == '59'
    for quiet in (Health(best_effort=True), Health(best_effort=False)):
        size = 752 * 480 if quiet.best_effort else 1280 * 720
        t = feed_numbered(quiet, 0.0, 15.0, every_other, size)
        level, message, _ = quiet.report(t, calibrated=True)
        assert level == WARN and '50 % of the images lost on the way' in message
        assert 'image_reliability' not in message, message


def test_no_loss_from_a_publisher_that_starts_over_and_a_loss_passes():
    """A lower sequence number is another (or a restarted) publisher, not a loss; a loss
    older than the window no longer warns, but stays counted."""
    health = Health()
    t = feed_numbered(health, 0.0, 20.0, list(range(1, 41)) + list(range(1, 41)), 100_000)
    assert health.report(t, calibrated=True)[0] == OK
    t = feed_numbered(health, t, 20.0, [50] + list(range(51, 61)), 100_000)  # 9 lost
    assert health.report(t, calibrated=True)[0] == WARN
    t = feed_numbered(health, t, 20.0, list(range(61, 121)), 100_000)  # 3 s later
    level, _, values = health.report(t, calibrated=True)
    assert level == OK and values['images lost on the way'] == '9'
