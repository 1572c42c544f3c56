"""Shifted view stacks and shift-and-add refocusing (DESIGN section 4).

A view ``i`` at position ``q_i`` is sampled at ``p + slope * q_i`` for every
output pixel ``p`` (bilinear). Samples that fall outside a view carry no
weight, and every average divides by the summed weight, so borders neither
darken nor brighten. For one slope the views are resampled once into a
:class:`ShiftedStack`; a refocus from any subset of views is then a weighted
mean of the stack, never a new resampling.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import _validate
from .lightfield import LightField
from .errors import ParameterError

__all__ = ["ShiftedStack", "ViewMoments", "shift_views", "refocus", "view_moments", "bilinear_shift"]


def _as_lightfield(lf):
    if not isinstance(lf, LightField):
        raise ParameterError(f"lf must be a napari_lfalias.LightField, got {type(lf).__name__}")
    return lf


def _taps(shift):
    """Integer offsets and bilinear weights of a sub-pixel ``shift`` (zero weights dropped)."""
    base = int(np.floor(shift))
    frac = float(shift - base)
    taps = [(base, 1.0 - frac), (base + 1, frac)]
    return [(offset, weight) for offset, weight in taps if weight > 1e-7]


def _overlap(n, offset):
    """Destination and source slices of an integer shift ``dst[i] = src[i + offset]``."""
    start = max(0, -offset)
    stop = min(n, n - offset)
    if stop <= start:
        return None, None
    return slice(start, stop), slice(start + offset, stop + offset)


def _shift_axis(image, shift, axis):
    """Linear interpolation of ``image`` at ``index + shift`` along ``axis``, zero outside."""
    out = np.zeros_like(image)
    n = image.shape[axis]
    for offset, weight in _taps(shift):
        dst, src = _overlap(n, offset)
        if dst is None:
            continue
        index_dst = [slice(None)] * image.ndim
        index_src = [slice(None)] * image.ndim
        index_dst[axis], index_src[axis] = dst, src
        index_dst, index_src = tuple(index_dst), tuple(index_src)
        if weight == 1.0:
            out[index_dst] += image[index_src]
        else:
            out[index_dst] += image[index_src] * np.float32(weight)
    return out


def _profile(n, shift):
    """Summed bilinear tap weight at each index of a length-``n`` axis (1 inside, < 1 near borders)."""
    return _shift_axis(np.ones(n, np.float32), shift, 0)


def bilinear_shift(image, dy, dx):
    """Sample ``image`` at ``(y + dy, x + dx)`` with bilinear weights, zero outside.

    Parameters
    ----------
    image : ndarray, shape (Y, X, ...)
        The image (any trailing channel axes).
    dy, dx : float
        The sub-pixel shift.

    Returns
    -------
    sampled : ndarray, like ``image``
        The tap-weighted sum; divide by ``bilinear_weight(shape, dy, dx)``
        to normalise near borders.
    weight : ndarray, shape (Y, X), float32
        The summed weight of the taps that fell inside the image.
    """
    sampled = _shift_axis(_shift_axis(image, dx, 1), dy, 0)
    weight = np.outer(_profile(image.shape[0], dy), _profile(image.shape[1], dx))
    return sampled, weight


@dataclass
class ShiftedStack:
    """Every view of a light field resampled for one slope.

    Attributes
    ----------
    values : ndarray, shape (n, Y, X, C), float32
        View ``i`` sampled at ``p + slope * q_i``, normalised by its weight
        (0 where the weight is 0).
    weights : ndarray, shape (n, Y, X), float32
        Validity of each sample in [0, 1]: 0 outside the view, fractional on
        the border row where bilinear taps leave the view, and the light
        field's own sample weights where it has them.
    slope : float
        The slope the views were shifted for.
    positions : ndarray, shape (n, 2)
        View positions, in the order of ``values``.
    """

    values: np.ndarray
    weights: np.ndarray
    slope: float
    positions: np.ndarray

    @property
    def n_views(self):
        return self.values.shape[0]

    def mean(self, view_weights=None):
        """Weighted mean over the views: the refocused image ``(Y, X, C)``.

        Parameters
        ----------
        view_weights : ndarray, shape (n,), optional
            A weight per view (for example 0/1 for a sampling pattern).

        Returns
        -------
        image : ndarray, shape (Y, X, C), float32
            ``sum_i a_i w_i x_i / sum_i a_i w_i`` per pixel; 0 where no view
            sees the pixel.
        """
        w = self.weights
        if view_weights is not None:
            view_weights = np.asarray(view_weights, np.float32)
            w = w * view_weights[:, None, None]
        num = np.einsum("nyx,nyxc->yxc", w, self.values, optimize=True)
        den = w.sum(axis=0)
        return _normalise(num, den)


def _normalise(num, den):
    """``num / den[..., None]`` where ``den > 0``, else 0; float32."""
    out = np.zeros(num.shape, np.float32)
    valid = den > 0
    np.divide(num, den[..., None], out=out, where=valid[..., None])
    return out


def _shift_args(lf, slope):
    lf = _as_lightfield(lf)
    slope = _validate.finite_float("slope", slope)
    if lf.is_lazy:
        lf = lf.compute()
    return lf, slope


def _iter_shifted(lf, slope):
    """Yield ``(i, premultiplied sample, weight)`` for every view of ``lf``."""
    views = lf.views()
    sample_weights = lf.flat_weights()
    shifts = slope * lf.flat_positions()
    for i, (dy, dx) in enumerate(shifts):
        view = views[i]
        if sample_weights is None:
            sampled, weight = bilinear_shift(view, dy, dx)
        else:
            w = sample_weights[i]
            sampled, _ = bilinear_shift(view * w[..., None], dy, dx)
            weight, _ = bilinear_shift(w, dy, dx)
        yield i, sampled, weight


def shift_views(lf, slope):
    """Resample every view of ``lf`` for ``slope`` into a :class:`ShiftedStack`.

    Parameters
    ----------
    lf : LightField
        The light field.
    slope : float
        Disparity of the plane to focus on (pixels per unit of view
        position); view ``i`` is sampled at ``p + slope * positions[i]``.

    Returns
    -------
    ShiftedStack
    """
    lf, slope = _shift_args(lf, slope)
    n = lf.n_views
    values = np.empty((n,) + lf.image_shape + (lf.n_channels,), np.float32)
    weights = np.empty((n,) + lf.image_shape, np.float32)
    for i, sampled, weight in _iter_shifted(lf, slope):
        values[i] = _normalise(sampled, weight)
        weights[i] = weight
    return ShiftedStack(values, weights, slope, lf.flat_positions().copy())


def refocus(lf, slope):
    """Shift-and-add refocus of ``lf`` on the plane of disparity ``slope``.

    Parameters
    ----------
    lf : LightField
        The light field.
    slope : float
        Disparity in focus (pixels per unit of view position).

    Returns
    -------
    image : ndarray, shape (Y, X, C), float32
        The weighted mean of the shifted views; pixels seen by no view are 0.

    Examples
    --------
    >>> import numpy as np
    >>> from napari_lfalias import LightField, refocus
    >>> lf = LightField(np.full((3, 3, 16, 16, 1), 0.5, np.float32))
    >>> bool(np.allclose(refocus(lf, 1.3), 0.5))
    True
    """
    lf, slope = _shift_args(lf, slope)
    num = np.zeros(lf.image_shape + (lf.n_channels,), np.float32)
    den = np.zeros(lf.image_shape, np.float32)
    for _, sampled, weight in _iter_shifted(lf, slope):
        num += sampled
        den += weight
    return _normalise(num, den)


@dataclass
class ViewMoments:
    """Per-pixel statistics of the shifted views for one slope.

    Attributes
    ----------
    mean : ndarray, shape (Y, X, C), float32
        Weighted mean of the shifted views (the refocused image).
    variance : ndarray, shape (Y, X, C), float32
        Weighted population variance across the views, >= 0.
    weight_sum : ndarray, shape (Y, X), float32
        Summed sample weight.
    count : ndarray, shape (Y, X), int32
        Number of views with a non-zero weight at the pixel.
    """

    mean: np.ndarray
    variance: np.ndarray
    weight_sum: np.ndarray
    count: np.ndarray


def view_moments(lf, slope, stack=None):
    """Mean and population variance across the shifted views, per pixel.

    Deviations are taken from the mean (two passes over the stack), never
    as ``E[x^2] - E[x]^2``, so float32 keeps its precision on data with a
    large offset.

    Parameters
    ----------
    lf : LightField
        The light field (use ``lf.luminance()`` for luminance statistics).
    slope : float
        Disparity in focus.
    stack : ShiftedStack, optional
        A stack already shifted for ``slope`` to reuse.

    Returns
    -------
    ViewMoments
    """
    if stack is None:
        stack = shift_views(lf, slope)
    w = stack.weights
    weight_sum = w.sum(axis=0)
    mean = stack.mean()
    var_num = np.zeros_like(mean)
    for i in range(stack.n_views):
        dev = stack.values[i] - mean
        dev *= dev
        dev *= w[i][..., None]
        var_num += dev
    variance = _normalise(var_num, weight_sum)
    np.maximum(variance, 0, out=variance)
    count = (w > 0).sum(axis=0, dtype=np.int32)
    return ViewMoments(mean, variance, weight_sum, count)
