"""The lens's vignetting, learned from the drive and divided out of every image before KLT.

KLT follows whatever brightness pattern its window holds. The road's texture moves through
the image; vignetting stays where it is, and pulls every window towards no motion: the
tracks come out short, most at the bottom of the view and in its corners, and the road
there looks tilted. Rendered with 17.5 % less light in the corners (a mild lens), a rigid
car was 0.3 % short in scale on a road of a third of the usual contrast (0.34 % t_rel; 0.08
once divided out, 0.02 without the vignette rendered) and 0.033 % on the usual road (0.011).

The vignetting is what the ground looks like on average: a travel-weighted mean of
block-averaged frames (the road's texture averages out as it moves past), to which a smooth
polynomial in the image coordinates (total degree 4) is fitted in log brightness over the
ground's blocks; its constant (the light, the exposure) is left out. Anything else that
stays put in the image and multiplies the light (lens shading, a dirty window's haze) is
taken out with it. The road's own stains must not be learned as vignetting: from 3 m driven
only the polynomial's terms symmetric about the image's centre are fitted (a lens's falloff
is; a stain is not), the whole polynomial once 10 m have averaged the stains out. Numpy and
OpenCV only; no ROS.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ['SYMMETRIC_AFTER_M', 'Vignetting']

_BLOCK = 8  # px: frames are averaged over blocks this size before they are remembered
_DEGREE = 4  # the polynomial's total degree in the image coordinates
# m of travel the mean remembers (an exponential memory), and the travel after which its
# symmetric part, then the whole polynomial, is used: the road's stains (tens of grey levels,
# metres wide) average out only over a few lengths of the view (a car's: 1.5-5 m ahead). The
# whole polynomial used from 3 m took the stains left for a tilt (bags/default with
# `estimate_attitude` 0.038 -> 0.060 % t_rel), from 10 m 0.039; its symmetric part from 3 m
# then the whole from 10 m 0.042, with the shipped defaults 0.024 -> 0.016 (docs/accuracy.md).
_MEMORY_M = 20.0
SYMMETRIC_AFTER_M = 3.0
_WHOLE_AFTER_M = 10.0
_REFIT_TRAVEL_M = 0.5  # m: the polynomial is fitted again after this much more travel (1.5 ms)
_DARK, _BRIGHT = 8.0, 247.0  # blocks whose mean is outside these (clipped) are not fitted


@dataclass(frozen=True)
class Vignetting:
    """The learned vignetting of one image size. Replaced, never changed in place.

    ``mean``: the travel-weighted mean of block-averaged raw frames (None before the first);
    ``travel``: m driven while it was learned; ``gain``: (H, W) float32 factor that takes
    the vignetting out, None until learned; ``fitted_at``: ``travel`` at the last fit;
    ``falloff``: how much darker the darkest ground block is than the brightest, 0..1.
    """

    shape: tuple[int, int] = (0, 0)
    mean: np.ndarray | None = None
    travel: float = 0.0
    gain: np.ndarray | None = None
    fitted_at: float = 0.0
    falloff: float = 0.0

    def corrected(self, gray: np.ndarray) -> np.ndarray:
        """``gray`` (uint8, HxW) with the vignetting divided out (itself until learned)."""
        if self.gain is None or self.gain.shape != gray.shape:
            return gray
        return cv2.multiply(gray, self.gain, dtype=cv2.CV_8U)  # rounded, saturated

    def with_frame(self, gray: np.ndarray, travel: float,
                   ground: np.ndarray | None) -> Vignetting:
        """Self after the raw frame ``gray`` (uint8, HxW), taken ``travel`` m after the last.

        ``ground``: uint8 mask (HxW, nonzero: ground) of the pixels the fit may use. A frame
        taken standing still (``travel`` 0) teaches nothing: the texture would be learned.
        """
        h, w = gray.shape
        if self.shape != (h, w):
            self = Vignetting(shape=(h, w))
        if not travel > 0.0 or ground is None or ground.shape != gray.shape:
            return self
        blocks = cv2.resize(gray, (w // _BLOCK, h // _BLOCK),
                            interpolation=cv2.INTER_AREA).astype(np.float32)
        total = self.travel + travel
        if self.mean is None:
            mean = blocks
        else:
            mean = self.mean + min(travel / min(total, _MEMORY_M), 1.0) * (blocks - self.mean)
        learned = dataclasses.replace(self, mean=mean, travel=total)
        due = total >= SYMMETRIC_AFTER_M and (self.gain is None
                                             or total - self.fitted_at >= _REFIT_TRAVEL_M)
        return learned._fitted(ground) if due else learned

    def _fitted(self, ground: np.ndarray) -> Vignetting:
        """Self with the polynomial fitted again over the mean's ground blocks.

        Its part symmetric about the image's centre only, before _WHOLE_AFTER_M.
        """
        h, w = self.shape
        bh, bw = self.mean.shape
        inside = cv2.resize((ground > 0).astype(np.uint8), (bw, bh),
                            interpolation=cv2.INTER_AREA) > 0
        # Only blocks wholly on the ground (the sky's edge is not vignetting), not clipped.
        inside = cv2.erode(inside.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        inside &= (self.mean > _DARK) & (self.mean < _BRIGHT)
        if np.count_nonzero(inside) < 4 * _TERMS:
            return self
        rows, cols = np.nonzero(inside)
        symmetric = self.travel < _WHOLE_AFTER_M
        powers = _POWERS[_SYMMETRIC] if symmetric else _POWERS
        design = _monomials(_centred(cols, bw), _centred(rows, bh), powers)
        coef = np.linalg.lstsq(design, np.log(self.mean[rows, cols]), rcond=None)[0]
        fitted = design @ coef
        # Evaluated on the blocks' centres and interpolated: the polynomial is smooth. Beyond
        # the fitted blocks' rows and columns the whole polynomial is held at their edge: it
        # runs off outside its data (gains of 0.06-9 above a rendered road), and KLT's windows
        # on the coarser pyramid levels reach there. The symmetric part mirrors what it fitted.
        table = np.zeros((_DEGREE + 1, _DEGREE + 1))  # [j, i]: the coefficient of u^i v^j
        table[powers[:, 1], powers[:, 0]] = coef
        held_rows, held_cols = np.arange(bh), np.arange(bw)
        if not symmetric:
            held_rows = np.clip(held_rows, rows.min(), rows.max())
            held_cols = np.clip(held_cols, cols.min(), cols.max())
        grid = _powers(_centred(held_rows, bh)) @ table @ _powers(_centred(held_cols, bw)).T
        gain = cv2.resize(np.exp(float(np.mean(fitted)) - grid).astype(np.float32), (w, h),
                          interpolation=cv2.INTER_LINEAR)
        return dataclasses.replace(self, gain=gain, fitted_at=self.travel,
                                   falloff=1.0 - float(np.exp(fitted.min() - fitted.max())))


_POWERS = np.array([(i, j) for i in range(_DEGREE + 1) for j in range(_DEGREE + 1 - i)])
_TERMS = len(_POWERS)
_SYMMETRIC = np.all(_POWERS % 2 == 0, axis=1)  # even in u and v: mirrored about the centre


def _centred(index: np.ndarray, blocks: int) -> np.ndarray:
    """Block ``index`` along an axis of ``blocks`` blocks: its centre scaled to -1..1."""
    return (np.asarray(index, dtype=float) + 0.5) / (0.5 * blocks) - 1.0


def _powers(x: np.ndarray) -> np.ndarray:
    """(N, _DEGREE + 1) x^0 .. x^_DEGREE."""
    return np.cumprod(np.column_stack([np.ones_like(x)] + [x] * _DEGREE), axis=1)


def _monomials(u: np.ndarray, v: np.ndarray, powers: np.ndarray) -> np.ndarray:
    """(N, len(powers)) u^i v^j for (i, j) in ``powers``."""
    return _powers(u)[:, powers[:, 0]] * _powers(v)[:, powers[:, 1]]
