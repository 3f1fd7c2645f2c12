"""The named driving scenarios, and building a scene, trajectory and renderer from one.

A scenario composes profiles owned by the modules that use them: the drive
(:class:`~planar_vo.synth.vehicle.DriveProfile`), the boxes
(:class:`~planar_vo.synth.scene.ObstacleProfile`), the sprung body
(:class:`~planar_vo.synth.vehicle.Suspension`) and the terrain kind
(:data:`~planar_vo.synth.terrain.TERRAIN_KINDS`). This module imports them; they never import
it.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from planar_vo.synth.lens import SynthCamera
from planar_vo.synth.mount import DEFAULT_MOUNTING, CameraMount
from planar_vo.synth.render import Renderer, exposure_gains
from planar_vo.synth.ride import CHASSIS, FINE_STEP, ride_grid, ride_over, with_world_path
from planar_vo.synth.scene import (
    ObstacleProfile,
    TrafficProfile,
    make_ground_texture,
    make_obstacles,
    make_traffic,
)
from planar_vo.synth.shutter import RollingShutter, row_poses, world_row_poses
from planar_vo.synth.terrain import (
    TERRAIN_KINDS,
    Terrain,
    TerrainError,
    TerrainShape,
    make_terrain,
)
from planar_vo.synth.vehicle import (
    RIGID,
    DriveProfile,
    SpeedSchedule,
    Suspension,
    make_trajectory,
    mount_camera,
)

VEHICLES = {'car': 'a car: rear axle (base_link) and front axle 2.7 m apart, track 1.6 m',
            'diff_drive': 'a differential-drive robot: two wheels 0.5 m apart (base_link '
                          'between them) and a caster 0.35 m behind'}


@dataclass(frozen=True)
class Scenario:
    """Drive, boxes, body motion, terrain and the scenario's camera attitude."""

    name: str
    drive: DriveProfile = DriveProfile()
    obstacles: ObstacleProfile = ObstacleProfile()
    description: str = ''
    suspension: Suspension = RIGID
    camera_roll: float = 0.0  # rad, the scenario's mounting (else DEFAULT_MOUNTING's)
    camera_yaw: float = 0.0
    terrain: str = 'flat'  # a key of TERRAIN_KINDS
    traffic: TrafficProfile | None = None  # road users crossing ahead at stops

    # The profiles' fields, read through the scenario (make_trajectory(SCENARIOS[...]) works).
    speed = property(lambda self: self.drive.speed)
    steer = property(lambda self: self.drive.steer)
    knot_dt = property(lambda self: self.drive.knot_dt)
    schedule = property(lambda self: self.drive.schedule)
    obstacles_per_100m = property(lambda self: self.obstacles.per_100m)
    ahead_fraction = property(lambda self: self.obstacles.ahead_fraction)

    @property
    def duration(self) -> float | None:
        """Seconds of the scenario's speed schedule (None: a drive of any length)."""
        return None if self.drive.schedule is None else self.drive.schedule.duration

    def frames(self, rate: float) -> int | None:
        """Frames at ``rate`` Hz covering the whole schedule (None: any number)."""
        d = self.duration
        return None if d is None else int(round(d * rate)) + 1

    @property
    def mounting(self) -> CameraMount:
        """The scenario's camera mounting: the default one with its roll and yaw."""
        return dataclasses.replace(DEFAULT_MOUNTING, roll=self.camera_roll,
                                   yaw=self.camera_yaw)


def _drive(speed, steer, knot_dt=(2.0, 3.5)) -> DriveProfile:
    return DriveProfile(speed, steer, knot_dt)


def _boxes(per_100m, ahead_fraction=0.2) -> ObstacleProfile:
    return ObstacleProfile(per_100m, ahead_fraction)


# Stop-and-go: (seconds, m/s) phases; a phase of speed 0 is a full stop (exactly still).
# Ramps of 2.5 s: 2.4 m/s^2 and 3.8 m/s^3 at most from 0 to 4 m/s.
STOP_AND_GO = SpeedSchedule(((1.5, 0.0), (5.0, 4.0), (5.0, 0.0), (5.0, 4.0), (6.5, 0.0),
                             (3.5, -1.5), (5.0, 0.0), (4.5, 3.0), (4.5, 0.0)), ramp=2.5)
CREEP = SpeedSchedule(((1.5, 0.0), (6.0, 0.03), (2.5, 0.0), (5.0, 0.02), (2.5, 0.0),
                       (5.0, 0.05), (2.0, 0.0)), ramp=0.5)
RED_LIGHT = SpeedSchedule(((3.0, 4.0), (63.0, 0.0), (4.0, 4.0)), ramp=2.5)

SCENARIOS = {
    'straight': Scenario('straight', _drive((5.0, 5.0), 0.0), _boxes(4.0),
                         description='straight line at a constant 5 m/s, few obstacles'),
    'gentle': Scenario('gentle', _drive((4.0, 7.0), 0.04), _boxes(4.0),
                       description='gentle curves (radius >= ~65 m), 4-7 m/s'),
    'tight': Scenario('tight', _drive((2.0, 3.0), 0.35, (1.5, 2.5)), _boxes(4.0),
                      description='tight turns (radius down to ~7.5 m), 2-3 m/s'),
    'obstacles': Scenario('obstacles', _drive((3.0, 6.0), 0.05), _boxes(30.0, 0.35),
                          description='gentle curves among many boxes (30 per 100 m)'),
    'default': Scenario('default', _drive((3.0, 8.0), 0.08), _boxes(8.0),
                        description='realistic mix: curves, speed changes 3-8 m/s, boxes'),
    'car': Scenario('car', _drive((3.0, 8.0), 0.14), _boxes(6.0),
                    suspension=Suspension.degrees(1.0, 0.6, 0.015),
                    camera_roll=math.radians(0.5), camera_yaw=math.radians(-0.7),
                    description='a sprung car body (pitch <= 1 deg, roll <= 0.6 deg, '
                                'bounce <= 1.5 cm), curves, speed changes 3-8 m/s, camera '
                                'rolled 0.5 deg and yawed -0.7 deg'),
    'rough': Scenario('rough', _drive((3.0, 7.0), 0.16), _boxes(6.0),
                      suspension=Suspension.degrees(2.0, 1.2, 0.03),
                      camera_roll=math.radians(-0.6), camera_yaw=math.radians(0.8),
                      description='rough road, twice the car body motion (pitch <= 2 deg, '
                                  'roll <= 1.2 deg, bounce <= 3 cm), camera rolled -0.6 deg '
                                  'and yawed 0.8 deg'),
    'road': Scenario('road', _drive((3.0, 8.0), 0.08), _boxes(8.0),
                     suspension=Suspension.degrees(1.0, 0.6, 0.015), terrain='all',
                     description="default's drive on a real road (terrain all: grades, "
                                 'bumps, camber, hills) in the sprung car body'),
    'stop_and_go': Scenario('stop_and_go', DriveProfile(steer=0.08, schedule=STOP_AND_GO),
                            _boxes(8.0), traffic=TrafficProfile(),
                            description='stop-and-go (40 s): starts standing, full stops of '
                                        '2-4 s, 3-4 m/s between them, reverses at 1.5 m/s; cars '
                                        'and people cross ahead at every stop'),
    'creep': Scenario('creep', DriveProfile(steer=0.0, schedule=CREEP), _boxes(8.0),
                      description='creeping (24.5 s): 3, 2 and 5 cm/s straight ahead for '
                                  '4.5-5.5 s each, full stops of 1.5-2 s around them'),
    'red_light': Scenario('red_light', DriveProfile(steer=0.04, schedule=RED_LIGHT),
                          _boxes(8.0), traffic=TrafficProfile(),
                          description='a red light (70 s): 4 m/s, a 60.5 s stop while cars and '
                                      'a person cross ahead, 4 m/s again'),
}


def render_scenario(scenario: str = 'default', frames: int = 300, seed: int = 0, *,
                    rate: float = 30.0, camera: SynthCamera | None = None, mounting=None,
                    suspension: Suspension | None = None, noise_sigma: float = 1.5,
                    max_range: float = 60.0, obstacles: bool = True, exposure: float = 0.0,
                    supersample: int = 1, terrain: str | Terrain | None = None,
                    vehicle: str = 'car', rolling_shutter: RollingShutter | None = None,
                    terrain_shape: TerrainShape | None = None, texture_contrast: float = 1.0,
                    vignetting: float = 0.35):
    """Build the scene; return ``(renderer, trajectory)``.

    ``terrain``: a key of :data:`TERRAIN_KINDS` or a :class:`Terrain` (default: the
    scenario's, ``flat`` for most); ``vehicle``: a key of :data:`VEHICLES`, whose wheels set
    the pose on a terrain (on flat ground both follow the same planar path). On terrain
    ``traj.pose3d`` is base_link's 3D pose in the world frame and (x, y, yaw) the planar
    truth along the surface (:mod:`planar_vo.synth.ride`); ``renderer.terrain`` is the
    height field. ``terrain_shape``: the sizes of a named kind's features.

    ``mounting`` (a :class:`CameraMount` or anything with its six numbers) and ``suspension``
    default to the scenario's. ``exposure`` is the auto-exposure range (0.2: gain within
    +-20 %, see :func:`exposure_gains`; ``renderer.exposure`` holds the gain of every frame).
    ``supersample``: rays per pixel side, averaged (see :class:`Renderer`).
    ``texture_contrast``: the road's contrast (see :func:`make_ground_texture`);
    ``vignetting``: the light lost towards the image's edges (corners: half of it).
    ``renderer.render_frame(traj, k)`` is frame k of the bag; ``traj.camera`` holds the true
    camera pose of every frame.

    ``rolling_shutter`` (a :class:`~planar_vo.synth.shutter.RollingShutter` with a readout
    over 0) renders each row from the pose at its own time (``renderer.rows``; on terrain
    the vehicle's 3D pose riding the height field then, the sprung body included); the
    trajectory stays the truth at the image stamps.
    """
    if not 0.0 <= exposure < 1.0:
        raise ValueError(f'exposure must be in [0, 1), got {exposure}')
    if scenario not in SCENARIOS:
        raise ValueError(f'unknown scenario {scenario!r} (choose from {", ".join(SCENARIOS)})')
    if vehicle not in VEHICLES:
        raise ValueError(f'unknown vehicle {vehicle!r} (choose from {", ".join(VEHICLES)})')
    sc = SCENARIOS[scenario]
    mounting = CameraMount.of(mounting or sc.mounting)
    suspension = sc.suspension if suspension is None else suspension
    traj = make_trajectory(sc.drive, frames, rate, seed)
    ground = terrain if isinstance(terrain, Terrain) else make_terrain(
        sc.terrain if terrain is None else terrain, seed, traj.x, traj.y, shape=terrain_shape)
    rolling = rolling_shutter is not None and not rolling_shutter.global_shutter
    grid = None
    if not ground.flat:
        if rolling:  # the ride solved beyond the first and the last stamp by the readout
            grid = ride_grid(sc.drive, ground, frames, rate, seed, CHASSIS[vehicle],
                             margin=rolling_shutter.readout + FINE_STEP)
        traj = ride_over(sc.drive, ground, frames, rate, seed, CHASSIS[vehicle], grid=grid)
    traj = mount_camera(traj, mounting, suspension, seed)
    boxes = make_obstacles(with_world_path(traj), sc.obstacles, seed, mounting) \
        if obstacles else []
    traffic = make_traffic(traj, sc.traffic, seed, mounting.x) if obstacles else []
    renderer = Renderer(camera, mounting, make_ground_texture(seed, contrast=texture_contrast),
                        boxes, vignetting=vignetting,
                        max_range=max_range, noise_sigma=noise_sigma, seed=seed,
                        max_tilt=suspension.pitch + suspension.roll + math.radians(1.0),
                        exposure=exposure_gains(traj.t, exposure, seed) if exposure else None,
                        supersample=supersample, terrain=ground, traffic=traffic,
                        frame_times=traj.t if traffic else None)
    if rolling and grid is not None:
        renderer.rows = world_row_poses(grid, traj, sc.drive, rate, seed, rolling_shutter,
                                        renderer.camera.height, mounting, suspension)
    elif rolling:
        renderer.rows = row_poses(sc.drive, traj, rate, seed, rolling_shutter,
                                  renderer.camera.height, mounting, suspension)
    return renderer, traj


__all__ = ['CREEP', 'RED_LIGHT', 'SCENARIOS', 'STOP_AND_GO', 'TERRAIN_KINDS', 'VEHICLES',
           'Scenario', 'TerrainError', 'render_scenario']
