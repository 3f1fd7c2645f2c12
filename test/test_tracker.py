import cv2
import numpy as np

from planar_vo.tracker import Tracker


def texture(seed=0, size=(480, 640)):
    rng = np.random.default_rng(seed)
    img = rng.random((size[0] // 4, size[1] // 4)).astype(np.float32)
    img = cv2.resize(img, (size[1], size[0]), interpolation=cv2.INTER_CUBIC)
    return np.clip(img * 255, 0, 255).astype(np.uint8)


def shifted(img, dx, dy):
    m = np.float32([[1, 0, dx], [0, 1, dy]])
    return cv2.warpAffine(img, m, (img.shape[1], img.shape[0]), borderMode=cv2.BORDER_REFLECT)


def test_tracks_follow_a_shift_and_stay_spread_in_the_mask():
    img = texture()
    mask = np.zeros_like(img)
    mask[200:460, 20:620] = 255
    tracker = Tracker(max_features=200)
    tracker.track(img)
    added = tracker.replenish(mask, is_reference=True)
    assert 150 <= added <= 200
    near_mask = cv2.dilate(mask, np.ones((5, 5), np.uint8))  # sub-pixel refinement moves them
    assert np.all(near_mask[tracker.points[:, 1].astype(int), tracker.points[:, 0].astype(int)])
    # spread: every column band of the mask holds features
    bands = np.histogram(tracker.points[:, 0], bins=8, range=(20, 620))[0]
    assert bands.min() > 5
    tracker.track(shifted(img, 3.5, -2.0))
    idx, ref, cur = tracker.correspondences()
    assert len(idx) > 0.9 * added
    np.testing.assert_allclose(cur - ref, np.tile([3.5, -2.0], (len(idx), 1)), atol=0.1)


def test_prediction_brings_large_motion_within_reach():
    img = texture(1)
    mask = np.full_like(img, 255)
    far = shifted(img, 120.0, 0.0)
    plain, seeded = Tracker(levels=1), Tracker(levels=1)
    for t in (plain, seeded):
        t.track(img)
        t.replenish(mask, is_reference=True)
    predicted = seeded.points + [119.0, 0.5]
    plain.track(far)
    seeded.track(far, predicted)
    assert len(seeded) > 3 * max(len(plain), 1)


def test_new_tracks_are_not_matched_before_a_reference():
    img = texture(2)
    tracker = Tracker(max_features=50)
    tracker.track(img)
    tracker.replenish(np.full_like(img, 255), is_reference=False)
    assert len(tracker) > 0 and len(tracker.correspondences()[0]) == 0
    tracker.set_reference()
    assert len(tracker.correspondences()[0]) == len(tracker)
    tracker.drop(np.arange(10))
    assert len(tracker) == len(tracker.correspondences()[0])


def test_normalized_coordinates_follow_every_track_operation():
    """Each position is undistorted once, and stays with its track through every change."""
    calls = []

    def normalize(pixels):
        calls.append(len(pixels))
        return (np.asarray(pixels, np.float64) - 320.0) / 500.0

    def check(tracker):
        np.testing.assert_allclose(tracker.points_normalized, normalize(tracker.points))
        np.testing.assert_allclose(tracker.reference_normalized, normalize(tracker.reference))

    img = texture(3)
    mask = np.full_like(img, 255)
    tracker = Tracker(max_features=120, normalize=normalize)
    tracker.track(img)
    tracker.replenish(mask, is_reference=False)
    check(tracker)
    assert np.isnan(tracker.reference_normalized).all()  # no reference yet
    tracker.set_reference()
    tracker.track(shifted(img, 2.0, 1.0))
    check(tracker)
    tracker.drop(np.arange(0, len(tracker), 3))
    check(tracker)
    calls.clear()
    added = tracker.replenish(mask, is_reference=True)
    assert added > 0 and calls == [added]  # only the new corners are undistorted
    check(tracker)
    tracker.set_normalize(lambda pixels: np.asarray(pixels, np.float64) / 100.0)
    np.testing.assert_allclose(tracker.points_normalized, tracker.points / 100.0)
