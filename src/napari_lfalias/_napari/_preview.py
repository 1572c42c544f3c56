"""Fast refocus and luminance moments for the live focus control.

The focus control must update the refocused image and the exact Cv within
about 100 ms for an 8x8x512x512 RGB light field. The numbers are those of
:func:`napari_lfalias.refocus` and :func:`napari_lfalias.view_moments`
(bilinear samples at ``p + slope * q``, zero weight outside a view, sums
divided by the summed weight); only the way they are computed differs:

- the 2x2 bilinear kernel of each view is one ``cv2.filter2D`` call on a
  zero-padded copy of the view (exact float taps, unlike ``warpAffine``'s
  fixed-point ones), followed by an integer offset;
- the shifted views are never stored: colour, luminance and squared
  luminance are accumulated in place (``cv2.accumulate*``; the squares in
  float64, so the variance ``E[x^2] - E[x]^2`` keeps its precision);
- every view's validity is the outer product of two 1-D tap profiles, so
  the summed weight and the view count are two small matrix products;
- the views are stored planar (one plane per channel, then luminance) and
  the work buffers are kept from call to call (fresh pages cost more to
  fault in than the arithmetic done on them). One thread: on a 2-core
  machine, splitting the views over threads ran slower, as the GUI thread
  and the software OpenGL renderer need the other core.

Light fields with per-sample weights (vignetted lenslet decodes) go through
the core functions instead.
"""

from __future__ import annotations

import math
import threading

import numpy as np

from ..lightfield import REC709
from ..refocus import ViewMoments

__all__ = ["LivePreview", "tap_profile"]

#: Taps lighter than this are dropped (as the core's bilinear sampler does).
_TAP_EPS = 1e-7


def _taps(shift):
    """Integer base and fraction of a sub-pixel shift, with near-integer fractions snapped."""
    base = math.floor(shift)
    frac = shift - base
    if frac <= _TAP_EPS:
        frac = 0.0
    elif 1.0 - frac <= _TAP_EPS:
        base, frac = base + 1, 0.0
    return int(base), float(frac)


def tap_profile(n, shift):
    """Summed weight of the bilinear taps of ``index + shift`` that fall in ``[0, n)``.

    Parameters
    ----------
    n : int
        Length of the axis.
    shift : float
        The sub-pixel shift.

    Returns
    -------
    ndarray, shape (n,), float64
        1 where both taps are inside, the inside tap's weight on the border
        sample, 0 where both taps are outside.
    """
    base, frac = _taps(shift)
    index = np.arange(n) + base
    profile = np.where((index >= 0) & (index < n), 1.0 - frac, 0.0)
    if frac:
        profile += np.where((index + 1 >= 0) & (index + 1 < n), frac, 0.0)
    return profile


def _pad(planes):
    """Planes ``(n, P, Y, X)`` with a one-pixel zero frame, so the 2x2 kernel reads zeros outside."""
    n, n_planes, n_rows, n_cols = planes.shape
    padded = np.zeros((n, n_planes, n_rows + 2, n_cols + 2), np.float32)
    padded[:, :, 1:-1, 1:-1] = planes
    return padded


def _regions(n, base):
    """Output slice and filtered-image slice of a shift with integer part ``base``.

    The filtered padded view ``f`` holds the bilinear sample of ``q - 1 + frac``
    at ``q``; the output ``p`` needs ``p + base + frac``, that is ``f[p + base + 1]``,
    which is non-zero only for ``-1 <= p + base <= n``.
    """
    start = max(0, -base - 1)
    stop = min(n, n - base + 1)
    if stop <= start:
        return None, None
    return slice(start, stop), slice(start + base + 1, stop + base + 1)


class LivePreview:
    """Refocus and luminance moments of one light field, for any slope, fast.

    Parameters
    ----------
    lf : LightField
        An in-memory light field without per-sample weights (see
        :meth:`supports`).
    """

    def __init__(self, lf):
        if not self.supports(lf):
            raise ValueError("LivePreview needs an in-memory light field without sample weights")
        import cv2  # noqa: F401  (fail here, not in the first focus change)

        views = lf.views()
        self.image_shape = lf.image_shape
        self.n_channels = lf.n_channels
        self.positions = lf.flat_positions().astype(np.float64)
        # planar (one plane per channel, then luminance): single-channel
        # filtering and accumulation run faster than interleaved colour
        planes = np.moveaxis(views, -1, 1)
        if lf.n_channels == 3:
            planes = np.concatenate([planes, (views @ REC709)[:, None]], axis=1)
        self._planes = _pad(planes)
        # Work buffers kept from call to call: fresh pages cost more to fault
        # in (zeroed by the kernel) than the arithmetic done on them.
        n_rows, n_cols = self.image_shape
        self._sums = (
            np.zeros((self.n_channels, n_rows, n_cols), np.float32),
            np.zeros((n_rows, n_cols), np.float64),
            np.zeros((n_rows, n_cols), np.float64),
        )
        self._weight_sum = np.empty((n_rows, n_cols), np.float64)
        self._inverse = np.empty((n_rows, n_cols), np.float64)
        self._filtered = np.empty((n_rows + 2, n_cols + 2), np.float32)
        self._lock = threading.Lock()  # the work buffers serve one call at a time

    @staticmethod
    def supports(lf):
        """True for in-memory light fields without per-sample weights."""
        return not lf.is_lazy and lf.weights is None

    def compute(self, slope):
        """Refocus on ``slope`` and take the moments of the shifted luminance.

        Parameters
        ----------
        slope : float
            Disparity in focus.

        Returns
        -------
        image : ndarray, shape (Y, X, C), float32
            Equal to ``napari_lfalias.refocus(lf, slope)``.
        moments : ViewMoments
            Equal to ``napari_lfalias.view_moments(lf.luminance(), slope)``
            (one channel).
        """
        with self._lock:
            return self._compute(slope)

    def _compute(self, slope):
        n_rows, n_cols = self.image_shape
        # float64 weights: the variance E[x^2] - E[x]^2 needs the same
        # weights in both terms to better than float32 precision
        profiles_y = np.stack([tap_profile(n_rows, slope * qy) for qy in self.positions[:, 0]])
        profiles_x = np.stack([tap_profile(n_cols, slope * qx) for qx in self.positions[:, 1]])
        sums = self._sums
        for total in sums:
            total.fill(0)
        self._accumulate(slope, profiles_y, profiles_x, sums)
        return self._finish(sums, profiles_y, profiles_x)

    def _finish(self, sums, profiles_y, profiles_x):
        """Divide the sums by the summed weight: refocused image and luminance moments."""
        colour_sum, lum_sum, lum_squares = sums
        weight_sum = np.matmul(profiles_y.T, profiles_x, out=self._weight_sum)
        # 1/W, and 0 where no view sees the pixel
        inverse = self._inverse
        inverse.fill(0)
        np.divide(1.0, weight_sum, out=inverse, where=weight_sum > 0)
        inverse32 = inverse.astype(np.float32)
        image = np.empty(colour_sum.shape[1:] + (self.n_channels,), np.float32)
        for c in range(self.n_channels):
            np.multiply(colour_sum[c], inverse32, out=image[..., c])
        mean = lum_sum
        mean *= inverse
        variance = lum_squares
        variance *= inverse
        variance -= np.multiply(mean, mean, out=inverse)  # 1/W is no longer needed
        np.maximum(variance, 0, out=variance)
        count = (profiles_y > 0).astype(np.float32).T @ (profiles_x > 0).astype(np.float32)
        moments = ViewMoments(
            mean.astype(np.float32)[..., None],
            variance.astype(np.float32)[..., None],
            weight_sum.astype(np.float32),
            count.astype(np.int32),
        )
        return image, moments

    def _accumulate(self, slope, profiles_y, profiles_x, sums):
        """Add every view's shifted colour, luminance and squared luminance to ``sums``."""
        import cv2

        colour_sum, lum_sum, lum_squares = sums
        n_rows, n_cols = self.image_shape
        buffer = self._filtered
        for i, (qy, qx) in enumerate(self.positions):
            (base_y, frac_y), (base_x, frac_x) = _taps(slope * qy), _taps(slope * qx)
            out_y, src_y = _regions(n_rows, base_y)
            out_x, src_x = _regions(n_cols, base_x)
            if out_y is None or out_x is None:
                continue
            kernel = np.array(
                [[(1 - frac_y) * (1 - frac_x), (1 - frac_y) * frac_x],
                 [frac_y * (1 - frac_x), frac_y * frac_x]],
                np.float32,
            )
            # the block holds one row more than used: the kernel reads row q + 1
            block = slice(src_y.start, src_y.stop + 1)
            rows = slice(0, src_y.stop - src_y.start)
            planes = self._planes[i, :, block]
            out = buffer[: planes.shape[1]]
            for c in range(planes.shape[0]):
                filtered = cv2.filter2D(planes[c], -1, kernel, dst=out, anchor=(0, 0),
                                        borderType=cv2.BORDER_CONSTANT)[rows, src_x]
                if c < self.n_channels:
                    cv2.accumulate(filtered, colour_sum[c, out_y, out_x])
            lum = filtered
            cv2.accumulate(lum, lum_sum[out_y, out_x])
            cv2.accumulateSquare(lum, lum_squares[out_y, out_x])
            self._correct_border_squares(lum, lum_squares, out_y, out_x, profiles_y[i], profiles_x[i])

    @staticmethod
    def _correct_border_squares(lum, squares, out_y, out_x, profile_y, profile_x):
        """Turn ``sample^2`` into ``w * value^2 = sample^2 / w`` where the weight ``w < 1``.

        A shifted sample is ``w * value`` (the taps that fell inside); the
        variance needs ``w * value^2``. Inside a view ``w = 1``; it is < 1
        only on the border row and column a fractional shift half leaves.
        """
        py = profile_y[out_y]
        px = profile_x[out_x]
        rows = np.flatnonzero((py > 0) & (py < 1))
        cols = np.flatnonzero((px > 0) & (px < 1))
        if rows.size == 0 and cols.size == 0:
            return
        # w = py * px. Columns first, over all rows: factor 1/px - 1. Then the
        # partial rows add (1/py - 1)/px, which completes 1/(py px) - 1 at the
        # corners. Where a profile is 0 the sample is 0, so the factor is moot.
        region = squares[out_y, out_x]
        inv_x = np.divide(1.0, px, out=np.zeros_like(px), where=px > 0)
        if cols.size:
            region[:, cols] += np.square(lum[:, cols], dtype=np.float64) * (inv_x[cols] - 1.0)
        if rows.size:
            factor = (1.0 / py[rows] - 1.0)[:, None] * inv_x[None, :]
            region[rows] += np.square(lum[rows], dtype=np.float64) * factor
