"""Fit a :class:`~.grid.GridModel` to a white image of the microlens array.

The approach follows Dansereau's LFToolbox (``LFBuildLensletGridModel``:
locate lens centres as peaks of the filtered white image, fit an ideal
lattice with separate horizontal and vertical spacings), without its
hand-set parameters and to sub-pixel accuracy:

1. **Rough lattice from the spectrum.** The power spectrum of the
   (windowed) white image has its strongest peaks on the reciprocal
   lattice. The lowest-frequency strong peak is a first-order one; the
   power at that peak turned by 60 and by 90 degrees says whether the grid
   is hexagonal or rectangular. No approximate pitch is needed, and a
   picture with no grid (noise, a flat field) has no peak standing out:
   a :class:`~napari_lfalias.errors.CalibrationError`.
2. **Rough lattice from the peaks.** Every lit lens is a local maximum of
   the white image divided by its envelope (:func:`~.lens_centres.find_peaks`,
   at about 7 pixels per pitch: a large sensor is reduced first). Lattice
   indices are assigned near the image centre first and the lattice fitted
   region by region, doubling until it covers the image
   (:func:`~.lattice_fit.grow_lattice`). A hexagonal grid is fitted with
   its rows along the x axis and along the y axis (on the transposed
   image); the rows nearer x are kept unless the other orientation fits
   clearly better. The half-pitch shift of alternate rows, and which rows
   carry it, come out of the lattice fit itself (its second basis vector
   is half a pitch along the row), so both parities need no guess.
3. **Sub-pixel centres, then the final fit.** With the rough lattice known,
   every lens (an even subset of a large sensor's, about 20 000) is
   measured inside its own cell, the vignetting's tilt divided out
   (:func:`~.lens_centres.cell_centroids`), and the lattice is fitted again
   by robust Gauss-Newton least squares (Tukey biweights) with five
   parameters: offset, pitch, rotation and the distance between rows
   (:mod:`.lattice_fit`). Twice: the second pass measures the cells of the
   refined grid. Where the optics bend the grid measurably (real relay
   lenses), a cubic displacement of the centres is fitted to the residuals
   as well.

Measured on synthetic white images with known grids (pitch 8-30 px,
rotation +-2 deg, vignetting, Bayer, noise): lens centres to a few
thousandths of a pixel and pitch to a few thousandths of a percent
(``benchmarks/results/lenslet.md``).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import CalibrationError, DecodeError, ParameterError
from .grid import GridModel, distortion_terms
from .lattice_fit import Lattice, fit_lattice, grow_lattice
from .lens_centres import DARK_FRACTION, Brightness, cell_centroids, find_peaks, least_squares
from .sensor import as_sensor_image

__all__ = ["calibrate", "prepare_white"]

#: Largest crop used for the spectrum (pixels per side).
_FFT_SIDE = 1024
#: A lattice peak must exceed the median power of its band this many times.
_PEAK_CONTRAST = 100.0
#: Fewest lens centres a fit needs.
_MIN_LENSES = 12
#: Lenses measured to sub-pixel precision on a large sensor (an even subset; the fit needs no more).
_MEASURED_LENSES = 20000
#: Rough peaks used to index the lattice on a large sensor (an even subset).
_ROUGH_PEAKS = 20000
_SQRT3_2 = math.sqrt(3.0) / 2.0


def _rotation_matrix(degrees):
    """Matrix turning a (y, x) vector by ``degrees`` towards +y."""
    a = math.radians(degrees)
    return np.array([[math.cos(a), math.sin(a)], [-math.sin(a), math.cos(a)]])


def prepare_white(white, dark=None, bayer=None):
    """The white image as one float32 ``(H, W)`` array, dark frame subtracted.

    Colour images are averaged over their channels; a Bayer mosaic is kept
    as it is (its 2-pixel pattern is filtered out where the image is
    looked at, see ``mosaic``), so a large sensor is not filtered whole.

    Returns
    -------
    data : ndarray (H, W) float32
        May be the caller's own array (never written to).
    image : SensorImage
        The white image as read.
    mosaic : bool
        True for a Bayer mosaic.

    Raises
    ------
    WhiteImageError
        If the white image holds NaN or infinite pixels.
    """
    from .devignetting import check_finite

    image = as_sensor_image(white, bayer=bayer, name="white")
    check_finite(image, "white")
    data = np.asarray(image.data, np.float32)
    if dark is not None:
        dark_image = as_sensor_image(dark, bayer=None, name="dark")
        if dark_image.shape != image.shape:
            raise DecodeError(
                f"{dark_image.label()}: the dark frame is {dark_image.shape[1]} x {dark_image.shape[0]} px but the "
                f"white image {image.label()} is {image.shape[1]} x {image.shape[0]}; use frames of one sensor size"
            )
        check_finite(dark_image, "dark")
        dark_data = np.asarray(dark_image.data, np.float32)
        if dark_data.ndim != data.ndim:
            dark_data = dark_data.mean(axis=-1) if dark_data.ndim == 3 else dark_data[..., None]
        data = data - dark_data
    if data.ndim == 3:
        data = data.mean(axis=-1)
    return np.ascontiguousarray(data, np.float32), image, image.bayer is not None and np.ndim(image.data) == 2


# -- 1. rough lattice from the spectrum ----------------------------------------------------


def _power_spectrum(grey, mosaic=False):
    """Centred power spectrum of a central crop (Hann window), and the crop's shape."""
    from .bayer import cfa_grey

    height, width = grey.shape
    h, w = min(height, _FFT_SIDE), min(width, _FFT_SIDE)
    y0, x0 = (height - h) // 2, (width - w) // 2
    crop = grey[y0:y0 + h, x0:x0 + w]
    crop = (cfa_grey(crop) if mosaic else crop).astype(np.float64)
    crop = crop - crop.mean()
    window = np.outer(np.hanning(h), np.hanning(w))
    spectrum = np.fft.fftshift(np.abs(np.fft.fft2(crop * window)) ** 2)
    return spectrum, (h, w)


def _frequencies(shape):
    h, w = shape
    ky = (np.arange(h) - h // 2) / h
    kx = (np.arange(w) - w // 2) / w
    return ky[:, None], kx[None, :]


def _refine_peak(spectrum, row, col, shape):
    """Sub-bin frequency (ky, kx) of a spectral peak: parabola through the log power on each axis."""
    h, w = shape
    log = np.log(spectrum[row - 1:row + 2, col - 1:col + 2] + 1e-30)

    def vertex(left, mid, right):
        denom = left - 2 * mid + right
        return 0.0 if denom >= 0 else float(np.clip(0.5 * (left - right) / denom, -0.5, 0.5))

    dy = vertex(log[0, 1], log[1, 1], log[2, 1])
    dx = vertex(log[1, 0], log[1, 1], log[1, 2])
    return np.array([(row + dy - h // 2) / h, (col + dx - w // 2) / w])


def _nearest_peak(spectrum, k, shape):
    """Bin (row, col) of the largest power within one bin of frequency ``k``, and that power."""
    h, w = shape
    row = int(round(k[0] * h)) + h // 2
    col = int(round(k[1] * w)) + w // 2
    if not (2 <= row < h - 2 and 2 <= col < w - 2):
        return None, 0.0
    patch = spectrum[row - 1:row + 2, col - 1:col + 2]
    dr, dc = np.unravel_index(int(np.argmax(patch)), patch.shape)
    return (row + dr - 1, col + dc - 1), float(patch.max())


def _spectral_lattice(grey, kind, pitch_hint, label, mosaic=False):
    """Reciprocal first-order peak ``k1`` and the grid kind, from the power spectrum."""
    from scipy.ndimage import maximum_filter

    spectrum, shape = _power_spectrum(grey, mosaic)
    h, w = shape
    ky, kx = _frequencies(shape)
    radius = np.hypot(ky, kx)
    if pitch_hint is None:
        band = (radius >= 4.0 / min(h, w)) & (radius <= 0.4)
    else:
        band = (radius >= 0.75 / pitch_hint) & (radius <= 1.45 / pitch_hint)
    band[:2, :] = band[-2:, :] = False
    band[:, :2] = band[:, -2:] = False
    if not band.any():
        raise CalibrationError(
            f"{label}: the image ({grey.shape[1]} x {grey.shape[0]} px) is too small to hold a lens grid"
        )
    masked = np.where(band, spectrum, 0.0)
    peaks = (masked == maximum_filter(masked, size=3)) & band & (masked > 0)
    strongest = float(masked.max())
    background = float(np.median(spectrum[band]))
    if strongest <= _PEAK_CONTRAST * max(background, 1e-30):
        raise CalibrationError(
            f"{label}: no microlens grid found: no periodic pattern stands out of the image's spectrum "
            f"(strongest peak {strongest / max(background, 1e-30):.0f} x the background, "
            f"needs {_PEAK_CONTRAST:.0f} x). "
            "Use a white image of the lenslet array (a diffuser or flat fluorescent slide)"
        )
    rows, cols = np.nonzero(peaks & (masked >= 0.2 * strongest))
    order = np.argsort(radius[rows, cols])
    row, col = int(rows[order[0]]), int(cols[order[0]])
    k1 = _refine_peak(spectrum, row, col, shape)
    power1 = float(spectrum[row, col])
    ratios = {}
    for angle in (60.0, 90.0):
        found = [_nearest_peak(spectrum, _rotation_matrix(sign * angle) @ k1, shape)[1] for sign in (1, -1)]
        ratios[angle] = min(found) / power1
    detected = "hexagonal" if ratios[60.0] > ratios[90.0] else "rectangular"
    if max(ratios.values()) < 0.05:
        raise CalibrationError(
            f"{label}: no microlens grid found: the image has a periodic pattern of {1 / np.hypot(*k1):.2f} px, "
            "but not in two directions (stripes, not a lens grid)"
        )
    return k1, (detected if kind == "auto" else kind)


def _orientations(k1, kind):
    """Starting lattices ``[(row_vector, transposed), ...]`` from the first-order reciprocal vector.

    The row vector is the lattice direction nearest the x axis. A
    hexagonal grid is also tried with its rows along the y axis (modelled
    on the transposed image); a rectangular grid's rows along y are its
    columns, so one orientation covers it.
    """
    turn = 60.0 if kind == "hexagonal" else 90.0
    k2 = _rotation_matrix(turn) @ k1
    basis = np.linalg.inv(np.array([k1, k2]))  # columns a1, a2 with k_i . a_j = delta_ij
    a1 = basis[:, 0]
    candidates = [_rotation_matrix(turn * n) @ a1 for n in range(int(round(360 / turn)))]
    found = []
    for transposed in ((False, True) if kind == "hexagonal" else (False,)):
        vectors = [v[::-1] for v in candidates] if transposed else candidates
        angles = [abs(math.degrees(math.atan2(v[0], v[1]))) for v in vectors]
        found.append((np.array(vectors[int(np.argmin(angles))]), transposed))
    return found


# -- 2. the lattice: rough from peaks, then refined on each lens' own cell -----------------------


def _lattice_of(grid):
    """The GridModel's ideal lattice (origin on lens (0, 0)) and ``(along, across)`` of its lenses, row-major."""
    e_y, e_x = grid.axes
    shifts = grid.row_shifts().astype(np.float64) * 0.5
    first = shifts[0]
    origin = np.asarray(grid.offset) + first * grid.pitch * e_x
    lattice = Lattice(tuple(origin), tuple(grid.pitch * e_x), grid.row_step / grid.pitch, grid.is_hexagonal)
    along = (np.arange(grid.n_cols)[None, :] + shifts[:, None] - first) * np.ones((grid.n_rows, 1))
    across = np.arange(grid.n_rows, dtype=np.float64)[:, None] * np.ones((1, grid.n_cols))
    return lattice, along.ravel(), across.ravel()


def _grid_from_lattice(lattice, model_shape, image_shape, transposed, fit, distortion=()):
    """Re-base a lattice (origin on a lens of an unshifted row) on the top-left lens covering the image."""
    kind = "hexagonal" if lattice.hexagonal else "rectangular"
    pitch, row_step = lattice.pitch, lattice.row_step
    origin = np.asarray(lattice.origin)
    probe = GridModel(kind, pitch, lattice.rotation, tuple(origin), 1, 1, image_shape, 0, transposed,
                      row_spacing=row_step)
    e_y, e_x = probe.axes
    height, width = model_shape
    corners = np.array([[-0.5, -0.5], [-0.5, width - 0.5], [height - 0.5, -0.5], [height - 0.5, width - 0.5]])
    across = (corners - origin) @ e_y / row_step
    along = (corners - origin) @ e_x / pitch
    rows = np.arange(math.floor(across.min()) - 1, math.ceil(across.max()) + 2)
    cols = np.arange(math.floor(along.min()) - 2, math.ceil(along.max()) + 2)
    # lattice row n holds column j at (j + (n % 2) / 2) pitches along the row
    shift = (rows % 2) * 0.5 if lattice.hexagonal else np.zeros(len(rows))
    centres = (origin + (rows[:, None, None] * row_step) * e_y
               + ((cols[None, :] + shift[:, None])[..., None] * pitch) * e_x)
    inside = ((centres[..., 0] >= -0.5) & (centres[..., 0] <= height - 0.5)
              & (centres[..., 1] >= -0.5) & (centres[..., 1] <= width - 0.5))
    if not inside.any():
        raise CalibrationError("the fitted lens grid does not cover the image")
    row_hits, col_hits = np.nonzero(inside)
    i0, i1 = rows[row_hits.min()], rows[row_hits.max()]
    j0, j1 = cols[col_hits.min()], cols[col_hits.max()]
    offset = origin + i0 * row_step * e_y + j0 * pitch * e_x
    shift_row = int((i0 + 1) % 2) if lattice.hexagonal else 0
    return GridModel(kind, pitch, lattice.rotation, tuple(offset), int(i1 - i0 + 1), int(j1 - j0 + 1),
                     image_shape, shift_row, transposed, distortion, fit, row_spacing=row_step)


def _rough_fit(peaks, row_vec, kind, transposed, shape):
    """Lattice indices and a robust fit of the rough peaks, in model coordinates."""
    points = peaks[:, ::-1] if transposed else peaks
    model_shape = shape[::-1] if transposed else shape
    ratio = _SQRT3_2 if kind == "hexagonal" else 1.0
    start = Lattice((0.0, 0.0), tuple(row_vec), ratio, kind == "hexagonal")
    lattice, _, _, weights, residual = grow_lattice(points, start, np.asarray(model_shape) / 2.0, _MIN_LENSES)
    kept = weights > 0
    rms = float(np.sqrt(np.mean(np.sum(residual[kept] ** 2, axis=1)))) if kept.any() else np.inf
    return lattice, int(kept.sum()), rms


def _choose_orientation(fits):
    """The fit with rows nearest the x axis, unless another fits clearly better (RMS < 0.8 x)."""
    usable = [f for f in fits if f[1][1] >= max(g[1][1] for g in fits) * 0.9]
    usable.sort(key=lambda f: abs(f[1][0].rotation))
    best = usable[0]
    for other in usable[1:]:
        if other[1][2] < 0.8 * best[1][2]:
            best = other
    return best


def _fit_distortion(lattice, along, across, residual, weights, model_shape):
    """Cubic displacement of the lens centres, when it explains the residuals clearly; else ``()``.

    Real relay optics bend the grid (antleg: about 1 px at the edges); an
    ideal lattice leaves that as residual. The polynomial is kept only if
    it cuts the RMS residual of the inner lenses (1.5 pitches from the
    borders, where centroids are cleanest) by 40 % and moves some lens by
    half a pixel or more, so clean grids stay ideal lattices.
    """
    ideal = lattice.positions(along, across)
    margin = 1.5 * lattice.pitch
    inner = ((ideal[:, 0] > margin) & (ideal[:, 0] < model_shape[0] - margin)
             & (ideal[:, 1] > margin) & (ideal[:, 1] < model_shape[1] - margin) & (weights > 0))
    if inner.sum() < 100:
        return (), None
    terms = distortion_terms(ideal[inner], model_shape)
    coeffs = least_squares(terms, residual[inner])  # (n_terms, 2)
    before = float(np.sqrt(np.mean(np.sum(residual[inner] ** 2, axis=1))))
    moved = terms @ coeffs
    after = float(np.sqrt(np.mean(np.sum((residual[inner] - moved) ** 2, axis=1))))
    reach = float(np.hypot(*moved.T).max())
    if after > 0.6 * before or reach < 0.5:
        return (), None
    return (tuple(coeffs[:, 0]), tuple(coeffs[:, 1])), after


def _measured_lenses(grid):
    """Flat indices of the lenses measured: all, or every s-th row and column of a large grid."""
    step = max(1, int(math.sqrt(grid.n_rows * grid.n_cols / _MEASURED_LENSES)))
    rows, cols = np.meshgrid(np.arange(0, grid.n_rows, step), np.arange(0, grid.n_cols, step), indexing="ij")
    return (rows * grid.n_cols + cols).ravel()


def _refine(grey, grid, bright, mosaic, vignetting=None):
    """Fit the lattice again to the centroid of every lens in its own cell.

    Lenses whose cell leaves the image, is dark, or is dimmer than the
    smooth vignetting predicts (cut by a dark border) are left out. A large
    grid is measured on an even subset of its lenses (rows and columns
    ``s`` apart, about :data:`_MEASURED_LENSES` of them). ``vignetting``
    (a :class:`~.lens_centres.Brightness` of an earlier pass) gives the
    tilt divided out of each cell.

    Returns
    -------
    lattice, along, across, residual, weights
        The fit and the lenses it used; ``None`` when too few lenses are lit.
    vignetting : Brightness
        This pass's brightness model.
    """
    lattice, along, across = _lattice_of(grid)
    chosen = _measured_lenses(grid)
    along, across = along[chosen], across[chosen]
    predicted = grid.lens_grid().reshape(-1, 2)[chosen]
    to_image = (lambda p: p[:, ::-1]) if grid.transposed else (lambda p: p)
    basis = lattice.basis()
    slopes = None if vignetting is None else to_image(vignetting.slopes(predicted))
    found, brightness, contrast = cell_centroids(grey, to_image(predicted), basis[::-1] if grid.transposed else basis,
                                                 slopes, mosaic)
    found = to_image(found)
    lit = (brightness > DARK_FRACTION * bright) & (contrast > 0.05)
    lit &= np.hypot(*(found - predicted).T) < 0.25 * lattice.pitch
    vignetting = Brightness(predicted, brightness, lit, grid.model_shape)
    lit &= brightness >= 0.9 * vignetting(predicted)  # dimmer than its neighbours: cut by a border
    if lit.sum() < _MIN_LENSES:
        return None, vignetting
    fitted, weights, residual = fit_lattice(found[lit], along[lit], across[lit], lattice)
    return (fitted, along[lit], across[lit], residual, weights), vignetting


def calibrate(white, dark=None, *, kind="auto", pitch=None, bayer=None):
    """Fit the microlens grid to a white image.

    Parameters
    ----------
    white : str, Path, ndarray or SensorImage
        White (flat-field) image of the lenslet array: a file, or an
        ``(H, W)`` / ``(H, W, 3)`` array.
    dark : str, Path, ndarray or SensorImage, optional
        Dark frame subtracted from the white image.
    kind : {"auto", "rectangular", "hexagonal"}
        Grid kind; ``"auto"`` detects it from the spectrum.
    pitch : float, optional
        Approximate lens pitch in pixels, to pick the grid among other
        periodic patterns; not needed for ordinary white images.
    bayer : str, optional
        Bayer layout of a grey mosaic file (``"RGGB"``, ...).

    Returns
    -------
    GridModel
        Its ``fit`` holds the number of lenses used and the RMS residual.

    Raises
    ------
    CalibrationError
        If no lens grid can be found (noise, flat or striped images, too
        few lenses); the message names the file.
    DecodeError
        If a file cannot be read, or the dark frame's size differs.

    Examples
    --------
    >>> from napari_lfalias.synthetic import render_lenslet, textured_plane
    >>> capture = render_lenslet(textured_plane(n_views=1, size=64), shape=(160, 160), pitch=9.3, rotation=0.4)
    >>> grid = calibrate(capture.white)
    >>> grid.kind, round(grid.pitch, 2), round(grid.rotation, 2)
    ('rectangular', 9.3, 0.4)
    """
    if kind not in ("auto", "rectangular", "hexagonal"):
        raise ParameterError(f"kind must be 'auto', 'rectangular' or 'hexagonal', got {kind!r}")
    if pitch is not None:
        if isinstance(pitch, bool) or not isinstance(pitch, (int, float)) or not 2.0 <= float(pitch) < 1e4:
            raise ParameterError(f"pitch must be an approximate lens pitch in pixels (>= 2), got {pitch!r}")
        pitch = float(pitch)
    grey, image, mosaic = prepare_white(white, dark, bayer)
    label = image.label()
    if min(grey.shape) < 16:
        raise CalibrationError(
            f"{label}: the image ({grey.shape[1]} x {grey.shape[0]} px) is too small to hold a lens grid"
        )
    k1, kind = _spectral_lattice(grey, kind, pitch, label, mosaic)
    orientations = _orientations(k1, kind)
    rough_pitch = float(np.hypot(*orientations[0][0]))
    peaks, bright = find_peaks(grey, rough_pitch, mosaic)
    if len(peaks) < _MIN_LENSES:
        raise CalibrationError(
            f"{label}: no microlens grid found: only {len(peaks)} bright lens centres (needs {_MIN_LENSES})"
        )
    fits = []
    subset = peaks[::max(1, len(peaks) // _ROUGH_PEAKS)]
    for row_vec, transposed in orientations:
        fitted = _rough_fit(subset, row_vec, kind, transposed, grey.shape)
        if fitted[1] >= _MIN_LENSES:
            fits.append((transposed, fitted))
    if not fits:
        raise CalibrationError(
            f"{label}: no microlens grid found: fewer than {_MIN_LENSES} lens centres fit one lattice; "
            "is this a white image of the lenslet array?"
        )
    transposed, (lattice, _, rough_rms) = _choose_orientation(fits)
    model_shape = grey.shape[::-1] if transposed else grey.shape
    if rough_rms > 0.15 * rough_pitch:
        raise CalibrationError(
            f"{label}: the lens centres do not fit one lattice (RMS residual {rough_rms:.2f} px)"
        )
    grid = _grid_from_lattice(lattice, model_shape, grey.shape, transposed, {})
    distortion, vignetting = (), None
    for _ in range(2):  # the second pass measures the cells of the refined (and perhaps bent) grid
        refined, vignetting = _refine(grey, grid, bright, mosaic, vignetting)
        if refined is None:
            raise CalibrationError(
                f"{label}: no microlens grid found: fewer than {_MIN_LENSES} whole, lit lenses to measure"
            )
        lattice, along, across, residual, weights = refined
        distortion, rms_after = _fit_distortion(lattice, along, across, residual, weights, model_shape)
        grid = _grid_from_lattice(lattice, model_shape, grey.shape, transposed, {}, distortion)
    kept = weights > 0
    rms = float(np.sqrt(np.mean(np.sum(residual[kept] ** 2, axis=1))))
    fit = {"lenses_fitted": int(kept.sum()), "rms_residual_px": round(rms, 4), "peaks_found": int(len(peaks))}
    if distortion:
        fit["rms_residual_after_distortion_px"] = round(rms_after, 4)
    return _grid_from_lattice(lattice, model_shape, grey.shape, transposed, fit, distortion)
