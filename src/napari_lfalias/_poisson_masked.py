"""The masked (Dirichlet) Poisson solve of :mod:`napari_lfalias.poisson`: ``A h = rhs`` on a mask.

``A`` is the graph Laplacian of the unknown pixels: on the diagonal the
number of the pixel's neighbours inside the image (fixed or not; Neumann
at the image's edge), -1 between unknown 4-neighbours. Its 4-connected
components are independent problems, so only they cost anything:

- each component is cut out on its bounding box (grown by a pixel), and
  the boxes of one solver are packed side by side, a pixel apart, into one
  small *atlas*: one solve for many components, with no cost for the
  pixels between them (the degree of every pixel comes from the image, so
  a component on the image's edge keeps its Neumann boundary); when the
  components' common bounding box is smaller than the atlas, they are
  solved in place on it;
- ``"auto"`` sends the components of at most ``small`` unknowns to one
  sparse LU (block diagonal: cheap) and the others to multigrid;
  ``"lu"`` and ``"multigrid"`` send every component to that solver.
"""

from __future__ import annotations

import importlib

import numpy as np
import scipy.sparse
import scipy.sparse.linalg
from scipy import ndimage

__all__ = ["bounding_box", "solve_masked"]


def bounding_box(mask):
    """Slices of the bounding box of ``mask`` grown by one pixel (clipped to the array)."""
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    return (slice(max(rows[0] - 1, 0), min(rows[-1] + 2, mask.shape[0])),
            slice(max(cols[0] - 1, 0), min(cols[-1] + 2, mask.shape[1])))


def _degree(image_shape, box):
    """Number of in-image 4-neighbours of every pixel of ``box``."""
    rows = np.arange(box[0].start, box[0].stop)
    cols = np.arange(box[1].start, box[1].stop)
    dy = 2.0 - (rows == 0) - (rows == image_shape[0] - 1)
    dx = 2.0 - (cols == 0) - (cols == image_shape[1] - 1)
    return dy[:, None] + dx[None, :]


# -- solvers on one grid ------------------------------------------------------------

def _masked_laplacian(mask, degree):
    """``A`` (CSC) of the unknowns ``mask``: ``degree`` on the diagonal, -1 between unknown neighbours."""
    number = np.full(mask.shape, -1, np.int64)
    n = int(np.count_nonzero(mask))
    number[mask] = np.arange(n)
    rows, cols = [], []
    for a, b in ((number[:-1], number[1:]), (number[:, :-1], number[:, 1:])):
        both = (a >= 0) & (b >= 0)
        rows += [a[both], b[both]]
        cols += [b[both], a[both]]
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    off = scipy.sparse.csc_matrix((-np.ones(len(rows)), (rows, cols)), shape=(n, n))
    return (off + scipy.sparse.diags(degree[mask])).tocsc()


def _solve_lu(mask, degree, rhs, tol):
    """``A h = rhs`` by one sparse LU for every channel; ``rhs (C, Y, X)``."""
    lu = scipy.sparse.linalg.splu(_masked_laplacian(mask, degree))
    h = np.zeros(rhs.shape, np.float64)
    h[:, mask] = lu.solve(np.ascontiguousarray(rhs[:, mask].T, np.float64)).T
    return h


def _solve_multigrid(mask, degree, rhs, tol):
    """``A h = rhs`` by multigrid-preconditioned CG to a relative residual ``tol``; ``rhs (C, Y, X)``."""
    kernels = importlib.import_module("._poisson_kernels", __package__)
    lock = importlib.import_module(".refocus", __package__)._KERNEL_LOCK
    hierarchy = kernels.build_hierarchy(mask, degree)
    with lock:
        h, _ = kernels.pcg(hierarchy, rhs, tol=tol)
    return h


_SOLVERS = {"lu": _solve_lu, "multigrid": _solve_multigrid}


# -- components and atlases ----------------------------------------------------------

def _pack(shapes, gap=1):
    """Shelf packing of rectangles ``(h, w)``: their top-left corners and the atlas shape.

    Rectangles are laid left to right on shelves, tallest first, ``gap``
    pixels apart; the shelf width is about the side of the square of the
    same total area (at least the widest rectangle).
    """
    shapes = np.asarray(shapes)
    width = max(int(shapes[:, 1].max()), int(np.sqrt((shapes + gap).prod(axis=1).sum()) * 1.1))
    corners = np.zeros_like(shapes)
    y = x = shelf = 0
    for k in np.argsort(-shapes[:, 0], kind="stable"):
        h, w = shapes[k]
        if x > 0 and x + w > width:
            y, x, shelf = y + shelf + gap, 0, 0
        corners[k] = (y, x)
        x += w + gap
        shelf = max(shelf, h)
    return corners, (y + shelf, width)


def _layout(tiles):
    """Where the tiles go: ``(corners, shape)`` of a packed atlas, or of their common box if that is smaller.

    In their common box the tiles keep their places (their unknowns never
    touch: they are distinct components).
    """
    corners, shape = _pack([unknowns.shape for _, unknowns in tiles])
    top = min(box[0].start for box, _ in tiles)
    left = min(box[1].start for box, _ in tiles)
    common = (max(box[0].stop for box, _ in tiles) - top, max(box[1].stop for box, _ in tiles) - left)
    if common[0] * common[1] <= shape[0] * shape[1]:
        corners = np.array([(box[0].start - top, box[1].start - left) for box, _ in tiles])
        shape = common
    return corners, shape


def _solve_atlas(tiles, rhs, degree, solver, tol):
    """Solve the components ``tiles`` (``(box, unknowns)``, boxes of ``rhs``) together on one grid.

    Returns the corrections ``h`` of the tiles, in their order.
    """
    corners, shape = _layout(tiles)
    mask = np.zeros(shape, bool)
    atlas_degree = np.zeros(shape)
    atlas_rhs = np.zeros((rhs.shape[0],) + shape)
    places = []
    for (box, unknowns), (y, x) in zip(tiles, corners):
        place = (slice(y, y + unknowns.shape[0]), slice(x, x + unknowns.shape[1]))
        places.append(place)
        mask[place] |= unknowns
        atlas_degree[place] = degree[box]
        atlas_rhs[(slice(None),) + place] += np.where(unknowns, rhs[(slice(None),) + box], 0.0)
    h = solver(mask, atlas_degree, atlas_rhs, tol)
    return [h[(slice(None),) + place] for place in places]


def _components(mask, small):
    """The 4-connected components of ``mask`` as ``(box, unknowns)``, split into small and large."""
    labels, count = ndimage.label(mask)
    sizes = np.bincount(labels.ravel(), minlength=count + 1)
    groups = ([], [])
    for k, (rows, cols) in enumerate(ndimage.find_objects(labels), start=1):
        box = (slice(max(rows.start - 1, 0), min(rows.stop + 1, mask.shape[0])),
               slice(max(cols.start - 1, 0), min(cols.stop + 1, mask.shape[1])))
        groups[int(sizes[k] > small)].append((box, labels[box] == k))
    return groups


def solve_masked(mask, image_shape, box, rhs, method, tol, small, screen=0.0):
    """The correction ``h (C, Yb, Xb)`` of ``(A + screen) h = rhs`` on ``mask (Yb, Xb)``, 0 elsewhere.

    ``mask`` and ``rhs (C, Yb, Xb)`` cover ``box`` of an image of
    ``image_shape`` (for the degrees); ``method`` is ``"auto"``, ``"lu"``
    or ``"multigrid"``; ``small`` the largest component ``"auto"`` sends to
    the LU. ``screen >= 0`` adds a data term: it is added to the diagonal.
    """
    degree = _degree(image_shape, box) + screen
    small_tiles, large_tiles = _components(mask, small if method == "auto" else np.inf)
    if method == "multigrid":
        small_tiles, large_tiles = [], small_tiles
    h = np.zeros(rhs.shape)
    for tiles, solver in ((small_tiles, _solve_lu), (large_tiles, _solve_multigrid)):
        if tiles:
            for (tile_box, unknowns), tile_h in zip(tiles, _solve_atlas(tiles, rhs, degree, solver, tol)):
                h[(slice(None),) + tile_box] += np.where(unknowns, tile_h, 0.0)
    return h
