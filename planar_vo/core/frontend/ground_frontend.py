"""The tracking front end: ground tracks followed from one image to the next.

KLT tracks (:mod:`planar_vo.core.frontend.tracker`) kept inside the ground mask, started
where the predicted motion puts them, in the last image warped through the ground by that
motion (:mod:`~planar_vo.core.frontend.warp`); the first pair after a start is predicted by
a search over planar motions (:mod:`~planar_vo.core.frontend.motion_search`).
"""

from __future__ import annotations

import numpy as np

from planar_vo.core.estimation.ransac import TransferModel
from planar_vo.core.estimation.rolling_shutter import ShutterModel
from planar_vo.core.frontend.ground_mask import ground_mask
from planar_vo.core.frontend.motion_search import GroundMotionSearch
from planar_vo.core.frontend.tracker import Tracker
from planar_vo.core.frontend.warp import GroundWarp
from planar_vo.core.geometry.camera import CameraModel, Mounting, rays_through
from planar_vo.core.geometry.se2 import step_length

__all__ = ['GroundFrontEnd']

# Below this predicted translation (m) the last image is not warped: nothing deforms KLT's
# windows yet, and the warped image's resampling biased a creeping vehicle's speed by
# +5 mm/s (3 cm/s at 20 Hz, 320x240: +16 %; -3 % without the warp).
_PREWARP_MIN_STEP = 0.005


class GroundFrontEnd:
    """Tracks on the ground between frames, predicted by the planar motion.

    Its state is the tracker's (tracks, last image) and the geometry it was set to.
    """

    def __init__(self, tracker: Tracker, *, horizon_margin: float, klt_prewarp: bool,
                 klt_first_search: bool) -> None:
        self.tracker = tracker
        self.horizon_margin = horizon_margin
        self.klt_prewarp = klt_prewarp  # see planar_vo.core.frontend.warp
        self.klt_first_search = klt_first_search  # see planar_vo.core.frontend.motion_search
        self.mask: np.ndarray | None = None
        self.mask_yaw = 0.0  # the mounting yaw the mask was drawn for
        self.camera: CameraModel | None = None
        self._warp: GroundWarp | None = None
        self._search: GroundMotionSearch | None = None

    def reset(self) -> None:
        """No tracks; the warp and search are rebuilt when next needed."""
        self.tracker.reset()
        self._warp = None
        self._search = None

    def mask_for(self, camera: CameraModel, mounting: Mounting, *,
                 check_round_trip: bool = False) -> np.ndarray | None:
        """The ground mask ``camera`` and ``mounting`` give (None for a camera of no size).

        Raises CameraModelError (see :func:`ground_mask`) and changes nothing then.
        """
        if camera.width > 0 and camera.height > 0:
            return ground_mask(camera, mounting, self.horizon_margin,
                               check_round_trip=check_round_trip)
        return None

    def set_geometry(self, camera: CameraModel, mounting: Mounting,
                     mask: np.ndarray | None) -> None:
        """Track with ``camera`` inside ``mask`` (from :meth:`mask_for`) from now on."""
        self.camera, self.mask = camera, mask
        self.mask_yaw = mounting.yaw
        self.tracker.set_normalize(camera.normalize)

    def predicted_motion(self, gray: np.ndarray, dt: float, model: TransferModel,
                         twist_motion: np.ndarray | None) -> np.ndarray | None:
        """The motion KLT starts from: ``twist_motion`` (the last twist held over ``dt``).

        With no twist to trust (the first pair after a start or a restart), the motion that
        aligns the last image with ``gray`` through the ground (``model``'s), if any.
        """
        if twist_motion is not None:
            return twist_motion
        if not self.klt_first_search or not len(self.tracker.points):
            return None
        if self._search is None or self._search.camera is not self.camera:
            self._search = GroundMotionSearch(self.camera)
        return self._search.search(self.tracker.last_image, gray, dt, model,
                                   self.horizon_margin)

    def track(self, gray: np.ndarray, motion: np.ndarray | None, mounting: Mounting,
              model: TransferModel, *, last_is_reference: bool,
              shutter: ShutterModel | None = None, dt: float = 0.0) -> None:
        """Follow the tracks into ``gray``, started where ``motion`` puts them.

        The last image is warped by the motion first when it is the reference frame. With a
        rolling ``shutter`` (``motion`` over ``dt`` s) each track and each pixel of the warp
        moves by the motion stretched by its rows' times: the warped window is then the
        image's, not sheared by the readout.
        """
        if shutter is not None and shutter.global_shutter:
            shutter = None
        predicted = None if motion is None else self._predict_tracks(motion, mounting, model,
                                                                     shutter, dt)
        warp, first_row = None, 0
        if (predicted is not None and self.klt_prewarp and last_is_reference
                and step_length(motion) >= _PREWARP_MIN_STEP):
            if self._warp is None or self._warp.camera is not self.camera:
                self._warp = GroundWarp(self.camera)
            # Only the rows KLT's windows can reach: two windows above the highest track.
            rows = predicted[np.isfinite(predicted[:, 1]), 1]
            first_row = max(int(rows.min()) - 2 * self.tracker.window - 4, 0) if len(rows) else 0
            warp = self._warp.rows_map(model, motion, first_row, shutter, dt)
        self.tracker.track(gray, predicted, warp, first_row)

    def _predict_tracks(self, motion: np.ndarray, mounting: Mounting, model: TransferModel,
                        shutter: ShutterModel | None = None,
                        dt: float = 0.0) -> np.ndarray | None:
        """Pixels (N, 2) where ground tracks should be after ``motion``."""
        points = self.tracker.points
        if not len(points):
            return None
        ground, valid = mounting.ground_points(rays_through(self.tracker.points_normalized))
        predicted = points.astype(np.float64)
        if shutter is not None:
            def pixels(ground_points: np.ndarray) -> np.ndarray:
                return self.camera.distort(model.transfer(np.zeros(3), ground_points))
            moved = shutter.seen_in_other(ground[valid], predicted[valid, 1], motion, dt,
                                          pixels, self.camera.height, forward=True)
            ok = np.all(np.isfinite(moved), axis=1)
            predicted[np.flatnonzero(valid)[ok]] = moved[ok]
            return predicted
        moved = model.transfer(motion, ground[valid])
        ok = np.all(np.isfinite(moved), axis=1)
        rows = np.flatnonzero(valid)[ok]
        predicted[rows] = self.camera.distort(moved[ok])
        return predicted

    def window_inside(self, pixels: np.ndarray) -> np.ndarray:
        """(N,) True where the KLT window around each pixel lies inside the image.

        Where it does not, KLT lags behind the true motion (measured on the rendered
        scenarios: 0.08-0.4 px at the bottom edge with a 15 px window), which is nothing to
        a rigid 3-DoF fit but tilts the estimated ground once the attitude is estimated
        (0.06 deg of pitch, 0.25 % of scale). The rigid model keeps those tracks.
        """
        margin = self.tracker.window // 2 + 1
        u, v = pixels[:, 0], pixels[:, 1]
        return ((u >= margin) & (u < self.camera.width - margin) & (v >= margin)
                & (v < self.camera.height - margin))

    def detect(self, *, is_reference: bool, gray: np.ndarray | None = None) -> None:
        """New tracks where cells are short of them; the reference moves here if asked."""
        if gray is not None:
            self.tracker.track(gray)  # no tracks yet: just stores the image
        self.tracker.replenish(self.mask, is_reference=is_reference)
        if is_reference:
            self.tracker.set_reference()

    def drop(self, indices: np.ndarray) -> None:
        """Forget the tracks at ``indices`` (obstacles, mismatches): their cells free up."""
        self.tracker.drop(indices)
