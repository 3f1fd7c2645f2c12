"""Ground height fields under the synthetic vehicle: ``z = h(x, y)`` in the world frame.

World frame: x, y horizontal, z up, metres; the vehicle starts at (0, 0) heading along +x
(the world frame is the planar odom frame at the first frame, before the ground lifts it).

Layout (the choice made here): every feature is a closed-form function of world (x, y):

- :class:`Grades`: the road grade along world x, piecewise constant (0 to +-4 %) and joined
  by parabolic vertical curves (the grade changes linearly over ``curve`` metres);
- :class:`Bumps`: speed bumps, smooth ``cos^2`` humps across world x (ridges along y);
- :class:`Hills`: rolling hills, two plane waves crossing at +-30 deg to x;
- :class:`Camber`: a crowned road. Its crown line follows the drive: it is the vehicle's
  planar path shifted ``offset`` metres to the left, as a function ``y = c(x)`` of world x
  (the drive must keep heading within +-80 deg of +x); the surface falls off at ``slope``
  either side of the crown (rounded over +-``rounding`` m so that h is C1), so a vehicle
  driving in the right-hand lane sits on the cross-slope. The cross-slope continues beyond
  the road (no ditches).

Scenarios drive mostly along +x (the named ones turn by less than 25 deg over 300 frames),
so grades and bumps meet the vehicle nearly head-on.

Each terrain gives ``height``, its analytic ``gradient``, ``bounds`` over a disc (for ray
casting) and, split into a smooth part and rough features (the bumps), a Lipschitz bound of
the smooth part. :class:`Composite` sums them. Heights are not shifted: the start is at
``h(0, 0)``, not necessarily 0.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

TERRAIN_KINDS = {
    'flat': 'the plane z = 0 (default)',
    'grades': 'road grade 0 to +-4 %, a change every ~15 m (12-18 m) joined by 10 m vertical '
              'curves',
    'bumps': 'speed bumps 8 cm high, 0.7 m long (cos^2 humps) every ~12 m (10-14 m)',
    'camber': 'a crowned road, 2 % cross-slope either side of a crown line 1.75 m left of '
              'the path (the vehicle sits on the right-hand slope)',
    'hills': 'rolling hills, 0.3 m amplitude, 20 m wavelength (two crossing waves)',
    'all': 'grades + bumps + camber + hills',
}


DESCRIBE_X = 150.0  # describe() lists features up to this world x (300 frames go ~80 m)


class TerrainError(ValueError):
    """A terrain cannot be built as asked (unknown kind, a path it cannot follow)."""


class Terrain:
    """A height field ``z = h(x, y)`` (world frame, metres). Arrays in, arrays out."""

    #: smooth terrains have no features shorter than a few metres; rough ones (bumps) do
    smooth = True
    #: an upper bound of |grad h| (smooth terrains; rough ones report their height range)
    lipschitz = 0.0

    @property
    def flat(self) -> bool:
        """True for the plane z = 0 (the renderer's and the vehicle's flat paths)."""
        return False

    def height(self, x, y) -> np.ndarray:
        """Height at world points (x, y), any broadcastable shapes."""
        raise NotImplementedError

    def gradient(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """(dh/dx, dh/dy) at world points (x, y)."""
        raise NotImplementedError

    def bounds(self, x: float, y: float, radius: float) -> tuple[float, float]:
        """(lowest, highest) h within ``radius`` m of (x, y) (may be loose, never tight)."""
        raise NotImplementedError

    def describe(self) -> dict:
        """Kind and parameters, for the bag's metadata."""
        return {'kind': type(self).__name__.lower()}


@dataclass(frozen=True)
class Flat(Terrain):
    """The plane z = 0."""

    @property
    def flat(self) -> bool:
        return True

    def height(self, x, y):
        return np.zeros(np.broadcast(x, y).shape)

    def gradient(self, x, y):
        z = np.zeros(np.broadcast(x, y).shape)
        return z, z.copy()

    def bounds(self, x, y, radius):
        return 0.0, 0.0

    def describe(self):
        return {'kind': 'flat'}


FLAT = Flat()


@dataclass(frozen=True)
class Plane(Terrain):
    """The plane ``h = z0 + gx x + gy y`` (a constant grade; for tests and closed forms)."""

    gx: float = 0.0
    gy: float = 0.0
    z0: float = 0.0

    @property
    def lipschitz(self) -> float:
        return math.hypot(self.gx, self.gy)

    def height(self, x, y):
        return self.z0 + self.gx * np.asarray(x, np.float64) + self.gy * np.asarray(y, np.float64)

    def gradient(self, x, y):
        shape = np.broadcast(x, y).shape
        return np.full(shape, self.gx), np.full(shape, self.gy)

    def bounds(self, x, y, radius):
        h = float(self.height(x, y))
        return h - self.lipschitz * radius, h + self.lipschitz * radius

    def describe(self):
        return {'kind': 'plane', 'gx': self.gx, 'gy': self.gy, 'z0': self.z0}


@dataclass(frozen=True)
class Grades(Terrain):
    """Road grade along world x, piecewise linear in x (parabolic vertical curves).

    The grade is ``knots_g[i]`` at ``x = knots_x[i]``, linear in between, constant outside;
    the height is its integral, 0 at x = 0.
    """

    knots_x: tuple
    knots_g: tuple
    _h: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        x, g = np.asarray(self.knots_x, np.float64), np.asarray(self.knots_g, np.float64)
        h = np.concatenate([[0.0], np.cumsum(np.diff(x) * 0.5 * (g[1:] + g[:-1]))])
        h -= self._eval(0.0, x, g, h)
        object.__setattr__(self, '_h', h)

    @classmethod
    def random(cls, seed: int, *, max_grade: float = 0.04, spacing=(12.0, 18.0),
               curve: float = 10.0, start: float = 8.0, length: float = 400.0) -> Grades:
        """Grades drawn within +-``max_grade``, a change every ``spacing`` m from ``start``."""
        rng = np.random.default_rng([seed, 7])
        xs, gs, x, g = [-1e3, start], [0.0, 0.0], start, 0.0
        while x < length:
            g = float(rng.uniform(-max_grade, max_grade))
            xs += [x + curve]
            gs += [g]
            x += float(rng.uniform(*spacing))
            xs += [x]
            gs += [g]
        return cls(tuple(xs), tuple(gs))

    @property
    def lipschitz(self) -> float:
        return float(np.max(np.abs(self.knots_g)))

    @staticmethod
    def _eval(x, kx, kg, kh):
        x = np.asarray(x, np.float64)
        i = np.clip(np.searchsorted(kx, x, side='right') - 1, 0, kx.size - 2)
        u = np.clip(x - kx[i], 0.0, None)
        width = kx[i + 1] - kx[i]
        slope = (kg[i + 1] - kg[i]) / width
        inside = np.minimum(u, width)
        h = kh[i] + inside * (kg[i] + 0.5 * slope * inside) + (u - inside) * kg[i + 1]
        return np.where(x < kx[0], kh[0] + (x - kx[0]) * kg[0], h)

    def grade(self, x) -> np.ndarray:
        """dh/dx at world x."""
        return np.interp(x, self.knots_x, self.knots_g)

    def height(self, x, y):
        kx, kg = np.asarray(self.knots_x), np.asarray(self.knots_g)
        return self._eval(x, kx, kg, self._h) + 0.0 * np.asarray(y)

    def gradient(self, x, y):
        gx = self.grade(x) + 0.0 * np.asarray(y)
        return gx, np.zeros_like(gx)

    def bounds(self, x, y, radius):
        h = self.height(np.linspace(x - radius, x + radius, int(2 * radius / 0.5) + 2), 0.0)
        return float(h.min()) - 0.01, float(h.max()) + 0.01

    def describe(self):
        near = [i for i in range(1, len(self.knots_x)) if self.knots_x[i] < DESCRIBE_X]
        return {'kind': 'grades', 'max_grade': round(self.lipschitz, 4),
                'knots_x': [round(self.knots_x[i], 2) for i in near],
                'knots_grade': [round(self.knots_g[i], 4) for i in near]}


@dataclass(frozen=True)
class Bumps(Terrain):
    """Speed bumps across world x: ``h = A cos^2(pi (x - x_j) / L)`` for |x - x_j| < L / 2."""

    centres: tuple
    amplitude: float = 0.08
    length: float = 0.7
    smooth = False
    _centres: np.ndarray = field(init=False, repr=False, compare=False)
    _midpoints: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        c = np.asarray(self.centres, np.float64)
        object.__setattr__(self, '_centres', c)
        object.__setattr__(self, '_midpoints', 0.5 * (c[1:] + c[:-1]))

    @classmethod
    def random(cls, seed: int, *, spacing=(10.0, 14.0), start: float = 10.0,
               length: float = 400.0, **kw) -> Bumps:
        """Bumps every ``spacing`` m from ``start``."""
        rng = np.random.default_rng([seed, 8])
        xs = [start]
        while xs[-1] < length:
            xs.append(xs[-1] + float(rng.uniform(*spacing)))
        return cls(tuple(xs), **kw)

    def _phase(self, x):
        """The offset of x from its nearest bump's centre; half the length beyond the bump.

        The nearest centre found among the midpoints between centres: one search and one
        look-up (the ray caster evaluates this for every step of every ray).
        """
        c = self._centres
        u = np.asarray(x, np.float64) - c[np.searchsorted(self._midpoints, x, side='right')]
        return np.where(np.abs(u) < 0.5 * self.length, u, 0.5 * self.length)

    def height(self, x, y):
        # the cosine only on the bumps (a few % of the points a ray caster asks about)
        u = self._phase(x)
        on = np.abs(u) < 0.5 * self.length
        h = np.full(u.shape, self.amplitude * np.cos(0.5 * math.pi) ** 2)  # off: ~0
        h[on] = self.amplitude * np.cos(math.pi * u[on] / self.length) ** 2
        return h + 0.0 * np.asarray(y)

    def gradient(self, x, y):
        u = self._phase(x)
        gx = (-self.amplitude * math.pi / self.length * np.sin(2 * math.pi * u / self.length)
              + 0.0 * np.asarray(y))
        return gx, np.zeros_like(gx)

    def bounds(self, x, y, radius):
        c = np.asarray(self.centres)
        near = np.any(np.abs(c - x) < radius + self.length)
        return 0.0, (self.amplitude if near else 0.0)

    def describe(self):
        return {'kind': 'bumps', 'height': self.amplitude, 'length': self.length,
                'at_x': [round(v, 2) for v in self.centres if v < DESCRIBE_X]}


@dataclass(frozen=True)
class Hills(Terrain):
    """Rolling hills: ``A/2 (sin(k1 . p + a) + sin(k2 . p + b))``, waves at +-``angle`` to x."""

    amplitude: float = 0.3
    wavelength: float = 20.0
    angle: float = math.radians(30.0)
    phases: tuple = (0.0, 0.0)

    @classmethod
    def random(cls, seed: int, **kw) -> Hills:
        """Hills with random phases."""
        rng = np.random.default_rng([seed, 9])
        return cls(phases=tuple(float(p) for p in rng.uniform(0, 2 * math.pi, 2)), **kw)

    def _waves(self):
        k = 2 * math.pi / self.wavelength
        return [(k * math.cos(s * self.angle), k * math.sin(s * self.angle), p)
                for s, p in zip((1, -1), self.phases, strict=True)]

    @property
    def lipschitz(self) -> float:
        return self.amplitude * 2 * math.pi / self.wavelength

    def height(self, x, y):
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        return 0.5 * self.amplitude * sum(np.sin(kx * x + ky * y + p)
                                          for kx, ky, p in self._waves())

    def gradient(self, x, y):
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        gx = gy = 0.0
        for kx, ky, p in self._waves():
            c = 0.5 * self.amplitude * np.cos(kx * x + ky * y + p)
            gx, gy = gx + kx * c, gy + ky * c
        return gx, gy

    def bounds(self, x, y, radius):
        return -self.amplitude, self.amplitude

    def describe(self):
        return {'kind': 'hills', 'amplitude': self.amplitude, 'wavelength': self.wavelength,
                'angle_deg': round(math.degrees(self.angle), 6),
                'phases': [round(p, 6) for p in self.phases]}


@dataclass(frozen=True)
class Camber(Terrain):
    """A crowned road: ``h = -slope * rho(n)``, n the distance across the crown line.

    The crown line is ``y = c(x)`` through the points (``line_x``, ``line_y``), x increasing;
    n = (y - c(x)) cos(a), a = atan(c'(x)); rho(n) = |n| beyond ``rounding``, a parabola
    inside (h is C1).
    """

    line_x: tuple
    line_y: tuple
    slope: float = 0.02
    rounding: float = 0.5
    _dydx: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        x, y = np.asarray(self.line_x), np.asarray(self.line_y)
        if x.size < 2 or np.any(np.diff(x) <= 0):
            raise TerrainError('camber: the crown line must advance along +x (the drive '
                               'turns back; choose a gentler scenario)')
        object.__setattr__(self, '_dydx', np.gradient(y, x))

    @classmethod
    def along(cls, path_x, path_y, *, offset: float = 1.75, **kw) -> Camber:
        """The crown ``offset`` m left of the path (x, y), extended 200 m both ways."""
        x, y = np.asarray(path_x, np.float64), np.asarray(path_y, np.float64)
        keep = np.concatenate([[True], np.hypot(np.diff(x), np.diff(y)) > 0.05])
        x, y = x[keep], y[keep]
        if x.size < 2:
            x, y = np.array([0.0, 1.0]), np.array([0.0, 0.0])
        heading = np.unwrap(np.arctan2(np.gradient(y), np.gradient(x)))
        if np.any(np.abs(heading) > math.radians(80.0)):
            raise TerrainError('camber: the path turns more than 80 deg away from +x (the '
                               'crown line follows it as y = c(x)); choose a gentler scenario')
        cx, cy = x - offset * np.sin(heading), y + offset * np.cos(heading)
        ext = np.linspace(5.0, 200.0, 40)
        h0, h1 = heading[0], heading[-1]
        cx = np.concatenate([cx[0] - ext[::-1] * math.cos(h0), cx, cx[-1] + ext * math.cos(h1)])
        cy = np.concatenate([cy[0] - ext[::-1] * math.sin(h0), cy, cy[-1] + ext * math.sin(h1)])
        return cls(tuple(cx), tuple(cy), **kw)

    @property
    def lipschitz(self) -> float:
        return self.slope

    def _across(self, x, y):
        """(n, dn/dx, dn/dy) at (x, y): exact for the piecewise-linear c(x) and c'(x)."""
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        lx, ly = np.asarray(self.line_x), np.asarray(self.line_y)
        i = np.clip(np.searchsorted(lx, x, side='right') - 1, 0, lx.size - 2)
        inside = (x >= lx[0]) & (x <= lx[-1])
        dx = lx[i + 1] - lx[i]
        c = np.interp(x, lx, ly)
        t = np.interp(x, lx, self._dydx)
        dc = np.where(inside, (ly[i + 1] - ly[i]) / dx, 0.0)
        dt = np.where(inside, (self._dydx[i + 1] - self._dydx[i]) / dx, 0.0)
        cos_a = 1.0 / np.sqrt(1.0 + t * t)
        d = y - c
        return d * cos_a, -dc * cos_a - d * t * cos_a ** 3 * dt, cos_a

    def height(self, x, y):
        t = np.interp(x, self.line_x, self._dydx)
        n = (y - np.interp(x, self.line_x, self.line_y)) / np.sqrt(1.0 + t * t)
        a, w = np.abs(n), self.rounding
        return -self.slope * np.where(a < w, 0.5 * (n * n / w + w), a)

    def gradient(self, x, y):
        n, dn_dx, dn_dy = self._across(x, y)
        dh_dn = -self.slope * np.clip(n / self.rounding, -1.0, 1.0)
        return dh_dn * dn_dx, dh_dn * dn_dy

    def bounds(self, x, y, radius):
        n, _, _ = self._across(x, y)
        far = abs(float(n)) + radius
        return -self.slope * far - 0.01, -self.slope * 0.5 * self.rounding

    def describe(self):
        return {'kind': 'camber', 'cross_slope': self.slope, 'rounding': self.rounding,
                'crown': 'the planar path shifted 1.75 m to the left'}


@dataclass(frozen=True)
class Composite(Terrain):
    """The sum of several terrains."""

    parts: tuple

    @property
    def flat(self) -> bool:
        return all(p.flat for p in self.parts)

    @property
    def lipschitz(self) -> float:
        return sum(p.lipschitz for p in self.parts if p.smooth)

    def height(self, x, y):
        return sum(p.height(x, y) for p in self.parts)

    def gradient(self, x, y):
        gx = gy = 0.0
        for p in self.parts:
            a, b = p.gradient(x, y)
            gx, gy = gx + a, gy + b
        return gx, gy

    def bounds(self, x, y, radius):
        lo = hi = 0.0
        for p in self.parts:
            a, b = p.bounds(x, y, radius)
            lo, hi = lo + a, hi + b
        return lo, hi

    def split(self) -> tuple[Terrain, float, float]:
        """(smooth part, lowest and highest rough height): h_smooth + lo <= h <= ... + hi."""
        smooth = Composite(tuple(p for p in self.parts if p.smooth))
        lo = hi = 0.0
        for p in self.parts:
            if not p.smooth:
                a, b = p.bounds(0.0, 0.0, math.inf)
                lo, hi = lo + a, hi + b
        return smooth, lo, hi

    def describe(self):
        return {'kind': 'composite', 'parts': [p.describe() for p in self.parts]}


def split(terrain: Terrain) -> tuple[Terrain, float, float]:
    """``terrain`` as a smooth part plus rough features within [lo, hi] (see Composite)."""
    if isinstance(terrain, Composite):
        return terrain.split()
    if terrain.smooth:
        return terrain, 0.0, 0.0
    lo, hi = terrain.bounds(0.0, 0.0, math.inf)
    return FLAT, lo, hi


@dataclass(frozen=True)
class TerrainShape:
    """The sizes of each kind's features (the defaults: :data:`TERRAIN_KINDS`' descriptions).

    Other shapes of the same kinds, to measure whether what was tuned on the defaults holds.
    """

    bump_height: float = 0.08  # m
    bump_length: float = 0.7  # m along x
    max_grade: float = 0.04  # the grades drawn within +-max_grade
    camber: float = 0.02  # cross-slope either side of the crown
    hill_amplitude: float = 0.3  # m
    hill_wavelength: float = 20.0  # m

    # (low, high) of each value: a vehicle can drive it and the renderer holds it
    RANGES: ClassVar[dict[str, tuple[float, float]]] = {
        'bump_height': (0.0, 0.2), 'bump_length': (0.2, 3.0), 'max_grade': (0.0, 0.12),
        'camber': (0.0, 0.06), 'hill_amplitude': (0.0, 1.0), 'hill_wavelength': (8.0, 200.0)}

    @classmethod
    def parse(cls, text: str) -> TerrainShape:
        """``'bump_height=0.1,max_grade=0.06'``; ValueError (one line) if bad."""
        values: dict[str, float] = {}
        for item in filter(None, (part.strip() for part in text.split(','))):
            name, sep, value = (part.strip() for part in item.partition('='))
            if not sep or name not in cls.RANGES:
                raise ValueError(f'{item!r} is not NAME=VALUE with NAME one of '
                                 f'{", ".join(cls.RANGES)}')
            try:
                number = float(value)
            except ValueError:
                raise ValueError(f'{name}={value!r} is not a number') from None
            low, high = cls.RANGES[name]
            if not low <= number <= high:
                raise ValueError(f'{name}={number:g} is outside [{low:g}, {high:g}]')
            values[name] = number
        if not values:
            raise ValueError(f'give at least one NAME=VALUE with NAME one of '
                             f'{", ".join(cls.RANGES)}')
        return cls(**values)


def make_terrain(kind: str, seed: int = 0, path_x=None, path_y=None,
                 shape: TerrainShape | None = None) -> Terrain:
    """The terrain ``kind`` (a key of :data:`TERRAIN_KINDS`) for a drive along (path_x, path_y).

    The path (the vehicle's planar path in the world frame) is needed by ``camber`` (its
    crown line follows it) and ``all``; the others are laid out in world x, y from ``seed``.
    ``shape``: the features' sizes (default :class:`TerrainShape`'s).
    """
    if kind not in TERRAIN_KINDS:
        raise TerrainError(f'unknown terrain {kind!r} (choose from {", ".join(TERRAIN_KINDS)})')
    if kind == 'flat':
        return FLAT
    shape = shape or TerrainShape()
    parts = []
    if kind in ('grades', 'all'):
        parts.append(Grades.random(seed, max_grade=shape.max_grade))
    if kind in ('bumps', 'all'):
        bumps = Bumps.random(seed, amplitude=shape.bump_height)  # random's length: the layout's
        parts.append(dataclasses.replace(bumps, length=shape.bump_length))
    if kind in ('camber', 'all'):
        if path_x is None:
            path_x, path_y = np.array([0.0, 1.0]), np.array([0.0, 0.0])
        parts.append(Camber.along(path_x, path_y, slope=shape.camber))
    if kind in ('hills', 'all'):
        parts.append(Hills.random(seed, amplitude=shape.hill_amplitude,
                                  wavelength=shape.hill_wavelength))
    return parts[0] if len(parts) == 1 else Composite(tuple(parts))
