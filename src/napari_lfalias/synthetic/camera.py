"""What a real camera does to a light field: vignetting, sensor noise, clipping, a Bayer mosaic.

:func:`capture` turns the ideal views of a synthetic scene into what a
camera records, so that the benchmarks and tests see users' data:

- **vignetting**: every sample is multiplied by a fall-off that darkens
  the corner views and the corners of every view (the corner views of a
  lenslet camera are mostly black; an array's outer cameras see less
  light off-axis). ``cos^4``-like: ``(1 + k (rho_q^2 + rho_p^2))^-2`` with
  ``rho_q`` the view's distance from the centre of the aperture and
  ``rho_p`` the pixel's from the centre of the view, both normalised;
- **exposure and clipping**: the signal is scaled by ``exposure`` and
  clipped at 1 (a saturated sky);
- **Bayer mosaic**: one colour per pixel (RGGB), demosaiced again by the
  package's own bilinear demosaic, as a raw converter would;
- **sensor noise**: Gaussian read noise plus shot noise whose variance
  grows with the signal.

With ``calibrated=True`` the vignetting is divided out again and returned
as the light field's sample weights, which is what a decoder with a white
image hands the user; without it the user gets the darkened views and no
weights (a folder of images), and the loader has to cope.

The vignette takes light from the rays themselves, so a camera with a dense
aperture and the same vignetting records them weighted by it too: the sum
over the aperture of the fall-off times the ray, which a flat field
divides by the fall-off's own sum. :func:`vignetted_reference` is that
dense-aperture image of a synthetic scene, the ground truth of a
calibrated capture (its naive refocus weighs each view's samples by their
fall-off alike); the scene's uniform
:meth:`~napari_lfalias.synthetic.SyntheticScene.reference` is not.
"""

from __future__ import annotations

import numpy as np

from .. import _validate
from ..errors import ParameterError
from ..lightfield import LightField, regular_positions

__all__ = ["capture", "vignetting_falloff", "vignetted_reference", "reference_through"]

#: Exponentials whose sum stands for the fall-off ``(1 + z)^-2`` in :func:`vignetted_reference` (each one
#: separable over the two axes), and the largest relative error of that sum it accepts.
FALLOFF_TERMS = 10
FALLOFF_TOLERANCE = 1e-4


def vignetting_falloff(positions, shape, strength):
    """Fall-off ``(U, V, Y, X)`` in (0, 1] of every sample for ``strength >= 0`` (module notes).

    Examples
    --------
    >>> from napari_lfalias import regular_positions
    >>> fall = vignetting_falloff(regular_positions(3, 3), (16, 16), 1.0)
    >>> float(fall[1, 1, 8, 8]) > float(fall[0, 0, 8, 8]) > float(fall[0, 0, 0, 0])
    True
    """
    strength = _validate.non_negative_float("strength", strength)
    positions = np.asarray(positions, np.float64)
    rho_q = np.hypot(positions[..., 0], positions[..., 1]) / _aperture_radius(positions)
    height, width = shape
    rho_p2 = _rho_p2_part(np.arange(height), height)[:, None] + _rho_p2_part(np.arange(width), width)[None, :]
    total = rho_q[..., None, None] ** 2 + rho_p2[None, None]
    return (1.0 / (1.0 + strength * total) ** 2).astype(np.float32)


def _aperture_radius(positions):
    """The unit of ``rho_q``: the largest distance of a view ``positions (..., 2)`` from the aperture's centre."""
    return max(float(np.hypot(positions[..., 0], positions[..., 1]).max()), 1e-9)


def _rho_p2_part(pixels, length):
    """One axis's share of ``rho_p^2`` at (any real) pixel coordinates ``pixels`` of a view ``length`` px
    long: the squared distance from the view's centre in half-lengths, halved (both axes add up to 1 at a
    corner of a square view)."""
    return ((pixels - (length - 1) / 2) / max(length / 2, 1)) ** 2 / 2


def _falloff_as_exponentials(z_max):
    """Coefficients ``c`` and rates ``r`` with ``sum(c * exp(-r * z))`` within :data:`FALLOFF_TOLERANCE` of
    ``(1 + z)^-2`` (relative) for ``0 <= z <= z_max``: a least-squares fit on geometric rates."""
    z = np.linspace(0.0, max(float(z_max), 1e-6), 2001)
    exact = (1.0 + z) ** -2.0
    rates = np.geomspace(0.02, 8.0, FALLOFF_TERMS) * (5.0 / max(float(z_max), 5.0))
    basis = np.exp(-np.outer(z, rates))
    coefficients = np.linalg.lstsq(basis / exact[:, None], np.ones_like(z), rcond=None)[0]
    error = float(np.abs(basis @ coefficients / exact - 1.0).max())
    if error > FALLOFF_TOLERANCE:
        raise ParameterError(f"the vignetting fall-off over 0 to {z_max:.3g} needs more than {FALLOFF_TERMS} "
                             f"exponentials (relative error {error:.2g}); lower the vignetting")
    return coefficients, rates


def vignetted_reference(scene, slope, vignetting, *, samples_per_view=None, max_step=0.25):
    """The dense-aperture image of ``scene`` at ``slope`` through a camera with ``vignetting`` (module notes).

    Every ray ``(q, p + slope q)`` of the aperture (``samples_per_view``
    per view cell and axis, as in the scene's
    :meth:`~napari_lfalias.synthetic.SyntheticScene.reference`) is weighed
    by :func:`vignetting_falloff` at its aperture position and at the pixel
    where it lands in its view, and the sum is divided by the sum of the
    weights: what a flat-fielded camera of that aperture records, and what
    the naive refocus of :func:`capture` ``(..., calibrated=True)``
    samples at one ray per view.

    Parameters
    ----------
    scene : SyntheticScene
        The scene (square views of ``scene.size`` px on a regular grid).
    slope : float
        Disparity in focus.
    vignetting : float
        The strength given to :func:`capture` (0: the uniform reference).
    samples_per_view : int, optional
        Aperture samples per view cell and axis (1: the views themselves);
        default ``scene.aperture_samples(slope, max_step)``.
    max_step : float
        See :meth:`~napari_lfalias.synthetic.SyntheticScene.aperture_samples`.

    Returns
    -------
    image : ndarray, shape (size, size, 3), float32

    Notes
    -----
    The fall-off ``(1 + k (rho_q^2 + rho_p^2))^-2`` is not separable over
    the image's axes; it is summed from :data:`FALLOFF_TERMS` exponentials
    of ``k (rho_q^2 + rho_p^2)``, each of which is (relative error at most
    :data:`FALLOFF_TOLERANCE`), and the scene's own separable sums do the
    rest (:meth:`~napari_lfalias.synthetic.SyntheticScene.reference` with
    ``pixel_terms``).

    Examples
    --------
    >>> import numpy as np
    >>> from napari_lfalias.synthetic import textured_plane
    >>> scene = textured_plane(n_views=3, size=32, disparity=1.0)
    >>> uniform = vignetted_reference(scene, 0.0, 0.0)
    >>> bool(np.allclose(uniform, scene.reference(0.0), atol=1e-5))
    True
    """
    slope = _validate.finite_float("slope", slope)
    vignetting = _validate.non_negative_float("vignetting", vignetting)
    m = scene.aperture_samples(slope, max_step) if samples_per_view is None else \
        _validate.integer_at_least("samples_per_view", samples_per_view, 1)
    aperture = scene.aperture_positions(m)
    radius = _aperture_radius(regular_positions(scene.n_views, scene.n_views))
    size = scene.size
    landing = np.arange(size)[None, :] + slope * aperture[:, None]  # where each ray lands in its view
    # vignetting_falloff's argument on one axis, for every aperture position and output pixel (M, size)
    axis_part = (aperture[:, None] / radius) ** 2 + _rho_p2_part(landing, size)
    z_max = vignetting * 2 * float(axis_part.max())
    if z_max == 0:
        return scene.reference(slope, m)
    coefficients, rates = _falloff_as_exponentials(z_max)
    terms = []
    for c, r in zip(coefficients, rates):
        axis_weight = np.exp(-r * vignetting * axis_part)  # the same on both axes: square views, square grid
        terms.append((float(c), axis_weight, axis_weight))
    return scene.reference(slope, m, pixel_terms=terms)


def reference_through(scene, slope, *, vignetting=0.0, exposure=1.0, calibrated=False, samples_per_view=None,
                      **sensor):
    """The dense-aperture image of ``scene`` at ``slope`` through the camera of :func:`capture` with these
    options: the ground truth of what :func:`capture` hands the user.

    Calibrated vignetting weighs the rays (:func:`vignetted_reference`); the
    exposure scales the image. The sensor records light between 0 and 1
    only, in the views' samples (:func:`capture` clips them there) as in
    the aperture's sum: a scene's textures may dip below 0 or rise above 1
    in places (the tails of a random texture, crossing dark lines), and the
    sum of the rays there is clipped too, at any exposure (before stop 55
    at 1 only where the exposure was not 1: 28 of 82 references of the
    fresh scenes through a camera at exposure 1 held pixels up to 1.32,
    which no view could record). The sensor's own options
    (``bayer``, ``read_noise``, ``shot_noise``, ``seed``, in ``sensor``)
    change the views, not what the aperture gathers, and uncalibrated
    vignetting is an artefact of the views that a loader has to correct:
    neither is in the reference.

    Parameters
    ----------
    scene : SyntheticScene
        The scene.
    slope : float
        Disparity in focus.
    vignetting, exposure, calibrated, **sensor
        As given to :func:`capture`.
    samples_per_view : int, optional
        Aperture samples per view cell and axis (1: the views' comb).

    Returns
    -------
    image : ndarray, shape (size, size, 3), float32

    Examples
    --------
    >>> import numpy as np
    >>> from napari_lfalias.synthetic import textured_plane
    >>> scene = textured_plane(n_views=3, size=32, disparity=1.0)
    >>> image = reference_through(scene, 0.0, exposure=2.0, read_noise=0.01)
    >>> bool(np.array_equal(image, np.minimum(2 * scene.reference(0.0), np.float32(1))))
    True
    """
    unknown = set(sensor) - {"bayer", "read_noise", "shot_noise", "seed"}
    if unknown:
        raise ParameterError(f"unknown camera options: {', '.join(sorted(unknown))}")
    exposure = np.float32(_validate.positive_float("exposure", exposure))
    strength = _validate.non_negative_float("vignetting", vignetting) if calibrated else 0.0
    if strength:
        image = vignetted_reference(scene, slope, strength, samples_per_view=samples_per_view)
    else:
        image = scene.reference(slope, samples_per_view, interpolation="exact")
    return np.clip(image * exposure, np.float32(0.0), np.float32(1.0))


def capture(lf, *, vignetting=0.0, exposure=1.0, bayer=False, read_noise=0.0, shot_noise=0.0, calibrated=False,
            seed=0):
    """The light field a camera records of the ideal ``lf`` (module notes).

    Parameters
    ----------
    lf : LightField
        Ideal views (a synthetic scene's ``lightfield``), colour.
    vignetting : float
        Strength ``k`` of the fall-off (0: none; 1.5: corner views at about
        a fifth of the centre's light).
    exposure : float
        Gain before clipping at 1 (> 1 saturates the bright parts).
    bayer : bool
        Sample through an RGGB mosaic and demosaic again.
    read_noise, shot_noise : float
        Standard deviation of the read noise, and of the shot noise at
        signal 1 (its variance grows linearly with the signal).
    calibrated : bool
        Divide the vignetting out and return it as the sample weights.
    seed : int
        Seed of the noise.

    Returns
    -------
    LightField
        Same shape and positions; ``meta["capture"]`` records the settings.

    Examples
    --------
    >>> from napari_lfalias.synthetic import textured_plane
    >>> lf = textured_plane(n_views=3, size=32).lightfield
    >>> raw = capture(lf, vignetting=1.0, read_noise=0.01)
    >>> bool(raw.data[0, 0].mean() < lf.data[0, 0].mean()), raw.weights is None
    (True, True)
    """
    from ..decoders.bayer import demosaic, mosaic

    if not isinstance(lf, LightField) or lf.n_channels != 3:
        raise ParameterError("lf must be a colour napari_lfalias.LightField")
    exposure = _validate.positive_float("exposure", exposure)
    read_noise = _validate.non_negative_float("read_noise", read_noise)
    shot_noise = _validate.non_negative_float("shot_noise", shot_noise)
    calibrated = _validate.boolean("calibrated", calibrated)
    bayer = _validate.boolean("bayer", bayer)
    rng = np.random.default_rng(_validate.integer_at_least("seed", seed, 0))
    lf = lf.compute()
    fall = vignetting_falloff(lf.positions, lf.image_shape, vignetting)
    signal = np.asarray(lf.data, np.float32) * (fall[..., None] * np.float32(exposure))
    if bayer:
        views = signal.reshape((-1,) + signal.shape[2:])
        signal = np.stack([mosaic(view, "RGGB") for view in views]).reshape(signal.shape[:4])[..., None]
    if read_noise or shot_noise:
        sigma = np.sqrt(read_noise ** 2 + shot_noise ** 2 * np.clip(signal, 0, None))
        signal = signal + rng.normal(size=signal.shape).astype(np.float32) * sigma.astype(np.float32)
    signal = np.clip(signal, 0.0, 1.0)
    if bayer:
        views = signal[..., 0].reshape((-1,) + lf.image_shape)
        signal = np.stack([demosaic(view, "RGGB") for view in views]).reshape(lf.shape).astype(np.float32)
    weights = None
    if calibrated:
        signal = signal / fall[..., None]
        weights = fall
    meta = dict(lf.meta)
    meta["capture"] = {"vignetting": float(vignetting), "exposure": exposure, "bayer": bayer,
                       "read_noise": read_noise, "shot_noise": shot_noise, "calibrated": calibrated}
    return LightField(signal.astype(np.float32), lf.positions, meta, weights=weights)
