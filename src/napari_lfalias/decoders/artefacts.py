"""What a real camera left in a folder of views: black borders, vignetting, clipped light.

A folder of views exported by another tool (the views of a plenoptic
camera decoded elsewhere, a rectified camera array) holds no sample
weights: its dark corner views, black borders and saturated sky are plain
pixel values, which darken every refocus and which the aliasing detector
would read as disagreement between views. The folder loader
(:mod:`.camera_array`) summarises every view while it reads it
(:func:`summarise_view`, a few passes over the view) and then calls
:func:`correct_artefacts`, which sets the light field's weights as the
lenslet decoder does from a white image (:mod:`.devignetting`):

Black borders
    Samples exactly black in every channel, in regions connected to the
    view's border (rectification, a sensor's unlit edge, the black corners
    of a lenslet camera's outer views), get weight 0. A black object inside
    the image is left alone.

Vignetting
    Each view's smooth fall-off relative to the brightest view is
    estimated from the data. The views are reduced to 48 blocks on their
    long side (block means of the luminance, black borders left out) and
    compared with the median view; the ratio is taken between heavily
    blurred sums (Gaussian, sigma 12 % of the view), so that parallax,
    which moves content by a few pixels between views, averages out, and
    divided by the brightest view's ratio at that place: vignetting only
    takes light away (the lenslet decoder's white image is likewise
    relative to its bright level), so a correction only brightens. Where
    light is clipped in any view no ratio is taken, and the fall-off is
    interpolated from around.

    A light field counts as vignetted only where some view is *clearly*
    darker: its fall-off, plus :data:`_SIGNIFICANCE` standard errors of
    the blurred ratio, below :data:`DETECTED` (unvignetted scenes with
    strong parallax stayed above 0.8; ``benchmarks/results/artefacts.md``).
    Then every view whose fall-off surely drops below :data:`CORRECTED`
    is divided by it and its weights are multiplied by it (0 below
    :data:`MIN_WEIGHT`). Views without vignetting are left exactly as read,
    and a folder without any comes back unchanged (``weights`` ``None``).
    The fall-off common to every view (the centre view's own corners)
    cannot be told from the scene and stays.

Clipped light
    The clipping level is the file's largest code value (1 after the
    division by 255 or 65535) where samples reach it, else the data's
    maximum when it is a plateau (at least 16 samples and one in 100 000
    exactly on it, but not all of them, and more than in the 2 % just below
    it: a sensor clips to one value, a natural histogram thins out towards
    its maximum).
    As in the lenslet decoder, every value at or above it after the
    vignetting correction is set to it (a clipped sky is "at least this
    bright" in every view, so the views agree) and the sample's weight is
    multiplied by :data:`~.devignetting.CLIPPED_WEIGHT`. Where the
    brightest view is clipped, a corrected view's fall-off is at most its
    luminance over the brightest view's (a lower bound of the light), so
    that under a clipped sky it reaches the level too.

Examples
--------
>>> import numpy as np
>>> data = np.random.default_rng(0).uniform(0.2, 0.8, (1, 2, 6, 6, 1)).astype(np.float32)
>>> data[0, 1, :, :2] = 0                      # a black border on the left of view (0, 1)
>>> summaries = [summarise_view(view) for view in data.reshape(2, 6, 6, 1)]
>>> weights, report = correct_artefacts(data, summaries)
>>> weights[0, 1, 0].tolist(), report["black_border_samples"]
([0.0, 0.0, 1.0, 1.0, 1.0, 1.0], 12)
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from .. import _budget
from ..errors import DecodeError
from ..lightfield import REC709
from .devignetting import CLIPPED_WEIGHT

__all__ = ["ViewSummary", "summarise_view", "correct_artefacts", "DETECTED", "CORRECTED", "MIN_WEIGHT"]

#: A light field is vignetted where some view's relative fall-off drops below this.
DETECTED = 0.7
#: In a vignetted light field, views whose fall-off drops below this are corrected.
CORRECTED = 0.85
#: Samples whose fall-off is below this get weight 0.
MIN_WEIGHT = 0.05
#: Long side, in blocks, of the reduced views the fall-off is estimated on.
_REDUCED = 48
#: Views with fewer pixels than this on a side are too small to tell vignetting from content.
_MIN_SIDE = 16
#: Sigma of the blur of the ratios, as a fraction of the reduced view's long side.
_BLUR = 0.12
#: Blocks darker than this fraction of the light field's bright level carry no ratio.
_DARK = 0.02
#: Blurred coverage (share of usable blocks) below which a ratio is not trusted.
_SUPPORT = 0.25
#: A view is darker than a threshold only where its fall-off plus this many standard errors is.
_SIGNIFICANCE = 4.0
#: A clipping plateau holds at least this many samples, and this fraction of them.
_PLATEAU = (16, 1e-5)
#: "Just below the maximum": from this fraction of it.
_NEAR_TOP = 0.98
#: Views blurred per OpenCV call (as the channels of one image: OpenCV 5 takes at most 128).
_CV_CHANNELS = 128


@dataclass(frozen=True)
class ViewSummary:
    """What :func:`correct_artefacts` needs of one view, taken while the view is read.

    Attributes
    ----------
    top : float
        The largest sample.
    border : ndarray of bool, shape (Y, X), or None
        Black samples connected to the view's border (``None``: none).
    small : ndarray, shape (h, w), float32
        Block means of the luminance, over the samples outside ``border``.
    coverage : ndarray, shape (h, w), float32, or None
        Share of each block outside ``border`` (``None``: all of it).
    """

    top: float
    border: np.ndarray | None
    small: np.ndarray
    coverage: np.ndarray | None


def _blocks(height, width):
    """Block ``(rows, columns)``: whole pixels, about :data:`_REDUCED` blocks on the long side.

    The reduced view covers ``(Y // rows) * rows`` rows and likewise columns
    (the last few pixels are left out: an integer factor keeps OpenCV's
    area reduction on its fast path).
    """
    step = max(1, -(-max(height, width) // _REDUCED))
    return min(step, height), min(step, width)


def _reduce(image, blocks):
    """Block means of ``image (Y, X[, C])`` (OpenCV area reduction by whole blocks)."""
    rows, cols = blocks
    n_rows, n_cols = image.shape[0] // rows, image.shape[1] // cols
    return cv2.resize(image[:n_rows * rows, :n_cols * cols], (n_cols, n_rows), interpolation=cv2.INTER_AREA)


def _expand(small, blocks, shape):
    """Bilinear enlargement of block values to ``shape (Y, X)``, the left-out edge repeating the last block."""
    rows, cols = blocks
    full = cv2.resize(small.astype(np.float32), (small.shape[1] * cols, small.shape[0] * rows),
                      interpolation=cv2.INTER_LINEAR)
    return np.pad(full, ((0, shape[0] - full.shape[0]), (0, shape[1] - full.shape[1])), mode="edge")


def black_border(view):
    """Samples of ``view (Y, X, C)`` black in every channel and connected to its border, or ``None``.

    Examples
    --------
    >>> view = np.ones((5, 6, 1), np.float32)
    >>> view[:, :2] = 0                 # a black band on the left
    >>> view[2, 4] = 0                  # a black pixel inside
    >>> black_border(view).sum(axis=1).tolist()
    [2, 2, 2, 2, 2]
    """
    edges = (view[0], view[-1], view[:, 0], view[:, -1])
    if not any((edge == 0).all(axis=-1).any() for edge in edges):
        return None
    black = (view == 0).all(axis=-1)
    _, labels = cv2.connectedComponents(black.view(np.uint8), connectivity=4)
    touching = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    touching = touching[touching > 0]  # label 0: the samples that are not black
    return np.isin(labels, touching)


def _luminance(image):
    image = image.reshape(image.shape[:2] + (-1,))
    return image @ REC709 if image.shape[2] == 3 else image[..., 0]


def _largest(native):
    """The largest sample of a view as decoded, in [0, 1] units; NaN if a float view holds NaN."""
    top = float(np.max(native))  # on 8 bits a small fraction of the float32 view's time; NaN propagates
    return top / np.iinfo(native.dtype).max if np.issubdtype(native.dtype, np.integer) else top


def summarise_view(view, native=None):
    """The :class:`ViewSummary` of one view, or ``None`` if it holds NaN or Inf.

    Parameters
    ----------
    view : ndarray, shape (Y, X, C), float32
        The view in [0, 1].
    native : ndarray, optional
        The same view as decoded (its own dtype), where its largest value
        is found faster.

    Examples
    --------
    >>> summary = summarise_view(np.full((128, 96, 3), 0.25, np.float32))
    >>> summary.small.shape, round(float(summary.small.mean()), 3), summary.border is None
    ((42, 32), 0.25, True)
    """
    height, width = view.shape[:2]
    top = _largest(view if native is None else native)
    border = black_border(view)
    blocks = _blocks(height, width)
    if border is None:
        small, coverage = _luminance(_reduce(view, blocks)), None
    else:
        keep = (~border).astype(np.float32)
        coverage = _reduce(keep, blocks)
        small = _luminance(_reduce(view * keep[..., None], blocks)) / np.maximum(coverage, np.float32(1e-6))
    left_out = (view[small.shape[0] * blocks[0]:], view[:, small.shape[1] * blocks[1]:])
    if not (np.isfinite(top) and np.isfinite(small).all() and all(np.isfinite(part.sum()) for part in left_out)):
        return None  # NaN or Inf: the LightField refuses or masks them
    return ViewSummary(float(top), border, small.astype(np.float32), coverage)


# -- clipping ------------------------------------------------------------------

def clip_level(views, summaries):
    """The level at which the views ``(n, Y, X, C)`` are clipped, or ``None`` (module notes).

    Examples
    --------
    >>> ramp = np.linspace(0, 0.8, 64 * 64, dtype=np.float32).reshape(1, 64, 64, 1)
    >>> clip_level(ramp, [summarise_view(ramp[0])]) is None
    True
    >>> clipped = np.minimum(ramp, 0.6)
    >>> clip_level(clipped, [summarise_view(clipped[0])])
    0.6000000238418579
    """
    examined = [i for i, s in enumerate(summaries) if s is not None]
    if not examined:
        return None
    top = max(summaries[i].top for i in examined)
    if top <= 0:
        return None
    if top == 1.0:  # the file's largest code value (255 / 65535): reaching it is clipping
        return 1.0
    n_top = n_near = 0
    for i in examined:  # only the views that reach the maximum: one or a few unless it is a plateau
        if summaries[i].top == top:
            high = views[i][views[i] >= np.float32(_NEAR_TOP * top)]
            at_top = int(np.count_nonzero(high == top))
            n_top, n_near = n_top + at_top, n_near + high.size - at_top
    n_samples = len(examined) * views[0].size
    plateau = max(_PLATEAU[0], _PLATEAU[1] * n_samples) <= n_top < n_samples  # all at one value: nothing clipped
    return top if plateau and n_top > n_near else None


# -- vignetting ----------------------------------------------------------------

def _quantile_over_views(values, q):
    """The ``q`` quantile (0..1, lower) over axis 0, ignoring NaN; NaN where every view is NaN."""
    ordered = np.sort(values, axis=0)  # NaN last
    count = np.count_nonzero(np.isfinite(values), axis=0)
    index = np.floor(q * np.maximum(count - 1, 0)).astype(np.intp)
    picked = np.take_along_axis(ordered, index[None], axis=0)[0]
    return np.where(count > 0, picked, np.nan)


def _blur(stack, sigma):
    """Gaussian blur of every image of ``stack (n, h, w)`` (OpenCV, the views as channels)."""
    out = np.empty(stack.shape, np.float32)
    for start in range(0, len(stack), _CV_CHANNELS):
        chunk = np.ascontiguousarray(np.moveaxis(stack[start:start + _CV_CHANNELS], 0, -1), np.float32)
        blurred = cv2.GaussianBlur(chunk, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
        out[start:start + _CV_CHANNELS] = np.moveaxis(blurred.reshape(chunk.shape), -1, 0)
    return out


def _ratios(small, usable, scene):
    """Each view's luminance relative to the ``scene``, heavily blurred, and its standard error.

    Returns ``(ratio, error)``, both ``(n, h, w)`` and NaN where unknown.
    ``ratio`` is the ratio of the blurred sums (the weighted mean of the
    blocks' ratios, weighted by the scene's brightness); ``error`` is the
    standard error of that mean, from the blocks' spread about it in the
    same window: small where the views are one image seen through
    different fall-offs, large where they differ (parallax, noise,
    unrelated images).
    """
    weight = np.where(np.isfinite(scene) & (usable >= 0.5), usable, 0) * np.nan_to_num(scene)  # a block's say
    with np.errstate(divide="ignore", invalid="ignore"):
        block_ratio = np.where(weight > 0, small / scene, 0)
    sigma = _BLUR * max(small.shape[1:])
    total = _blur(weight, sigma)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = _blur(weight * block_ratio, sigma) / total
        spread = _blur(weight * (block_ratio - np.nan_to_num(ratio)) ** 2, sigma) / total
        # (sum k w)^2 / sum k^2 w^2 for the normalised kernel k: k^2 is a Gaussian of sigma / sqrt(2)
        n_effective = total ** 2 * (4 * np.pi * sigma ** 2) / _blur(weight ** 2, sigma / np.sqrt(2))
        error = np.sqrt(spread / n_effective)
        support = total / _blur(np.nan_to_num(scene)[None], sigma)  # the brightness-weighted share of usable blocks
    known = (support >= _SUPPORT) & (total > 0)
    return np.where(known, ratio, np.nan), np.where(known, error, np.nan)


def _lowest(falloff):
    """Each view's lowest fall-off (1 for a view without any estimate)."""
    flat = falloff.reshape(len(falloff), -1)
    known = np.isfinite(flat)
    return np.where(known.any(axis=1), np.min(np.where(known, flat, np.inf), axis=1), 1.0)


def relative_falloff(small, usable):
    """Fall-off of every view relative to the brightest, and how low it surely is; or None.

    Parameters
    ----------
    small : ndarray, shape (n, h, w)
        The reduced luminance of every view (:class:`ViewSummary`).
    usable : ndarray, shape (n, h, w)
        The say of every block (0 where a view is not examined or black,
        and in every view where one is clipped).

    Returns
    -------
    falloff, upper : ndarray, shape (n, h, w)
        The fall-off (NaN where unknown) and its upper bound, the fall-off
        plus :data:`_SIGNIFICANCE` standard errors: a view is darker than
        ``t`` somewhere only where ``upper < t``. ``None`` when the views
        are dark everywhere.
    """
    scene = _quantile_over_views(np.where(usable >= 0.5, small, np.nan), 0.5)  # the median view
    finite = scene[np.isfinite(scene)]
    if finite.size == 0 or np.percentile(finite, 99) <= 0:
        return None
    scene = np.where(scene > _DARK * np.percentile(finite, 99), scene, np.nan)
    ratio, error = _ratios(small, usable, scene)
    with np.errstate(invalid="ignore", divide="ignore"):
        level = np.fmax.reduce(ratio, axis=0)[None]  # the brightest view's (NaN only where every view's is)
        return (ratio / level).astype(np.float32), ((ratio + _SIGNIFICANCE * error) / level).astype(np.float32)


def _fill_unknown(falloff):
    """NaN blocks take the value of the nearest known block (1 where a view has none)."""
    out = np.empty_like(falloff)
    for i, view in enumerate(falloff):
        unknown = ~np.isfinite(view)
        if unknown.all():
            out[i] = 1.0
        elif unknown.any():
            nearest = ndimage.distance_transform_edt(unknown, return_distances=False, return_indices=True)
            out[i] = view[tuple(nearest)]
        else:
            out[i] = view
    return out


def _usable(summaries, n_blocks_shape, clipped_share):
    """Say ``(n, h, w)`` of every block in the estimate: its coverage; 0 for views not examined, and where clipped."""
    usable = np.zeros((len(summaries),) + n_blocks_shape, np.float32)
    for i, summary in enumerate(summaries):
        if summary is not None:
            usable[i] = 1.0 if summary.coverage is None else summary.coverage
    if clipped_share is not None:  # where one view is clipped, the median view may be: no ratio there
        usable *= clipped_share.max(axis=0)[None] <= 0.01
    return usable


# -- the whole correction ------------------------------------------------------

def _clipped_share(flat, level, examined):
    """Per view ``(n, Y, X, C)``, the share of each block clipped at ``level`` ``(n, h, w)``, and the clipped masks."""
    height, width = flat.shape[1:3]
    blocks = _blocks(height, width)
    share = np.zeros((len(flat), height // blocks[0], width // blocks[1]), np.float32)
    masks = [None] * len(flat)
    for i in examined:
        mask = (flat[i] >= np.float32(level)).any(axis=-1)
        if mask.any():
            masks[i] = mask
            share[i] = _reduce(mask.astype(np.float32), blocks)
    return share, masks


class _Weights:
    """The light field's sample weights, allocated (within the memory budget) at the first artefact found."""

    def __init__(self, weights, shape, source):
        self.array, self._shape, self._source = weights, shape, source

    def of(self, i):
        """The weights ``(Y, X)`` of view ``i`` (row-major), to change in place."""
        if self.array is None:
            _budget.check(int(np.prod(self._shape)) * 4,
                          f"{self._source}: the sample weights of its black borders, vignetting or clipped light",
                          DecodeError)
            self.array = np.ones(self._shape, np.float32)
        return self.array.reshape((-1,) + self._shape[2:])[i]


def correct_artefacts(data, summaries, weights=None, *, source="the folder"):
    """Weights for black borders, vignetting and clipped light; vignetted views corrected in place.

    Parameters
    ----------
    data : ndarray, shape (U, V, Y, X, C), float32
        The views as read; vignetted views are divided by their fall-off
        and clipped light set to the clipping level, in place.
    summaries : sequence of ViewSummary or None
        One per view, row-major (:func:`summarise_view`); ``None`` for a
        view not examined (missing, or holding NaN/Inf): it is left alone.
    weights : ndarray, shape (U, V, Y, X), float32, optional
        Weights already known (views missing from the folder); multiplied
        in place.
    source : str
        Names the folder in a memory-budget error.

    Returns
    -------
    weights : ndarray, shape (U, V, Y, X), float32, or None
        ``None`` when nothing was found and no weights were given.
    report : dict
        Empty when nothing was found; else what was: ``black_border_samples``;
        ``vignetted_views`` (``[u, v]`` of the corrected views) and
        ``lowest_falloff``; ``clip_level`` and ``clipped_samples``.

    Raises
    ------
    DecodeError
        If the weights do not fit the memory budget.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> scene = rng.uniform(0.2, 0.8, (1, 1, 32, 32, 1)).astype(np.float32)
    >>> data = np.repeat(np.repeat(scene, 3, 0), 3, 1)
    >>> data[0, 0] *= 0.4                               # a dark corner view
    >>> summaries = [summarise_view(v) for v in data.reshape(9, 32, 32, 1)]
    >>> weights, report = correct_artefacts(data, summaries)
    >>> report["vignetted_views"], round(float(np.abs(data[0, 0] - scene[0, 0]).max()), 3)
    ([[0, 0]], 0.0)
    >>> round(float(weights[0, 0].mean()), 2), float(weights[1, 1].min())
    (0.4, 1.0)
    """
    flat = data.reshape((-1,) + data.shape[2:])
    examined = [i for i, s in enumerate(summaries) if s is not None]
    if not examined:
        return weights, {}
    weights = _Weights(weights, data.shape[:4], source)
    report = _black_borders(summaries, examined, weights)
    level = clip_level(flat, summaries)
    share, masks = _clipped_share(flat, level, examined) if level is not None else (None, None)
    corrected, found = _vignetting(flat, summaries, examined, share, weights)
    if corrected:
        report["vignetted_views"] = [[i // data.shape[1], i % data.shape[1]] for i in corrected]
    report.update(found)
    if level is not None:
        report.update(_ceiling(flat, level, masks, corrected, examined, weights))
    return weights.array, report


def _black_borders(summaries, examined, weights):
    """Weight 0 on every view's black border; the report."""
    count = 0
    for i in examined:
        if summaries[i].border is not None:
            weights.of(i)[summaries[i].border] = 0
            count += int(np.count_nonzero(summaries[i].border))
    return {"black_border_samples": count} if count else {}


def _vignetting(flat, summaries, examined, share, weights):
    """Divide the clearly vignetted views by their fall-off (module notes): their indices, and the report."""
    height, width = flat.shape[1:3]
    if len(examined) < 2 or min(height, width) < _MIN_SIDE:
        return [], {}
    blank = np.zeros_like(summaries[examined[0]].small)
    small = np.stack([blank if s is None else s.small for s in summaries])
    estimate = relative_falloff(small, _usable(summaries, small.shape[1:], share))
    if estimate is None:
        return [], {}
    falloff, upper = estimate
    surely_below = _lowest(upper[examined])
    if surely_below.min() >= DETECTED:
        return [], {}
    corrected = [i for i, low in zip(examined, surely_below) if low < CORRECTED]
    filled = _fill_unknown(falloff)
    if share is not None:
        filled = _under_clipped_light(filled, small, share)
    _divide_out(flat, filled[corrected], corrected, weights)
    return corrected, {"lowest_falloff": round(float(_lowest(falloff[corrected]).min()), 3)}


def _ceiling(flat, level, masks, corrected, examined, weights):
    """Clipped light at one level in every view, at :data:`CLIPPED_WEIGHT`; the report."""
    for i in corrected:  # a corrected view may pass the level
        np.minimum(flat[i], np.float32(level), out=flat[i])
        masks[i] = (flat[i] >= np.float32(level)).any(axis=-1)
    count = 0
    for i in examined:
        if masks[i] is not None and masks[i].any():
            weights.of(i)[masks[i]] *= np.float32(CLIPPED_WEIGHT)
            count += int(np.count_nonzero(masks[i]))
    return {"clip_level": float(level), "clipped_samples": count} if count else {}


def _under_clipped_light(falloff, small, share):
    """The fall-off, at most ``small / small[brightest]`` where the brightest view is clipped.

    No fall-off is estimated where a view is clipped (:func:`_usable`), so
    under a large clipped sky it is interpolated. But there the clipped
    brightest view's luminance is a lower bound of the light, so a view
    seeing ``L`` of it has a fall-off of at most ``L / L_brightest``; with
    that bound, the view divided by its fall-off reaches the clipping level
    too, and the views agree on the sky.
    """
    brightest = np.argmax(falloff, axis=0)[None]
    clipped = np.take_along_axis(share, brightest, axis=0)[0] >= 0.5
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = small / np.take_along_axis(small, brightest, axis=0)
    return np.where(clipped[None] & (bound < falloff), bound, falloff)


def _divide_out(flat, falloff, corrected, weights):
    """Divide each corrected view by its fall-off (blocks, enlarged) and multiply its weights by it."""
    height, width = flat.shape[1:3]
    for i, small in zip(corrected, falloff):
        full = _expand(small, _blocks(height, width), (height, width))
        flat[i] /= np.maximum(full, np.float32(MIN_WEIGHT))[..., None]
        weights.of(i)[...] *= np.where(full >= MIN_WEIGHT, np.minimum(full, 1), 0).astype(np.float32)
