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
"""

from __future__ import annotations

import numpy as np

from .. import _validate
from ..errors import ParameterError
from ..lightfield import LightField

__all__ = ["capture", "vignetting_falloff"]


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
    q = np.hypot(positions[..., 0], positions[..., 1])
    rho_q = q / max(float(q.max()), 1e-9)
    height, width = shape
    y = (np.arange(height) - (height - 1) / 2) / max(height / 2, 1)
    x = (np.arange(width) - (width - 1) / 2) / max(width / 2, 1)
    rho_p2 = (y[:, None] ** 2 + x[None, :] ** 2) / 2
    total = rho_q[..., None, None] ** 2 + rho_p2[None, None]
    return (1.0 / (1.0 + strength * total) ** 2).astype(np.float32)


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
