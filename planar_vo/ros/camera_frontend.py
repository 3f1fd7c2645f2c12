"""Images and CameraInfos in, what to do with each image out: the odometry's camera side.

What the node (:mod:`planar_vo.ros.node`) and the offline replay
(:mod:`planar_vo.tools.replay`) both do between receiving messages and running the odometry:

1. pair each image with the CameraInfo of its stamp (:class:`planar_vo.ros.pairing.Pairing`);
2. keep the camera the odometry uses: the :class:`VisualOdometry` is created from the
   parameters on the first good CameraInfo, given a new calibration with ``set_camera`` when
   the size, the lens model, K or D change, and keeps its previous camera when the new one is
   refused (``CameraModelError``);
3. say, for each image released by the pairing, whether to process it and what went wrong on
   the way (:class:`Step`), as data: the caller logs, counts or collects it in its own words.

No ROS imports (no rclpy, no message packages): a CameraInfo arrives already converted into a
:class:`CameraModel` (``planar_vo.ros.messages.camera_info_to_model``), an image is whatever
the caller passes (a message, or a message and its decoder), handed back untouched.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from planar_vo.core import config
from planar_vo.core.geometry.camera import CameraModel, CameraModelError
from planar_vo.core.odometry import VisualOdometry
from planar_vo.ros.pairing import Paired, Pairing

__all__ = ['CameraFrontend', 'Step', 'same_calibration', 'CREATED', 'CHANGED',
           'NO_CAMERA_INFO', 'INEXACT', 'UNMATCHED']

CREATED = 'created'  # Step.camera: the odometry was created for this image's camera
CHANGED = 'changed'  # Step.camera: the odometry took this image's new calibration

# Reasons, as Step.reasons words them (refusals add the CameraModelError's message).
NO_CAMERA_INFO = 'no CameraInfo yet: image skipped'
INEXACT = "no CameraInfo of the image's stamp: paired with the newest CameraInfo"
UNMATCHED = ("no CameraInfo with the image's stamp (the driver stamps them differently?): "
             'using the newest CameraInfo')


@dataclass(frozen=True)
class Step:
    """One image released by the pairing, oldest first, and what to do with it.

    ``process``: give ``image`` to :attr:`CameraFrontend.vo` (its camera is set); False when
    there is no usable camera yet (``skipped`` says why). ``exact``: it was paired with a
    CameraInfo of its own stamp; ``unmatched``: stamps keep not matching, images use the
    newest CameraInfo at once (:attr:`Pairing.unmatched`). ``refused``: why its CameraInfo was
    refused (the odometry keeps its previous camera, if it has one). ``camera``: ``CREATED``
    or ``CHANGED`` when the odometry's camera was set for this image, else None.
    """

    image: Any
    process: bool
    exact: bool = True
    unmatched: bool = False
    skipped: str | None = None
    refused: str | None = None
    camera: str | None = None

    @property
    def reasons(self) -> list[str]:
        """What is worth a warning about this image, in plain words (empty: nothing)."""
        out = []
        if self.skipped is not None and self.skipped != self.refused:
            out.append(self.skipped)
        if self.refused is not None:
            out.append(f'CameraInfo refused: {self.refused}')
        if self.process and not self.exact:
            out.append(UNMATCHED if self.unmatched else INEXACT)
        return out


def same_calibration(a: CameraModel, b: CameraModel) -> bool:
    """The two describe the same camera: size, lens model, K and D."""
    return ((a.width, a.height, a.distortion_model) == (b.width, b.height, b.distortion_model)
            and np.array_equal(a.K, b.K) and np.array_equal(a.D, b.D))


class CameraFrontend:
    """The pairing, the accepted camera and the odometry built on it.

    ``params``: validated node parameters (:mod:`planar_vo.core.config`); the odometry is made
    with :meth:`VisualOdometry.from_params` on the first camera that it accepts.
    """

    def __init__(self, params: Mapping[str, Any] | config.Params,
                 pairing: Pairing | None = None) -> None:
        self.params = params
        self.pairing = pairing if pairing is not None else Pairing()
        self.vo: VisualOdometry | None = None
        self.camera: CameraModel | None = None  # the calibration the odometry uses

    @property
    def waiting(self) -> bool:
        """An image waits for the CameraInfo of its stamp: call :meth:`flush` if it is late."""
        return self.pairing.waiting

    def add_info(self, stamp_ns: int, camera: CameraModel) -> list[Step]:
        """A CameraInfo (converted); the images it releases."""
        return self.steps(self.pairing.add_info(stamp_ns, camera))

    def add_image(self, stamp_ns: int, image: Any) -> list[Step]:
        """An image; the images ready now (it, an earlier one, both or none), oldest first."""
        return self.steps(self.pairing.add_image(stamp_ns, image))

    def flush(self) -> list[Step]:
        """Stop waiting: the waiting image, if any, with the newest CameraInfo."""
        return self.steps(self.pairing.flush())

    def rebuild(self, params: Mapping[str, Any] | config.Params | None = None) -> None:
        """A new odometry from the accepted camera (and ``params`` if given), same pose.

        Pose, covariance and counters carry over; tracking restarts. Does nothing before the
        first camera. Raises CameraModelError if the new parameters refuse the camera (the
        old odometry stays).
        """
        if params is not None:
            self.params = params
        if self.camera is None:
            return
        old, new = self.vo, VisualOdometry.from_params(self.camera, self.params)
        if old is not None:
            new.set_pose(old.pose, old.pose_covariance)
            new.counters = old.counters
        self.vo = new

    def steps(self, ready: list[Paired]) -> list[Step]:
        """What to do with each image :attr:`pairing` released.

        For a caller that uses the pairing directly: the node pairs on one thread and sets
        the camera (and runs the odometry) on another.
        """
        return [self._step(paired) for paired in ready]

    def _step(self, paired: Paired) -> Step:
        exact, unmatched = paired.exact, self.pairing.unmatched
        if paired.info is None:
            return Step(paired.image, False, exact, unmatched, skipped=NO_CAMERA_INFO)
        try:
            event = self._set_camera(paired.info)
        except CameraModelError as err:  # the odometry keeps its previous camera
            reason = str(err)
            if self.vo is None:
                return Step(paired.image, False, exact, unmatched, skipped=reason,
                            refused=reason)
            return Step(paired.image, True, exact, unmatched, refused=reason)
        return Step(paired.image, True, exact, unmatched, camera=event)

    def _set_camera(self, camera: CameraModel) -> str | None:
        """Make ``camera`` the odometry's; CREATED, CHANGED or None (the same calibration)."""
        if camera is self.camera or (self.camera is not None
                                     and same_calibration(camera, self.camera)):
            return None
        if self.vo is None:
            self.vo = VisualOdometry.from_params(camera, self.params)
            event = CREATED
        else:
            self.vo.set_camera(camera)  # keeps the old camera if it raises
            event = CHANGED
        self.camera = camera
        return event
