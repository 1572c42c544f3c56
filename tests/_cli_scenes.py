"""Small light fields with known disparity, written to real files, for the CLI, sweep and batch tests."""

from pathlib import Path

import numpy as np

import napari_lfalias as lfa
from napari_lfalias import io_write


def plane_lightfield(n=5, size=48, disparity=1, channels=1, seed=0):
    """A textured fronto-parallel plane at integer ``disparity`` seen by ``n x n`` views.

    A point at centre pixel ``p`` is seen in view ``(u, v)`` at
    ``p + disparity * positions[u, v]`` (DESIGN section 2), exactly: the
    views are integer crops of one random texture.
    """
    rng = np.random.default_rng(seed)
    half = n // 2
    pad = abs(disparity) * half + 1
    texture = rng.random((size + 2 * pad, size + 2 * pad, channels), dtype=np.float32)
    positions = lfa.regular_positions(n, n)
    views = np.empty((n, n, size, size, channels), np.float32)
    for u in range(n):
        for v in range(n):
            dy, dx = (disparity * positions[u, v]).astype(int)
            # view(x) = centre(x - d * q)
            views[u, v] = texture[pad - dy: pad - dy + size, pad - dx: pad - dx + size]
    return lfa.LightField(views, positions, {"source": "plane", "disparity_range": (disparity, disparity)})


def write_plane(path, **kw):
    """Write :func:`plane_lightfield` as a light-field TIFF/zarr; return (path, light field)."""
    lf = plane_lightfield(**kw)
    io_write.write_lightfield(path, lf)
    return Path(path), lf


def temporaries(folder):
    """Every temporary name left anywhere under ``folder``; asked while a writer works there, a folder that
    goes away during the walk (a temporary renamed into place) means the walk is made again."""
    while True:
        try:
            return [p for p in Path(folder).rglob("*") if io_write.is_temporary(p)]
        except FileNotFoundError:
            continue


def write_views_folder(folder, lf):
    """Write a one-channel ``lf`` as a camera-array folder of 16-bit PNGs named ``view_RR_CC.png``."""
    import imageio.v3 as iio

    folder = Path(folder)
    folder.mkdir(parents=True)
    for u in range(lf.grid_shape[0]):
        for v in range(lf.grid_shape[1]):
            pixels = np.round(np.clip(lf.data[u, v, :, :, 0], 0, 1) * 65535).astype(np.uint16)
            iio.imwrite(folder / f"view_{u:02d}_{v:02d}.png", pixels)
    return folder


def write_views_with_a_nan(folder, grid=(3, 3), shape=(16, 20), at=(1, 2, 4, 5)):
    """A camera-array folder of float32 TIFF views ``view_U_V.tif``, all 0.5 but one NaN sample at ``at``
    (view row, view column, y, x)."""
    import tifffile

    folder = Path(folder)
    folder.mkdir(parents=True)
    for u in range(grid[0]):
        for v in range(grid[1]):
            view = np.full(shape, 0.5, np.float32)
            if (u, v) == tuple(at[:2]):
                view[at[2], at[3]] = np.nan
            tifffile.imwrite(folder / f"view_{u}_{v}.tif", view)
    return folder
