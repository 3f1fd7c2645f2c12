"""The named driving scenarios, and building a scene, trajectory and renderer from one."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from planar_vo.synth.lens import SynthCamera
from planar_vo.synth.mount import DEFAULT_MOUNTING, CameraMount
from planar_vo.synth.render import Renderer, exposure_gains
from planar_vo.synth.scene import make_ground_texture, make_obstacles
from planar_vo.synth.vehicle import RIGID, Suspension, make_trajectory, mount_camera


@dataclass(frozen=True)
class Scenario:
    """Driving profile, obstacle density, body motion and the scenario's camera attitude."""

    name: str
    speed: tuple = (3.0, 8.0)  # m/s range of the speed knots
    steer: float = 0.06  # max |steering angle| of the knots (rad)
    knot_dt: tuple = (2.0, 3.5)  # seconds between knots
    obstacles_per_100m: float = 6.0
    ahead_fraction: float = 0.2  # fraction of obstacles close to the path (seen ahead)
    description: str = ''
    suspension: Suspension = RIGID
    camera_roll: float = 0.0  # rad, the scenario's mounting (else DEFAULT_MOUNTING's)
    camera_yaw: float = 0.0

    @property
    def mounting(self) -> CameraMount:
        """The scenario's camera mounting: the default one with its roll and yaw."""
        return dataclasses.replace(DEFAULT_MOUNTING, roll=self.camera_roll,
                                   yaw=self.camera_yaw)


SCENARIOS = {
    'straight': Scenario('straight', speed=(5.0, 5.0), steer=0.0, obstacles_per_100m=4.0,
                         description='straight line at a constant 5 m/s, few obstacles'),
    'gentle': Scenario('gentle', speed=(4.0, 7.0), steer=0.04, obstacles_per_100m=4.0,
                       description='gentle curves (radius >= ~65 m), 4-7 m/s'),
    'tight': Scenario('tight', speed=(2.0, 3.0), steer=0.35, knot_dt=(1.5, 2.5),
                      obstacles_per_100m=4.0,
                      description='tight turns (radius down to ~7.5 m), 2-3 m/s'),
    'obstacles': Scenario('obstacles', speed=(3.0, 6.0), steer=0.05, obstacles_per_100m=30.0,
                          ahead_fraction=0.35,
                          description='gentle curves among many boxes (30 per 100 m)'),
    'default': Scenario('default', speed=(3.0, 8.0), steer=0.08, obstacles_per_100m=8.0,
                        description='realistic mix: curves, speed changes 3-8 m/s, boxes'),
    'car': Scenario('car', speed=(3.0, 8.0), steer=0.14, obstacles_per_100m=6.0,
                    suspension=Suspension.degrees(1.0, 0.6, 0.015),
                    camera_roll=math.radians(0.5), camera_yaw=math.radians(-0.7),
                    description='a sprung car body (pitch <= 1 deg, roll <= 0.6 deg, '
                                'bounce <= 1.5 cm), curves, speed changes 3-8 m/s, camera '
                                'rolled 0.5 deg and yawed -0.7 deg'),
    'rough': Scenario('rough', speed=(3.0, 7.0), steer=0.16, obstacles_per_100m=6.0,
                      suspension=Suspension.degrees(2.0, 1.2, 0.03),
                      camera_roll=math.radians(-0.6), camera_yaw=math.radians(0.8),
                      description='rough road, twice the car body motion (pitch <= 2 deg, '
                                  'roll <= 1.2 deg, bounce <= 3 cm), camera rolled -0.6 deg '
                                  'and yawed 0.8 deg'),
}


def render_scenario(scenario: str = 'default', frames: int = 300, seed: int = 0, *,
                    rate: float = 30.0, camera: SynthCamera | None = None, mounting=None,
                    suspension: Suspension | None = None, noise_sigma: float = 1.5,
                    max_range: float = 60.0, obstacles: bool = True, exposure: float = 0.0,
                    supersample: int = 1):
    """Build the scene; return ``(renderer, trajectory)``.

    ``mounting`` (a :class:`CameraMount` or anything with its six numbers) and ``suspension``
    default to the scenario's. ``exposure`` is the auto-exposure range (0.2: gain within
    +-20 %, see :func:`exposure_gains`; ``renderer.exposure`` holds the gain of every frame).
    ``supersample``: rays per pixel side, averaged (see :class:`Renderer`).
    ``renderer.render_frame(traj, k)`` is frame k of the bag; ``traj.camera`` holds the true
    camera pose of every frame.
    """
    if not 0.0 <= exposure < 1.0:
        raise ValueError(f'exposure must be in [0, 1), got {exposure}')
    if scenario not in SCENARIOS:
        raise ValueError(f'unknown scenario {scenario!r} (choose from {", ".join(SCENARIOS)})')
    sc = SCENARIOS[scenario]
    mounting = CameraMount.of(mounting or sc.mounting)
    suspension = sc.suspension if suspension is None else suspension
    traj = mount_camera(make_trajectory(sc, frames, rate, seed), mounting, suspension, seed)
    boxes = make_obstacles(traj, sc, seed, mounting) if obstacles else []
    renderer = Renderer(camera, mounting, make_ground_texture(seed), boxes,
                        max_range=max_range, noise_sigma=noise_sigma, seed=seed,
                        max_tilt=suspension.pitch + suspension.roll + math.radians(1.0),
                        exposure=exposure_gains(traj.t, exposure, seed) if exposure else None,
                        supersample=supersample)
    return renderer, traj
