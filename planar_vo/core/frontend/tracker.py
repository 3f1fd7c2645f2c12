"""KLT feature tracking with a forward-backward check and grid replenishment (OpenCV).

Every track remembers where it was in the *reference* frame (the last frame whose motion
was estimated), so a frame that cannot be estimated does not lose motion: the next frame
is matched against the same reference while its tracks survive. Tracks also carry their
undistorted (normalized) coordinates, so each position is undistorted once, when it is
first measured, not again every time it is used.

Cost (measured, see README "Speed"): KLT's work grows with tracks x window area x levels.
KLT starts from the predicted position when there is one, so a shallow pyramid reaches it
(forward and back: 1 level instead of 3 costs about a third less, same accuracy).
Corners are detected only inside the ground mask's bounding box.
(Reusing each image's pyramid between the two KLT calls would save at most ~0.3 ms a frame,
and OpenCV's Python binding cannot pass a pyramid to calcOpticalFlowPyrLK anyway.)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import cv2
import numpy as np

__all__ = ['Tracker', 'feature_spacing']

# Features at least this far apart, px, on images up to REFERENCE_PIXELS (752x480, where the
# defaults were measured); on larger images the spacing grows with the image's side.
SPACING_PX = 8.0
REFERENCE_PIXELS = 752 * 480

# When a prediction loses more than this share of the tracks, the motion was not the one
# predicted (a jolt, a dropped frame): the lost ones are tracked again on the full pyramid.
_RETRY_LOST = 0.5
# When the check in the prewarped image on the full image alone fails more than this share
# of the tracks (normally 0-3 %), the prediction was off (a jolt): the check is repeated on
# the forward pass's levels.
_JOLT_FAILED = 0.1


def feature_spacing(min_distance: float, width: int, height: int) -> float:
    """The least distance between features, px: ``min_distance``, or 8 px grown with the image.

    For 0 (the default) 8 px, grown beyond 752x480 by the square root of the image's area:
    the same 600 corners 8 px apart crowd into a 1280x720 image's best-textured patches and
    their errors go together (rendered 720p drives: t_rel 0.25 -> 0.16 %, 0.37 -> 0.16 at
    13 px). On smaller images the budget already fills the road at 8 px (376x240 at 4 px was
    worse).
    """
    if min_distance > 0:
        return min_distance
    return SPACING_PX * max(1.0, math.sqrt(width * height / REFERENCE_PIXELS))


class Tracker:
    """Pyramidal Lucas-Kanade tracks, kept spread over a grid inside a detection mask."""

    def __init__(
        self,
        *,
        max_features: int = 600,
        quality_level: float = 0.005,
        min_distance: float = SPACING_PX,
        window: int = 25,
        levels: int = 3,
        predicted_levels: int = 1,
        warped_levels: int = 1,
        iterations: int = 30,
        fb_threshold: float = 0.5,
        grid: tuple[int, int] = (4, 8),
        normalize: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> None:
        self.max_features = max_features
        self.quality_level = quality_level
        self.min_distance = min_distance
        self.fb_threshold = fb_threshold
        self.grid = grid
        self.levels, self.predicted_levels = levels, min(predicted_levels, levels)
        # Pyramid levels of KLT in the prewarped image: the warp leaves only the prediction's
        # error, which the full image alone mostly reaches (0 levels: 0.84x the time of one,
        # t_rel of the rendered scenarios -2..+4 %, docs/speed.md); but pulling away from a
        # stop lost its tracks with none (the prediction after a stop is poor), so one.
        self.warped_levels = warped_levels
        self._lk = {
            'winSize': (window | 1, window | 1),
            'criteria': (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, iterations, 0.01),
        }
        self._image: np.ndarray | None = None
        self._mask_box: tuple | None = None  # (mask, its bounding box)
        # Reused from frame to frame: the warped template's rows, the detection mask.
        self._template: np.ndarray | None = None
        self._free: np.ndarray | None = None
        self._normalize = normalize or _as_float64
        self.reset()

    @classmethod
    def from_params(cls, params: Mapping[str, Any], width: int, height: int,
                    **kwargs: Any) -> Tracker:
        """The tracker the parameter schema's values set for ``width`` x ``height`` images."""
        return cls(max_features=params['max_features'], quality_level=params['quality_level'],
                   min_distance=feature_spacing(params['min_distance'], width, height),
                   window=params['klt_window'], levels=params['klt_levels'],
                   fb_threshold=params['fb_threshold'], **kwargs)

    @property
    def window(self) -> int:
        """Lucas-Kanade window size, px."""
        return self._lk['winSize'][0]

    @property
    def last_image(self) -> np.ndarray | None:
        """The last image tracked (what the next one is matched against), None before it."""
        return self._image

    @property
    def image_shape(self) -> tuple[int, int] | None:
        """(height, width) of the last image tracked, None before the first."""
        return None if self._image is None else self._image.shape[:2]

    def reset(self) -> None:
        """Forget every track; the last image stays, so new tracks can start in it."""
        self.points = np.zeros((0, 2), np.float32)  # (N, 2) in the current image
        self.reference = np.zeros((0, 2), np.float32)  # (N, 2) in the reference, NaN if new
        self.points_normalized = np.zeros((0, 2))  # the same, undistorted
        self.reference_normalized = np.zeros((0, 2))

    def set_normalize(self, normalize: Callable[[np.ndarray], np.ndarray]) -> None:
        """Undistort with ``normalize`` (pixels (N, 2) to normalized (N, 2)) from now on."""
        self._normalize = normalize
        self.points_normalized = normalize(self.points)
        self.reference_normalized = normalize(self.reference)

    def __len__(self) -> int:
        return len(self.points)

    def track(self, gray: np.ndarray, predicted: np.ndarray | None = None,
              warp: np.ndarray | None = None, warp_row: int = 0) -> None:
        """Follow every track into ``gray`` (uint8, HxW); drop the ones that fail.

        Args:
            predicted: (N, 2) where each track is expected (from the motion so far); KLT
                starts there with ``predicted_levels`` pyramid levels, so fast motion and
                skipped frames stay within its reach. Without it KLT uses ``levels``, and
                so do the tracks a prediction loses when it loses most of them (a jolt the
                motion did not foresee).
            warp: with ``predicted``, the (H, W, 2) map of
            :class:`planar_vo.core.frontend.warp.GroundWarp`
                for the same motion: KLT then matches the last image warped by it, so its
                windows no longer deform. A track's position in the last image becomes where
                the warp takes it from (within a pixel of where it was): use it only when the
                last image is the reference.
            warp_row: ``warp`` holds the map's rows from this one on (every predicted track
                at least two windows below it), as ``GroundWarp.rows_map`` gives them.
        """
        if self._image is not None and len(self.points):
            prev = self.points.reshape(-1, 1, 2)
            warped = np.zeros(len(prev), bool)
            if predicted is None:
                cur, keep = self._follow(gray, prev, None, self.levels)
            else:
                predicted = np.asarray(predicted, np.float32).reshape(-1, 2)
                if warp is not None:  # where the warp does not hold (sky), tracks end
                    cur, keep, anchor = self._follow_warped(gray, predicted, warp, warp_row)
                    warped = keep.copy()
                else:
                    cur, keep = self._follow(gray, prev, predicted, self.predicted_levels)
                lost = ~keep
                if np.count_nonzero(lost) > _RETRY_LOST * len(keep):
                    cur[lost], keep[lost] = self._follow(gray, prev[lost], None, self.levels)
            if np.any(warped):
                self.reference = self.reference.copy()
                self.reference[warped] = anchor[warped]
                self.reference_normalized = self.reference_normalized.copy()
                self.reference_normalized[warped] = self._normalize(anchor[warped])
            self.points, self.reference = cur[keep], self.reference[keep]
            self.reference_normalized = self.reference_normalized[keep]
            self.points_normalized = self._normalize(self.points)
        self._image = gray

    def _follow_warped(self, gray: np.ndarray, predicted: np.ndarray, warp: np.ndarray,
                       warp_row: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """KLT from the last image warped by ``warp``, starting at ``predicted`` (N, 2).

        Returns positions (N, 2), which tracks it followed (N,) bool, and each track's
        position in the last image as the warp has it (N, 2).
        """
        anchor = _bilinear(warp, predicted - np.float32([0, warp_row]))
        near = np.linalg.norm(anchor - self.points, axis=1) < 1.0  # the warp is sound there
        if not np.any(near):
            return np.empty_like(predicted), near, anchor
        # Only the rows the windows can reach (the ground, below the horizon) are warped, and
        # KLT sees only those rows of both images (views, no copy): its per-call work on the
        # whole image (derivatives) shrinks to the ground's share. No window of the full image
        # or of one pyramid level gets near the band's top edge (its margin is two windows).
        top = max(int(predicted[near, 1].min()) - 2 * self.window - 4, warp_row)
        if self._template is None or self._template.shape != self._image.shape:
            self._template = np.empty_like(self._image)
        template = cv2.remap(self._image, warp[top - warp_row:], None, cv2.INTER_LINEAR,
                             dst=self._template[:len(self._image) - top],
                             borderMode=cv2.BORDER_REPLICATE)
        start = predicted[near] - np.float32([0, top])
        cur = np.empty_like(predicted)
        # The check's start, where the track came from, is within the prediction's error of
        # where it ends: the full image alone reaches it (the same tracks kept as with the
        # forward pass's pyramid level on the rendered scenarios and the bench bags, in half
        # the check's time; a jolt is checked on that level, see _follow).
        cur[near], ok = self._follow(gray[top:], start.reshape(-1, 1, 2), start,
                                     self.warped_levels, image=template, back_levels=0)
        cur[near, 1] += top
        used = near.copy()
        used[near] = ok
        return cur, used, anchor.astype(np.float32)

    def _follow(self, gray: np.ndarray, prev: np.ndarray, start: np.ndarray | None,
                levels: int, image: np.ndarray | None = None,
                back_levels: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """KLT of ``prev`` (N, 1, 2) into ``gray`` from ``start`` (N, 2) or from ``prev``.

        ``image``: the image ``prev`` is in (default: the last one); ``back_levels``: the
        pyramid levels of the forward-backward check (default: ``levels``).

        Returns:
            (positions (N, 2), which passed the forward-backward check (N,) bool).
        """
        image = self._image if image is None else image
        if start is None:
            cur, ok, _ = cv2.calcOpticalFlowPyrLK(
                image, gray, prev, None, maxLevel=levels, **self._lk)
        else:
            cur, ok, _ = cv2.calcOpticalFlowPyrLK(
                image, gray, prev, start.reshape(-1, 1, 2).astype(np.float32),
                flags=cv2.OPTFLOW_USE_INITIAL_FLOW, maxLevel=levels, **self._lk)
        # The check starts where the track came from, by default on as many levels as the
        # forward pass (fewer let more false tracks through when the motion is large).
        ok = ok.ravel() == 1
        back_levels = levels if back_levels is None else back_levels
        checked = self._check(gray, image, cur, prev, back_levels)
        if (back_levels < levels
                and np.count_nonzero(ok & ~checked) > _JOLT_FAILED * len(ok)):
            # A jolt: fewer levels let more false tracks through (and keep the lost ones below
            # the share that tracks them again); the forward pass's levels check them all.
            checked = self._check(gray, image, cur, prev, levels)
        h, w = gray.shape
        cur = cur.reshape(-1, 2)
        keep = (ok & checked & (cur[:, 0] >= 0) & (cur[:, 1] >= 0) & (cur[:, 0] <= w - 1)
                & (cur[:, 1] <= h - 1))
        return cur, keep

    def _check(self, gray: np.ndarray, image: np.ndarray, cur: np.ndarray, prev: np.ndarray,
               levels: int) -> np.ndarray:
        """Which tracks pass the forward-backward check, (N,) bool.

        KLT from ``cur`` in ``gray`` back into ``image`` on ``levels`` pyramid levels must
        end within ``fb_threshold`` of ``prev`` (both (N, 1, 2)).
        """
        back, ok, _ = cv2.calcOpticalFlowPyrLK(
            gray, image, cur, prev.copy(), flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
            maxLevel=levels, **self._lk)
        return (ok.ravel() == 1) & (np.linalg.norm((back - prev).reshape(-1, 2), axis=1)
                                    < self.fb_threshold)

    def correspondences(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(indices, reference points, current points) of tracks seen in the reference."""
        idx = np.flatnonzero(np.isfinite(self.reference[:, 0]))
        return idx, self.reference[idx], self.points[idx]

    def set_reference(self) -> None:
        """The current frame becomes the reference of every track."""
        self.reference = self.points.copy()
        self.reference_normalized = self.points_normalized.copy()

    def restore(self, image: np.ndarray, points: np.ndarray, normalized: np.ndarray) -> None:
        """Track ``points`` (N, 2) of ``image`` from now on, each its own reference.

        A held reference frame (the vehicle stands still): every new image is matched
        against it directly, so the tracks do not drift along a chain of images.
        """
        self.points = self.reference = np.asarray(points, np.float32)
        self.points_normalized = self.reference_normalized = np.asarray(normalized)
        self._image = image

    def replace_image(self, image: np.ndarray) -> None:
        """The last image, the same frame corrected otherwise (tracks stay where they are)."""
        self._image = image

    def drop(self, indices: np.ndarray) -> None:
        """Remove tracks (e.g. outliers: obstacles, mismatches) so the grid refills."""
        keep = np.ones(len(self.points), bool)
        keep[indices] = False
        self.points, self.reference = self.points[keep], self.reference[keep]
        self.points_normalized = self.points_normalized[keep]
        self.reference_normalized = self.reference_normalized[keep]

    def replenish(self, mask: np.ndarray, *, is_reference: bool) -> int:
        """Detect new corners in under-populated grid cells of ``mask`` (uint8, 255 = use).

        Args:
            is_reference: the current frame is the reference, so new tracks are usable at once.

        Returns:
            how many tracks were added.
        """
        deficit = self.max_features - len(self.points)
        if self._image is None or deficit < 0.1 * self.max_features:
            return 0
        x0, y0, w, h = self._detection_box(mask)
        if w == 0 or h == 0:
            return 0
        if self._free is None or self._free.shape != (h, w):
            self._free = np.empty((h, w), np.uint8)
        free = self._free  # no track within min_distance of a new one
        np.copyto(free, mask[y0:y0 + h, x0:x0 + w])
        radius = int(self.min_distance)
        for x, y in (self.points.astype(np.int32) - [x0, y0]).tolist():
            cv2.circle(free, (x, y), radius, 0, -1)
        corners = cv2.goodFeaturesToTrack(
            self._image[y0:y0 + h, x0:x0 + w], maxCorners=3 * deficit,
            qualityLevel=self.quality_level, minDistance=self.min_distance, mask=free,
            blockSize=5)
        if corners is None:
            return 0
        corners = corners.reshape(-1, 2) + np.float32([x0, y0])
        new = self._spread(corners, mask.shape, deficit)
        if len(new):
            cv2.cornerSubPix(self._image, new.reshape(-1, 1, 2), (3, 3), (-1, -1),
                             (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 10, 0.03))
        normalized = self._normalize(new)
        self.points = np.concatenate([self.points, new])
        self.points_normalized = np.concatenate([self.points_normalized, normalized])
        if is_reference:
            ref, ref_normalized = new.copy(), normalized
        else:
            ref, ref_normalized = np.full_like(new, np.nan), np.full_like(normalized, np.nan)
        self.reference = np.concatenate([self.reference, ref])
        self.reference_normalized = np.concatenate([self.reference_normalized, ref_normalized])
        return len(new)

    def _detection_box(self, mask: np.ndarray) -> tuple[int, int, int, int]:
        """(x, y, w, h) around ``mask``, computed once per mask.

        The sky is most of a level camera's view: detecting only in this box is what keeps
        detection cheap. (Narrowing it to the grid cells short of tracks gained nothing:
        on bags/default they span the whole box in every frame.)
        """
        if self._mask_box is None or self._mask_box[0] is not mask:
            self._mask_box = (mask, cv2.boundingRect(mask))
        return self._mask_box[1]

    def _cells(self, points: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """Grid cell index (N,) of each point (N, 2)."""
        rows, cols = self.grid
        h, w = shape
        return (np.minimum(points[:, 1] * rows // h, rows - 1) * cols
                + np.minimum(points[:, 0] * cols // w, cols - 1)).astype(int)

    def _spread(self, corners: np.ndarray, shape: tuple[int, int], deficit: int) -> np.ndarray:
        """Take the best corners cell by cell so no cell holds more than its share."""
        rows, cols = self.grid
        cell = self._cells(corners, shape)
        occupied = np.bincount(self._cells(self.points, shape), minlength=rows * cols)
        share = int(np.ceil(self.max_features / max(np.count_nonzero(np.bincount(
            cell, minlength=rows * cols) + occupied), 1)))
        # Corners come sorted by quality: each is taken while its cell has room for it, i.e.
        # when fewer than the room left in its cell came before it there.
        order = np.argsort(cell, kind='stable')
        first = np.searchsorted(cell[order], cell[order])
        rank = np.empty(len(cell), np.int64)
        rank[order] = np.arange(len(cell)) - first
        taken = np.flatnonzero(rank < share - occupied[cell])[:deficit]
        return corners[taken].astype(np.float32)


def _bilinear(grid: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``grid`` (H, W, C) interpolated at ``points`` (N, 2) pixel positions (x, y), clamped."""
    h, w = grid.shape[:2]
    x = np.clip(points[:, 0], 0, w - 1.001)
    y = np.clip(points[:, 1], 0, h - 1.001)
    x0, y0 = x.astype(np.int64), y.astype(np.int64)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    top = grid[y0, x0] * (1 - fx) + grid[y0, x0 + 1] * fx
    bottom = grid[y0 + 1, x0] * (1 - fx) + grid[y0 + 1, x0 + 1] * fx
    return top * (1 - fy) + bottom * fy


def _as_float64(pixels: np.ndarray) -> np.ndarray:
    """No camera model: normalized coordinates are the pixels themselves."""
    return np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
