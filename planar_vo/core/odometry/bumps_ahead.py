"""Speed bumps seen ahead, remembered until the wheels have passed them.

A bump's own tracks bend the smooth surface of the local ground onto it, a frame at a time,
while it comes closer (measured on rendered 8 cm bumps: the curvature 0.006 -> 0.08 /m over
2 m, +60 to +250 mm of along-track error a drive), and once bent the surface hides the bump
from the test of bands off it. Seen where it first stands out (at the far edge of the
tracks, against the surface before), a bump is remembered in base_link, moved on with each
pair, and its tracks are left out until it has passed under the camera. Where it stands is
the mean of the bands that have shown it since (see _SAME). Where the road curves, a hill's
bend can make one band: there a band is a bump once a band of a later pair confirms it
(see _CONFIRM).

While the front wheels stand on it the road past the front axle is below the wheels' plane,
which no surface hinged there can hold without a height at the hinge: the front wheels'
height is summed from the pairs' lifts (the height change at the front axle less the smooth
road's) while a remembered bump is at the front axle. Numpy only; no ROS.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

__all__ = ['BumpsAhead']

# Tracks whose ray meets the wheel plane from this far before a bump to BAND_REACH past it
# are its own (a band's rays meet the wheel plane up to 0.4 m beyond the bump).
_BEFORE = 0.6
# m: a band this close to a remembered bump is that bump (or its shadow), and moves it to
# the mean of its bands. The first band, at the far edge of the tracks, lacks the rays past
# the bump (on rendered 8 cm bumps 0.2 m before to 0.26 m past it; the bands that follow as it
# comes closer 0.3-0.7 m past it), so the window its tracks are hidden in, placed for a band
# past the bump, left the rays of its far face in the fit: their faster flow made the steps
# beside it long (+2 to +7 mm a pair on an all-four drive). Kept where first seen, as before
# stop 50, 79 rendered drives summed 19.98 % t_rel; at the mean 19.44 (the two worst all-four
# drives 0.437 / 0.349 -> 0.166 / 0.147; 12 others worse by over 0.02, at most 0.196 ->
# 0.325; bumps alone 0.047-0.111 -> 0.067-0.113); at the latest band as good on the all-four
# drives, but the bumps drives 0.062 / 0.111 -> 0.097 / 0.227.
_SAME = 2.0
# m: where the road curves (the caller says), a band is a candidate until a band of a later
# pair within this of it confirms it; the bump then stands at their mean. A bump shows in
# band after band as it comes closer, a hill's bend in one now and then (on three rendered
# all-four drives, every false band alone). The search used to stop where the road curves
# over 0.01 /m, and over hills half the bumps were never remembered; searched there with one
# band enough, bands of hills passed for bumps (59 drives 14.41 -> 15.33 % summed).
# Confirmed, see road_ahead's _BUMP_CURVATURE; within 0.35 m as good, within 1 m 93
# drives 20.46 -> 20.70 % summed.
_CONFIRM = 0.6
_GONE = 1.0  # m past the camera: passed under its view, forgotten
# The front wheels are on a remembered bump from this far before the front axle to this far
# past it; off it, their height decays by this factor a pair (a bump is a frame or two long).
# A bump is placed at its band's centre, which lies past the bump (its far face's rays), and
# the wheelbase is the user's tape: ahead of the axle up to 0.6 m, 34 rendered drives summed
# 4.76 % (a 30 Hz drive over all four terrains 0.165 %); up to 1.2 m, 4.53 (0.074 %). Six of
# them with the wheelbase configured 0.3 m short: 1.39 -> 0.98; 0.3 m long: 1.08 -> 1.04.
# (Behind the axle, a bump is forgotten at the camera's view first: _GONE.)
_FRONT_BEFORE = 1.0
_FRONT_AFTER = 1.2
_FRONT_DECAY = 0.3


@dataclass(frozen=True)
class BumpsAhead:
    """Bumps seen ahead (x in base_link, m) and the front wheels' height on one (m).

    ``sightings``: how many bands have shown each bump (its x is their mean); one each if
    not given. ``candidates``: bands seen once where the road curves, not yet bumps (x, m).
    """

    ahead: tuple = ()
    front_height: float = 0.0
    sightings: tuple = ()
    candidates: tuple = ()

    def __post_init__(self) -> None:
        if len(self.sightings) != len(self.ahead):
            object.__setattr__(self, 'sightings', (1,) * len(self.ahead))

    def hides(self, distance: np.ndarray, reach: float, *,
              candidates: bool = False) -> np.ndarray:
        """Which tracks (N,) bool lie on a remembered bump, or with ``candidates`` on a band.

        A band waits for a later pair to confirm it a bump. ``distance``: where their rays
        meet the wheel plane (m); ``reach``: how far past a bump they still do.
        """
        hidden = np.zeros(len(distance), bool)
        for x in self.ahead + (self.candidates if candidates else ()):
            hidden |= (distance > x - _BEFORE) & (distance < x + reach)
        return hidden

    def seen(self, distance: np.ndarray, band: float, *, confirm: bool = False) -> BumpsAhead:
        """Self with the bands of tracks at ``distance`` (m) remembered as bumps.

        A band within _SAME of a bump remembered before the pair is that bump seen again: it
        moves to the mean of its bands; one within _SAME of a bump first seen in this pair is
        that bump. ``confirm`` (the road curves): any other band is a candidate, and a bump
        once a band of a later pair within _CONFIRM of it shows it again.
        """
        ahead, sightings = list(self.ahead), list(self.sightings)
        candidates = list(self.candidates)
        again: dict[int, list[float]] = {}
        for b in np.unique(np.floor(distance / band)):
            centre = float(np.mean(distance[np.floor(distance / band) == b]))
            known = [i for i, x in enumerate(self.ahead) if abs(centre - x) < _SAME]
            if known:
                again.setdefault(known[0], []).append(centre)
                continue
            if any(abs(centre - x) < _SAME for x in ahead[len(self.ahead):]):
                continue
            if not confirm:
                ahead.append(centre)
                sightings.append(1)
                continue
            earlier = [x for x in self.candidates if abs(centre - x) < _CONFIRM]
            if earlier:
                ahead.append(0.5 * (earlier[0] + centre))
                sightings.append(2)
                candidates.remove(earlier[0])
            elif not any(abs(centre - x) < _CONFIRM for x in candidates):
                candidates.append(centre)
        for i, centres in again.items():
            n = sightings[i]
            ahead[i] = (ahead[i] * n + sum(centres)) / (n + len(centres))
            sightings[i] = n + len(centres)
        order = np.argsort(ahead, kind='stable')
        return BumpsAhead(tuple(ahead[i] for i in order), self.front_height,
                          tuple(sightings[i] for i in order), tuple(candidates))

    def at_front(self, hinge: float) -> bool:
        """Whether a remembered bump is at the front axle (``hinge``, m ahead of base_link)."""
        return any(-_FRONT_BEFORE < x - hinge < _FRONT_AFTER for x in self.ahead)

    def lifted(self, rise: float | None, hinge: float) -> BumpsAhead:
        """Self after a pair.

        ``rise``: the front axle's rise above the smooth road (m) if a wheel lifted, else None.
        """
        if rise is not None and self.at_front(hinge):
            return dataclasses.replace(self, front_height=self.front_height + rise)
        return dataclasses.replace(self, front_height=self.front_height * _FRONT_DECAY)

    def moved(self, travel: float, camera_x: float) -> BumpsAhead:
        """Self in base_link after ``travel`` m forward.

        Bumps and candidates past the camera's view go, and all of them when reversing (they
        were seen on the way forward).
        """
        if travel < 0.0:
            return BumpsAhead((), self.front_height)
        kept = [i for i, x in enumerate(self.ahead) if x - travel > camera_x + _GONE]
        candidates = tuple(x - travel for x in self.candidates if x - travel > camera_x + _GONE)
        return BumpsAhead(tuple(self.ahead[i] - travel for i in kept), self.front_height,
                          tuple(self.sightings[i] for i in kept), candidates)
