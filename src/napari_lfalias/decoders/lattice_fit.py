"""Robust least-squares fit of a microlens lattice to measured lens centres.

The lattice is the :class:`~.grid.GridModel` geometry: lens rows along
``a1 = (A, B) = pitch * (sin r, cos r)`` and rows ``row_step = k * pitch``
apart, so a lens ``along`` pitches along its row (half-integer on the
shifted rows of a hexagonal grid) and ``across`` rows down lies at::

    y = o_y + along * A + across * k * B
    x = o_x + along * B - across * k * A

Five parameters ``(o_y, o_x, A, B, k)``: the offset, the pitch and rotation,
and the row spacing (free, as LFToolbox fits its horizontal and vertical
spacings apart: a real or rendered array whose rows are 0.5 % closer than
a regular hexagon's otherwise costs a 0.2 % pitch error). The fit is
Gauss-Newton with Tukey biweights (iteratively reweighted), so lenses that
are missing, doubled or cut by a dark border do not pull it.

:func:`grow_lattice` gives every measured point its lattice index, starting
from the lens nearest the image centre and doubling the region until it
covers the image; :func:`fit_lattice` fits the parameters to points whose
indices are known.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Lattice", "fit_lattice", "grow_lattice", "lattice_indices"]

#: Tukey biweight tuning constant (95 % efficiency on Gaussian residuals).
_TUKEY = 4.685
#: Residual scale floor in pixels (noise-free renderings would otherwise reject everything but the median).
_SCALE_FLOOR = 0.02


@dataclass(frozen=True)
class Lattice:
    """An ideal lattice: offset ``(o_y, o_x)``, row vector ``(A, B)``, row spacing ratio ``k``, kind."""

    origin: tuple
    row_vector: tuple
    ratio: float
    hexagonal: bool

    @property
    def pitch(self):
        return float(math.hypot(*self.row_vector))

    @property
    def rotation(self):
        """Degrees from the x axis towards +y."""
        return math.degrees(math.atan2(self.row_vector[0], self.row_vector[1]))

    @property
    def row_step(self):
        return self.ratio * self.pitch

    def basis(self):
        """``(2, 2)`` columns: the row vector and the vector to the next row's first lens."""
        a, b = self.row_vector
        half = 0.5 if self.hexagonal else 0.0
        return np.array([[a, self.ratio * b + half * a], [b, -self.ratio * a + half * b]])

    def positions(self, along, across):
        """``(n, 2)`` (y, x) of lenses at ``along`` pitches and ``across`` rows from the origin."""
        a, b = self.row_vector
        k = self.ratio
        along, across = np.asarray(along, np.float64), np.asarray(across, np.float64)
        y = self.origin[0] + along * a + across * k * b
        x = self.origin[1] + along * b - across * k * a
        return np.stack([y, x], axis=-1)


def lattice_indices(points, lattice):
    """Nearest lattice ``(along, across)`` of every point, and its residual ``(n, 2)``.

    ``along`` is half-integer on the shifted rows of a hexagonal lattice.
    """
    basis = lattice.basis()
    coords = np.linalg.solve(basis, (np.asarray(points, np.float64) - lattice.origin).T).T
    index = np.round(coords)  # (m, n): m row vectors and n next-row vectors
    half = 0.5 if lattice.hexagonal else 0.0
    along = index[:, 0] + half * index[:, 1]
    across = index[:, 1]
    return along, across, points - lattice.positions(along, across)


def _tukey(norms, cap):
    """Biweights of residual norms, with the scale from their median (floored)."""
    scale = max(1.4826 * float(np.median(norms)), _SCALE_FLOOR) if norms.size else _SCALE_FLOOR
    cut = min(_TUKEY * scale, cap)
    t = np.clip(norms / cut, 0.0, 1.0)
    return (1.0 - t * t) ** 2 * (norms < cut)


def _gauss_newton_step(theta, along, across, residual, w):
    """Weighted least-squares step of the five parameters, from the 5 x 5 normal equations."""
    a, b, k = theta[2], theta[3], theta[4]
    zero, one = np.zeros_like(along), np.ones_like(along)
    jac_y = np.stack([one, zero, along, across * k, across * b])  # d y / d theta, (5, n)
    jac_x = np.stack([zero, one, -across * k, along, -across * a])
    normal = (jac_y * w) @ jac_y.T + (jac_x * w) @ jac_x.T
    rhs = (jac_y * w) @ residual[:, 0] + (jac_x * w) @ residual[:, 1]
    return np.linalg.lstsq(normal, rhs, rcond=None)[0]


def fit_lattice(points, along, across, start, weights=None, cap=None, iterations=8):
    """Robust Gauss-Newton fit of the lattice to points of known index.

    Parameters
    ----------
    points : ndarray, shape (n, 2)
        Measured (y, x) lens centres.
    along, across : ndarray, shape (n,)
        Their lattice indices (see :func:`lattice_indices`).
    start : Lattice
        Starting parameters (its kind is kept).
    weights : ndarray, shape (n,), optional
        Prior weights (0 excludes a point); default all 1.
    cap : float, optional
        Residuals beyond this many pixels get no weight (default a quarter pitch).
    iterations : int
        Gauss-Newton steps, each with biweights recomputed from the residuals.

    Returns
    -------
    lattice : Lattice
    weights : ndarray, shape (n,)
        Final biweights (0 for outliers).
    residuals : ndarray, shape (n, 2)

    Examples
    --------
    >>> truth = Lattice((3.0, 4.0), (0.1, 10.0), 0.87, True)
    >>> along, across = np.meshgrid(np.arange(8.0), np.arange(6.0))
    >>> along = (along + 0.5 * (across % 2)).ravel(); across = across.ravel()
    >>> points = truth.positions(along, across)
    >>> fitted, w, _ = fit_lattice(points, along, across, Lattice((2.0, 5.0), (0.0, 10.1), 0.866, True))
    >>> np.round([fitted.pitch, fitted.ratio, fitted.rotation], 6).tolist()
    [10.0005, 0.87, 0.572939]
    """
    points = np.asarray(points, np.float64)
    along = np.asarray(along, np.float64)
    across = np.asarray(across, np.float64)
    prior = np.ones(len(points)) if weights is None else np.asarray(weights, np.float64)
    theta = np.array([start.origin[0], start.origin[1], start.row_vector[0], start.row_vector[1], start.ratio])
    cap = 0.25 * start.pitch if cap is None else float(cap)
    for _ in range(iterations):
        lattice = Lattice((theta[0], theta[1]), (theta[2], theta[3]), float(theta[4]), start.hexagonal)
        residual = points - lattice.positions(along, across)
        w = prior * _tukey(np.hypot(*residual.T), cap)
        if np.count_nonzero(w) < 6:
            break
        step = _gauss_newton_step(theta, along, across, residual, w)
        theta = theta + step
        if np.abs(step[:2]).max() < 1e-7 and np.abs(step[2:4]).max() < 1e-9 and abs(step[4]) < 1e-10:
            break
    lattice = Lattice((theta[0], theta[1]), (theta[2], theta[3]), float(theta[4]), start.hexagonal)
    residual = points - lattice.positions(along, across)
    return lattice, prior * _tukey(np.hypot(*residual.T), cap), residual


def grow_lattice(points, start, centre, min_points=12):
    """Index and fit points from the one nearest ``centre`` outwards (region doubled each round).

    A rough start (a pitch within a fraction of a percent, say) is enough:
    each round fits the region it covers, so its prediction is good
    a little further out.

    Returns
    -------
    lattice : Lattice
    along, across : ndarray
        Indices of every point (from the final lattice).
    weights : ndarray
        Biweights (0: outlier, including points more than 0.3 pitch off).
    residuals : ndarray, shape (n, 2)
    """
    points = np.asarray(points, np.float64)
    pitch = start.pitch
    anchor = points[int(np.argmin(np.hypot(*(points - np.asarray(centre)).T)))]
    lattice = Lattice(tuple(anchor), start.row_vector, start.ratio, start.hexagonal)
    distance = np.hypot(*(points - anchor).T)
    radius = 6.0 * pitch
    while True:
        near = distance <= radius
        part = points[near]
        along, across, residual = lattice_indices(part, lattice)
        close = np.hypot(*residual.T) < 0.3 * pitch
        if close.sum() >= min_points:
            lattice, _, _ = fit_lattice(part[close], along[close], across[close], lattice, cap=0.3 * pitch,
                                        iterations=4)
        if near.all():
            break
        radius *= 2.0
    along, across, residual = lattice_indices(points, lattice)
    prior = (np.hypot(*residual.T) < 0.3 * pitch).astype(np.float64)
    lattice, weights, residual = fit_lattice(points, along, across, lattice, prior, cap=0.3 * pitch)
    return lattice, along, across, weights, residual
