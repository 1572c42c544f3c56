"""Forward model of a lenslet camera: a raw image and its white image from a known scene.

A :class:`~napari_lfalias.synthetic.scenes.SyntheticScene` is a sum of
separable, band-limited layers, so its radiance can be evaluated at any
spatial point and any aperture position. :func:`render_lenslet` lays an
ideal microlens grid (rectangular or hexagonal, any real pitch, any
rotation) over a sensor and, for every sensor pixel (point sampled at its
centre):

- finds the nearest microlens ``(i, j)`` and the pixel's offset ``q`` from
  its centre along the grid's axes (pixels; one view per pixel);
- takes the scene's radiance at that lens's spatial position and aperture
  position ``q`` (the convention of :mod:`napari_lfalias.decoders.lenslet`:
  the offset under the lens is the position on the aperture);
- multiplies it by the white level: a soft microlens disc, a mild fall-off
  inside it, and a radial vignetting of the main lens; optionally a dark
  strip on the left edge;
- adds a dark level with a fixed pattern, Gaussian noise, and samples the
  colour through a Bayer filter (or takes Rec. 709 luminance); optionally
  clips the capture at a saturation level.

The sensor is rendered in bands of rows, so Illum-size captures (7728 x
5368) fit in memory. The decoder's output pixel is ``row_step`` sensor
pixels high and ``column_step`` wide (the lens pitch on a rectangular
grid, ``row_step`` on a hexagonal one); ``scale`` scene pixels per output pixel
sets how much texture each lens sees. :meth:`LensletCapture.reference`
evaluates the scene exactly where a decoded light field says its samples
lie, which is the ground truth of a round trip.

>>> from napari_lfalias.synthetic import render_lenslet, textured_plane
>>> capture = render_lenslet(textured_plane(n_views=1, size=64), shape=(120, 100), pitch=9.6, rotation=0.3)
>>> capture.raw.shape, capture.grid.kind
((120, 100), 'rectangular')
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.fft

from .. import _validate
from ..errors import ParameterError
from ..lightfield import REC709, LightField

__all__ = ["LensletCapture", "render_lenslet", "SceneRadiance"]

#: Table oversampling of the 1-D scene factors (linear look-up error ~1e-4).
_OVERSAMPLE = 64
#: Pixels evaluated per batch (bounds memory).
_BATCH = 1 << 15


class SceneRadiance:
    """The radiance of a SyntheticScene at any (spatial, aperture) point, from fine factor tables.

    Each layer's 1-D factors (band-limited Fourier series) are tabulated at
    ``1 / 64`` pixel and looked up linearly; the layers are composited front
    to back (``sum_k a_k T_k prod_{j<k} (1 - a_j)``), as the scene does.

    Parameters
    ----------
    scene : SyntheticScene

    Examples
    --------
    >>> import numpy as np
    >>> from napari_lfalias.synthetic import textured_plane
    >>> scene = textured_plane(n_views=3, size=32, disparity=1.0)
    >>> radiance = SceneRadiance(scene)
    >>> y, x = np.mgrid[0:32, 0:32]
    >>> view = radiance(y, x, np.full(y.shape, -1.0), np.full(y.shape, 1.0)).reshape(32, 32, 3)
    >>> bool(np.abs(view - scene.lightfield.data[0, 2]).max() < 1e-3)
    True
    """

    def __init__(self, scene):
        self.scene = scene
        self._layers = []
        for layer in scene.layers:
            colour = (self._table(layer.colour.y, layer.colour.period),
                      self._table(layer.colour.x, layer.colour.period))
            alpha = None
            if layer.alpha is not None:
                alpha = (self._table(layer.alpha.y, layer.alpha.period),
                         self._table(layer.alpha.x, layer.alpha.period))
            self._layers.append((float(layer.disparity), colour, alpha))

    @staticmethod
    def _table(spectrum, period):
        """Factor values every 1/64 pixel over one period, sample axis first: (L, K) or (L, K, C)."""
        fine = scipy.fft.irfft(spectrum, n=period * _OVERSAMPLE, axis=-1) * _OVERSAMPLE
        return np.ascontiguousarray(np.moveaxis(fine, -1, 0)), period

    @staticmethod
    def _look_up(table, t):
        """Factors at real coordinates ``t`` (N,): (N, K) or (N, K, C)."""
        fine, period = table
        size = fine.shape[0]
        pos = np.mod(t, period) * _OVERSAMPLE
        i0 = np.floor(pos).astype(np.int64)
        frac = (pos - i0).reshape((-1,) + (1,) * (fine.ndim - 1))
        i0 %= size
        return fine[i0] * (1.0 - frac) + fine[(i0 + 1) % size] * frac

    def _factor_product(self, pair, ty, tx):
        rows = self._look_up(pair[0], ty)  # (N, K)
        cols = self._look_up(pair[1], tx)  # (N, K, C)
        return np.einsum("nk,nkc->nc", rows, cols)

    def __call__(self, y, x, qy, qx):
        """Radiance ``(N, 3)`` at scene pixels ``(y, x)`` seen from aperture positions ``(qy, qx)`` (all (N,))."""
        y, x, qy, qx = (np.asarray(a, np.float64).ravel() for a in (y, x, qy, qx))
        out = np.empty((y.size, 3))
        for start in range(0, y.size, _BATCH):
            part = slice(start, start + _BATCH)
            total = np.zeros((len(y[part]), 3))
            transmit = np.ones((len(y[part]), 1))
            for disparity, colour, alpha in self._layers:
                ty = y[part] - disparity * qy[part]
                tx = x[part] - disparity * qx[part]
                texture = self._factor_product(colour, ty, tx)
                cover = np.ones_like(transmit) if alpha is None else self._factor_product(alpha, ty, tx)
                total += transmit * cover * texture
                transmit = transmit * (1.0 - cover)
            out[part] = total
        return out


@dataclass
class LensletCapture:
    """A rendered lenslet capture and its ground truth.

    Attributes
    ----------
    raw, white, dark : ndarray, shape (H, W), float32
        Capture, white image and dark frame (dark level included in all three).
    grid : GridModel
        The true microlens grid.
    bayer : str or None
        Bayer layout of the mosaics, or ``None`` for grey (luminance) images.
    scale : float
        Scene pixels per decoded output pixel.
    layers_disparity : dict of str to float
        Disparity of every scene layer in decoded pixels per view step.
    exposure : float
        Gain on the scene's radiance (the reference includes it).
    """

    raw: np.ndarray
    white: np.ndarray
    dark: np.ndarray
    grid: object
    bayer: str | None
    scene: object = field(repr=False)
    scale: float = 0.5
    scene_origin: tuple = (0.0, 0.0)
    layers_disparity: dict = field(default_factory=dict)
    exposure: float = 1.0

    def _radiance(self):
        if self.scene is None:
            raise ParameterError("a capture of a uniform white scene (scene=None) has no scene to compare with")
        if getattr(self, "_radiance_cache", None) is None:
            self._radiance_cache = SceneRadiance(self.scene)
        return self._radiance_cache

    def _scene_points(self, sensor_points):
        """Scene (y, x) of sensor points that are lens centres (nearest true lens, continuous row coordinate)."""
        grid = self.grid
        e_y, e_x = grid.axes
        rel = sensor_points - np.asarray(grid.offset)
        rows = rel @ e_y / grid.row_step
        along = rel @ e_x / grid.column_step  # output pixels along the row
        cy, cx = self.scene_origin
        return rows * self.scale + cy, along * self.scale + cx

    def reference(self, lf):
        """The exact scene where the samples of a decoded light field ``lf`` lie.

        Uses the grid in ``lf.meta["grid"]`` (and ``lens_window``) to place
        every output pixel on the sensor, and ``lf.positions`` (times
        ``view_step_px``) as the aperture positions.

        Returns
        -------
        LightField
            Same shape as ``lf``; one channel (luminance) for grey captures.
        """
        model = lf.meta["grid"]
        if model.transposed or self.grid.transposed:
            raise ParameterError("reference() needs grids in the image's own orientation (transposed=False)")
        y0, y1, x0, x1 = lf.meta.get("lens_window") or (0, lf.image_shape[0], 0, lf.image_shape[1])
        n_y, n_x = y1 - y0, x1 - x0
        rows, cols = np.meshgrid(np.arange(y0, y1), np.arange(x0, x1), indexing="ij")
        centres = model.pixel_centres(rows, cols)
        sy, sx = self._scene_points(centres.reshape(-1, 2))
        radiance = self._radiance()
        positions = np.asarray(lf.positions) * float(lf.meta.get("view_step_px", 1.0))
        n_u, n_v = lf.grid_shape
        grey = self.bayer is None
        data = np.empty((n_u, n_v, n_y, n_x, 1 if grey else 3), np.float32)
        for u in range(n_u):
            for v in range(n_v):
                qy, qx = positions[u, v]
                values = self.exposure * radiance(sy, sx, np.full(sy.shape, qy), np.full(sy.shape, qx))
                values = values @ REC709[:, None] if grey else values
                view = values.reshape(n_y, n_x, -1)
                data[u, v] = view
        return LightField(data, lf.positions, {"source": "lenslet forward model reference"})

    def write(self, folder, prefix="synthetic"):
        """Write raw, white and dark frames as 16-bit TIFFs; returns ``{"raw", "white", "dark"}`` paths."""
        import tifffile

        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        paths = {}
        for key in ("raw", "white", "dark"):
            path = folder / f"{prefix}_{key}.tif"
            image = np.clip(np.round(getattr(self, key) * 65535.0), 0, 65535).astype(np.uint16)
            tifffile.imwrite(path, image)
            paths[key] = path
        return paths


def _lens_of_pixels(grid, points):
    """Nearest lens (row, column) of every point, and the point's offset from its centre (model axes)."""
    e_y, e_x = grid.axes
    rel = points - np.asarray(grid.offset)
    across = rel @ e_y / grid.row_step
    along = rel @ e_x / grid.pitch
    best_row = best_col = best_dist = None
    for candidate in (np.floor(across), np.floor(across) + 1.0):
        if grid.is_hexagonal:
            shift = (np.mod(candidate, 2) == grid.hex_shift_row) * 0.5
        else:
            shift = 0.0
        col = np.round(along - shift)
        dy = (across - candidate) * grid.row_step
        dx = (along - shift - col) * grid.pitch
        dist = dy * dy + dx * dx
        if best_dist is None:
            best_row, best_col, best_dist, best_q = candidate, col, dist, (dy, dx)
        else:
            better = dist < best_dist
            best_row = np.where(better, candidate, best_row)
            best_col = np.where(better, col, best_col)
            best_q = (np.where(better, dy, best_q[0]), np.where(better, dx, best_q[1]))
            best_dist = np.where(better, dist, best_dist)
    return best_row, best_col, best_q


def _disc(radius, rim, edge=1.5):
    """White level under a microlens: disc of radius ``rim`` with a soft edge ``edge`` px wide, mild inner fall-off."""
    edge_frac = np.clip((rim + 0.5 * edge - radius) / edge, 0.0, 1.0)
    soft = 0.5 - 0.5 * np.cos(np.pi * edge_frac)
    return soft * (1.0 - 0.15 * np.clip(radius / rim, 0.0, 1.0) ** 2)


def _true_grid(shape, pitch, rotation, kind, offset, row_spacing=None, hex_shift_row=1):
    from ..decoders.grid import GridModel

    kind = _validate.one_of("kind", kind, ("rectangular", "hexagonal"))
    pitch = _validate.finite_float("pitch", pitch)
    if not 4.0 <= pitch <= min(shape) / 4:
        raise ParameterError(
            f"pitch must be between 4 and a quarter of the sensor ({min(shape) / 4:g}) px, got {pitch}"
        )
    rotation = _validate.finite_float("rotation", rotation)
    if abs(rotation) > 10:
        raise ParameterError(f"rotation must be within +-10 degrees, got {rotation}")
    hex_shift_row = _validate.one_of("hex_shift_row", hex_shift_row, (0, 1))
    regular = pitch * (math.sqrt(3) / 2 if kind == "hexagonal" else 1.0)
    row_step = regular if row_spacing is None else _validate.finite_float("row_spacing", row_spacing)
    if not 0.8 * regular <= row_step <= 1.25 * regular:
        raise ParameterError(f"row_spacing must be within 0.8 to 1.25 times {regular:g} px, got {row_step}")
    n_rows = int(math.ceil(shape[0] / row_step)) + 6
    n_cols = int(math.ceil(shape[1] / pitch)) + 6
    if offset is None:
        offset = (0.37 * row_step - 2 * row_step, 0.61 * pitch - 2 * pitch)
    return GridModel(kind, pitch, rotation, tuple(offset), n_rows, n_cols, tuple(shape), hex_shift_row,
                     row_spacing=row_step)


def _bands(height, width):
    """Row ranges covering the sensor in bands of about ``_BATCH * 16`` pixels."""
    rows = max(1, (_BATCH * 16) // width)
    return [(r0, min(r0 + rows, height)) for r0 in range(0, height, rows)]


def _band_pixels(r0, r1, width):
    return np.stack(np.meshgrid(np.arange(r0, r1, dtype=np.float64), np.arange(width, dtype=np.float64),
                                indexing="ij"), axis=-1).reshape(-1, 2)


def _decoded_position(grid, rows, cols):
    """Decoded-pixel (y, x) of lenses ``(rows, cols)``: the row, and the position along it in decoded pixels."""
    shifts = (np.mod(rows, 2) == grid.hex_shift_row) * 0.5 if grid.is_hexagonal else 0.0
    return rows, (cols + shifts) * grid.pitch / grid.column_step


def _white_level(grid, pixels, q, shape, fill, edge, vignetting, dark_border):
    """White level of sensor pixels at lens offsets ``q``: soft disc, radial vignetting, dark strip."""
    height, width = shape
    level = _disc(np.hypot(*q), fill * grid.pitch / 2.0, edge)
    corner = np.hypot((pixels[:, 0] - (height - 1) / 2) / (height / 2), (pixels[:, 1] - (width - 1) / 2) / (width / 2))
    level = level * (1.0 - vignetting * (corner / math.sqrt(2.0)) ** 2)
    if dark_border:
        level = level * (pixels[:, 1] >= dark_border)
    return 0.85 * level


def _scene_origin(scene, grid, bands, width, scale):
    """Scene (y, x) of decoded pixel (0, 0) that centres the scene on the decoded extent; checks it fits."""
    low, high = np.full(2, np.inf), np.full(2, -np.inf)
    for r0, r1 in bands:
        rows, cols, _ = _lens_of_pixels(grid, _band_pixels(r0, r1, width))
        out = np.stack(_decoded_position(grid, rows, cols))
        low, high = np.minimum(low, out.min(axis=1)), np.maximum(high, out.max(axis=1))
    centre = (low + high) / 2.0
    origin = (scene.size / 2.0 - centre[0] * scale, scene.size / 2.0 - centre[1] * scale)
    reach = max(abs(d) for d in scene.layers_disparity.values()) * grid.pitch / 2.0
    first, last = low * scale + origin, high * scale + origin
    if first.min() - reach < 0 or last.max() + reach >= scene.size:
        need = int(math.ceil(max(high - low) * scale + 2 * reach + 2))
        raise ParameterError(f"the scene is too small for this sensor and scale: size must be at least {need}")
    return origin


class _Streams:
    """Independent noise streams (dark pattern, capture noise, white noise), drawn in raster order."""

    def __init__(self, seed):
        self.dark, self.raw, self.white = (np.random.default_rng([int(seed), k]) for k in range(3))


def render_lenslet(scene, shape=(256, 256), pitch=10.3, rotation=0.25, kind="rectangular", *, scale=0.5,
                   vignetting=0.35, fill=0.96, bayer=None, noise=0.0, dark_level=0.02, dark_border=0,
                   offset=None, seed=0, edge=1.5, row_spacing=None, hex_shift_row=1, exposure=1.0,
                   saturation=None):
    """Render the lenslet image and white image of a synthetic scene.

    Parameters
    ----------
    scene : SyntheticScene or None
        The scene (its ``size`` must cover the sensor's lenses times
        ``scale``; a ParameterError says how large); ``None``: a uniform
        white scene, whose capture is a white image (fast: no scene to
        evaluate; for calibration studies).
    shape : tuple of int
        Sensor ``(height, width)`` in pixels.
    pitch : float
        Microlens pitch in pixels (any real number >= 4).
    rotation : float
        Rotation of the lens rows in degrees (positive towards +y).
    kind : {"rectangular", "hexagonal"}
        Microlens lattice.
    scale : float
        Scene pixels per decoded pixel (0.5: the scene's texture, cut off
        at 0.3 cycles per scene pixel, reaches 0.15 cycles per lens).
    vignetting : float
        Fraction of light lost in the sensor's corners (radial, quadratic).
    fill : float
        Microlens disc diameter as a fraction of the pitch.
    bayer : str, optional
        Sample colour through this Bayer layout; default grey (Rec. 709).
    noise : float
        Standard deviation of Gaussian noise on the capture (a quarter of
        it on the white image), relative to the white level 1.
    dark_level : float
        Dark level added to every frame (plus a fixed pattern of 10 % of it).
    dark_border : int
        Width of an unlit strip on the left edge, in pixels.
    offset : tuple of float, optional
        Lattice origin ``(y, x)``; default a non-integer position.
    seed : int
        Seed of the noise and of the dark pattern.
    edge : float
        Width in pixels over which a microlens disc fades from lit to dark.
    row_spacing : float, optional
        Distance between lens rows (default: the regular lattice's).
    hex_shift_row : {0, 1}
        Parity of the lens rows shifted by half a pitch (hexagonal).
    exposure : float
        Gain on the scene's radiance (above 1/0.85, bright parts pass the
        white image's level).
    saturation : float, optional
        Sensor clipping level: capture values above it (dark level
        included) are clipped, as a real sensor's full well clips them.

    Returns
    -------
    LensletCapture

    Raises
    ------
    ParameterError
        For out-of-range parameters, or a scene too small for the sensor.

    Examples
    --------
    >>> from napari_lfalias.synthetic import textured_plane
    >>> capture = render_lenslet(textured_plane(n_views=1, size=96), shape=(200, 180), pitch=11.4,
    ...                          kind="hexagonal", bayer="RGGB", noise=0.002)
    >>> capture.raw.shape, capture.bayer, round(capture.grid.row_step, 3)
    ((200, 180), 'RGGB', 9.873)
    """
    shape = tuple(_validate.integer_at_least("shape", int(v), 32) for v in shape)
    scale = _validate.positive_float("scale", scale)
    fill = _validate.in_open_interval("fill", fill, 0.2, 1.01)
    edge = _validate.positive_float("edge", edge)
    exposure = _validate.positive_float("exposure", exposure)
    saturation = None if saturation is None else _validate.positive_float("saturation", saturation)
    grid = _true_grid(shape, pitch, rotation, kind, offset, row_spacing, hex_shift_row)
    from ..decoders.bayer import bayer_pattern, channel_index

    bayer = bayer_pattern(bayer)
    height, width = shape
    bands = _bands(height, width)
    origin, evaluator = (0.0, 0.0), None
    if scene is not None:
        origin = _scene_origin(scene, grid, bands, width, scale)
        evaluator = SceneRadiance(scene)
    gains = np.array([0.8, 1.0, 0.7])
    streams = _Streams(seed)
    raw, white, dark = (np.empty(shape, np.float32) for _ in range(3))
    for r0, r1 in bands:
        pixels = _band_pixels(r0, r1, width)
        rows, cols, q = _lens_of_pixels(grid, pixels)
        out_y, out_x = _decoded_position(grid, rows, cols)
        if evaluator is None:
            radiance = np.full((len(pixels), 3), exposure)
        else:
            radiance = exposure * evaluator(out_y * scale + origin[0], out_x * scale + origin[1], *q)  # (N, 3)
        level = _white_level(grid, pixels, q, shape, fill, edge, vignetting, dark_border)
        if bayer is None:
            signal = (radiance @ REC709.astype(np.float64)) * level
            white_level = level
        else:
            channel = channel_index(bayer, shape)[r0:r1].ravel()
            signal = radiance[np.arange(len(channel)), channel] * level * gains[channel]
            white_level = level * gains[channel]
        count = len(pixels)
        dark_band = dark_level * (1.0 + 0.1 * streams.dark.standard_normal(count))
        raw_band = signal + dark_band + noise * streams.raw.standard_normal(count)
        if saturation is not None:
            raw_band = np.minimum(raw_band, saturation)
        raw[r0:r1] = raw_band.reshape(r1 - r0, width)
        white[r0:r1] = (white_level + dark_band + 0.25 * noise * streams.white.standard_normal(count)).reshape(
            r1 - r0, width)
        dark[r0:r1] = dark_band.reshape(r1 - r0, width)
    disparity = {} if scene is None else {name: d / scale for name, d in scene.layers_disparity.items()}
    capture = LensletCapture(raw, white, dark, grid, bayer, scene, scale, origin, disparity, exposure)
    capture._radiance_cache = evaluator
    return capture
