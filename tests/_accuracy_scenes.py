"""Helpers of the accuracy tests (disparity, dense-aperture rendering, disparity-guided reduction)."""

import sys
from pathlib import Path

import numpy as np
from scipy import ndimage

import napari_lfalias as lfa


def as_user_has_it(lf):
    """``lf`` without the ground truth a synthetic scene stores in its metadata.

    A synthetic light field's ``meta`` holds ``disparity`` and
    ``disparity_range``; :func:`napari_lfalias.estimate_disparity` searches
    around ``meta["disparity_range"]``, which for a single plane is the
    answer. Users' light fields carry no such thing, and neither may the
    tests' ones.
    """
    return lfa.LightField(lf.data, lf.positions, {"source": "test"}, weights=lf.weights)


def benchmark_cases():
    """``benchmarks/accuracy_cases.py`` (not a package): the benchmark's scenes, references and truth."""
    path = str(Path(__file__).resolve().parents[1] / "benchmarks")
    if path not in sys.path:
        sys.path.insert(0, path)
    import accuracy_cases  # noqa: E402

    return accuracy_cases


def distance_from_depth_edges(disparity):
    """Distance (px) of every pixel from the nearest pixel whose 4-neighbour has another disparity."""
    edge = np.zeros(disparity.shape, bool)
    jumps_y = np.diff(disparity, axis=0) != 0
    jumps_x = np.diff(disparity, axis=1) != 0
    edge[:-1] |= jumps_y
    edge[1:] |= jumps_y
    edge[:, :-1] |= jumps_x
    edge[:, 1:] |= jumps_x
    if not edge.any():
        return np.full(disparity.shape, np.inf)
    return ndimage.distance_transform_edt(~edge)


def slanted_plane(n_views=5, size=160, slant=(0.08, 0.0), offset=0.3, contrast=0.1, noise=0.0, seed=0, flat_from=None):
    """A grey light field of one plane whose disparity is ``offset + slant . (p - centre)`` (px per px), and
    that disparity ``(size, size)``: the layered scenes of :mod:`napari_lfalias.synthetic` are fronto-parallel.

    The plane's texture is white noise blurred by a Gaussian of 1 px
    (standard deviation ``contrast`` about 0.5), drawn in every view at
    the point of the plane that projects there (cubic interpolation);
    ``noise`` adds sensor noise of that standard deviation to every view;
    from the row ``flat_from`` of the centre view on, the plane has no
    texture (a flat grey 0.5).
    """
    rng = np.random.default_rng(seed)
    margin = 64
    texture = ndimage.gaussian_filter(rng.standard_normal((size + 2 * margin,) * 2), 1.0)
    texture = 0.5 + contrast * texture / texture.std()
    if flat_from is not None:
        texture[margin + flat_from:] = 0.5
    centre = (size - 1) / 2.0
    steps = np.arange(n_views) - (n_views - 1) / 2.0
    grid = np.mgrid[0:size, 0:size].reshape(2, -1) - centre
    data = np.empty((n_views, n_views, size, size, 1), np.float32)
    positions = np.zeros((n_views, n_views, 2))
    for i, qy in enumerate(steps):
        for j, qx in enumerate(steps):
            positions[i, j] = (qy, qx)
            # view q shows the plane's point t at t + d(t) q: solve that (linear in t) for t
            shear = np.array([[1 + slant[0] * qy, slant[1] * qy], [slant[0] * qx, 1 + slant[1] * qx]])
            seen = np.linalg.solve(shear, grid - offset * np.array([[qy], [qx]]))
            view = ndimage.map_coordinates(texture, seen + centre + margin, order=3, mode="reflect")
            if noise:
                view = view + noise * rng.standard_normal(view.shape)
            data[i, j, ..., 0] = view.reshape(size, size)
    truth = offset + slant[0] * grid[0].reshape(size, size) + slant[1] * grid[1].reshape(size, size)
    return lfa.LightField(data, positions, {"source": "slanted plane"}), truth
