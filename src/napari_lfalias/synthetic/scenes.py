"""Procedural layered scenes with exact ground truth.

A scene is a stack of fronto-parallel planes, front to back, each with a
colour texture, an alpha mask and a disparity ``d``. View ``q = (y, x)``
shows layer ``k`` at texture coordinate ``t = p - d_k * q`` (the convention
of DESIGN section 2) and composites the layers front to back::

    view = sum_k a_k T_k prod_{j<k} (1 - a_j)

Every texture and mask is a sum of separable products ``f(y) g(x)`` whose
1-D factors are periodic and band-limited (a raised-cosine low-pass,
so a product of a texture and a mask stays below 0.48 cycles/px on each
axis). A view is thus the exact sampling of a band-limited image: no
spatial aliasing, and any sub-pixel position can be evaluated exactly
(Fourier shift of the 1-D factors). The compositing expands into a sum of
separable terms, so a view is one matrix product, and a refocus over a
separable grid of aperture positions is a sum of 1-D factors per axis
followed by one matrix product -- which makes a dense-aperture reference
with thousands of aperture samples cost about as much as a single view.

Dense-aperture reference
------------------------
``SyntheticScene.reference(slope)`` integrates over the continuous square
aperture made of the cells of the views: view ``i`` at grid position
``c_i`` owns the cell ``[c_i - 1/2, c_i + 1/2]`` on each axis, so the
aperture spans ``[-U/2, U/2]``. The regular views are the midpoint rule of
that integral with one sample per cell; the reference uses ``m`` samples
per cell per axis (midpoint rule again), ``m`` chosen so that adjacent
samples of every layer move by at most ``max_step`` pixels after
refocusing. Each sample is the view evaluated exactly at ``p + slope * q``
(ideal interpolation of the band-limited scene), weighted by the same
border validity as :func:`napari_lfalias.refocus` (1 inside, falling
linearly to 0 within one pixel outside the view), and the sum is divided
by the summed weight. With ``samples_per_view=1, interpolation="bilinear"``
the same machinery reproduces :func:`napari_lfalias.refocus` of the
scene's light field, which ties the two together.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from itertools import combinations

import numpy as np
import scipy.fft

from .. import _validate
from ..errors import ParameterError
from ..lightfield import LightField, regular_positions

__all__ = ["Plane", "SyntheticScene", "brick_room", "textureless_plane", "textured_plane", "layered_scene", "TEXTURES"]

#: Low-pass cut-offs (cycles per pixel) of texture and mask factors; their
#: sum stays below Nyquist, so a masked texture is still band-limited.
TEXTURE_CUTOFF = 0.30
MASK_CUTOFF = 0.18
#: Positions evaluated per batch when summing over the aperture (bounds memory).
_BATCH = 8


# -- 1-D band-limited factors -------------------------------------------------

def _lowpass(samples, cutoff):
    """Spectrum (rfft over the last axis) of ``samples`` after a raised-cosine (Hann) low-pass.

    The gain falls from 1 at 0 to exactly 0 at ``cutoff`` and stays 0
    beyond (a strict band limit). A filtered step rings by under 1 %, so
    textures stay within [0, 1]; its tails fall below 1e-3 about 8 px
    from a mask's edge.
    """
    freq = np.fft.rfftfreq(samples.shape[-1])
    gain = np.where(freq < cutoff, 0.5 + 0.5 * np.cos(np.pi * freq / cutoff), 0.0)
    return scipy.fft.rfft(samples, axis=-1) * gain


@dataclass
class _Factors:
    """A sum of separable products ``sum_k y_k(t_y) x_k(t_x, c)``, periodic and band-limited.

    ``y`` holds the spectra (K, F) of the row factors, ``x`` those of the
    column factors (K, C, F); ``period`` is the common period in pixels.
    """

    y: np.ndarray
    x: np.ndarray
    period: int

    @classmethod
    def from_samples(cls, y, x, cutoff):
        y = np.atleast_2d(np.asarray(y, np.float64))
        x = np.asarray(x, np.float64)
        if x.ndim == 2:
            x = x[:, None, :]
        return cls(_lowpass(y, cutoff), _lowpass(x, cutoff), y.shape[-1])

    def sample(self, axis, shifts, n):
        """Factors of ``axis`` ("y" or "x") at ``t = j - shift`` for ``j < n``, one row per shift.

        Returns (M, K, n) for "y" and (M, K, n, C) for "x", float64.
        """
        spectrum = self.y if axis == "y" else self.x
        k = np.arange(spectrum.shape[-1])
        ramp = np.exp(-2j * np.pi * np.outer(shifts, k) / self.period)
        ramp = ramp.reshape(ramp.shape[:1] + (1,) * (spectrum.ndim - 1) + ramp.shape[1:])
        values = scipy.fft.irfft(spectrum[None] * ramp, n=self.period, axis=-1)[..., :n]
        return values if axis == "y" else np.moveaxis(values, 2, 3)


def _indicator(period, intervals):
    """Samples ``(len(intervals), period)`` equal to 1 on each ``[start, stop)`` (mod period), else 0."""
    out = np.zeros((len(intervals), period))
    index = np.arange(period)
    for row, (start, stop) in enumerate(intervals):
        out[row, (index - start) % period < stop - start] = 1.0
    return out


# -- textures and masks -------------------------------------------------------

def _brick_texture(rng, period, seam, brick=(16, 40), mortar=3):
    """A brick wall: rows of bricks of random colour, half a brick offset on odd rows, light mortar.

    Whole bricks only, so none overlaps across the period; the left-over
    strip (and the half-brick offset) sit just before ``seam``, which the
    caller places outside every view.
    """
    height, width = brick
    mortar_colour = np.array([0.74, 0.72, 0.66])
    n_rows = period // height
    rows = _indicator(period, [(seam + i * height + mortar, seam + (i + 1) * height) for i in range(n_rows)])
    cols = np.zeros((n_rows, 3, period))
    n_cols = period // width
    for i in range(n_rows):
        offset = (width // 2) * (i % 2)
        starts = [seam + j * width + offset + mortar for j in range(n_cols)]
        bricks = _indicator(period, [(s, s - mortar + width) for s in starts])
        base = np.array([0.55, 0.26, 0.18]) + rng.uniform(-0.12, 0.12, size=(n_cols, 1))
        colours = np.clip(base + rng.uniform(-0.05, 0.05, size=(n_cols, 3)), 0.12, 0.85)
        cols[i] = (colours - mortar_colour).T @ bricks
    grain_rows = rng.normal(size=(6, period))
    grain_rows *= 0.03 / grain_rows.std(axis=1, keepdims=True)
    grain_cols = np.repeat(rng.normal(size=(6, 1, period)), 3, axis=1)
    grain_cols *= 1.0 / grain_cols.std(axis=2, keepdims=True)
    y = np.concatenate([np.ones((1, period)), rows, grain_rows])
    x = np.concatenate([np.broadcast_to(mortar_colour[None, :, None], (1, 3, period)), cols, grain_cols])
    return _Factors.from_samples(y, x, TEXTURE_CUTOFF)


def _mosaic_texture(rng, period, box, tile=4):
    """Tiles of random colours (high contrast) covering ``box = (y0, y1, x0, x1)``."""
    y0, y1, x0, x1 = box
    row_edges = list(range(y0, y1, tile)) + [y1]
    col_edges = list(range(x0, x1, tile)) + [x1]
    rows = _indicator(period, list(zip(row_edges[:-1], row_edges[1:])))
    tiles = _indicator(period, list(zip(col_edges[:-1], col_edges[1:])))
    colours = rng.uniform(0.15, 0.85, size=(len(rows), len(tiles), 3))
    cols = np.einsum("itc,tx->icx", colours, tiles)
    return _Factors.from_samples(rows, cols, TEXTURE_CUTOFF)


def _constant_texture(period, colour):
    colour = np.asarray(colour, np.float64)
    x = np.broadcast_to(colour[None, :, None], (1, 3, period))
    return _Factors.from_samples(np.ones((1, period)), x, TEXTURE_CUTOFF)


def _scaled(y, x, mean, contrast, rng_colour):
    """Factors ``y (K, P)``, ``x (K, C, P)`` scaled to zero-mean unit-spread, with ``contrast`` and a
    constant term of colour ``mean``: the texture ``mean + contrast * sum_k y_k x_k``."""
    values = np.einsum("kp,kcq->pqc", y[:, :64], x[:, :, :64])
    spread = float(values.std()) or 1.0
    period = y.shape[-1]
    y = np.concatenate([np.ones((1, period)), y * (contrast / spread)])
    x = np.concatenate([np.broadcast_to(np.asarray(mean, np.float64)[None, :, None], (1, 3, period)), x])
    if rng_colour is not None:  # a random tint per term
        x[1:] *= rng_colour[:, :, None]
    return y, x


def _noise_texture(rng, period, cutoff, contrast=0.1, rank=12, colour=True):
    """Band-limited random texture (a sum of ``rank`` random separable products), about
    ``mean +- contrast`` (one standard deviation); ``cutoff`` (cycles/px) from smooth (0.03) to near-Nyquist (0.45)."""
    y = rng.normal(size=(rank, period))
    x = rng.normal(size=(rank, 1, period)).repeat(3, axis=1)
    tint = rng.uniform(0.7, 1.3, size=(rank, 3)) if colour else None
    # low-pass before scaling, so the contrast is that of the band-limited texture
    y = scipy.fft.irfft(_lowpass(y, cutoff), n=period, axis=-1)
    x = scipy.fft.irfft(_lowpass(x, cutoff), n=period, axis=-1)
    mean = rng.uniform(0.3, 0.6, size=3) if colour else np.full(3, 0.45)
    y, x = _scaled(y, x, mean, contrast, tint)
    return _Factors.from_samples(y, x, min(cutoff * 1.05, 0.499))


def _grating_texture(rng, period, frequency, angle, contrast=0.25):
    """A sinusoidal grating of ``frequency`` cycles/px at ``angle`` radians (rank 2: cos(a + b)),
    on the texture's period (the nearest whole number of cycles)."""
    t = np.arange(period)
    cycles_y = round(frequency * np.sin(angle) * period)
    cycles_x = round(frequency * np.cos(angle) * period)
    phase = rng.uniform(0, 2 * np.pi)
    ay, ax = 2 * np.pi * cycles_y * t / period, 2 * np.pi * cycles_x * t / period + phase
    y = np.stack([np.cos(ay), -np.sin(ay)])
    x = np.stack([np.cos(ax), np.sin(ax)])[:, None, :].repeat(3, axis=1)
    mean = rng.uniform(0.35, 0.55, size=3)
    y, x = _scaled(y, x, mean, contrast, None)
    return _Factors.from_samples(y, x, 0.499)


def _checker_texture(rng, period, seam, cell, contrast=0.3):
    """A checkerboard of ``cell`` px squares (a product of two square waves), band-limited; the
    squares start at ``seam`` (outside every view), where the period may cut one short."""
    t = (np.arange(period) - seam) % period
    wave = np.where((t // cell) % 2 == 0, 1.0, -1.0)
    mean = rng.uniform(0.35, 0.55, size=3)
    y, x = _scaled(wave[None], wave[None, None].repeat(3, axis=1), mean, contrast, None)
    return _Factors.from_samples(y, x, TEXTURE_CUTOFF)


def _tiles_texture(rng, period, seam, tile):
    """Square tiles of ``tile`` px of random colours over the whole period (high contrast, like the
    brick room's cube), starting at ``seam``."""
    edges = list(range(seam, seam + period, tile)) + [seam + period]
    spans = [(a % period, (a % period) + (b - a)) for a, b in zip(edges[:-1], edges[1:])]
    indicator = _indicator(period, spans)
    colours = rng.uniform(0.15, 0.85, size=(len(spans), len(spans), 3))
    cols = np.einsum("itc,tx->icx", colours, indicator)
    return _Factors.from_samples(indicator, cols, TEXTURE_CUTOFF)


def _lines_texture(rng, period, seam, spacing=(8, 28), width=(1.5, 3.5)):
    """Thin dark and light lines, horizontal and vertical, at random spacings (a grid of lines like
    mortar, window frames or text strokes: what angular aliasing shows most), on a random background."""
    t = np.arange(period, dtype=np.float64)

    def lines():
        positions = np.cumsum(rng.uniform(*spacing, size=period // spacing[0] + 2)) + seam
        profile = np.zeros(period)
        for centre in positions:
            half = rng.uniform(*width) / 2
            distance = np.abs((t - centre + period / 2) % period - period / 2)
            profile += rng.choice([-1.0, 1.0]) * (distance <= half)
        return profile

    background = rng.uniform(0.3, 0.6, size=3)
    tint = rng.uniform(0.6, 1.0, size=(2, 3))
    y = np.stack([np.ones(period), lines(), np.ones(period)])
    x = np.stack([np.broadcast_to(background[:, None], (3, period)),
                  0.4 * tint[0][:, None] * np.ones(period), 0.4 * tint[1][:, None] * lines()[None, :]])
    return _Factors.from_samples(y, x, TEXTURE_CUTOFF)


#: The texture kinds of :func:`layered_scene`: name -> maker ``(rng, period, seam) -> _Factors``.
TEXTURES = {
    "smooth": lambda rng, period, seam: _noise_texture(rng, period, 0.03, contrast=0.15),
    "noise": lambda rng, period, seam: _noise_texture(rng, period, 0.25, contrast=0.2),
    "fine": lambda rng, period, seam: _noise_texture(rng, period, 0.45, contrast=0.15),
    "grey": lambda rng, period, seam: _noise_texture(rng, period, 0.2, contrast=0.2, colour=False),
    "tiles": lambda rng, period, seam: _tiles_texture(rng, period, seam, int(rng.integers(6, 16))),
    "lines": _lines_texture,
    "stripes": lambda rng, period, seam: _grating_texture(rng, period, rng.uniform(0.05, 0.3), rng.uniform(0, np.pi)),
    "checker": lambda rng, period, seam: _checker_texture(rng, period, seam, int(rng.integers(3, 7))),
    "bricks": _brick_texture,
    "flat": lambda rng, period, seam: _constant_texture(period, rng.uniform(0.25, 0.65, size=3)),
}


def _box_mask(period, box):
    """Alpha of the rectangle ``box = (y0, y1, x0, x1)`` (soft, band-limited edges)."""
    y0, y1, x0, x1 = box
    return _Factors.from_samples(_indicator(period, [(y0, y1)]), _indicator(period, [(x0, x1)]), MASK_CUTOFF)


@dataclass
class Plane:
    """One fronto-parallel layer of a :class:`SyntheticScene`.

    Attributes
    ----------
    name : str
        Key of the layer in ``SyntheticScene.layers_disparity``.
    disparity : float
        Pixels per unit of view position (DESIGN section 2).
    colour : _Factors
        The band-limited colour texture.
    alpha : _Factors or None
        The band-limited coverage; ``None`` for an opaque plane.
    """

    name: str
    disparity: float
    colour: _Factors = field(repr=False)
    alpha: _Factors | None = field(default=None, repr=False)


def _composite_terms(n_layers, opaque):
    """Signed products of the front-to-back compositing sum, as ``(sign, colour layer, alpha layers)``."""
    terms = []
    for k in range(n_layers):
        front = range(k)
        own = () if opaque[k] else (k,)
        for size in range(k + 1):
            for subset in combinations(front, size):
                terms.append(((-1) ** size, k, own + subset))
    return terms


# -- the scene ----------------------------------------------------------------

class SyntheticScene:
    """A layered scene with its light field and ground truth.

    Parameters
    ----------
    layers : sequence of Plane
        The planes, front to back (the last one is usually opaque).
    n_views : int
        Views per side of the square camera grid (regular positions).
    size : int
        Width and height of every view in pixels.
    name : str
        A description, stored in the light field's metadata.

    Attributes
    ----------
    layers_disparity : dict of str to float
        Disparity of every layer: the useful focal planes.

    Notes
    -----
    See the module docstring for the rendering model and the definition of
    the dense-aperture reference.
    """

    def __init__(self, layers, n_views, size, name="synthetic scene"):
        self.layers = list(layers)
        if not self.layers:
            raise ParameterError("layers must hold at least one Plane")
        self.n_views = _validate.integer_at_least("n_views", n_views, 1)
        self.size = _validate.integer_at_least("size", size, 8)
        self.name = name
        self.layers_disparity = {layer.name: float(layer.disparity) for layer in self.layers}
        self._terms = _composite_terms(len(self.layers), [layer.alpha is None for layer in self.layers])

    # -- evaluation of the separable terms --------------------------------
    def _axis_factors(self, axis, positions, slope, origin=0.0, n=None):
        """Every compositing term's factors on ``axis`` for views at ``positions``, sampled at ``origin + p + slope*q``.

        ``p`` runs over ``n`` pixels (default ``size``). Returns (M, J, n)
        for "y", (M, J, n, C) for "x"; J is the number of separable terms
        (the signs are folded into the "y" factors).
        """
        positions = np.asarray(positions, np.float64)
        n = self.size if n is None else n
        colour, alpha = {}, {}
        for k, layer in enumerate(self.layers):
            shifts = (layer.disparity - slope) * positions - origin
            colour[k] = layer.colour.sample(axis, shifts, n)
            if layer.alpha is not None:
                alpha[k] = layer.alpha.sample(axis, shifts, n)
        blocks = []
        for sign, k, alphas in self._terms:
            block = colour[k] * sign if axis == "y" else colour[k]
            for j in alphas:
                # alphas have a single term (rank 1 masks): broadcast over the texture's terms
                block = block * alpha[j]
            blocks.append(block)
        return np.concatenate(blocks, axis=1)

    def _view_from_factors(self, y, x, dtype):
        """One view ``(n, n, C)`` from its row factors (J, n) and column factors (J, n, C)."""
        n, channels = x.shape[1], x.shape[2]
        image = y.T.astype(dtype) @ x.reshape(x.shape[0], -1).astype(dtype)
        return image.reshape(n, n, channels)

    def render_view(self, pos):
        """The view at aperture position ``pos = (y, x)`` (any real numbers).

        Parameters
        ----------
        pos : sequence of two floats
            ``(y, x)`` in units of the view grid step, centred on 0.

        Returns
        -------
        view : ndarray, shape (size, size, 3), float32
        """
        pos_y = _validate.finite_float("pos[0]", _item(pos, 0))
        pos_x = _validate.finite_float("pos[1]", _item(pos, 1))
        y = self._axis_factors("y", [pos_y], 0.0)[0]
        x = self._axis_factors("x", [pos_x], 0.0)[0]
        return self._view_from_factors(y, x, np.float64).astype(np.float32)

    @cached_property
    def lightfield(self):
        """The ``(U, U, size, size, 3)`` float32 light field on the regular grid (cached)."""
        positions = regular_positions(self.n_views, self.n_views)
        grid = positions[:, 0, 0]
        y = self._axis_factors("y", grid, 0.0)
        x = self._axis_factors("x", grid, 0.0)
        data = np.empty((self.n_views, self.n_views, self.size, self.size, 3), np.float32)
        for u in range(self.n_views):
            for v in range(self.n_views):
                data[u, v] = self._view_from_factors(y[u], x[v], np.float32)
        disparities = list(self.layers_disparity.values())
        meta = {
            "source": "synthetic",
            "scene": self.name,
            "disparity": self.disparity,
            "disparity_range": (min(disparities), max(disparities)),
            "layers_disparity": dict(self.layers_disparity),
        }
        return LightField(data, positions, meta)

    @cached_property
    def disparity(self):
        """``(size, size)`` float32 ground-truth disparity at the centre of the aperture.

        Each pixel takes the disparity of the front-most layer whose
        coverage there is at least 1/2.
        """
        out = np.full((self.size, self.size), np.float32(self.layers[-1].disparity))
        covered = np.zeros(out.shape, bool)
        for layer in self.layers:
            if layer.alpha is None:
                coverage = np.ones(out.shape)
            else:
                ay = layer.alpha.sample("y", [0.0], self.size)[0, 0]
                ax = layer.alpha.sample("x", [0.0], self.size)[0, 0, :, 0]
                coverage = np.outer(ay, ax)
            front = (coverage >= 0.5) & ~covered
            out[front] = layer.disparity
            covered |= front
        return out

    # -- dense-aperture reference -----------------------------------------
    def aperture_samples(self, slope, max_step=0.25):
        """Samples per view cell per axis so that no layer moves more than ``max_step`` px between them."""
        slope = _validate.finite_float("slope", slope)
        max_step = _validate.positive_float("max_step", max_step)
        spread = max(abs(layer.disparity - slope) for layer in self.layers)
        return max(1, math.ceil(spread / max_step))

    def reference(self, slope, samples_per_view=None, interpolation="exact", max_step=0.25, pixel_terms=None):
        """Refocus over the dense, continuous aperture: the alias-free ground truth.

        Parameters
        ----------
        slope : float
            Disparity in focus (pixels per unit of view position).
        samples_per_view : int, optional
            Aperture samples per view cell and axis; default
            :meth:`aperture_samples` ``(slope, max_step)``.
        interpolation : {"exact", "bilinear"}
            ``"exact"`` evaluates every view exactly at ``p + slope * q``;
            ``"bilinear"`` interpolates its pixels as
            :func:`napari_lfalias.refocus` does.
        max_step : float
            Largest motion (px) of any layer between adjacent aperture
            samples when ``samples_per_view`` is not given.
        pixel_terms : sequence of (float, ndarray, ndarray), optional
            Weigh every ray by a sum of separable terms ``(c, w_y, w_x)``:
            the ray of aperture position ``(a_y[m], a_x[l])`` into output
            pixel ``(y, x)`` by ``sum(c * w_y[m, y] * w_x[l, x])``, with
            ``a_y = a_x`` the :meth:`aperture_positions` (arrays ``(M, size)``).
            A camera's vignetting, which depends on where a ray lands
            (:func:`~napari_lfalias.synthetic.camera.vignetted_reference`).
            Only with ``interpolation="exact"``. Default: every ray alike.

        Returns
        -------
        image : ndarray, shape (size, size, 3), float32
            Weighted mean over the aperture samples (see the module notes).
        """
        slope = _validate.finite_float("slope", slope)
        _validate.one_of("interpolation", interpolation, ("exact", "bilinear"))
        if samples_per_view is None:
            samples_per_view = self.aperture_samples(slope, max_step)
        positions = self.aperture_positions(samples_per_view)
        if pixel_terms is None:
            coefficients, y_weights, x_weights = [1.0], [None], [None]
        elif interpolation != "exact":
            raise ParameterError('pixel_terms needs interpolation="exact"')
        else:
            coefficients, y_weights, x_weights = zip(*pixel_terms)
        num, den = 0.0, 0.0
        for c, (y_sum, y_weight), (x_sum, x_weight) in zip(
                coefficients, self._aperture_sum("y", positions, slope, interpolation, y_weights),
                self._aperture_sum("x", positions, slope, interpolation, x_weights)):
            num = num + c * self._view_from_factors(y_sum, x_sum, np.float64)
            den = den + c * np.outer(y_weight, x_weight)[..., None]
        out = np.zeros_like(num)
        np.divide(num, den, out=out, where=den > 0)
        return out.astype(np.float32)

    def aperture_positions(self, samples_per_view):
        """The :meth:`reference`'s aperture positions on one axis (units of the view step), ``(n_views *
        samples_per_view,)``: ``samples_per_view`` midpoints of every view's cell."""
        m = _validate.integer_at_least("samples_per_view", samples_per_view, 1)
        centres = regular_positions(self.n_views, 1)[:, 0, 0]
        return (centres[:, None] + (np.arange(m) + 0.5) / m - 0.5).ravel()

    def aperture_refocus(self, slope, aperture_y, aperture_x, transmission, origin=(0.0, 0.0), shape=None):
        """Refocus over any aperture: the transmission-weighted mean of exact views on a grid of aperture positions.

        Output pixel ``p`` (pixel ``(0, 0)`` at scene point ``origin``) is the
        mean over the aperture positions ``q = (aperture_y[m], aperture_x[l])``
        of the view at ``q`` evaluated exactly at ``origin + p + slope * q``,
        weighted by ``transmission[m, l]`` times the border validity of
        ``p + slope * q`` within ``shape`` (as in :meth:`reference`). A disc
        aperture, or views on any part of a grid, is a transmission that is
        zero elsewhere; :meth:`reference` is the uniform square one.

        Parameters
        ----------
        slope : float
            Disparity in focus.
        aperture_y, aperture_x : array_like, shapes (M,) and (L,)
            Aperture positions along each axis (units of the view grid step).
        transmission : array_like, shape (M, L)
            Non-negative weight of every aperture position.
        origin : tuple of float
            Scene ``(y, x)`` of output pixel ``(0, 0)`` (any real numbers).
        shape : tuple of int, optional
            Output ``(Y, X)``; default ``(size, size)``. The output must lie
            within the scene: ``origin + shape <= size``.

        Returns
        -------
        image : ndarray, shape (Y, X, 3), float32

        Examples
        --------
        >>> import numpy as np
        >>> scene = textured_plane(n_views=3, size=40, disparity=1.0)
        >>> q = np.array([-1.0, 0.0, 1.0])
        >>> square = scene.aperture_refocus(0.5, q, q, np.ones((3, 3)))
        >>> bool(np.allclose(square, scene.reference(0.5, samples_per_view=1), atol=1e-5))
        True
        """
        slope = _validate.finite_float("slope", slope)
        aperture_y = np.asarray(aperture_y, np.float64).ravel()
        aperture_x = np.asarray(aperture_x, np.float64).ravel()
        transmission = np.asarray(transmission, np.float64)
        if transmission.shape != (aperture_y.size, aperture_x.size) or not np.all(transmission >= 0):
            raise ParameterError(f"transmission must be non-negative, shape ({aperture_y.size}, {aperture_x.size}) "
                                 f"(aperture_y by aperture_x), got shape {transmission.shape}")
        out_y, out_x = (self.size, self.size) if shape is None else (int(v) for v in shape)
        oy, ox = (float(v) for v in origin)
        if min(oy, ox) < 0 or oy + out_y > self.size or ox + out_x > self.size:
            raise ParameterError(f"origin {origin} and shape {(out_y, out_x)} reach outside the scene "
                                 f"(0 to {self.size} px)")
        valid_x = sum(_bilinear_taps(out_x, slope * aperture_x)[1:])  # (L, X)
        x = np.concatenate([(self._axis_factors("x", aperture_x[cols], slope, ox, out_x)
                             * valid_x[cols, None, :, None]).reshape(len(aperture_x[cols]), -1)
                            for cols in _batches(len(aperture_x))])  # (L, J * X * C)
        num, den = 0.0, np.zeros((out_y, out_x))
        for rows in _batches(len(aperture_y)):
            valid_y = sum(_bilinear_taps(out_y, slope * aperture_y[rows])[1:])  # (M, Y)
            y = self._axis_factors("y", aperture_y[rows], slope, oy, out_y) * valid_y[:, None, :]
            mixed = transmission[rows] @ x  # (M, J * X * C)
            num += y.reshape(-1, out_y).T @ mixed.reshape(y.shape[0] * y.shape[1], -1)
            den += valid_y.T @ transmission[rows] @ valid_x
        num = np.reshape(num, (out_y, out_x, -1))
        out = np.zeros_like(num)
        np.divide(num, den[..., None], out=out, where=den[..., None] > 0)
        return out.astype(np.float32)

    def _aperture_sum(self, axis, positions, slope, interpolation, pixel_weights=(None,)):
        """Sums over ``positions`` of the validity-weighted factors on ``axis``, and of the validity: one
        ``(total, weight)`` pair per entry of ``pixel_weights`` (``(M, size)`` weights of every position's
        pixels, ``None``: 1; only with exact interpolation)."""
        n = self.size
        sums = [[None, np.zeros(n)] for _ in pixel_weights]
        for start in range(0, len(positions), _BATCH):
            batch = positions[start:start + _BATCH]
            shifts = slope * batch
            index, w0, w1 = _bilinear_taps(n, shifts)
            values = self._axis_factors(axis, batch, slope if interpolation == "exact" else 0.0)
            for pair, pixel_weight in zip(sums, pixel_weights):
                if interpolation != "exact":
                    part = (_gather(values, index, w0) + _gather(values, index + 1, w1)).sum(axis=0)
                    taps = w0 + w1
                else:
                    taps = w0 + w1 if pixel_weight is None else (w0 + w1) * pixel_weight[start:start + _BATCH]
                    part = (_expand(taps, values) * values).sum(axis=0)
                pair[0] = part if pair[0] is None else pair[0] + part
                pair[1] += taps.sum(axis=0)
        return [tuple(pair) for pair in sums]


def _item(pos, i):
    try:
        return pos[i]
    except (TypeError, IndexError):
        raise ParameterError(f"pos must be a (y, x) pair of numbers, got {pos!r}") from None


def _batches(count):
    """Slices of ``_BATCH`` aperture positions covering ``count``."""
    return [slice(start, start + _BATCH) for start in range(0, count, _BATCH)]


def _bilinear_taps(n, shifts):
    """Bilinear taps of ``j + shift`` on an axis of length ``n``: first tap's index and the two weights.

    The weights are zero for taps outside ``[0, n)``; their sum is the
    sample's validity (DESIGN section 2). Shapes (M, n).
    """
    shifts = np.asarray(shifts, np.float64)
    base = np.floor(shifts)
    frac = (shifts - base)[:, None]
    index = np.arange(n)[None, :] + base.astype(np.int64)[:, None]
    inside0 = (index >= 0) & (index < n)
    inside1 = (index + 1 >= 0) & (index + 1 < n)
    w0 = np.where(inside0, 1.0 - frac, 0.0)
    w1 = np.where(inside1, frac, 0.0)
    return index, w0, w1


def _expand(weights, values):
    """Broadcast per-(position, pixel) weights (M, n) against factors (M, J, n[, C])."""
    shape = weights.shape[:1] + (1,) + weights.shape[1:] + (1,) * (values.ndim - 3)
    return weights.reshape(shape)


def _gather(values, index, weights):
    """``values[m, :, index[m, j]] * weights[m, j]`` for factors (M, J, n[, C]); zero weight outside."""
    rows = np.arange(values.shape[0])[:, None]
    index = np.clip(index, 0, values.shape[2] - 1)
    picked = np.moveaxis(values, 1, -1)[rows, index]  # (M, n, [C,] J)
    picked = np.moveaxis(picked, -1, 1)
    return _expand(weights, values) * picked


# -- scenes ---------------------------------------------------------------------

def _period(size, n_views, disparities, margin=64):
    """Texture period and seam: the view plus the largest layer motion over the aperture, plus a margin.

    Nothing wraps into a view, and the seam (where a periodic texture
    starts over) lies in the middle of the part no view sees.
    """
    reach = max(abs(d) for d in disparities) * (n_views / 2 + 1)
    period = scipy.fft.next_fast_len(size + 2 * math.ceil(reach) + 2 * margin)
    return period, (size + period) // 2


def _textures_for(values):
    """:func:`layered_scene`'s ``textures_for`` as a non-empty list of finite floats, or a
    :class:`ParameterError` naming it."""
    try:
        values = list(values)
    except TypeError:
        raise ParameterError(f"textures_for must be a sequence of disparities, got {values!r}") from None
    if not values:
        raise ParameterError("textures_for must hold at least one disparity")
    return [_validate.finite_float(f"textures_for[{k}]", value) for k, value in enumerate(values)]


def _check(n_views, size, seed):
    n_views = _validate.integer_at_least("n_views", n_views, 1)
    size = _validate.integer_at_least("size", size, 8)
    if seed is not None:
        seed = _validate.integer_at_least("seed", seed, 0)
    return n_views, size, np.random.default_rng(seed)


def _centred_box(size, fraction, centre=(0.5, 0.5)):
    half = max(2, round(size * fraction / 2))
    cy, cx = round(size * centre[0]), round(size * centre[1])
    return (cy - half, cy + half, cx - half, cx + half)


def _tiles_before_wall(name, n_views, size, rng, wall, front, box_fraction, box_centre):
    """A soft-edged square of random tiles in front of an opaque wall.

    ``wall`` is ``(layer name, parameter name, disparity, texture(rng, period, seam))``,
    ``front`` is ``(layer name, parameter name, disparity)``.
    """
    wall_name, wall_param, wall_disparity, wall_texture = wall
    front_name, front_param, front_disparity = front
    wall_disparity = _validate.finite_float(wall_param, wall_disparity)
    front_disparity = _validate.finite_float(front_param, front_disparity)
    period, seam = _period(size, n_views, (wall_disparity, front_disparity))
    box = _centred_box(size, box_fraction, box_centre)
    back = Plane(wall_name, wall_disparity, wall_texture(rng, period, seam))
    tiles = Plane(front_name, front_disparity, _mosaic_texture(rng, period, box), _box_mask(period, box))
    return SyntheticScene([tiles, back], n_views, size, name=name)


def brick_room(n_views=8, size=512, seed=0, wall_disparity=-4.0, cube_disparity=4.0):
    """The brick room of Xiao et al. (2014), Figure 6: a brick wall behind a textured cube.

    The back wall is an opaque brick texture; the cube's front face is a
    square mosaic of random high-contrast tiles. Their disparities differ
    by 8 px per view step, so focusing on either leaves the other strongly
    angularly aliased. Both defaults are even, so the views' half-integer
    positions (even ``n_views``) shift either plane by whole pixels.

    Parameters
    ----------
    n_views : int
        Views per side (the paper uses 8).
    size : int
        View width and height in pixels (the paper uses 512).
    seed : int or None
        Seed of the brick colours and tiles; the same seed gives the same scene.
    wall_disparity, cube_disparity : float
        Disparities of the back wall and of the cube's front face.

    Returns
    -------
    SyntheticScene
        ``layers_disparity`` is ``{"cube_front": ..., "back_wall": ...}``.
    """
    n_views, size, rng = _check(n_views, size, seed)
    return _tiles_before_wall(
        "brick room", n_views, size, rng,
        wall=("back_wall", "wall_disparity", wall_disparity, _brick_texture),
        front=("cube_front", "cube_disparity", cube_disparity),
        box_fraction=0.4, box_centre=(0.55, 0.5),
    )


def textureless_plane(n_views=8, size=512, seed=0, wall_disparity=0.0, object_disparity=2.0,
                      wall_colour=(0.5, 0.5, 0.5)):
    """A large constant (textureless) wall with one small textured object in front.

    Useful to check that detection stays quiet on flat regions whatever
    the focus (a textureless plane cannot alias).

    Parameters
    ----------
    n_views, size, seed
        As in :func:`brick_room`.
    wall_disparity, object_disparity : float
        Disparities of the wall and of the object.
    wall_colour : sequence of 3 floats
        The wall's constant RGB colour, in [0, 1].

    Returns
    -------
    SyntheticScene
        ``layers_disparity`` is ``{"object": ..., "wall": ...}``.
    """
    n_views, size, rng = _check(n_views, size, seed)
    colour = np.asarray(wall_colour, np.float64)
    if colour.shape != (3,) or not np.all((colour >= 0) & (colour <= 1)):
        raise ParameterError(f"wall_colour must be three numbers in [0, 1], got {wall_colour!r}")
    return _tiles_before_wall(
        "textureless plane", n_views, size, rng,
        wall=("wall", "wall_disparity", wall_disparity, lambda rng, period, seam: _constant_texture(period, colour)),
        front=("object", "object_disparity", object_disparity),
        box_fraction=0.25, box_centre=(0.4, 0.6),
    )


def textured_plane(n_views=8, size=512, seed=0, disparity=1.0):
    """A single opaque brick-textured plane at one disparity (the simplest ground truth).

    Parameters
    ----------
    n_views, size, seed
        As in :func:`brick_room`.
    disparity : float
        The plane's disparity.

    Returns
    -------
    SyntheticScene
        ``layers_disparity`` is ``{"plane": disparity}``.
    """
    n_views, size, rng = _check(n_views, size, seed)
    disparity = _validate.finite_float("disparity", disparity)
    period, seam = _period(size, n_views, (disparity,))
    plane = Plane("plane", disparity, _brick_texture(rng, period, seam))
    return SyntheticScene([plane], n_views, size, name="textured plane")


def layered_scene(layers, n_views=8, size=256, seed=0, name="layered scene", *, textures_for=None):
    """A scene of fronto-parallel layers with textures of several kinds, front to back.

    Parameters
    ----------
    layers : sequence of (float, str, tuple or None)
        ``(disparity, texture, box)`` per layer, front to back: ``texture``
        one of :data:`TEXTURES` (smooth, noise, fine, grey, tiles, lines,
        stripes, checker, bricks, flat); ``box`` the layer's rectangle ``(y0, y1, x0, x1)`` as
        fractions of the view, or ``None`` for an opaque layer covering the
        view (the last layer usually is one).
    n_views, size, seed
        As in :func:`brick_room`.
    name : str
        Stored in the light field's metadata.
    textures_for : sequence of float, optional
        The layers' disparities the textures are drawn for (their period
        spans the view and the largest motion over the aperture; default:
        the layers' own). Given the disparities of another scene with the
        same ``seed``, the textures are that scene's: a checker wall moved
        by a whole period of its texture per view step then gives the same
        views (``benchmarks/periodic_ambiguity.py``).

    Returns
    -------
    SyntheticScene
        Layer ``k`` is named ``"layer{k}"`` in ``layers_disparity``.

    Examples
    --------
    >>> scene = layered_scene([(3.0, "checker", (0.3, 0.7, 0.2, 0.6)), (-1.0, "noise", None)], n_views=3, size=32)
    >>> scene.lightfield.shape, sorted(scene.layers_disparity.values())
    ((3, 3, 32, 32, 3), [-1.0, 3.0])
    """
    n_views, size, rng = _check(n_views, size, seed)
    specs = list(layers)
    if not specs:
        raise ParameterError("layers must hold at least one (disparity, texture, box) entry")
    disparities = []
    for k, spec in enumerate(specs):
        try:
            disparity, texture, box = spec
        except (TypeError, ValueError):
            raise ParameterError(f"layers[{k}] must be (disparity, texture, box), got {spec!r}") from None
        disparities.append(_validate.finite_float(f"layers[{k}] disparity", disparity))
        _validate.one_of(f"layers[{k}] texture", texture, tuple(TEXTURES))
    period, seam = _period(size, n_views, disparities if textures_for is None else _textures_for(textures_for))
    planes = []
    for k, (disparity, texture, box) in enumerate(specs):
        colour = TEXTURES[texture](rng, period, seam)
        alpha = None
        if box is not None:
            y0, y1, x0, x1 = (float(v) for v in box)
            if not (0 <= y0 < y1 <= 1 and 0 <= x0 < x1 <= 1):
                raise ParameterError(f"layers[{k}] box must be fractions 0 <= y0 < y1 <= 1, 0 <= x0 < x1 <= 1, "
                                     f"got {box!r}")
            alpha = _box_mask(period, (round(y0 * size), round(y1 * size), round(x0 * size), round(x1 * size)))
        planes.append(Plane(f"layer{k}", disparities[k], colour, alpha))
    return SyntheticScene(planes, n_views, size, name=name)
