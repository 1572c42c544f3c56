"""Gradient-domain (Poisson) solvers and gradient fusion (Perez et al. 2003).

Discretisation
--------------
Pixels are the nodes of the 4-neighbour grid graph of the image. A
gradient field is one value per edge: ``gy[y, x]`` on the edge from
``(y, x)`` to ``(y + 1, x)`` and ``gx[y, x]`` on the edge to ``(y, x + 1)``
(forward differences; the last row of ``gy`` and last column of ``gx``
lie outside the image and are ignored). :func:`divergence` is minus the
adjoint of :func:`gradients`, and ``divergence(*gradients(f))`` is the
5-point Laplacian with Neumann (mirror) boundaries: only edges inside the
image count. A solve finds ``f`` with ``laplacian(f) = div`` -- on the
whole image (:func:`solve_neumann`) or on the pixels of a mask, the others
fixed (:func:`solve_dirichlet`, the discrete equation (7) of Perez et al.).

Solvers
-------
``"dct"`` -- :func:`solve_neumann`: the DCT-II diagonalises the Neumann
Laplacian, so the whole-image solve is two transforms (about 11 ms for
512x512x3 float32 here). Optionally *screened*: ``laplacian(f) -
screen * (f - reference) = div``, which pins low frequencies to
``reference``. It solves for every pixel: fusing with it moves pixels
outside the mask (by a smooth drift that spreads over the whole image).

``"lu"`` -- the exact masked (Dirichlet) solve: a sparse LU
(:func:`scipy.sparse.linalg.splu`) of the masked Laplacian, factored once
and applied to every channel. Exact (1e-8 here), but its cost grows much
faster than the number of unknowns: 0.1-0.3 s at 10 % of a 512x512
image, 1-6 s at 60-85 %.

``"multigrid"`` -- the same masked problem by conjugate gradients
preconditioned with a multigrid V-cycle (:mod:`._poisson_kernels`, numba,
float32), to a relative residual ``tol``: a small multiple of the DCT's
time whatever the mask, and within a few 1e-5 of the LU at the default
``tol=1e-5``.

``"auto"`` (the default of :func:`solve_dirichlet` and
:func:`fuse_gradients`) -- the masked solve, split into the 4-connected
components of the mask (independent problems): components of at most
:data:`SMALL_COMPONENT` unknowns go to one sparse LU, the others to
multigrid; each component is cut out on its bounding box and the boxes
are packed side by side into one small grid (:mod:`._poisson_masked`), so
only the pixels near the mask cost anything.

Why ``"auto"`` is the default: pixels outside the mask are never changed
(the exact solve's property, which Algorithm 2 needs: the in-focus
regions must stay the level-0 refocus), the result is within ~5e-5 of the
exact LU solve, and it costs 0.7-8x the whole-image DCT on 512x512x3 with
masks of 10-85 % (20-25 ms for the brick room's 16 % aliased plane,
0.1-0.26 s for its 84 % one, with the load of this shared 2-core
machine). The DCT fusion, though faster on large masks, moves pixels
outside the mask by up to 0.1-0.18 (10-18 % of the range) on the same
problems, and screening does not fix the maximum. Numbers:
``benchmarks/results/poisson.md``.

Examples
--------
>>> import numpy as np
>>> from napari_lfalias.poisson import fuse_gradients
>>> base = np.zeros((32, 32), np.float32)
>>> source = np.tile(np.linspace(0, 1, 32, dtype=np.float32), (32, 1))
>>> labels = np.zeros((32, 32), np.int8)
>>> labels[8:24, 8:24] = 1
>>> fused = fuse_gradients(base, [source], labels)
>>> bool(np.array_equal(fused[labels == 0], base[labels == 0]))
True
"""

from __future__ import annotations

import importlib

import numpy as np
import scipy.fft

from . import _poisson_masked as _masked
from . import _validate
from ._numerics import unit_scale
from .errors import ParameterError

__all__ = [
    "gradients",
    "divergence",
    "laplacian",
    "solve_neumann",
    "solve_dirichlet",
    "fuse_gradients",
    "METHODS",
    "SMALL_COMPONENT",
]

#: The solvers :func:`solve_dirichlet` and :func:`fuse_gradients` accept.
METHODS = ("auto", "lu", "multigrid", "dct")
#: ``"auto"`` solves the connected components of the mask with at most this
#: many unknowns by one sparse LU (block diagonal: cheap), larger ones by
#: multigrid (:mod:`._poisson_masked`).
SMALL_COMPONENT = 32


# -- input checks ---------------------------------------------------------------

def _image(name, image):
    """``image`` as a finite float (Y, X, C) array (float32 or float64) and whether it was 2-D."""
    array = np.asarray(image)
    if array.ndim not in (2, 3) or min(array.shape, default=0) < 1:
        raise ParameterError(f"{name} must have shape (Y, X) or (Y, X, C), got shape {array.shape}")
    if array.dtype == np.bool_ or not np.issubdtype(array.dtype, np.number) \
            or np.issubdtype(array.dtype, np.complexfloating):
        raise ParameterError(f"{name} must be a real numeric array, got dtype {array.dtype}")
    dtype = np.float64 if array.dtype == np.float64 else np.float32
    array = array.astype(dtype, copy=False)
    if not np.all(np.isfinite(array)):
        raise ParameterError(f"{name} holds NaN or Inf values; pass finite images")
    flat = array.ndim == 2
    return (array[..., None] if flat else array), flat


def _same_shape(name, array, shape):
    if array.shape != shape:
        raise ParameterError(f"{name} must have shape {shape} (like the image), got {array.shape}")


def _mask(name, mask, shape):
    mask = np.asarray(mask)
    if mask.shape != shape:
        raise ParameterError(f"{name} must have shape {shape} (the image's Y, X), got {mask.shape}")
    if mask.dtype != np.bool_:
        raise ParameterError(f"{name} must be a boolean array, got dtype {mask.dtype}")
    return mask


def _tolerance(tol):
    return _validate.in_open_interval("tol", tol, 0.0, 1.0)


def _restore(result, flat, dtype=np.float32):
    result = result.astype(dtype, copy=False)
    return result[..., 0] if flat else result


# -- discrete operators -----------------------------------------------------------

def gradients(image):
    """Forward differences of ``image``: one value per edge of the pixel grid.

    Parameters
    ----------
    image : array_like, shape (Y, X) or (Y, X, C)

    Returns
    -------
    gy, gx : ndarray, like ``image``
        ``gy[y, x] = image[y + 1, x] - image[y, x]`` (0 on the last row),
        ``gx[y, x] = image[y, x + 1] - image[y, x]`` (0 on the last column).

    Examples
    --------
    >>> import numpy as np
    >>> gy, gx = gradients(np.array([[0.0, 1.0], [2.0, 4.0]]))
    >>> gy.tolist(), gx.tolist()
    ([[2.0, 3.0], [0.0, 0.0]], [[1.0, 0.0], [2.0, 0.0]])
    """
    image = np.asarray(image)
    gy = np.zeros_like(image)
    gx = np.zeros_like(image)
    np.subtract(image[1:], image[:-1], out=gy[:-1])
    np.subtract(image[:, 1:], image[:, :-1], out=gx[:, :-1])
    return gy, gx


def divergence(gy, gx):
    """Divergence of an edge field (backward differences, Neumann boundary).

    ``divergence(*gradients(f))`` is the 5-point Laplacian of ``f`` in
    which edges leaving the image do not count. The last row of ``gy`` and
    the last column of ``gx`` (edges outside the image) are ignored.

    Parameters
    ----------
    gy, gx : array_like, shape (Y, X) or (Y, X, C)

    Returns
    -------
    div : ndarray, like ``gy``

    Examples
    --------
    >>> import numpy as np
    >>> f = np.array([[0.0, 1.0], [2.0, 4.0]])
    >>> divergence(*gradients(f)).tolist()
    [[3.0, 2.0], [0.0, -5.0]]
    """
    gy, gx = np.asarray(gy), np.asarray(gx)
    if gy.shape != gx.shape or gy.ndim not in (2, 3):
        raise ParameterError(f"gy and gx must have the same shape (Y, X[, C]), got {gy.shape} and {gx.shape}")
    div = np.zeros(np.broadcast_shapes(gy.shape), np.result_type(gy, gx))
    div[:-1] += gy[:-1]
    div[1:] -= gy[:-1]
    div[:, :-1] += gx[:, :-1]
    div[:, 1:] -= gx[:, :-1]
    return div


def laplacian(image):
    """5-point Laplacian with Neumann boundary: ``divergence(*gradients(image))``."""
    return divergence(*gradients(image))


# -- whole image: DCT ---------------------------------------------------------------

def _neumann_eigenvalues(n_rows, n_cols, dtype):
    """Eigenvalues of the Neumann Laplacian on the DCT-II basis, shape (Y, X, 1)."""
    ey = 2.0 * np.cos(np.pi * np.arange(n_rows) / n_rows) - 2.0
    ex = 2.0 * np.cos(np.pi * np.arange(n_cols) / n_cols) - 2.0
    return (ey[:, None] + ex[None, :])[..., None].astype(dtype)


def _dct_solve(div, screen, reference, mean):
    """``laplacian(f) - screen * (f - reference) = div`` on (Y, X, C) in ``div``'s precision."""
    n_rows, n_cols = div.shape[:2]
    spectrum = scipy.fft.dctn(div, type=2, norm="ortho", axes=(0, 1))
    eig = _neumann_eigenvalues(n_rows, n_cols, div.dtype)
    if screen > 0:
        if reference is not None:
            spectrum -= screen * scipy.fft.dctn(reference, type=2, norm="ortho", axes=(0, 1))
        spectrum /= eig - screen
    else:
        eig[0, 0] = 1.0
        spectrum /= eig
        # the DC coefficient of the orthonormal DCT is mean * sqrt(Y * X)
        spectrum[0, 0] = mean * np.sqrt(n_rows * n_cols)
    return scipy.fft.idctn(spectrum, type=2, norm="ortho", axes=(0, 1))


def solve_neumann(div, *, screen=0.0, reference=None, mean=None):
    """Whole-image Poisson solve, Neumann boundary, by the DCT.

    Solves ``laplacian(f) - screen * (f - reference) = div`` for every
    pixel. Without screening ``f`` is defined up to a constant, set by
    ``mean`` (or the mean of ``reference``, or 0); the part of ``div``
    with a non-zero sum (not a divergence of any field) is dropped.

    Parameters
    ----------
    div : array_like, shape (Y, X) or (Y, X, C)
        The target Laplacian (e.g. ``divergence(gy, gx)``).
    screen : float
        Weight of the data term, >= 0. A small value (1e-3 to 1e-1) keeps
        frequencies below about ``sqrt(screen) / (2 pi)`` cycles/px near
        ``reference``.
    reference : array_like, like ``div``, optional
        The image the data term pulls towards (0 if not given).
    mean : float or sequence of float, optional
        Mean of ``f`` (per channel) when ``screen == 0``.

    Returns
    -------
    f : ndarray, like ``div``, float32 (float64 for float64 input)

    Examples
    --------
    >>> import numpy as np
    >>> y, x = np.mgrid[0:16, 0:24]
    >>> f = np.cos(y / 5.0) * np.sin(x / 7.0)
    >>> g = solve_neumann(laplacian(f), mean=f.mean())
    >>> bool(np.abs(g - f).max() < 1e-9)
    True
    """
    div, flat = _image("div", div)
    screen = _validate.non_negative_float("screen", screen)
    if reference is not None:
        reference, _ = _image("reference", reference)
        _same_shape("reference", reference, div.shape)
        reference = reference.astype(div.dtype, copy=False)
    if mean is None:
        mean = reference.mean(axis=(0, 1)) if reference is not None else np.zeros(div.shape[2])
    mean = np.broadcast_to(np.asarray(mean, np.float64), (div.shape[2],))
    if not np.all(np.isfinite(mean)):
        raise ParameterError(f"mean must be finite, got {mean!r}")
    result = _dct_solve(div.copy(), screen, reference, mean)
    return _restore(result, flat, div.dtype)


# -- masked: Dirichlet ------------------------------------------------------------------

def _check_method(method):
    return _validate.one_of("method", method, METHODS)


def solve_dirichlet(image, mask, div, *, method="auto", tol=1e-5, screen=0.0):
    """Poisson solve on the pixels of ``mask``; the other pixels keep ``image``.

    Finds ``f`` with ``laplacian(f) = div`` at every masked pixel and
    ``f = image`` elsewhere (Dirichlet data on the mask's boundary;
    Neumann at the image's edge). The masked values of ``image`` are not
    used. A mask covering the whole image has no Dirichlet data: it is
    solved by the DCT with the mean of ``image``.

    Parameters
    ----------
    image : array_like, shape (Y, X) or (Y, X, C)
        The fixed values outside ``mask``.
    mask : array_like of bool, shape (Y, X)
        The unknowns.
    div : array_like, like ``image``
        The target Laplacian.
    method : {"auto", "lu", "multigrid", "dct"}
        The solver (module docstring). ``"dct"`` solves the whole image
        (screened by ``screen`` towards ``image``), so it changes pixels
        outside the mask too.
    tol : float
        Relative residual at which ``"multigrid"`` stops, in (0, 1).
    screen : float
        Weight of a data term (>= 0): the masked methods solve
        ``laplacian(f) - screen * (f - image) = div`` on the mask, so
        ``image``'s masked values then pull ``f`` towards them; ``"dct"``
        does so on every pixel.

    Returns
    -------
    f : ndarray, like ``image``, float32

    Examples
    --------
    >>> import numpy as np
    >>> y, x = np.mgrid[0:20, 0:20]
    >>> f = np.sin(y / 4.0) + np.cos(x / 3.0)
    >>> mask = np.zeros((20, 20), bool)
    >>> mask[5:15, 3:12] = True
    >>> g = solve_dirichlet(np.where(mask, 0.0, f), mask, laplacian(f), method="lu")
    >>> bool(np.abs(g - f).max() < 1e-5)
    True
    """
    image, flat = _image("image", image)
    mask = _mask("mask", mask, image.shape[:2])
    div, _ = _image("div", div)
    _same_shape("div", div, image.shape)
    method, tol = _check_method(method), _tolerance(tol)
    screen = _validate.non_negative_float("screen", screen)
    # correction form: f = image + h, h = 0 off the mask, A h = laplacian(image) - div on it

    def rhs(box):
        values = laplacian(image[box].astype(np.float64)) - div[box]
        return np.moveaxis(np.where(mask[box][..., None], values, 0.0), 2, 0)

    return _restore(_apply_correction(image, mask, rhs, method, tol, screen), flat)


def _apply_correction(image, mask, make_rhs, method, tol, screen):
    """``image`` (a float32 copy) plus the correction ``h`` of a masked solve.

    ``h`` solves ``A h = rhs`` on ``mask`` and is 0 elsewhere; only the
    connected components of the mask cost anything
    (:mod:`._poisson_masked`), and ``make_rhs(box)`` gives ``rhs (C, Yb,
    Xb)`` on the mask's bounding box (grown by a pixel).
    ``"dct"`` and a mask covering the whole image solve
    ``laplacian(h) - screen * h = -rhs`` on every pixel instead.
    """
    out = image.astype(np.float32)
    if not mask.any():
        return out
    if method == "dct" or mask.all():
        box = (slice(None), slice(None))
        rhs = np.moveaxis(make_rhs(box), 0, 2).astype(np.float32)
        out += _dct_solve(-rhs, screen, None, np.zeros(rhs.shape[2]))
        return out
    box = _masked.bounding_box(mask)
    h = _masked.solve_masked(mask[box], mask.shape, box, make_rhs(box), method, tol, SMALL_COMPONENT, screen)
    out[box] += np.moveaxis(h, 0, 2)
    return out


# -- fusion ------------------------------------------------------------------------------

def _labels(labels, shape, highest, name="labels", meaning="0 = base, k = sources[k - 1]"):
    """``labels`` as an integer (Y, X) array of ``shape`` with values in ``0 .. highest``."""
    labels = np.asarray(labels)
    if labels.shape != shape:
        raise ParameterError(f"{name} must have shape {shape} (the image's Y, X), got {labels.shape}")
    if not np.issubdtype(labels.dtype, np.integer):
        raise ParameterError(f"{name} must be an integer array, got dtype {labels.dtype}")
    if labels.size and (labels.min() < 0 or labels.max() > highest):
        raise ParameterError(
            f"{name} must lie in 0..{highest} ({meaning}), "
            f"got values in {labels.min()}..{labels.max()}"
        )
    return labels


def fuse_gradients(base, sources, labels, *, method="auto", tol=1e-5, screen=0.0):
    """Gradient-domain fusion: ``base`` where ``labels == 0``, the gradients of ``sources`` elsewhere.

    The pixels with ``labels > 0`` are the unknowns of a Poisson equation
    (Perez et al. 2003, Eq. 7) whose guidance field takes, on every edge,
    the gradient of ``sources[k - 1]`` with ``k`` the larger label of the
    edge's two pixels; the pixels with label 0 are fixed to ``base``.
    Only the bounding box of the labelled pixels is solved, and a source
    is read only on the edges that use it.

    Made for Algorithm 2 of Xiao et al. (2014): ``base`` is the level-0
    refocus, ``sources[l - 1]`` the level-``l`` rendering upsampled to full
    resolution, and ``labels`` the level map ``l*``.

    Parameters
    ----------
    base : array_like, shape (Y, X) or (Y, X, C)
        The image kept where the label is 0.
    sources : sequence of array_like, each like ``base``
        The images whose gradients fill labels ``1 .. len(sources)``.
    labels : array_like of int, shape (Y, X)
        0 keeps ``base``; ``k`` takes its gradients from ``sources[k - 1]``.
    method : {"auto", "lu", "multigrid", "dct"}
        The solver (module docstring). ``"auto"``, ``"lu"`` and
        ``"multigrid"`` never change a pixel with label 0; ``"dct"`` solves
        the whole image and does.
    tol : float
        Relative residual at which ``"multigrid"`` stops, in (0, 1).
    screen : float
        Weight of a data term (>= 0). The masked methods solve the
        *screened* fusion ``laplacian(f) - screen * (f - s) = div(guidance)``
        on the labelled pixels, ``s`` the pixel's own source: a mismatch
        between ``base`` on the mask's boundary and the sources then fades
        within about ``1 / sqrt(screen)`` pixels instead of drifting over
        the whole region (Algorithm 2 uses this). ``"dct"`` pulls every
        pixel towards ``base`` instead.

    Returns
    -------
    fused : ndarray, like ``base``, float32

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> base = rng.random((24, 24, 3)).astype(np.float32)
    >>> labels = np.zeros((24, 24), np.int8)
    >>> labels[6:18, 4:20] = 1
    >>> fused = fuse_gradients(base, [base + 0.5], labels)
    >>> bool(np.abs(fused - base).max() < 1e-5)
    True
    """
    base, flat = _image("base", base)
    if isinstance(sources, np.ndarray):
        sources = list(sources)
    if not isinstance(sources, (list, tuple)):
        raise ParameterError(f"sources must be a sequence of images shaped like base, got {type(sources).__name__}")
    checked = []
    for k, source in enumerate(sources):
        source, _ = _image(f"sources[{k}]", source)
        _same_shape(f"sources[{k}]", source, base.shape)
        checked.append(source)
    labels = _labels(labels, base.shape[:2], len(checked))
    method, tol = _check_method(method), _tolerance(tol)
    screen = _validate.non_negative_float("screen", screen)
    scale = unit_scale(max(float(np.abs(image).max(initial=0.0)) for image in [base, *checked]))
    if scale != 1.0:  # the fusion is linear: solve near 1, where float32 residuals cannot overflow
        fused = fuse_gradients(base * np.float32(scale), [source * np.float32(scale) for source in checked], labels,
                               method=method, tol=tol, screen=screen)
        return _restore(fused / np.float32(scale), flat)

    def rhs(box):
        # the divergence of grad(base) - guidance (on the labelled pixels, unless the DCT solves them all)
        kernels = importlib.import_module("._poisson_kernels", __package__)
        out = kernels.fusion_rhs(base[box], [source[box] for source in checked], labels[box], method == "dct")
        if screen > 0 and method != "dct":
            # the data term screen * (source - base) pulls each labelled pixel towards its own source
            for k, source in enumerate(checked, start=1):
                own = labels[box] == k
                out[:, own] += screen * np.moveaxis(source[box][own] - base[box][own], -1, 0)
        return out

    return _restore(_apply_correction(base, labels > 0, rhs, method, tol, screen), flat)
