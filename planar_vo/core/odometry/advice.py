"""What /diagnostics says of the mounting and the ground model, and the advice it gives.

Read from the odometry's parts, nothing changed: self-calibration's estimate beside the
configured mounting (and the parameters the drive says are off), and where the local ground
cannot hold as configured (front wheels set inside the camera's view, a camera turned away
from straight ahead). Numpy only; no ROS.
"""

from __future__ import annotations

import numpy as np

from planar_vo.core.estimation.calibration import calibrated_params, mounting_advice
from planar_vo.core.geometry.camera import Mounting
from planar_vo.core.odometry.attitude_filter import AttitudeFilter
from planar_vo.core.odometry.ground_filter import LocalGroundFilter

__all__ = ['calibration_report', 'ground_advice']

# A camera turned further than this from straight ahead is told the local ground is not for it
# (rendered flat drives: 20 deg as ahead, 30 deg 0.22-0.35 % against the plane model's 0.11).
_LOOKS_AHEAD = np.radians(25.0)


def calibration_report(tilt_filter: AttitudeFilter | LocalGroundFilter | None,
                       configured: Mounting) -> tuple[dict[str, str], dict[str, str]]:
    """Self-calibration's estimate beside the configured mounting, and advice per parameter.

    ``tilt_filter``: the part that learns the mounting; nothing while it does not.
    """
    if tilt_filter is None or not tilt_filter.self_calibrate:
        return {}, {}
    estimate = tilt_filter.calibrator.estimate()
    now = calibrated_params(configured)
    values = {}
    for name, value in estimate.as_params().items():
        std = estimate.std[name]
        if name == 'camera_x':
            values[f'{name} estimated (m)'] = f'{value:.3f} +- {std:.3f}'
            values[f'{name} configured (m)'] = f'{now[name]:.3f}'
        else:
            values[f'{name} estimated (deg)'] = (f'{np.degrees(value):.3f} +- '
                                                 f'{np.degrees(std):.3f}')
            values[f'{name} configured (deg)'] = f'{np.degrees(now[name]):.3f}'
    values['calibration drive (s)'] = f'{estimate.seconds:.1f}'
    return values, mounting_advice(configured, estimate)


def ground_advice(ground: LocalGroundFilter | None, mounting: Mounting) -> dict[str, str]:
    """Advice when the local ground cannot hold as configured.

    Wheels set where the camera sees the ground: the local ground then bends from where the
    camera sees it (see :meth:`LocalGroundFilter.see_ground`); the wheels' own place is still
    better. A camera turned away from straight ahead is told what the local ground cannot do
    for it instead.
    """
    if ground is None:
        return {}
    turned = float(np.arccos(np.cos(mounting.yaw)))  # 0..pi from straight ahead
    if turned > _LOOKS_AHEAD:
        return {'ground_model': (
            f'the camera is turned {np.degrees(turned):.0f} deg '
            'from straight ahead: the local ground is built for a camera that sees the road '
            'its wheels will drive on (rendered flat roads, turned 30-90 deg: 0.2-0.6 %, '
            'the plane model 0.1-0.2; looking back 0.11 %, over grades, bumps, camber and '
            'hills 2.1 %); on a flat floor set ground_model to plane')}
    if not ground.wheels_inside_view():
        return {}
    return {'wheelbase': (
        f'wheelbase is {ground.wheelbase:.2f} m but the camera sees the ground from '
        f'{ground.hinge:.2f} m ahead of base_link: the road is taken to bend from '
        'there. Set wheelbase to where the front wheels stand (a differential-drive robot: '
        'its front caster, or 0 when its drive wheels lead)')}
