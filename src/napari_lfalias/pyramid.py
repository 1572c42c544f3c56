"""Gaussian pyramids of images and of light fields (Burt and Adelson, 1983).

Algorithm 2 of Xiao et al. detects aliasing on coarser pyramid levels of
the shifted views. Blurring, decimation and resampling are linear, so the
pyramid is built once per light field on the *unshifted* views, and level
``l`` is refocused with slope ``slope / 2**l`` (DESIGN section 4): the
pyramid does not depend on the slope, and a slider that changes the focus
reuses it.

One level is the 5-tap binomial blur ``[1, 4, 6, 4, 1] / 16`` followed by
keeping every second row and column (``ceil(n / 2)`` samples). Taps that
fall outside an image, or on samples of weight 0, carry no weight
(normalised convolution), so borders are neither darkened nor counted as
structure, as everywhere else in the package (DESIGN section 2).
"""

from __future__ import annotations

import numpy as np

from . import _validate
from .errors import ParameterError
from .lightfield import LightField

__all__ = ["pyr_down", "pyr_up", "gaussian_pyramid", "lightfield_pyramid", "level_shape", "MAX_LEVEL"]

#: The coarsest level any function takes: a 2**16-pixel blur, beyond the side of any image.
MAX_LEVEL = 16


def level_shape(shape, level):
    """``(Y, X)`` of pyramid level ``level`` of an image of shape ``shape``.

    Examples
    --------
    >>> level_shape((512, 301), 2)
    (128, 76)
    """
    height, width = int(shape[0]), int(shape[1])
    for _ in range(level):
        height, width = (height + 1) // 2, (width + 1) // 2
    return height, width


def _reduce_stack(images, weights=None, per_weight=1):
    """One pyramid level of ``images (m, Y, X)`` float32 (and of their ``weights (m / per_weight, Y, X)``)."""
    from .refocus import _run

    images = np.ascontiguousarray(images, np.float32)
    m = images.shape[0]
    shape = level_shape(images.shape[1:], 1)
    out = np.empty((m,) + shape, np.float32)
    if weights is None:
        _run("pyr_down", images, np.ones((1, 1, 1), np.float32), False, 1, out, np.empty((1, 1, 1), np.float32))
        return out, None
    weights = np.ascontiguousarray(weights, np.float32)
    out_weights = np.empty((weights.shape[0],) + shape, np.float32)
    _run("pyr_down", images, weights, True, per_weight, out, out_weights)
    return out, out_weights


def pyr_down(image, weights=None):
    """Blur with the binomial kernel and keep every second row and column.

    Parameters
    ----------
    image : ndarray, shape (Y, X) or (Y, X, C)
        The image.
    weights : ndarray, shape (Y, X), optional
        Validity of each pixel in [0, 1]; 0 means "not observed".

    Returns
    -------
    reduced : ndarray, shape (ceil(Y/2), ceil(X/2)[, C]), float32
        The normalised convolution ``sum k w x / sum k w`` at the even pixels.
    reduced_weights : ndarray or None
        The valid fraction of each output's footprint (``None`` without
        ``weights``).

    Examples
    --------
    >>> import numpy as np
    >>> small, _ = pyr_down(np.full((5, 8), 0.25, np.float32))
    >>> small.shape, bool(np.allclose(small, 0.25))
    ((3, 4), True)
    """
    image = np.asarray(image)
    if image.ndim not in (2, 3) or min(image.shape[:2]) < 1:
        raise ParameterError(f"image must have shape (Y, X) or (Y, X, C), got shape {image.shape}")
    if weights is not None:
        weights = np.asarray(weights, np.float32)
        if weights.shape != image.shape[:2]:
            raise ParameterError(f"weights must have shape {image.shape[:2]} (Y, X), got {weights.shape}")
        weights = weights[None]
    planes = image[None] if image.ndim == 2 else np.moveaxis(image, -1, 0)
    reduced, reduced_weights = _reduce_stack(planes, weights, per_weight=planes.shape[0])
    reduced = reduced[0] if image.ndim == 2 else np.moveaxis(reduced, 0, -1)
    return reduced, (None if reduced_weights is None else reduced_weights[0])


def _expand_axis(array, n_out, axis):
    """Burt-Adelson expansion by 2 along ``axis`` to ``n_out`` samples, normalised at the ends.

    Output ``2j`` is ``(x[j-1] + 6 x[j] + x[j+1]) / 8`` and output ``2j+1`` is
    ``(x[j] + x[j+1]) / 2``; taps beyond the ends are dropped and the rest
    renormalised.
    """
    array = np.moveaxis(array, axis, 0)
    n_in = array.shape[0]
    out = np.empty((n_out,) + array.shape[1:], array.dtype)
    padded = np.concatenate([array[:1], array, array[-1:]])  # replaced at the ends below
    even = (padded[:-2] + 6 * padded[1:-1] + padded[2:]) / 8
    if n_in > 1:
        even[0] = (6 * array[0] + array[1]) / 7
        even[-1] = (array[-2] + 6 * array[-1]) / 7
    odd = np.concatenate([(array[:-1] + array[1:]) / 2, array[-1:]])
    out[0::2] = even[: (n_out + 1) // 2]
    out[1::2] = odd[: n_out // 2]
    return np.moveaxis(out, 0, axis)


def pyr_up(image, shape):
    """Expand a pyramid level by 2 in each axis (Burt-Adelson), to ``shape = (Y, X)``.

    Parameters
    ----------
    image : ndarray, shape (y, x) or (y, x, C)
        A level; ``shape`` must reduce to it (``ceil(Y/2) == y``).
    shape : (int, int)
        The size of the finer level.

    Returns
    -------
    ndarray, shape (Y, X[, C]), float32

    Examples
    --------
    >>> import numpy as np
    >>> pyr_up(np.ones((3, 4), np.float32), (5, 8)).shape
    (5, 8)
    """
    image = np.asarray(image, np.float32)
    if image.ndim not in (2, 3):
        raise ParameterError(f"image must have shape (Y, X) or (Y, X, C), got shape {image.shape}")
    if level_shape(shape, 1) != image.shape[:2]:
        raise ParameterError(f"shape {tuple(shape)} does not reduce to the image's {image.shape[:2]}")
    out = _expand_axis(image, int(shape[0]), 0)
    return _expand_axis(out, int(shape[1]), 1)


def gaussian_pyramid(image, max_level):
    """Levels ``0 .. max_level`` of the Gaussian pyramid of ``image`` (level 0 is ``image``).

    Parameters
    ----------
    image : ndarray, shape (Y, X) or (Y, X, C)
    max_level : int
        The coarsest level (>= 0).

    Returns
    -------
    list of ndarray, float32

    Examples
    --------
    >>> import numpy as np
    >>> [level.shape for level in gaussian_pyramid(np.zeros((9, 16)), 2)]
    [(9, 16), (5, 8), (3, 4)]
    """
    max_level = _validate.integer_between("max_level", max_level, 0, MAX_LEVEL)
    levels = [np.asarray(image, np.float32)]
    for _ in range(max_level):
        levels.append(pyr_down(levels[-1])[0])
    return levels


def lightfield_pyramid(lf, max_level):
    """Levels ``0 .. max_level`` of a light field: every view reduced, positions kept.

    Level ``l`` views are ``2**l`` times smaller, so a scene point of
    disparity ``d`` has disparity ``d / 2**l`` there: refocus level ``l``
    with ``slope / 2**l``. Per-sample weights are reduced with the views
    (normalised convolution).

    Parameters
    ----------
    lf : LightField
    max_level : int

    Returns
    -------
    list of LightField
        ``[lf, level 1, ..., level max_level]``; coarser levels keep
        ``lf.positions`` and carry ``meta["pyramid_level"]``.

    Examples
    --------
    >>> import numpy as np
    >>> lf = LightField(np.zeros((2, 2, 16, 12, 1), np.float32))
    >>> [level.image_shape for level in lightfield_pyramid(lf, 2)]
    [(16, 12), (8, 6), (4, 3)]
    """
    if not isinstance(lf, LightField):
        raise ParameterError(f"lf must be a napari_lfalias.LightField, got {type(lf).__name__}")
    max_level = _validate.integer_between("max_level", max_level, 0, MAX_LEVEL)
    if lf.is_lazy:
        lf = lf.compute()
    levels = [lf]
    n, n_ch = lf.n_views, lf.n_channels
    for level in range(1, max_level + 1):
        previous = levels[-1]
        views = previous.views()  # (n, Y, X, C)
        planes = np.moveaxis(views, -1, 1).reshape((n * n_ch,) + previous.image_shape)
        reduced, weights = _reduce_stack(planes, previous.flat_weights(), per_weight=n_ch)
        height, width = reduced.shape[1:]
        data = np.ascontiguousarray(np.moveaxis(reduced.reshape(n, n_ch, height, width), 1, -1))
        data = data.reshape(lf.grid_shape + (height, width, n_ch))
        if weights is not None:
            weights = weights.reshape(lf.grid_shape + (height, width))
        meta = {"source": lf.meta.get("source"), "pyramid_level": level}
        levels.append(LightField._derived(data, lf.positions, meta, weights))
    return levels
