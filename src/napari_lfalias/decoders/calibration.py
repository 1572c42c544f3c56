"""Fit a :class:`~.grid.GridModel` to a white image of the microlens array.

The approach follows Dansereau's LFToolbox (``LFBuildLensletGridModel``:
locate lens centres as peaks of the filtered white image, fit an ideal
lattice), with three changes that remove its hand-set parameters:

1. **Rough lattice from the spectrum.** The power spectrum of the
   (windowed) white image has its strongest peaks on the reciprocal
   lattice. The lowest-frequency strong peak is a first-order one; the
   power at that peak turned by 60 and by 90 degrees says whether the grid
   is hexagonal or rectangular. No approximate pitch is needed, and a
   picture with no grid (noise, a flat field) has no peak standing out:
   a :class:`~napari_lfalias.errors.CalibrationError`.
2. **Sub-pixel centres on a flattened image.** The white image is divided
   by its envelope (Gaussian of one pitch), so vignetting neither biases
   the centres nor hides the lenses in dark corners. Lenses are the local
   maxima of the flattened image smoothed by a fifth of the pitch; their
   centres are the centroids of the flattened image above its mid-level
   within a disc around each maximum (weights that fade to zero at the
   contour do not lock onto whole pixels). Regions darker than a fifth of
   the bright level (dark borders) are ignored.
3. **Lattice fit that grows from the centre.** Lattice indices are
   assigned near the image centre first, the lattice (offset, pitch,
   rotation; ideal square or hexagonal shape) is fitted by linear least
   squares, and the region is doubled until it covers the image; outliers
   (missing or doubled peaks) are rejected by their residual. Where the
   optics bend the grid measurably (real relay lenses), a cubic
   displacement of the centres is fitted to the residuals as well.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import CalibrationError, DecodeError, ParameterError
from .grid import GridModel, distortion_terms
from .sensor import as_sensor_image

__all__ = ["calibrate", "prepare_white"]

#: Largest crop used for the spectrum (pixels per side).
_FFT_SIDE = 1024
#: A lattice peak must exceed the median power of its band this many times.
_PEAK_CONTRAST = 100.0
#: Lens regions darker than this fraction of the bright level are ignored.
_DARK_FRACTION = 0.2
#: Fewest lens centres a fit needs.
_MIN_LENSES = 12
_SQRT3_2 = math.sqrt(3.0) / 2.0


def _rotation_matrix(degrees):
    """Matrix turning a (y, x) vector by ``degrees`` towards +y."""
    a = math.radians(degrees)
    return np.array([[math.cos(a), math.sin(a)], [-math.sin(a), math.cos(a)]])


def prepare_white(white, dark=None, bayer=None):
    """The white image as one grey float32 ``(H, W)`` array, dark frame subtracted.

    Bayer mosaics are filtered free of their 2-pixel pattern and colour
    images averaged over their channels.

    Returns
    -------
    grey : ndarray (H, W) float32
    image : SensorImage
        The white image as read.
    """
    from .bayer import cfa_grey

    image = as_sensor_image(white, bayer=bayer, name="white")
    data = np.asarray(image.data, np.float32)
    if dark is not None:
        dark_image = as_sensor_image(dark, bayer=None, name="dark")
        if dark_image.shape != image.shape:
            raise DecodeError(
                f"{dark_image.label()}: the dark frame is {dark_image.shape[1]} x {dark_image.shape[0]} px but the "
                f"white image {image.label()} is {image.shape[1]} x {image.shape[0]}; use frames of one sensor size"
            )
        dark_data = np.asarray(dark_image.data, np.float32)
        if dark_data.ndim != data.ndim:
            dark_data = dark_data.mean(axis=-1) if dark_data.ndim == 3 else dark_data[..., None]
        data = data - dark_data
    if data.ndim == 3:
        data = data.mean(axis=-1)
    elif image.bayer is not None:
        data = cfa_grey(data)
    return np.ascontiguousarray(data, np.float32), image


# -- 1. rough lattice from the spectrum ----------------------------------------------------


def _power_spectrum(grey):
    """Centred power spectrum of a central crop (Hann window), and the crop's shape."""
    height, width = grey.shape
    h, w = min(height, _FFT_SIDE), min(width, _FFT_SIDE)
    y0, x0 = (height - h) // 2, (width - w) // 2
    crop = grey[y0:y0 + h, x0:x0 + w].astype(np.float64)
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


def _spectral_lattice(grey, kind, pitch_hint, label):
    """Reciprocal first-order peak ``k1`` and the grid kind, from the power spectrum."""
    from scipy.ndimage import maximum_filter

    spectrum, shape = _power_spectrum(grey)
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


def _row_vector(k1, kind):
    """Real-space lens-row vector (y, x) from the first-order reciprocal vector, turned near +x.

    Returns the vector and whether the grid is modelled transposed (a
    hexagonal grid whose rows run nearer the vertical).
    """
    turn = 60.0 if kind == "hexagonal" else 90.0
    k2 = _rotation_matrix(turn) @ k1
    basis = np.linalg.inv(np.array([k1, k2]))  # columns a1, a2 with k_i . a_j = delta_ij
    a1 = basis[:, 0]  # a nearest-neighbour vector; the others are a1 turned by multiples of `turn`
    pitch = np.hypot(*a1)
    candidates = [_rotation_matrix(turn * n) @ a1 for n in range(int(round(360 / turn)))]
    angles = [math.degrees(math.atan2(v[0], v[1])) for v in candidates]
    best = int(np.argmin([abs(a) for a in angles]))
    transposed = kind == "hexagonal" and abs(angles[best]) > 15.0
    if transposed:
        swapped = [v[::-1] for v in candidates]
        angles = [math.degrees(math.atan2(v[0], v[1])) for v in swapped]
        best = int(np.argmin([abs(a) for a in angles]))
        return swapped[best] / np.hypot(*swapped[best]) * pitch, True
    return candidates[best], False


# -- 2. sub-pixel lens centres --------------------------------------------------------------


def _envelope(grey, pitch):
    """The white image's slow envelope (vignetting): a Gaussian of one pitch, computed at low resolution."""
    import cv2

    height, width = grey.shape
    factor = max(1.0, pitch / 4.0)
    small_size = (max(8, int(round(width / factor))), max(8, int(round(height / factor))))
    small = cv2.resize(grey, small_size, interpolation=cv2.INTER_AREA)
    sigma = pitch * small_size[0] / width
    small = cv2.GaussianBlur(small, (0, 0), sigmaX=max(sigma, 0.5), borderType=cv2.BORDER_REFLECT)
    return cv2.resize(small, (width, height), interpolation=cv2.INTER_LINEAR), small


def _fully_lit(small, bright, pitch, shape):
    """Pixels whose whole neighbourhood (one pitch across) is brighter than the dark fraction.

    Lenses cut by a dark border or the sensor's edge are left out: their
    centroids would be pulled inwards.
    """
    import cv2

    lit = (small > _DARK_FRACTION * bright).astype(np.uint8)
    factor = shape[1] / small.shape[1]
    size = 2 * int(math.ceil(0.5 * pitch / factor)) + 1
    lit = cv2.erode(lit, np.ones((size, size), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return cv2.resize(lit, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST).astype(bool)


def _centroids(flat, rows, cols, pitch):
    """Sub-pixel (y, x) of blobs near integer peaks: centroid of the part above mid-level in a disc.

    Weights fall continuously to zero at the half-level contour, so the
    estimate does not lock onto whole pixels as a 3-point parabola does.
    """
    radius = max(1, int(round(0.42 * pitch)))
    d = np.arange(-radius, radius + 1)
    dy, dx = np.meshgrid(d, d, indexing="ij")
    disc = (dy * dy + dx * dx) <= radius * radius
    height, width = flat.shape
    out = np.empty((len(rows), 2))
    for start in range(0, len(rows), 1024):
        r = rows[start:start + 1024, None, None] + dy
        c = cols[start:start + 1024, None, None] + dx
        inside = disc & (r >= 0) & (r < height) & (c >= 0) & (c < width)
        patch = flat[np.clip(r, 0, height - 1), np.clip(c, 0, width - 1)]
        top = patch.max(axis=(1, 2), where=inside, initial=-np.inf)
        low = patch.min(axis=(1, 2), where=inside, initial=np.inf)
        weight = np.clip(patch - (0.5 * (top + low))[:, None, None], 0.0, None) * inside
        total = np.maximum(weight.sum(axis=(1, 2)), 1e-12)
        out[start:start + 1024, 0] = rows[start:start + 1024] + (weight * dy).sum(axis=(1, 2)) / total
        out[start:start + 1024, 1] = cols[start:start + 1024] + (weight * dx).sum(axis=(1, 2)) / total
    return out


def _lens_peaks(grey, pitch):
    """``(n, 2)`` sub-pixel (y, x) of the lens centres in the bright part of the image."""
    import cv2

    envelope, small = _envelope(grey, pitch)
    bright = float(np.percentile(small, 99.0))
    if not bright > 0:
        return np.zeros((0, 2))
    flat = grey / np.maximum(envelope, 0.05 * bright)
    smooth = cv2.GaussianBlur(flat, (0, 0), sigmaX=max(pitch / 5.0, 0.8), borderType=cv2.BORDER_REFLECT)
    size = max(3, int(round(0.7 * pitch)) | 1)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    local_max = cv2.dilate(smooth, kernel)
    keep = (smooth >= local_max) & _fully_lit(small, bright, pitch, grey.shape) & (smooth > 1.0)
    keep[:1, :] = keep[-1:, :] = False
    keep[:, :1] = keep[:, -1:] = False
    rows, cols = np.nonzero(keep)
    if rows.size == 0:
        return np.zeros((0, 2))
    return _centroids(flat, rows, cols, pitch)


# -- 3. lattice fit ---------------------------------------------------------------------------


def _lattice_shape(kind):
    """Matrix taking the row vector to the next-row vector (a lattice basis with it)."""
    return _rotation_matrix(60.0 if kind == "hexagonal" else 90.0)


def _assign(points, origin, row_vec, shape_matrix):
    """Integer lattice coordinates (m, n) and residuals of points for basis (row_vec, M @ row_vec)."""
    basis = np.column_stack([row_vec, shape_matrix @ row_vec])
    coords = np.linalg.solve(basis, (points - origin).T).T
    index = np.round(coords)
    residual = points - origin - index @ basis.T
    return index, residual


def _solve(points, index, shape_matrix):
    """Least-squares origin and row vector of ``points = origin + (m I + n M) row_vec``."""
    m, n = index[:, 0], index[:, 1]
    count = len(points)
    design = np.zeros((2 * count, 4))
    design[:count, 0] = 1.0
    design[count:, 1] = 1.0
    # y = o_y + (m + n M00) r_y + n M01 r_x ; x = o_x + n M10 r_y + (m + n M11) r_x
    design[:count, 2] = m + n * shape_matrix[0, 0]
    design[:count, 3] = n * shape_matrix[0, 1]
    design[count:, 2] = n * shape_matrix[1, 0]
    design[count:, 3] = m + n * shape_matrix[1, 1]
    target = np.concatenate([points[:, 0], points[:, 1]])
    solution = np.linalg.lstsq(design, target, rcond=None)[0]
    return solution[:2], solution[2:]


def _fit_lattice(points, row_vec, kind, model_shape, label):
    """Grow the fit from the lens nearest the image centre; return origin, row vector, inliers, residuals."""
    shape_matrix = _lattice_shape(kind)
    pitch = float(np.hypot(*row_vec))
    centre = np.array(model_shape, np.float64) / 2.0
    origin = points[int(np.argmin(np.hypot(*(points - centre).T)))]
    distance = np.hypot(*(points - origin).T)
    radius = 6.0 * pitch
    inliers = np.zeros(len(points), bool)
    while True:
        near = distance <= radius
        index, residual = _assign(points, origin, row_vec, shape_matrix)
        inliers = near & (np.hypot(*residual.T) < 0.3 * pitch)
        if inliers.sum() >= 4:
            origin, row_vec = _solve(points[inliers], index[inliers], shape_matrix)
        if near.all():
            break
        radius *= 2.0
    for _ in range(3):
        index, residual = _assign(points, origin, row_vec, shape_matrix)
        error = np.hypot(*residual.T)
        spread = 1.4826 * np.median(error[inliers]) if inliers.any() else pitch
        inliers = error < min(0.3 * pitch, max(4.0 * spread, 0.05 * pitch))
        if inliers.sum() < _MIN_LENSES:
            break
        origin, row_vec = _solve(points[inliers], index[inliers], shape_matrix)
    if inliers.sum() < _MIN_LENSES:
        raise CalibrationError(
            f"{label}: no microlens grid found: only {int(inliers.sum())} lens centres fit one lattice "
            f"(needs {_MIN_LENSES}); is this a white image of the lenslet array?"
        )
    index, residual = _assign(points, origin, row_vec, shape_matrix)
    return origin, row_vec, index[inliers], residual[inliers]


def _fit_distortion(origin, row_vec, kind, index, residual, model_shape):
    """Cubic displacement of the lens centres, when it explains the residuals clearly; else ``()``.

    Real relay optics bend the grid (antleg: about 1 px at the edges); an
    ideal lattice leaves that as residual. The polynomial is kept only if
    it cuts the RMS residual of the inner lenses (1.5 pitches from the
    borders, where centroids are cleanest) by 40 % and moves some lens by
    half a pixel or more, so clean grids stay ideal lattices.
    """
    basis = np.column_stack([row_vec, _lattice_shape(kind) @ row_vec])
    ideal = origin + index @ basis.T
    margin = 1.5 * float(np.hypot(*row_vec))
    inner = ((ideal[:, 0] > margin) & (ideal[:, 0] < model_shape[0] - margin)
             & (ideal[:, 1] > margin) & (ideal[:, 1] < model_shape[1] - margin))
    if inner.sum() < 100:
        return (), None
    terms = distortion_terms(ideal[inner], model_shape)
    coeffs = np.linalg.lstsq(terms, residual[inner], rcond=None)[0]  # (n_terms, 2)
    before = float(np.sqrt(np.mean(np.sum(residual[inner] ** 2, axis=1))))
    moved = terms @ coeffs
    after = float(np.sqrt(np.mean(np.sum((residual[inner] - moved) ** 2, axis=1))))
    reach = float(np.hypot(*moved.T).max())
    if after > 0.6 * before or reach < 0.5:
        return (), None
    return (tuple(coeffs[:, 0]), tuple(coeffs[:, 1])), after


def _grid_from_lattice(origin, row_vec, kind, model_shape, image_shape, transposed, fit, distortion=()):
    """Re-base the fitted lattice on the top-left lens covering the image and build the GridModel."""
    pitch = float(np.hypot(*row_vec))
    rotation = math.degrees(math.atan2(row_vec[0], row_vec[1]))
    probe = GridModel(kind, pitch, rotation, tuple(origin), 1, 1, image_shape, 0, transposed)
    e_y, e_x = probe.axes
    row_step = probe.row_step
    height, width = model_shape
    corners = np.array([[-0.5, -0.5], [-0.5, width - 0.5], [height - 0.5, -0.5], [height - 0.5, width - 0.5]])
    across = (corners - origin) @ e_y / row_step
    along = (corners - origin) @ e_x / pitch
    rows = np.arange(math.floor(across.min()) - 1, math.ceil(across.max()) + 2)
    cols = np.arange(math.floor(along.min()) - 2, math.ceil(along.max()) + 2)
    # lattice point (m, n) = row n, column j = m + floor(n / 2) at (j + (n % 2) / 2) pitches along the row
    shift = (rows % 2) * 0.5 if kind == "hexagonal" else np.zeros(len(rows))
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
    shift_row = int((i0 + 1) % 2) if kind == "hexagonal" else 0
    return GridModel(kind, pitch, rotation, tuple(offset), int(i1 - i0 + 1), int(j1 - j0 + 1),
                     image_shape, shift_row, transposed, distortion, fit)


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
    >>> grid.kind, round(grid.pitch, 1), round(grid.rotation, 1)
    ('rectangular', 9.3, 0.4)
    """
    if kind not in ("auto", "rectangular", "hexagonal"):
        raise ParameterError(f"kind must be 'auto', 'rectangular' or 'hexagonal', got {kind!r}")
    if pitch is not None:
        if isinstance(pitch, bool) or not isinstance(pitch, (int, float)) or not 2.0 <= float(pitch) < 1e4:
            raise ParameterError(f"pitch must be an approximate lens pitch in pixels (>= 2), got {pitch!r}")
        pitch = float(pitch)
    grey, image = prepare_white(white, dark, bayer)
    label = image.label()
    if min(grey.shape) < 16:
        raise CalibrationError(
            f"{label}: the image ({grey.shape[1]} x {grey.shape[0]} px) is too small to hold a lens grid"
        )
    k1, kind = _spectral_lattice(grey, kind, pitch, label)
    row_vec, transposed = _row_vector(k1, kind)
    rough_pitch = float(np.hypot(*row_vec))
    points = _lens_peaks(grey, rough_pitch)
    if len(points) < _MIN_LENSES:
        raise CalibrationError(
            f"{label}: no microlens grid found: only {len(points)} bright lens centres (needs {_MIN_LENSES})"
        )
    model_shape = grey.shape[::-1] if transposed else grey.shape
    if transposed:
        points = points[:, ::-1]
    origin, row_vec, index, residual = _fit_lattice(points, row_vec, kind, model_shape, label)
    rms = float(np.sqrt(np.mean(np.sum(residual ** 2, axis=1))))
    fit = {"lenses_fitted": int(len(index)), "rms_residual_px": round(rms, 4), "peaks_found": int(len(points))}
    if rms > 0.15 * rough_pitch:
        raise CalibrationError(f"{label}: the lens centres do not fit one lattice (RMS residual {rms:.2f} px)")
    distortion, rms_after = _fit_distortion(origin, row_vec, kind, index, residual, model_shape)
    if distortion:
        fit["rms_residual_after_distortion_px"] = round(rms_after, 4)
    return _grid_from_lattice(origin, row_vec, kind, model_shape, grey.shape, transposed, fit, distortion)
