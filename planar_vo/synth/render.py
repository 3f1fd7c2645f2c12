"""Rendering mono8 images of the ground and boxes seen from the mounted camera."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from planar_vo.synth.lens import SynthCamera
from planar_vo.synth.mount import BODY_FROM_OPTICAL, DEFAULT_MOUNTING, CameraMount
from planar_vo.synth.raycast import intersect
from planar_vo.synth.scene import Texture, make_ground_texture
from planar_vo.synth.shutter import WorldRowPoses
from planar_vo.synth.terrain import FLAT, Terrain
from planar_vo.synth.vehicle import Trajectory


def exposure_gains(t: np.ndarray, fraction: float, seed: int) -> np.ndarray:
    """Auto-exposure gain at times ``t`` (s), within 1 +- ``fraction``.

    Half the range is a smooth drift (two slow sines, 0.05-0.3 Hz), half are steps, as an
    auto-exposure loop makes: a new level every 1.5-4 s, reached from one frame to the next.
    """
    t = np.asarray(t, np.float64)
    if fraction == 0:
        return np.ones_like(t)
    rng = np.random.default_rng([seed, 6])
    smooth = (0.6 * np.sin(2 * math.pi * rng.uniform(0.05, 0.12) * t + rng.uniform(0, 7))
              + 0.4 * np.sin(2 * math.pi * rng.uniform(0.12, 0.3) * t + rng.uniform(0, 7)))
    switch = np.cumsum(rng.uniform(1.5, 4.0, int(t.max(initial=0) / 1.5) + 2))
    levels = rng.uniform(-1.0, 1.0, switch.size + 1)
    levels[0] = 0.0
    steps = levels[np.searchsorted(switch, t, side='right')]
    return 1.0 + 0.5 * fraction * (smooth + steps)


def _rotate(rotation: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """``rotation @ vectors`` for (3, N) float32 vectors.

    Written out: BLAS threads stall such thin products on a busy machine.
    """
    return np.stack([rotation[i, 0] * vectors[0] + rotation[i, 1] * vectors[1]
                     + rotation[i, 2] * vectors[2] for i in range(3)])


class Renderer:
    """Render mono8 images of the ground (and boxes) for base_link poses in odom.

    For the nominal (rigid) mount all per-pixel ground geometry is fixed in base_link (planar
    motion), so it is computed once: ground hit points, mip levels, haze; per frame only a 2-D
    rigid transform, the texture look-ups, the boxes and the noise. A camera moving on a
    sprung body (:meth:`render_frame`, :meth:`render_pose`) gets its ground intersection per
    frame, for every pixel whose nominal ray is less than ``max_tilt`` above the horizon;
    the mip levels stay those of the nominal pose (the body moves by a degree or two: tilted
    by 1-2 deg this differs from a renderer built for the tilted mount by 0.9-1.6 grey levels
    on average, about the sensor noise, against a texture contrast of 24).

    ``supersample`` s > 1 renders s x s rays per pixel and averages them, as a sensor
    integrates the light over its pixel; with 1 each pixel is its centre's ray, mip-mapped,
    whose aliasing biases KLT (the rigid model's t_rel on the sprung scenarios' paths is
    0.035 % point-sampled, 0.019-0.020 % area-sampled at 2x).

    On a ``terrain`` (not flat) frames of a trajectory with a 3D pose go through
    :meth:`render_world`: every pixel's ray is intersected with the height field
    (:func:`planar_vo.synth.raycast.intersect`), the texture sampled at the hit's world (x, y)
    with the mip level of the hit's footprint (finite differences of neighbouring hits), and
    boxes stand on the ground under their centre.

    A rolling shutter sets :attr:`rows` (:mod:`planar_vo.synth.shutter`): on flat ground the
    planar pose of every row (:meth:`render_rows`), on terrain the 3D pose of every row
    (:meth:`render_world_rows`: each row's rays cast from its own camera pose).
    """

    def __init__(self, camera: SynthCamera | None = None, mounting=None,
                 texture: Texture | None = None, boxes=(), *, max_range: float = 60.0,
                 noise_sigma: float = 1.5, seed: int = 0, illumination: bool = True,
                 haze: bool = True, max_tilt: float = math.radians(4.0),
                 exposure: np.ndarray | None = None, supersample: int = 1,
                 terrain: Terrain | None = None, traffic=(),
                 frame_times: np.ndarray | None = None, vignetting: float = 0.35) -> None:
        self.terrain = FLAT if terrain is None else terrain
        if int(supersample) != supersample or supersample < 1:
            raise ValueError(f'supersample must be a whole number >= 1, got {supersample}')
        self.camera = camera or SynthCamera()
        self.supersample = int(supersample)
        self.exposure = None if exposure is None else np.asarray(exposure, np.float64)
        self.mounting = CameraMount.of(mounting or DEFAULT_MOUNTING)
        self.texture = texture if texture is not None else make_ground_texture(seed)
        self.boxes = list(boxes)
        # Moving boxes (scene.MovingBox): where they are at frame k is at frame_times[k].
        self.traffic = list(traffic)
        self.frame_times = None if frame_times is None else np.asarray(frame_times, np.float64)
        if self.traffic and self.frame_times is None:
            raise ValueError('moving boxes need the frame times')
        self._still: tuple | None = None  # (pose, ground image) of the last render()
        self.max_range = float(max_range)
        self.noise_sigma = float(noise_sigma)
        self.seed = seed
        self.illumination = illumination
        self.haze = haze
        # The geometry is that of the rays rendered; vignetting and noise are the sensor's.
        cam, mnt = _subpixel_camera(self.camera, self.supersample), self.mounting
        self._render_fx = cam.fx
        h, w = cam.height, cam.width
        rays = cam.rays().reshape(-1, 3)
        self.base_from_optical = mnt.rotation @ BODY_FROM_OPTICAL
        d = rays @ self.base_from_optical.T
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        self.dirs = np.ascontiguousarray(d.T, np.float32)  # (3, N) unit rays in base_link
        self.origin = mnt.position
        cz = self.origin[2]
        if cz <= 0:
            raise ValueError('camera_height must be > 0')
        with np.errstate(divide='ignore', invalid='ignore'):  # sky rays: t = inf, masked below
            t = np.where(d[:, 2] < -1e-9, cz / -d[:, 2], np.inf)
            gp = self.origin[None, :2] + t[:, None] * d[:, :2]
        dist = np.hypot(gp[:, 0] - self.origin[0], gp[:, 1] - self.origin[1])
        ground = np.isfinite(t) & (dist < max_range)
        self.t_ground = np.where(ground, t, np.inf)
        # Footprint of each pixel on the ground (finite differences of hit points).
        g = np.where(ground[:, None], gp, np.nan)
        foot = _footprint(g[:, 0].reshape(h, w), g[:, 1].reshape(h, w)).ravel()
        level = np.log2(np.maximum(np.nan_to_num(foot, nan=1e3) / self.texture.texel, 1e-9))
        level = np.clip(level, 0.0, self.texture.nlevels - 1.0)
        idx = np.flatnonzero(ground)
        l0 = np.floor(level[idx]).astype(np.int64)
        order = np.argsort(l0, kind='stable')
        self.g_idx = idx[order]
        self.g_l0 = l0[order]
        self.g_frac = (level[idx] - l0)[order].astype(np.float32)
        self.g_pts = gp[self.g_idx]
        self.sky = self._sky(d[:, 2])
        self.g_fog = self._haze(dist[self.g_idx])
        # Vignetting (fixed per pixel).
        sensor = self.camera
        uu, vv = np.meshgrid((np.arange(sensor.width) - sensor.cx) / sensor.width,
                             (np.arange(sensor.height) - sensor.cy) / sensor.height)
        self.vignette = (1.0 - vignetting * (uu * uu + vv * vv)).ravel().astype(np.float32)
        # A pixel is ground when all its rays are.
        self.ground_mask = ground.reshape(sensor.height, self.supersample, sensor.width,
                                          self.supersample).all(axis=(1, 3))
        # Pixels a tilted camera may see the ground through, sorted by their nominal level.
        unit_rays = rays / np.linalg.norm(rays, axis=1, keepdims=True)
        self._unit_rays = np.ascontiguousarray(unit_rays.T, np.float32)  # (3, N)
        cand = np.flatnonzero(d[:, 2] < math.sin(max_tilt))
        cand_level = np.where(ground[cand], level[cand], self.texture.nlevels - 1.0)
        c0 = np.floor(cand_level).astype(np.int64)
        order = np.argsort(c0, kind='stable')
        self._c_idx = cand[order]
        self._c_l0 = c0[order]
        self._c_frac = (cand_level[order] - c0[order]).astype(np.float32)
        # A rolling shutter (planar_vo.synth.shutter): the pose of every row of every frame.
        self.rows = None

    def _sensor_row(self, index: np.ndarray) -> np.ndarray:
        """The sensor row of rendered rays ``index`` (flat, supersampled grid)."""
        s = self.supersample
        return index // (self.camera.width * s) // s

    @staticmethod
    def _sky(up: np.ndarray) -> np.ndarray:
        """Sky grey level from each unit ray's upward component (its elevation only)."""
        elev = np.arcsin(np.clip(up, -1, 1))
        return (196.0 + 45.0 * np.sin(np.clip(elev, 0, None)) ** 0.7
                - 12.0 * np.clip(-elev, 0, 0.2) / 0.2).astype(np.float32)

    def _haze(self, dist: np.ndarray) -> np.ndarray:
        """Blend factor towards the sky for ground at ``dist`` m (1 = all sky)."""
        if not self.haze:
            return np.zeros(dist.shape, np.float32)
        s = np.clip((dist - 0.5 * self.max_range) / (0.5 * self.max_range), 0, 1)
        fog = 0.12 * (1 - np.exp(-dist / 30.0)) + 0.88 * s * s * (3 - 2 * s)
        return np.clip(fog, 0, 1).astype(np.float32)

    def ground_points_base(self) -> np.ndarray:
        """(H, W, 2) ground hit point of every ray rendered in base_link (NaN = no ground).

        One ray per pixel; s x s per pixel when supersampled (H and W then s times the image's).
        """
        s = self.supersample
        out = np.full((self.camera.height * s * self.camera.width * s, 2), np.nan)
        out[self.g_idx] = self.g_pts
        return out.reshape(self.camera.height * s, self.camera.width * s, 2)

    def gain(self, k: int) -> float:
        """Global gain of frame k: slow, smooth illumination times the auto-exposure gain."""
        exposure = 1.0 if self.exposure is None else float(self.exposure[k])
        if not self.illumination:
            return exposure
        ph = (self.seed % 97) * 0.37
        return (1.0 + 0.05 * math.sin(0.21 * k / 30.0 * 2 * math.pi + ph)
                + 0.02 * math.sin(0.9 * k / 30.0 * 2 * math.pi + 2 * ph)) * exposure

    def boxes_at(self, k: int) -> list:
        """The boxes of frame k: the static ones and the moving ones in the scene then."""
        if not self.traffic:
            return self.boxes
        t = float(self.frame_times[k])
        moving = [box for box in (m.at(t) for m in self.traffic) if box is not None]
        return self.boxes + moving

    def render(self, x: float, y: float, yaw: float, k: int = 0) -> np.ndarray:
        """Render the image seen from base_link pose (x, y, yaw) in odom; frame index k.

        The ground seen from the last pose rendered is kept: a vehicle standing still costs
        only its boxes, illumination and noise per frame.
        """
        pose = (x, y, yaw)
        if self._still is not None and self._still[0] == pose:
            img = self._still[1].copy()
        else:
            img = self.sky.copy()
            c, s = math.cos(yaw), math.sin(yaw)
            gx = x + c * self.g_pts[:, 0] - s * self.g_pts[:, 1]
            gy = y + s * self.g_pts[:, 0] + c * self.g_pts[:, 1]
            val = self.texture.sample_sorted(gx, gy, self.g_l0, self.g_frac)
            sky = img[self.g_idx]
            img[self.g_idx] = val + (sky - val) * self.g_fog
            self._still = (pose, img.copy())
        boxes = self.boxes_at(k)
        if boxes:
            self._render_boxes(img, x, y, yaw, self.origin, self.dirs, self.t_ground.copy(),
                               self.sky, boxes=boxes)
        return self._finish(img, k)

    def render_frame(self, traj: Trajectory, k: int) -> np.ndarray:
        """Frame k of ``traj``: its base_link pose and, when set, its true camera pose.

        With :attr:`rows` set (a rolling shutter) each row from the pose at its own time.
        """
        if self.rows is not None:
            return self.render_rows(k)
        if traj.pose3d is not None:
            rot, pos = traj.pose3d.rotation[k], traj.pose3d.position[k]
            if traj.camera is None:
                cam_pos, cam_rot = self.origin, self.base_from_optical
            else:
                cam_pos, cam_rot = traj.camera.position[k], traj.camera.base_from_optical(k)
            return self.render_world(k, pos + rot @ cam_pos, rot @ cam_rot)
        if traj.camera is None:
            return self.render(traj.x[k], traj.y[k], traj.yaw[k], k)
        return self.render_pose(traj.x[k], traj.y[k], traj.yaw[k], k,
                                traj.camera.position[k], traj.camera.base_from_optical(k))

    def render_pose(self, x: float, y: float, yaw: float, k: int, position: np.ndarray,
                    base_from_optical: np.ndarray) -> np.ndarray:
        """Render from base_link pose (x, y, yaw) with the camera moved on the body.

        ``position`` (3,) and ``base_from_optical`` (3x3) are the camera's pose in base_link
        at this frame.
        """
        if (np.array_equal(position, self.origin)
                and np.array_equal(base_from_optical, self.base_from_optical)):
            return self.render(x, y, yaw, k)  # the nominal pose: geometry precomputed
        position = np.asarray(position, np.float64)
        if position[2] <= 0:
            raise ValueError('the camera must stay above the ground')
        # float32 throughout: ground points within max_range of the camera, and the odom
        # position wrapped to the texture's period (the texture repeats exactly).
        rotation = np.asarray(base_from_optical, np.float32)
        dirs = _rotate(rotation, self._unit_rays)
        sky = self._sky_fast(dirs[2])
        img = sky.copy()
        d = dirs[:, self._c_idx]
        depression = -d[2]
        down = depression > 1e-6
        t = np.float32(position[2]) / np.where(down, depression, np.float32(1.0))
        dist = t * np.hypot(d[0], d[1])
        ground = down & (dist < self.max_range)
        t[~ground] = 0.0  # no ground within range: sampled at the camera's foot, fog hides it
        bx = np.float32(position[0]) + t * d[0]
        by = np.float32(position[1]) + t * d[1]
        c, s = np.float32(math.cos(yaw)), np.float32(math.sin(yaw))
        period = self.texture.texel * self.texture.sizes[0]
        val = self.texture.sample_sorted(np.float32(x % period) + c * bx - s * by,
                                         np.float32(y % period) + s * bx + c * by,
                                         self._c_l0, self._c_frac)
        fog = np.where(ground, self._haze(dist), np.float32(1.0))
        behind = img[self._c_idx]
        img[self._c_idx] = val + (behind - val) * fog
        boxes = self.boxes_at(k)
        if boxes:
            depth = np.full(img.shape[0], np.inf)
            depth[self._c_idx[ground]] = t[ground]
            self._render_boxes(img, x, y, yaw, position, dirs, depth, sky, boxes=boxes)
        return self._finish(img, k)

    def render_rows(self, k: int) -> np.ndarray:
        """Frame k with a rolling shutter: every row from its own pose (:attr:`rows`)."""
        rows = self.rows
        if isinstance(rows, WorldRowPoses):
            return self.render_world_rows(k)
        xr, yr, yawr = rows.x[k], rows.y[k], rows.yaw[k]
        s = self.supersample
        if rows.camera_position is None:  # rigid mount: the ground geometry is precomputed
            img = self.sky.copy()
            r = self._sensor_row(self.g_idx)
            c, sn = np.cos(yawr)[r], np.sin(yawr)[r]
            gx = xr[r] + c * self.g_pts[:, 0] - sn * self.g_pts[:, 1]
            gy = yr[r] + sn * self.g_pts[:, 0] + c * self.g_pts[:, 1]
            val = self.texture.sample_sorted(gx, gy, self.g_l0, self.g_frac)
            behind = img[self.g_idx]
            img[self.g_idx] = val + (behind - val) * self.g_fog
            depth, dirs, sky = self.t_ground.copy(), self.dirs, self.sky
            positions = np.broadcast_to(self.origin, (len(xr), 3))
        else:
            rotation = np.einsum('rij,jk->rik', rows.camera_rotation[k],
                                 BODY_FROM_OPTICAL).astype(np.float32)
            positions = rows.camera_position[k]
            if np.any(positions[:, 2] <= 0):
                raise ValueError('the camera must stay above the ground')
            dirs = _rotate_rows(np.repeat(rotation, s, axis=0), self._unit_rays)
            sky = self._sky_fast(dirs[2])
            img = sky.copy()
            r = self._sensor_row(self._c_idx)
            d = dirs[:, self._c_idx]
            depression = -d[2]
            down = depression > 1e-6
            pos = positions.astype(np.float32)[r]
            t = pos[:, 2] / np.where(down, depression, np.float32(1.0))
            dist = t * np.hypot(d[0], d[1])
            ground = down & (dist < self.max_range)
            t[~ground] = 0.0
            bx = pos[:, 0] + t * d[0]
            by = pos[:, 1] + t * d[1]
            period = self.texture.texel * self.texture.sizes[0]
            # odom position wrapped to the texture's period in float64, then float32 offsets
            c, sn = np.cos(yawr)[r].astype(np.float32), np.sin(yawr)[r].astype(np.float32)
            ox, oy = (xr % period)[r].astype(np.float32), (yr % period)[r].astype(np.float32)
            val = self.texture.sample_sorted(ox + c * bx - sn * by, oy + sn * bx + c * by,
                                             self._c_l0, self._c_frac)
            fog = np.where(ground, self._haze(dist), np.float32(1.0))
            behind = img[self._c_idx]
            img[self._c_idx] = val + (behind - val) * fog
            depth = np.full(img.shape[0], np.inf)
            depth[self._c_idx[ground]] = t[ground]
        boxes = self.boxes_at(k)  # the traffic where it is at the frame's stamp
        if boxes:  # each rendered row seen from its own pose
            self._render_boxes(img, np.repeat(xr, s), np.repeat(yr, s), np.repeat(yawr, s),
                               np.repeat(positions, s, axis=0), dirs, depth, sky, boxes=boxes)
        return self._finish(img, k)

    def render_world(self, k: int, position: np.ndarray,
                     world_from_optical: np.ndarray) -> np.ndarray:
        """Frame k over ``self.terrain`` (the first hit of each ray).

        The camera is at ``position`` (3,) in the world frame, rotated by
        ``world_from_optical`` (3x3).
        """
        position = np.asarray(position, np.float64)
        rotation = np.asarray(world_from_optical, np.float64)
        if position[2] <= float(self.terrain.height(position[0], position[1])):
            raise ValueError('the camera must stay above the ground')
        dirs = _rotate(rotation, self._unit_rays.astype(np.float64))
        sky = self._sky_fast(dirs[2].astype(np.float32))
        img = sky.copy()
        t, hit = intersect(self.terrain, position, dirs, self.max_range)
        idx = np.flatnonzero(hit)
        gx = position[0] + t[idx] * dirs[0, idx]
        gy = position[1] + t[idx] * dirs[1, idx]
        self._texture_hits(img, idx, gx, gy, np.hypot(gx - position[0], gy - position[1]),
                           gx, gy)
        boxes = self.boxes_at(k)
        if boxes:
            depth = np.where(hit, t, np.inf)
            self._render_boxes(img, 0.0, 0.0, 0.0, position, dirs.astype(np.float32), depth,
                               sky, ground=self.terrain, boxes=boxes)
        return self._finish(img, k)

    def row_cameras(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The camera's world pose at each sensor row's time of frame k, on terrain.

        ``(position (H, 3), world_from_optical (H, 3, 3))`` from :attr:`rows` (a
        :class:`~planar_vo.synth.shutter.WorldRowPoses`): base_link's pose at the row's time
        composed with the camera's pose on the body then (the mount's on a rigid one).
        """
        rows = self.rows
        pos, rot = rows.position[k], rows.rotation[k]
        if rows.camera_position is None:
            cam_pos = np.broadcast_to(self.origin, pos.shape)
            cam_rot = np.broadcast_to(self.base_from_optical, rot.shape)
        else:
            cam_pos = rows.camera_position[k]
            cam_rot = rows.camera_rotation[k] @ BODY_FROM_OPTICAL
        return pos + (rot @ cam_pos[:, :, None])[:, :, 0], rot @ cam_rot

    def render_world_rows(self, k: int) -> np.ndarray:
        """Frame k over ``self.terrain`` with a rolling shutter: each row from its own pose.

        Every row's rays start at its camera's 3D pose (:meth:`row_cameras`) and are
        intersected with the height field from there. As :meth:`render_world` otherwise; the
        mip level comes from the footprint of the hits with each row's camera translation
        (relative to the first row's) taken out, as one instant's projection sees it, and
        boxes are drawn row by row from the row's pose.
        """
        positions, rotations = self.row_cameras(k)
        ground = self.terrain.height(positions[:, 0], positions[:, 1])
        if np.any(positions[:, 2] <= ground):
            raise ValueError('the camera must stay above the ground')
        n = self._unit_rays.shape[1]
        row = self._sensor_row(np.arange(n))
        dirs = _rotate_rows(np.repeat(rotations, self.supersample, axis=0),
                            self._unit_rays.astype(np.float64))
        origins = positions.T[:, row]  # (3, N): each ray from its row's camera
        sky = self._sky_fast(dirs[2].astype(np.float32))
        img = sky.copy()
        t, hit = intersect(self.terrain, origins, dirs, self.max_range)
        idx = np.flatnonzero(hit)
        ox, oy = origins[0, idx], origins[1, idx]
        gx = ox + t[idx] * dirs[0, idx]
        gy = oy + t[idx] * dirs[1, idx]
        # the footprint of each hit less its row camera's offset from the first row's
        # (exactly the hits when the rows agree)
        self._texture_hits(img, idx, gx, gy, np.hypot(gx - ox, gy - oy),
                           gx - (ox - positions[0, 0]), gy - (oy - positions[0, 1]))
        s = self.supersample
        boxes = self.boxes_at(k)
        if boxes:  # each rendered row seen from its own pose
            self._render_boxes(img, 0.0, 0.0, 0.0, np.repeat(positions, s, axis=0),
                               dirs.astype(np.float32), np.where(hit, t, np.inf), sky,
                               ground=self.terrain, boxes=boxes)
        return self._finish(img, k)

    def _texture_hits(self, img: np.ndarray, idx: np.ndarray, gx: np.ndarray, gy: np.ndarray,
                      dist: np.ndarray, foot_x: np.ndarray, foot_y: np.ndarray) -> None:
        """Rays ``idx`` (into ``img``) hit the ground at (gx, gy), ``dist`` m away: textured.

        The mip level from the footprint: finite differences of neighbouring rays' (foot_x,
        foot_y).
        """
        cam, s = self.camera, self.supersample
        shape = (cam.height * s, cam.width * s)
        grid_x, grid_y = np.full(shape[0] * shape[1], np.nan), np.full(shape[0] * shape[1], np.nan)
        grid_x[idx], grid_y[idx] = foot_x, foot_y
        foot = _footprint(grid_x.reshape(shape), grid_y.reshape(shape)).ravel()[idx]
        level = np.log2(np.maximum(np.nan_to_num(foot, nan=1e3) / self.texture.texel, 1e-9))
        level = np.clip(level, 0.0, self.texture.nlevels - 1.0)
        l0 = np.floor(level).astype(np.int64)
        order = np.argsort(l0, kind='stable')
        idx, gx, gy, dist = idx[order], gx[order], gy[order], dist[order]
        val = self.texture.sample_sorted(gx, gy, l0[order],
                                         (level[order] - l0[order]).astype(np.float32))
        fog = self._haze(dist)
        behind = img[idx]
        img[idx] = val + (behind - val) * fog

    @staticmethod
    def _sky_fast(up: np.ndarray) -> np.ndarray:
        """:meth:`_sky` in float32 arithmetic (``sin(arcsin(up)) = up``)."""
        return (np.float32(196.0) + np.float32(45.0) * np.maximum(up, 0) ** np.float32(0.7)
                - np.float32(60.0) * np.clip(-np.arcsin(np.clip(up, -1, 1)), 0, 0.2))

    def _finish(self, img: np.ndarray, k: int) -> np.ndarray:
        """Pixel integration, vignetting, illumination and sensor noise; mono8 (H, W)."""
        cam, s = self.camera, self.supersample
        if s > 1:
            img = img.reshape(cam.height, s, cam.width, s).mean(axis=(1, 3)).ravel()
        img *= self.vignette * self.gain(k)
        if self.noise_sigma > 0:
            rng = np.random.default_rng([self.seed, 4, k])
            img += rng.standard_normal(img.shape[0], np.float32) * np.float32(self.noise_sigma)
        return np.clip(img + 0.5, 0, 255).astype(np.uint8).reshape(cam.height, cam.width)

    def _render_boxes(self, img: np.ndarray, x, y, yaw, origin: np.ndarray, dirs: np.ndarray,
                      depth: np.ndarray, sky: np.ndarray, ground: Terrain | None = None,
                      boxes: list | None = None) -> None:
        """Draw ``boxes`` (default: the static ones) over ``img`` from base_link (x, y, yaw).

        ``origin`` and the unit pixel rays ``dirs`` (3, N) are in base_link; ``depth`` is the
        ground's ray length per pixel, ``sky`` the sky behind the haze. One pose (scalars,
        ``origin`` (3,)) or one per band of N / R consecutive pixels (arrays (R,), ``origin``
        (R, 3): the rows of a rolling shutter), so that a frame is one call. On a ``ground``
        terrain (world frame: x = y = yaw = 0) each box stands on the height under its centre
        and reaches 0.5 m below it (the ground hides that part). The order the boxes are
        drawn in does not matter: the nearest hit wins the depth test and the haze blends
        towards ``sky``.
        """
        origin = np.asarray(origin, np.float64).reshape(-1, 3)
        x, y, yaw, ox, oy, oz_camera = np.broadcast_arrays(
            *(np.asarray(v, np.float64).reshape(-1) for v in (x, y, yaw)), *origin.T)
        bands = x.size
        band = dirs.shape[1] // bands  # pixels per pose
        rays = [dirs[i].reshape(bands, band) for i in range(3)]
        c, s = np.cos(yaw), np.sin(yaw)
        cwx, cwy = x + c * ox - s * oy, y + s * ox + c * oy  # camera centre in odom
        for b in self.boxes if boxes is None else boxes:
            if ground is None:
                oz, bottom = oz_camera, 0.0
            else:  # the box's own vertical frame: z = 0 on the ground under its centre
                base = float(ground.height(b.x, b.y))
                oz, bottom = oz_camera - base, -0.5
            dx, dy = b.x - cwx, b.y - cwy
            mid, half = (b.height + bottom) / 2, (b.height - bottom) / 2
            r = math.sqrt(b.half_x ** 2 + b.half_y ** 2 + half ** 2)
            dist = np.sqrt(dx * dx + dy * dy + (mid - oz) ** 2)
            seen = dist - r <= self.max_range  # beyond: not drawn, not even against the sky
            if not seen.any():
                continue
            # The rays within the bounding sphere's cone (all of them from inside it; none
            # from a pose that does not see the box), in float32.
            outside = dist > r * 1.001
            with np.errstate(invalid='ignore'):
                cos_th = np.where(outside, np.cos(np.arcsin(r / dist)), -np.inf)
            cos_th = np.where(seen, cos_th, np.inf).astype(np.float32)[:, None]
            # Direction to the centre in base_link.
            vb = (np.stack([c * dx + s * dy, -s * dx + c * dy, mid - oz])
                  / dist).astype(np.float32)[:, :, None]
            sel = np.flatnonzero(rays[0] * vb[0] + rays[1] * vb[1] + rays[2] * vb[2] > cos_th)
            if sel.size == 0:
                continue
            pose = sel // band
            d = dirs[:, sel].T.astype(np.float64)
            a = yaw - b.yaw  # base → box rotation
            ca, sa = np.cos(a)[pose], np.sin(a)[pose]
            dlx = ca * d[:, 0] - sa * d[:, 1]
            dly = sa * d[:, 0] + ca * d[:, 1]
            dlz = d[:, 2]
            cb, sb = math.cos(b.yaw), math.sin(b.yaw)
            olx = (cb * (cwx - b.x) + sb * (cwy - b.y))[pose]
            oly = (-sb * (cwx - b.x) + cb * (cwy - b.y))[pose]
            olz = oz[pose]
            with np.errstate(divide='ignore', invalid='ignore'):
                tx1, tx2 = (-b.half_x - olx) / dlx, (b.half_x - olx) / dlx
                ty1, ty2 = (-b.half_y - oly) / dly, (b.half_y - oly) / dly
                tz1, tz2 = (bottom - olz) / dlz, (b.height - olz) / dlz
            tnx, tfx = np.fmin(tx1, tx2), np.fmax(tx1, tx2)
            tny, tfy = np.fmin(ty1, ty2), np.fmax(ty1, ty2)
            tnz, tfz = np.fmin(tz1, tz2), np.fmax(tz1, tz2)
            tnear = np.fmax(np.fmax(tnx, tny), tnz)
            tfar = np.fmin(np.fmin(tfx, tfy), tfz)
            hit = (tnear <= tfar) & (tnear > 1e-6) & (tnear < depth[sel])
            if not hit.any():
                continue
            tn = tnear[hit]
            px = olx[hit] + tn * dlx[hit]
            py = oly[hit] + tn * dly[hit]
            pz = olz[hit] + tn * dlz[hit]
            face_x = tnx[hit] >= np.fmax(tny[hit], tnz[hit])
            face_z = ~face_x & (tnz[hit] >= tny[hit])
            tu = np.where(face_x, py, px)
            tv = np.where(face_z, py, pz)
            shade = np.where(face_x, np.where(px > 0, 0.85, 1.1),
                             np.where(face_z, 1.2, np.where(py > 0, 0.95, 0.75)))
            level = np.log2(np.maximum(tn / self._render_fx / self.texture.texel, 1e-9))
            tex = self.texture.sample(tu + b.tex_x, tv + b.tex_y, level)
            idx = sel[hit]
            val = (b.albedo * shade * (tex - 110.0) * 1.3 + 100.0 + b.offset) * shade
            rr = tn
            fs = np.clip((rr - 0.5 * self.max_range) / (0.5 * self.max_range), 0, 1)
            fog = 0.12 * (1 - np.exp(-rr / 30.0)) + 0.88 * fs * fs * (3 - 2 * fs)
            img[idx] = val + (sky[idx] - val) * fog
            depth[idx] = tn


def _footprint(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Per pixel, the larger step between neighbouring ground points (x, y) (H, W) grids.

    Central differences along each image axis (np.gradient); NaN where a neighbour has no
    ground. The two planes apart: the norm over an interleaved axis of 2 is several times
    slower (the same numbers).
    """
    du = np.gradient(x, axis=1), np.gradient(y, axis=1)
    dv = np.gradient(x, axis=0), np.gradient(y, axis=0)
    return np.fmax(np.sqrt(du[0] * du[0] + du[1] * du[1]),
                   np.sqrt(dv[0] * dv[0] + dv[1] * dv[1]))


def _rotate_rows(rotations: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """``rotations[b] @ vectors[:, n]`` for every ray n of band b: (3, N).

    The N rays are R (``len(rotations)``) bands of N / R consecutive ones (the rendered rows),
    each turned by its own rotation: broadcast over the band, not gathered per ray.
    """
    r = rotations[:, :, :, None]
    v = vectors.reshape(3, len(rotations), -1)
    return np.stack([r[:, i, 0] * v[0] + r[:, i, 1] * v[1] + r[:, i, 2] * v[2]
                     for i in range(3)]).reshape(3, -1)


def _subpixel_camera(camera: SynthCamera, s: int) -> SynthCamera:
    """The camera whose pixels are ``camera``'s cut s x s.

    Pixel u of ``camera`` is pixels s*u .. s*u + s-1 of this one (and likewise v), so its
    centre is at s*u + (s-1)/2.
    """
    if s == 1:
        return camera
    return dataclasses.replace(camera, width=camera.width * s, height=camera.height * s,
                               fx=camera.fx * s, fy=camera.fy * s,
                               cx=camera.cx * s + (s - 1) / 2, cy=camera.cy * s + (s - 1) / 2)
