"""First hit of camera rays with a height field ``z = h(x, y)``, vectorised (numpy only).

For every ray ``o + t d`` (d a unit vector, world frame) the first root of
``f(t) = o_z + t d_z - h(o_x + t d_x, o_y + t d_y)`` within ``max_range`` (horizontal
distance), in three phases on the rays still active:

1. sphere tracing on the smooth part of the terrain plus the rough features' highest height
   (``terrain.split``): a step ``f_upper / (|d_z| + L |d_xy|)``, L the smooth part's
   Lipschitz bound, cannot pass the surface; it stops ``margin`` above the envelope;
2. a march with steps of ``clip(rel * s, step_min, step_max)`` metres of horizontal distance
   s on the full height until ``f <= 0`` (a bracket) or out of range: features shorter than a
   step (a bump's top seen at grazing incidence far away) may be cut;
3. refinement of the bracket by regula falsi (Illinois) to ``tol`` metres of height.

Independent of ``planar_vo.core``: it must not share the code it tests.
"""

from __future__ import annotations

import numpy as np

from planar_vo.synth.terrain import Terrain, split


def intersect(terrain: Terrain, origin, dirs: np.ndarray, max_range: float, *,
              margin: float = 0.05, rel: float = 0.01, step_min: float = 0.04,
              step_max: float = 0.3, tol: float = 1e-7, iterations: int = 40):
    """Ray length ``t`` (N,) to the first hit and ``hit`` (N,) bool (False: none in range).

    ``origin`` (3,) is the common ray origin, or (3, N) one per ray (a rolling shutter: each
    row from its own pose); ``dirs`` (3, N) unit directions (world frame). ``max_range`` is
    the horizontal distance from each ray's own origin. ``t`` is inf where there is no hit.
    """
    d = np.asarray(dirs, np.float64)
    n = d.shape[1]
    o = np.asarray(origin, np.float64)
    if o.ndim == 1:  # one origin: scalars, as before
        ox, oy, oz = (float(v) for v in o)
        centre, spread = (ox, oy), 0.0
    else:
        if o.shape != (3, n):
            raise ValueError(f'origin must be (3,) or (3, {n}), got {o.shape}')
        ox, oy, oz = o
        # the terrain's bounds over a disc holding every ray's range
        centre = (float(ox[0]), float(oy[0]))
        spread = float(np.max(np.hypot(ox - ox[0], oy - oy[0]), initial=0.0))
    horiz = np.hypot(d[0], d[1])
    with np.errstate(divide='ignore'):
        t_end = np.where(horiz > 1e-12, max_range / horiz, np.inf)
    lo, hi = terrain.bounds(*centre, max_range + spread)
    smooth, _, rough_hi = split(terrain)
    lipschitz = smooth.lipschitz
    # The ray is above every point of the surface until it comes down to `hi`.
    with np.errstate(divide='ignore', invalid='ignore'):
        t_top = np.where(d[2] < 0, (oz - hi) / -d[2], 0.0)
        t_bottom = np.where(d[2] < 0, (oz - lo) / -d[2], np.inf)
    t_top = np.maximum(t_top, 0.0)
    t_end = np.minimum(t_end, t_bottom * (1 + 1e-9) + 1e-9)
    # a rising ray leaves the slab [lo, hi] through its top (or is above it from the start)
    with np.errstate(divide='ignore', invalid='ignore'):
        t_rise = np.where(d[2] > 0, np.maximum(hi - oz, 0.0) / d[2], np.inf)
    t_end = np.minimum(t_end, t_rise)
    t_out = np.full(n, np.inf)
    act = np.flatnonzero(t_top < t_end)
    t = t_top[act]

    def at(idx):
        """The origins of rays ``idx``: the common one's scalars, or each ray's own."""
        if o.ndim == 1:
            return ox, oy, oz
        return ox[idx], oy[idx], oz[idx]

    def f_of(idx, tt):
        x0, y0, z0 = at(idx)
        return z0 + tt * d[2, idx] - terrain.height(x0 + tt * d[0, idx], y0 + tt * d[1, idx])

    # 1. sphere tracing on the upper envelope (smooth part + highest rough feature)
    rate = np.abs(d[2, act]) + lipschitz * horiz[act]
    near_idx, near_t = [], []
    for _ in range(iterations):
        if act.size == 0:
            break
        x0, y0, z0 = at(act)
        up = (z0 + t * d[2, act] - smooth.height(x0 + t * d[0, act], y0 + t * d[1, act])
              - rough_hi)
        far = up > 2 * margin
        near_idx.append(act[~far])
        near_t.append(t[~far])
        t = t[far] + (up[far] - margin) / rate[far]
        act, rate = act[far], rate[far]
        keep = t < t_end[act]
        act, t, rate = act[keep], t[keep], rate[keep]
    act, t = np.concatenate(near_idx + [act]), np.concatenate(near_t + [t])
    # 2. march on the full height until f <= 0
    f = f_of(act, t)
    below = f <= 0  # should not happen (f >= the envelope's margin): step back once
    done_idx, done_lo, done_hi, done_flo, done_fhi = [], [], [], [], []
    if below.any():
        back = np.maximum(t[below] - 4 * margin / np.maximum(np.abs(d[2, act[below]]), 0.05),
                          0.0)
        done_idx.append(act[below])
        done_lo.append(back)
        done_flo.append(f_of(act[below], back))
        done_hi.append(t[below])
        done_fhi.append(f[below])
    act, lo_t, lo_f = act[~below], t[~below], f[~below]
    while act.size:
        s = lo_t * horiz[act]
        step = np.clip(rel * s, step_min, step_max) / np.maximum(horiz[act], 0.05)
        nt = lo_t + step
        nf = f_of(act, nt)
        crossed = nf <= 0
        if crossed.any():
            done_idx.append(act[crossed])
            done_lo.append(lo_t[crossed])
            done_flo.append(lo_f[crossed])
            done_hi.append(nt[crossed])
            done_fhi.append(nf[crossed])
        keep = ~crossed & (nt < t_end[act])
        act, lo_t, lo_f = act[keep], nt[keep], nf[keep]
    if not done_idx:
        return t_out, np.isfinite(t_out)
    idx = np.concatenate(done_idx)
    a, b = np.concatenate(done_lo), np.concatenate(done_hi)
    fa, fb = np.concatenate(done_flo), np.concatenate(done_fhi)
    fa = np.where(fa > 0, fa, np.nan)  # a back-step still below ground: bisect
    # 3. Illinois regula falsi on [a, b], f(a) > 0 >= f(b); converged rays leave the set
    side = np.zeros(idx.size, np.int8)
    for _ in range(iterations):
        m = np.where(np.isfinite(fa), (a * fb - b * fa) / (fb - fa), b)
        m = np.where((m > a) & (m <= b), m, 0.5 * (a + b))
        fm = f_of(idx, m)
        conv = (np.abs(fm) < tol) | (b - a < 1e-9)
        t_out[idx[conv]] = m[conv]
        if conv.all():
            idx = idx[:0]
            break
        keep = ~conv
        idx, a, b, fa, fb, m, fm, side = (v[keep] for v in (idx, a, b, fa, fb, m, fm, side))
        pos = fm > 0
        a = np.where(pos, m, a)
        fa_new = np.where(pos, fm, fa)
        fb = np.where(pos & (side == 1), 0.5 * fb, fb)
        fb = np.where(~pos, fm, fb)
        fa_new = np.where(~pos & (side == -1), 0.5 * fa_new, fa_new)
        b = np.where(~pos, m, b)
        fa = fa_new
        side = np.where(pos, 1, -1).astype(np.int8)
    t_out[idx] = 0.5 * (a + b) if idx.size else t_out[idx]
    hit = np.isfinite(t_out) & (t_out * horiz < max_range)
    t_out[~hit] = np.inf
    return t_out, hit
