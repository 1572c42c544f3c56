"""Shifted view stacks and shift-and-add refocusing (DESIGN section 4).

A view ``i`` at position ``q_i`` is sampled at ``p + slope * q_i`` for every
output pixel ``p`` (bilinear). Samples that fall outside a view carry no
weight, and every average divides by the summed weight, so borders neither
darken nor brighten. For one slope the views are resampled once into a
:class:`ShiftedStack`; a refocus from any subset of views is then a weighted
mean of the stack, never a new resampling.

The work is done by fused kernels (:mod:`napari_lfalias._kernels`) that read
each view once and store the shifted views only when asked: a refocus of an
8x8x512x512x3 light field costs about three times one plain sum over its
views (``benchmarks/results/refocus.md``).
"""

from __future__ import annotations

import importlib
import threading
from dataclasses import dataclass

import numpy as np

from . import _validate
from ._numerics import unit_scale
from .errors import ParameterError
from .lightfield import LightField

__all__ = ["ShiftedStack", "ViewMoments", "shift_views", "refocus", "view_moments", "bilinear_shift"]

#: Stand-in for "no per-sample weights" (the kernels take one array type).
_NO_WEIGHTS = np.ones((1, 1, 1), np.float32)

#: One kernel call at a time: each already uses every core, and numba's
#: fallback thread pool (workqueue) aborts on concurrent calls.
_KERNEL_LOCK = threading.Lock()


def _run(name, *args):
    """Call kernel ``name`` of :mod:`._kernels` (imported on first use: numba loads in ~0.15 s)."""
    kernels = importlib.import_module("._kernels", __package__)
    with _KERNEL_LOCK:
        getattr(kernels, name)(*args)


def _split_shifts(shifts):
    return importlib.import_module("._kernels", __package__).split_shifts(shifts)


def _as_lightfield(lf):
    if not isinstance(lf, LightField):
        raise ParameterError(f"lf must be a napari_lfalias.LightField, got {type(lf).__name__}")
    return lf


def _normalise(num, den):
    """``num / den[..., None]`` where ``den > 0``, else 0; float32."""
    out = np.zeros(num.shape, np.float32)
    valid = den > 0
    np.divide(num, den[..., None], out=out, where=valid[..., None])
    return out


def _kernel_inputs(views, sample_weights, shifts):
    """Arguments shared by the kernels: rows ``(n, Y, X*C)``, channels, weights, split shifts."""
    n, n_rows, n_cols, n_ch = views.shape
    flat = np.ascontiguousarray(views).reshape(n, n_rows, n_cols * n_ch)
    if sample_weights is None:
        weights, has_weight = _NO_WEIGHTS, False
    else:
        weights, has_weight = np.ascontiguousarray(sample_weights, np.float32), True
    base, frac = _split_shifts(shifts)
    return flat, n_ch, weights, has_weight, base, frac


def bilinear_shift(image, dy, dx):
    """Sample ``image`` at ``(y + dy, x + dx)`` with bilinear weights, zero outside.

    Parameters
    ----------
    image : ndarray, shape (Y, X) or (Y, X, C)
        The image.
    dy, dx : float
        The sub-pixel shift.

    Returns
    -------
    sampled : ndarray, like ``image``
        The tap-weighted sum (float32, float64 for float64 input); divide
        by ``weight`` to normalise near borders.
    weight : ndarray, shape (Y, X)
        The summed weight of the taps that fell inside the image.
    """
    image = np.asarray(image)
    if image.ndim not in (2, 3) or min(image.shape) < 1:
        raise ParameterError(f"image must have shape (Y, X) or (Y, X, C), got shape {image.shape}")
    dy = _validate.finite_float("dy", dy)
    dx = _validate.finite_float("dx", dx)
    dtype = np.float64 if image.dtype == np.float64 else np.float32
    views = image.astype(dtype, copy=False).reshape((1,) + image.shape[:2] + (-1,))
    num = np.empty(views.shape[1:], dtype)
    den = np.empty(views.shape[1:3], dtype)
    _run("refocus_sum", *_kernel_inputs(views, None, [[dy, dx]]), np.ones(1), num, den)
    return num.reshape(image.shape), den


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
    graded : bool
        Whether the light field has sample weights of its own (a vignette:
        they may vary across the aperture, not only at the views' edges).
    """

    values: np.ndarray
    weights: np.ndarray
    slope: float
    positions: np.ndarray
    graded: bool = False

    @property
    def n_views(self):
        return self.values.shape[0]

    def _arrays(self):
        """Values as rows ``(n, Y, X*C)`` and weights ``(n, Y, X)``, contiguous float32."""
        values = np.ascontiguousarray(self.values, np.float32)
        return values.reshape(values.shape[:2] + (-1,)), np.ascontiguousarray(self.weights, np.float32)

    def mean(self, view_weights=None):
        """Weighted mean over the views: the refocused image ``(Y, X, C)``.

        Parameters
        ----------
        view_weights : ndarray, shape (n,), optional
            A non-negative weight per view (for example 0/1 for a sampling
            pattern).

        Returns
        -------
        image : ndarray, shape (Y, X, C), float32
            ``sum_i a_i w_i x_i / sum_i a_i w_i`` per pixel; 0 where no view
            sees the pixel.
        """
        n = self.n_views
        if view_weights is None:
            view_weights = np.ones(n)
        view_weights = np.asarray(view_weights, np.float64)
        if view_weights.shape != (n,) or not np.all(np.isfinite(view_weights)) or view_weights.min() < 0:
            raise ParameterError(
                f"view_weights must hold {n} finite non-negative numbers (one per view), "
                f"got an array of shape {view_weights.shape}"
            )
        values, weights = self._arrays()
        out = np.empty(self.values.shape[1:], np.float32)
        _run("stack_mean", values, self.values.shape[3], weights, view_weights, out)
        return out


def _shift_args(lf, slope):
    lf = _as_lightfield(lf)
    slope = _validate.finite_float("slope", slope)
    if lf.is_lazy:
        lf = lf.compute()
    return lf, slope


def _inputs(lf, slope):
    return _kernel_inputs(lf.views(), lf.flat_weights(), slope * lf.flat_positions())


def shift_views(lf, slope, pad=0):
    """Resample every view of ``lf`` for ``slope`` into a :class:`ShiftedStack`.

    Parameters
    ----------
    lf : LightField
        The light field.
    slope : float
        Disparity of the plane to focus on (pixels per unit of view
        position); view ``i`` is sampled at ``p + slope * positions[i]``.
    pad : int
        Also sample ``pad`` px beyond the image on every side (the stack is
        ``(n, Y + 2 pad, X + 2 pad, C)``, its pixel ``(y, x)`` the image's
        ``(y - pad, x - pad)``): a view shifted towards the image's edge
        still holds samples there.

    Returns
    -------
    ShiftedStack
    """
    lf, slope = _shift_args(lf, slope)
    pad = _validate.integer_at_least("pad", pad, 0)
    n = lf.n_views
    shape = (lf.image_shape[0] + 2 * pad, lf.image_shape[1] + 2 * pad)
    values = np.empty((n,) + shape + (lf.n_channels,), np.float32)
    weights = np.empty((n,) + shape, np.float32)
    _run("shifted_stack", *_inputs(lf, slope), values, weights)
    return ShiftedStack(values, weights, slope, lf.flat_positions().copy(), lf.weights is not None)


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
    image = _weighted_mean(lf, slope)
    if not np.isfinite(image).all():  # float32 sums of values near its maximum overflowed
        scale = unit_scale(float(np.abs(lf.data).max()))
        scaled = LightField._derived(lf.data * np.float32(scale), lf.positions, lf.meta, lf.weights)
        image = _weighted_mean(scaled, slope) / np.float32(scale)
    return image


def _weighted_mean(lf, slope):
    num = np.empty(lf.image_shape + (lf.n_channels,), np.float32)
    den = np.empty(lf.image_shape, np.float32)
    _run("refocus_sum", *_inputs(lf, slope), np.ones(lf.n_views), num, den)
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

    One pass over the views: each pixel sums the weighted deviations of
    its samples from its first sample, and their squares, in float64
    (never ``E[x^2] - E[x]^2`` of the raw values), so float32 data with a
    large offset keep their precision (the result equals a weighted
    Welford update to float32 precision, and vectorises). The shifted
    views are not stored.

    Parameters
    ----------
    lf : LightField
        The light field (use ``lf.luminance()`` for luminance statistics).
    slope : float
        Disparity in focus.
    stack : ShiftedStack, optional
        A stack already shifted for ``slope`` to reuse; ``lf`` is then not
        read.

    Returns
    -------
    ViewMoments
    """
    if stack is None:
        lf, slope = _shift_args(lf, slope)
        shape, n_ch = lf.image_shape, lf.n_channels
    else:
        shape, n_ch = stack.values.shape[1:3], stack.values.shape[3]
    mean = np.empty(shape + (n_ch,), np.float32)
    variance = np.empty_like(mean)
    weight_sum = np.empty(shape, np.float32)
    count = np.empty(shape, np.int32)
    outputs = (mean, variance, weight_sum, count)
    if stack is None:
        _run("moments", *_inputs(lf, slope), *outputs)
    else:
        values, weights = stack._arrays()
        _run("stack_moments", values, n_ch, weights, *outputs)
    return ViewMoments(mean, variance, weight_sum, count)
