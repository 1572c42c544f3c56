"""The in-focus layer of a refocused pixel: the views that agree there.

Where a defocused occluder partly hides an in-focus surface (the halo
around a defocused object), a refocused pixel mixes two things: the
in-focus surface, seen identically by every view that sees it, and the
occluder, seen differently by each view. Only the second aliases. Blurring
the whole pixel, as Algorithm 2 does, also blurs the in-focus texture the
dense-aperture reference keeps sharp.

:func:`in_focus_layer` splits such a pixel without any depth: the largest
group of views whose samples agree (luminance within :data:`REL_TOL` of
each other) is taken for the in-focus surface when it holds at least
:data:`MIN_SHARE` of the views. The refocus is then

    refocused = share * colour + rest

with ``colour`` the group's mean colour and ``rest`` the other views'
weighted contribution. :func:`napari_lfalias.reduce_aliasing` blurs
``share`` (the occluder's silhouette) and ``rest`` (the occluder) and keeps
``colour`` sharp. A flat defocused surface also forms groups; there
``colour`` is locally constant, so the split changes nothing, which is why
no stricter test is needed. Measured in ``benchmarks/results/reduction.md``.
"""

from __future__ import annotations

import numpy as np

from .lightfield import REC709
from .refocus import _run

__all__ = ["in_focus_layer", "REL_TOL", "MIN_SHARE"]

#: Samples whose luminance differs by less than this fraction agree.
REL_TOL = 0.02
#: Smallest share of the views (by weight) a group needs to count as in focus.
MIN_SHARE = 0.25


def in_focus_layer(lf, slope, pixels, floor, *, rel_tol=REL_TOL, min_share=MIN_SHARE):
    """The share of the views that agree at each pixel, and the colour they agree on.

    Parameters
    ----------
    lf : LightField
        The light field (in memory).
    slope : float
        The slope it is refocused at.
    pixels : ndarray of bool, shape (Y, X)
        The pixels to split; the others get share 0.
    floor : float
        Samples darker than this agree when within ``floor`` of each other
        (the detection's dark floor, in luminance).
    rel_tol, min_share : float
        See :data:`REL_TOL` and :data:`MIN_SHARE`.

    Returns
    -------
    share : ndarray, shape (Y, X), float32
        The weight share of the largest agreeing group, 0 where it is
        below ``min_share`` or outside ``pixels``.
    colour : ndarray, shape (Y, X, C), float32
        The group's mean colour (0 where ``share`` is 0).

    Examples
    --------
    >>> import numpy as np
    >>> from napari_lfalias import LightField
    >>> data = np.full((2, 2, 8, 8, 1), 0.5, np.float32)
    >>> data[0, 0] = 0.9                       # one view of four disagrees
    >>> share, colour = in_focus_layer(LightField(data), 0.0, np.ones((8, 8), bool), 0.01)
    >>> float(share[4, 4]), float(colour[4, 4, 0])
    (0.75, 0.5)
    """
    views = np.ascontiguousarray(lf.views(), np.float32)
    n, height, width, n_ch = views.shape
    weights = lf.flat_weights()
    has_valid = weights is not None
    valid = np.ascontiguousarray(weights, np.float32) if has_valid else np.ones((n, 1, 1), np.float32)
    coeffs = REC709 if n_ch == 3 else np.full(n_ch, 1.0 / n_ch)
    ys, xs = np.nonzero(pixels)
    share = np.zeros((height, width), np.float32)
    colour = np.zeros((height, width, n_ch), np.float32)
    _run("in_focus_consensus", views, valid, has_valid, slope * lf.flat_positions().astype(np.float64),
         np.asarray(coeffs, np.float64), ys.astype(np.int64), xs.astype(np.int64),
         float(rel_tol), float(floor), float(min_share), share, colour)
    return share, colour
