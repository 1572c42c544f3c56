"""Numba kernels of the masked Poisson solvers (:mod:`napari_lfalias.poisson`).

Two parts: the right-hand side of a gradient fusion, and conjugate
gradients preconditioned by a multigrid V-cycle.

The masked problem is ``A h = r`` on the unknown pixels of a mask, where
``A`` is the 5-point graph Laplacian with conductance 1 between
4-neighbours inside the image, and the neighbours outside the mask are
fixed (Dirichlet): they add to the diagonal and nothing else. ``A`` is
symmetric positive definite as soon as every connected component of the
mask has a fixed neighbour.

Multigrid levels carry a ghost ring of zeros, so the stencil needs no
bounds checks. Each level stores five arrays of shape ``(Y + 2, X + 2)``:

- ``wy[i, j]``: conductance between cells ``(i, j)`` and ``(i + 1, j)``
  (0 unless both are unknown);
- ``wx[i, j]``: conductance between ``(i, j)`` and ``(i, j + 1)``;
- ``diag[i, j]``: the diagonal of ``A`` (0 on cells that are not unknowns);
- ``scaled_inv``: ``SMOOTHING / diag`` (0 off the unknowns);
- ``inside``: 1 on the unknowns, else 0.

Coarse levels aggregate 2x2 cells (piecewise-constant prolongation ``P``,
restriction ``P^T``) with the Galerkin operator ``P^T A P`` scaled by
:data:`COARSE_SCALE`: piecewise-constant aggregation makes the coarse
Laplacian about twice too stiff, and scaling it down restores the coarse
correction (over-correction, as in unsmoothed-aggregation multigrid). The
coarsest level is solved exactly (dense inverse). The smoother is damped
Jacobi, the same number of sweeps before and after the coarse correction,
so the V-cycle is a symmetric positive definite preconditioner and
conjugate gradients converge on it. Every loop is branch-free over a row,
so it vectorises; values are float32, sums float64. Kernels run on one
thread: the V-cycle is many short loops, and on a loaded machine thread
barriers cost more than they save.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["Hierarchy", "build_hierarchy", "pcg", "fusion_rhs"]

#: Scale of the Galerkin coarse operators (see the module docstring).
COARSE_SCALE = 0.6
#: Damping of the Jacobi smoother (4/5 is the best smoother of the 5-point Laplacian).
SMOOTHING = 0.8
#: Stop coarsening when a level has at most this many unknowns.
COARSEST_UNKNOWNS = 96

_jit = njit(cache=True, fastmath=True, error_model="numpy")
_jit_inline = njit(cache=True, fastmath=True, error_model="numpy", inline="always")


# -- fusion right-hand side ------------------------------------------------------

@_jit
def _fusion_rhs(differences, labels, every_pixel, out):
    """``out[c, i, j] = sum over the 4-neighbours q of p = (i, j) of D_k(q) - D_k(p)``.

    ``differences[k] = D_k = base - sources[k - 1]`` (``D_0 = 0``) with
    ``k`` the larger label of ``p`` and ``q``: the divergence of
    ``grad(base) - guidance``. Neighbours outside the arrays do not count.
    Pixels with label 0 get 0 unless ``every_pixel`` (a whole-image solve
    needs them too).
    """
    n_rows, n_cols, n_ch = differences.shape[1:]
    for i in range(n_rows):
        for j in range(n_cols):
            lp = labels[i, j]
            for c in range(n_ch):
                out[c, i, j] = 0.0
            if lp == 0 and not every_pixel:
                continue
            for d in range(4):
                qi = i + (1 if d == 0 else (-1 if d == 1 else 0))
                qj = j + (1 if d == 2 else (-1 if d == 3 else 0))
                if qi < 0 or qi >= n_rows or qj < 0 or qj >= n_cols:
                    continue
                k = max(lp, labels[qi, qj])
                for c in range(n_ch):
                    out[c, i, j] += differences[k, qi, qj, c] - differences[k, i, j, c]


def fusion_rhs(base, sources, labels, every_pixel=False):
    """The fusion's ``A h = rhs`` right-hand side ``(C, Y, X)`` float64 (see :func:`_fusion_rhs`).

    ``base`` and every source ``(Y, X, C)``, ``labels (Y, X)`` with values
    in ``0 .. len(sources)``. ``base - source`` is exactly 0 where they are
    equal, so fusing an image with itself changes nothing.
    """
    differences = np.zeros((len(sources) + 1,) + base.shape, np.float32)
    for k, source in enumerate(sources):
        np.subtract(base, source, out=differences[k + 1], casting="unsafe")
    out = np.empty((base.shape[2],) + base.shape[:2])
    _fusion_rhs(differences, np.ascontiguousarray(labels, np.int32), bool(every_pixel), out)
    return out


# -- multigrid levels -------------------------------------------------------------

class Hierarchy:
    """The levels of the multigrid preconditioner for one mask, packed in flat arrays.

    Plain arrays rather than a ``numba.typed.List``: typed lists make numba
    compile their helpers again in every process (about 2 s), while the
    kernels on plain arrays load from its cache.

    Attributes
    ----------
    ops : ndarray, shape (5, total), float32
        ``wy, wx, diag, scaled_inv, inside`` of every level, each level's
        padded ``(Y + 2, X + 2)`` array flattened at ``offsets[level]``.
    shapes : ndarray, shape (L, 2), int64
        The padded shape of every level, finest first.
    offsets : ndarray, shape (L + 1,), int64
        Where each level starts in ``ops`` (and, times C, in the work buffers).
    coarse_index : ndarray, shape (m, 2), int64
        Cells ``(i, j)`` of the unknowns of the coarsest level.
    coarse_inverse : ndarray, shape (m, m), float64
        Inverse of the coarsest operator on those unknowns.
    """

    def __init__(self, levels, coarse_index, coarse_inverse):
        self.shapes = np.array([level[0].shape for level in levels], np.int64)
        sizes = self.shapes[:, 0] * self.shapes[:, 1]
        self.offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        self.ops = np.empty((5, int(self.offsets[-1])), np.float32)
        for level, arrays in enumerate(levels):
            for field, array in enumerate(arrays):
                self.ops[field, self.offsets[level]:self.offsets[level + 1]] = array.ravel()
        self.coarse_index = coarse_index
        self.coarse_inverse = coarse_inverse

    @property
    def n_levels(self):
        return len(self.shapes)


@_jit_inline
def _field(ops, shapes, offsets, level, field):
    """Field ``field`` (0 wy, 1 wx, 2 diag, 3 scaled_inv, 4 inside) of ``level``: a (Y + 2, X + 2) view."""
    n_rows, n_cols = shapes[level, 0], shapes[level, 1]
    return ops[field][offsets[level]:offsets[level] + n_rows * n_cols].reshape(n_rows, n_cols)


@_jit_inline
def _work(buffer, n_ch, shapes, offsets, level):
    """Level ``level`` of a flat work buffer: a (C, Y + 2, X + 2) view."""
    n_rows, n_cols = shapes[level, 0], shapes[level, 1]
    start = n_ch * offsets[level]
    return buffer[start:start + n_ch * n_rows * n_cols].reshape(n_ch, n_rows, n_cols)


@_jit
def _finish_level(diag, scaled_inv, inside, smoothing):
    n_rows, n_cols = diag.shape
    count = 0
    for i in range(n_rows):
        for j in range(n_cols):
            d = diag[i, j]
            if d > 0.0:
                scaled_inv[i, j] = smoothing / d
                inside[i, j] = 1.0
                count += 1
    return count


@_jit
def _fine_level(mask, degree, wy, wx, diag):
    """Operator of the finest level for ``mask (Y, X)`` (True = unknown) into padded arrays (zeroed).

    ``degree (Y, X)`` is the diagonal: the pixel's neighbours in the image,
    fixed or not (Neumann at the image's edge).
    """
    n_rows, n_cols = mask.shape
    for y in range(n_rows):
        for x in range(n_cols):
            if not mask[y, x]:
                continue
            i, j = y + 1, x + 1
            diag[i, j] = degree[y, x]
            if y < n_rows - 1 and mask[y + 1, x]:
                wy[i, j] = 1.0
            if x < n_cols - 1 and mask[y, x + 1]:
                wx[i, j] = 1.0


@_jit
def _coarsen(wy, wx, diag, cwy, cwx, cdiag, scale):
    """Scaled Galerkin operator of the 2x2 aggregates of a padded level into zeroed coarse arrays."""
    n_rows, n_cols = diag.shape[0] - 2, diag.shape[1] - 2
    for i in range(1, n_rows + 1):
        ci = (i + 1) // 2
        first_row = i % 2 == 1  # the aggregate's upper row: its edge down stays inside
        for j in range(1, n_cols + 1):
            cj = (j + 1) // 2
            first_col = j % 2 == 1
            cdiag[ci, cj] += scale * diag[i, j]
            if first_row:
                cdiag[ci, cj] -= 2.0 * scale * wy[i, j]
            else:
                cwy[ci, cj] += scale * wy[i, j]
            if first_col:
                cdiag[ci, cj] -= 2.0 * scale * wx[i, j]
            else:
                cwx[ci, cj] += scale * wx[i, j]


def _level(shape):
    return tuple(np.zeros(shape, np.float32) for _ in range(5))


def _dense_operator(wy, wx, diag):
    """The operator of a (small) level as a dense matrix over its unknowns, and their cells."""
    index = np.argwhere(diag > 0)
    number = -np.ones(diag.shape, np.int64)
    number[index[:, 0], index[:, 1]] = np.arange(len(index))
    matrix = np.diag(diag[index[:, 0], index[:, 1]].astype(np.float64))
    for weights, (di, dj) in ((wy, (1, 0)), (wx, (0, 1))):
        for k, (i, j) in enumerate(index):
            w = weights[i, j]
            if w > 0:
                q = number[i + di, j + dj]
                matrix[k, q] -= w
                matrix[q, k] -= w
    return matrix, index


def build_hierarchy(mask, degree):
    """The multigrid levels for the unknowns ``mask (Y, X)`` with diagonal ``degree (Y, X)``.

    Every component of the mask must have a fixed neighbour (its degree
    exceeds its unknown neighbours somewhere), or ``A`` is singular.
    """
    mask = np.ascontiguousarray(mask, np.bool_)
    level = _level((mask.shape[0] + 2, mask.shape[1] + 2))
    _fine_level(mask, np.ascontiguousarray(degree, np.float32), *level[:3])
    levels = []
    while True:
        count = _finish_level(*level[2:], SMOOTHING)
        levels.append(level)
        n_rows, n_cols = level[2].shape[0] - 2, level[2].shape[1] - 2
        if count <= COARSEST_UNKNOWNS or max(n_rows, n_cols) <= 1:
            break
        coarse = _level(((n_rows + 1) // 2 + 2, (n_cols + 1) // 2 + 2))
        _coarsen(*level[:3], *coarse[:3], COARSE_SCALE)
        level = coarse
    matrix, index = _dense_operator(*level[:3])
    inverse = np.linalg.inv(matrix) if len(index) else np.zeros((0, 0))
    return Hierarchy(levels, index.astype(np.int64), inverse)


# -- kernels ------------------------------------------------------------------
# Values are (C, Y + 2, X + 2) float32. The loops have no branches (cells that
# are not unknowns have zero weights, diagonal and inverse diagonal), so the
# inner loops over a row vectorise; sums are float64.


@_jit
def _apply_dot(wy, wx, diag, u, out, dots):
    """``out = A u`` (0 off the unknowns) and ``dots[c] = <u, A u>``."""
    n_ch, n_rows, n_cols = u.shape
    for c in range(n_ch):
        acc = 0.0
        for i in range(1, n_rows - 1):
            for j in range(1, n_cols - 1):
                out[c, i, j] = (diag[i, j] * u[c, i, j] - wy[i - 1, j] * u[c, i - 1, j]
                                - wy[i, j] * u[c, i + 1, j] - wx[i, j - 1] * u[c, i, j - 1]
                                - wx[i, j] * u[c, i, j + 1])
            for j in range(1, n_cols - 1):
                acc += out[c, i, j] * u[c, i, j]
        dots[c] = acc


@_jit
def _jacobi(wy, wx, diag, scaled_inv, u, rhs, out):
    """One damped Jacobi sweep ``out = u + omega D^-1 (rhs - A u)``; ``scaled_inv = omega / D`` (0 off the unknowns)."""
    n_ch, n_rows, n_cols = u.shape
    for c in range(n_ch):
        for i in range(1, n_rows - 1):
            for j in range(1, n_cols - 1):
                au = (diag[i, j] * u[c, i, j] - wy[i - 1, j] * u[c, i - 1, j] - wy[i, j] * u[c, i + 1, j]
                      - wx[i, j - 1] * u[c, i, j - 1] - wx[i, j] * u[c, i, j + 1])
                out[c, i, j] = u[c, i, j] + scaled_inv[i, j] * (rhs[c, i, j] - au)


@_jit
def _scale(scaled_inv, rhs, out):
    """The first Jacobi sweep from a zero guess: ``out = omega D^-1 rhs``."""
    n_ch, n_rows, n_cols = rhs.shape
    for c in range(n_ch):
        for i in range(n_rows):
            for j in range(n_cols):
                out[c, i, j] = scaled_inv[i, j] * rhs[c, i, j]


@_jit
def _restrict_residual(wy, wx, diag, u, rhs, coarse_rhs):
    """``coarse_rhs = P^T (rhs - A u)``: the residual summed over each 2x2 aggregate."""
    n_ch, n_rows, n_cols = u.shape
    work = np.empty(n_cols, np.float32)
    coarse_rhs[:] = 0.0
    for c in range(n_ch):
        for i in range(1, n_rows - 1):
            for j in range(1, n_cols - 1):
                work[j] = rhs[c, i, j] - (
                    diag[i, j] * u[c, i, j] - wy[i - 1, j] * u[c, i - 1, j] - wy[i, j] * u[c, i + 1, j]
                    - wx[i, j - 1] * u[c, i, j - 1] - wx[i, j] * u[c, i, j + 1])
            ci = (i + 1) // 2
            for cj in range(1, (n_cols - 1) // 2 + 1):
                coarse_rhs[c, ci, cj] += work[2 * cj - 1]
            for cj in range(1, n_cols // 2):
                coarse_rhs[c, ci, cj] += work[2 * cj]


@_jit
def _prolong_add(inside, coarse, u):
    """``u += P coarse`` on the unknowns (``inside`` is 1 there, else 0)."""
    n_ch, n_rows, n_cols = u.shape
    row = np.empty(n_cols, np.float32)
    for c in range(n_ch):
        for i in range(1, n_rows - 1):
            ci = (i + 1) // 2
            for j in range(1, n_cols - 1):
                row[j] = coarse[c, ci, (j + 1) // 2]
            for j in range(1, n_cols - 1):
                u[c, i, j] += inside[i, j] * row[j]


@_jit
def _coarsest(coarse_index, coarse_inverse, rhs, u):
    """``u = A^-1 rhs`` on the coarsest level (dense inverse)."""
    m, n_ch = coarse_index.shape[0], u.shape[0]
    for c in range(n_ch):
        for a in range(m):
            acc = 0.0
            for b in range(m):
                acc += coarse_inverse[a, b] * rhs[c, coarse_index[b, 0], coarse_index[b, 1]]
            u[c, coarse_index[a, 0], coarse_index[a, 1]] = acc


@_jit
def _vcycle(ops, shapes, offsets, us, tmps, rhss, coarse_index, coarse_inverse, sweeps, n_ch):
    """``us[0] = M^-1 rhss[0]``: one symmetric V-cycle from a zero guess.

    ``ops``, ``shapes`` and ``offsets`` are a :class:`Hierarchy`'s; ``us``,
    ``tmps`` and ``rhss`` flat work buffers laid out like it (times ``n_ch``).
    ``sweeps`` damped Jacobi sweeps before and after the coarse correction
    (an even number, so the result lands in ``us``).
    """
    n_levels = shapes.shape[0]
    for level in range(n_levels - 1):
        wy, wx, diag = (_field(ops, shapes, offsets, level, 0), _field(ops, shapes, offsets, level, 1),
                        _field(ops, shapes, offsets, level, 2))
        scaled_inv = _field(ops, shapes, offsets, level, 3)
        u, tmp = _work(us, n_ch, shapes, offsets, level), _work(tmps, n_ch, shapes, offsets, level)
        rhs = _work(rhss, n_ch, shapes, offsets, level)
        _scale(scaled_inv, rhs, tmp)
        _jacobi(wy, wx, diag, scaled_inv, tmp, rhs, u)
        for _ in range(1, sweeps // 2):
            _jacobi(wy, wx, diag, scaled_inv, u, rhs, tmp)
            _jacobi(wy, wx, diag, scaled_inv, tmp, rhs, u)
        _restrict_residual(wy, wx, diag, u, rhs, _work(rhss, n_ch, shapes, offsets, level + 1))
    last = n_levels - 1
    _coarsest(coarse_index, coarse_inverse, _work(rhss, n_ch, shapes, offsets, last),
              _work(us, n_ch, shapes, offsets, last))
    for level in range(n_levels - 2, -1, -1):
        wy, wx, diag = (_field(ops, shapes, offsets, level, 0), _field(ops, shapes, offsets, level, 1),
                        _field(ops, shapes, offsets, level, 2))
        scaled_inv, inside = _field(ops, shapes, offsets, level, 3), _field(ops, shapes, offsets, level, 4)
        u, tmp = _work(us, n_ch, shapes, offsets, level), _work(tmps, n_ch, shapes, offsets, level)
        rhs = _work(rhss, n_ch, shapes, offsets, level)
        _prolong_add(inside, _work(us, n_ch, shapes, offsets, level + 1), u)
        for _ in range(sweeps // 2):
            _jacobi(wy, wx, diag, scaled_inv, u, rhs, tmp)
            _jacobi(wy, wx, diag, scaled_inv, tmp, rhs, u)


@_jit
def _step(x, r, p, q, alpha, dots):
    """``x += alpha p``, ``r -= alpha q``; ``dots[c] = <r, r>``."""
    n_ch, n_rows, n_cols = x.shape
    for c in range(n_ch):
        a = alpha[c]
        acc = 0.0
        for i in range(n_rows):
            for j in range(n_cols):
                x[c, i, j] += a * p[c, i, j]
                value = r[c, i, j] - a * q[c, i, j]
                r[c, i, j] = value
                acc += value * value
        dots[c] = acc


@_jit
def _dot(a, b, dots):
    """``dots[c] = <a, b>``."""
    n_ch, n_rows, n_cols = a.shape
    for c in range(n_ch):
        acc = 0.0
        for i in range(n_rows):
            for j in range(n_cols):
                acc += a[c, i, j] * b[c, i, j]
        dots[c] = acc


@_jit
def _direction(z, beta, p):
    """``p = z + beta p``."""
    n_ch, n_rows, n_cols = p.shape
    for c in range(n_ch):
        b = beta[c]
        for i in range(n_rows):
            for j in range(n_cols):
                p[c, i, j] = z[c, i, j] + b * p[c, i, j]


@_jit
def _pcg(ops, shapes, offsets, us, tmps, rhss, coarse_index, coarse_inverse, tol, max_iter, sweeps, x):
    """Preconditioned CG on ``A x = rhs`` (level 0 of ``rhss``) from ``x = 0``; returns the iterations.

    Level 0 of ``rhss`` holds the residual as the iterations go (it is the
    V-cycle's right-hand side); level 0 of ``us`` the preconditioned residual.
    """
    n_ch = x.shape[0]
    wy, wx, diag = _field(ops, shapes, offsets, 0, 0), _field(ops, shapes, offsets, 0, 1), _field(ops, shapes, offsets, 0, 2)
    r, z = _work(rhss, n_ch, shapes, offsets, 0), _work(us, n_ch, shapes, offsets, 0)
    q = np.zeros_like(x)
    rr, rz, pq = np.zeros(n_ch), np.zeros(n_ch), np.zeros(n_ch)
    alpha, beta = np.zeros(n_ch), np.zeros(n_ch)
    _dot(r, r, rr)
    goal = (tol * tol) * rr
    if np.all(rr <= 0.0):
        return 0
    _vcycle(ops, shapes, offsets, us, tmps, rhss, coarse_index, coarse_inverse, sweeps, n_ch)
    p = z.copy()
    _dot(r, z, rz)
    for iteration in range(1, max_iter + 1):
        _apply_dot(wy, wx, diag, p, q, pq)
        for c in range(n_ch):
            alpha[c] = rz[c] / pq[c] if pq[c] > 0.0 else 0.0
        _step(x, r, p, q, alpha, rr)
        if np.all(rr <= goal):
            return iteration
        _vcycle(ops, shapes, offsets, us, tmps, rhss, coarse_index, coarse_inverse, sweeps, n_ch)
        for c in range(n_ch):
            beta[c] = rz[c]
        _dot(r, z, rz)
        for c in range(n_ch):
            beta[c] = rz[c] / beta[c] if beta[c] > 0.0 else 0.0
        _direction(z, beta, p)
    return max_iter


def pcg(hierarchy, rhs, tol=1e-6, max_iter=200, sweeps=2):
    """Solve ``A h = rhs`` for every channel; ``rhs (C, Y, X)`` on the unknowns (0 elsewhere).

    Returns ``(h (C, Y, X) float32, iterations)``; the iterations stop when
    the residual of every channel has fallen by ``tol`` (relative to ``rhs``).
    """
    n_ch = rhs.shape[0]
    size = n_ch * int(hierarchy.offsets[-1])
    us, tmps, rhss = (np.zeros(size, np.float32) for _ in range(3))
    fine = tuple(int(n) for n in hierarchy.shapes[0])
    rhss[:n_ch * fine[0] * fine[1]].reshape((n_ch,) + fine)[:, 1:-1, 1:-1] = rhs
    x = np.zeros((n_ch,) + fine, np.float32)
    iterations = _pcg(hierarchy.ops, hierarchy.shapes, hierarchy.offsets, us, tmps, rhss, hierarchy.coarse_index,
                      hierarchy.coarse_inverse, float(tol), int(max_iter), 2 * max(1, int(sweeps) // 2), x)
    return x[:, 1:-1, 1:-1], iterations
