"""HCI 4D light-field benchmark metadata: ``parameters.cfg`` and PFM disparity maps.

The benchmark (Honauer et al., ACCV 2016) stores views as
``input_CamNNN.png`` (``NNN = row * n_cols + col``), the scene parameters
in an INI file ``parameters.cfg``, and the ground-truth disparity of the
centre view in ``gt_disp_lowres.pfm``. HCI's disparity has the opposite
sign of this package's: a point of HCI disparity ``d`` at centre pixel
``p`` is seen in view ``(u, v)`` at ``p - d * positions[u, v]``, so
:func:`hci_metadata` returns ``-d``.
"""

from __future__ import annotations

import configparser
import re
from pathlib import Path

import numpy as np

from ..errors import DecodeError

__all__ = ["read_pfm", "read_parameters_cfg", "hci_metadata", "GT_DISPARITY_NAME", "PARAMETERS_NAME"]

GT_DISPARITY_NAME = "gt_disp_lowres.pfm"
PARAMETERS_NAME = "parameters.cfg"
#: Header of a PFM file: type, width, height, scale, each followed by whitespace.
_PFM_HEADER = re.compile(rb"^(P[Ff])\s+(\d+)\s+(\d+)\s+([-+0-9.eE]+)\s")


def read_pfm(path):
    """Read a PFM (portable float map) image, top row first.

    Parameters
    ----------
    path : str or Path
        A ``Pf`` (grey) or ``PF`` (RGB) file. A negative scale means
        little-endian samples; rows are stored bottom-up and are flipped.

    Returns
    -------
    image : ndarray, shape (Y, X) or (Y, X, 3), float32

    Raises
    ------
    DecodeError
        If the file is missing, has no PFM header, or is truncated.

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> path = os.path.join(tempfile.mkdtemp(), "d.pfm")
    >>> rows = np.array([[1, 2], [3, 4]], "<f4")  # stored bottom-up
    >>> with open(path, "wb") as f:
    ...     _ = f.write(b"Pf\\n2 2\\n-1.0\\n" + rows.tobytes())
    >>> read_pfm(path).tolist()
    [[3.0, 4.0], [1.0, 2.0]]
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise DecodeError(f"{path}: cannot read the PFM file ({exc.strerror})") from exc
    match = _PFM_HEADER.match(raw[:256])
    if match is None:
        raise DecodeError(f"{path}: not a PFM file (no 'Pf'/'PF' header); replace or remove it")
    kind, width, height, scale = match.groups()
    channels = 3 if kind == b"PF" else 1
    width, height = int(width), int(height)
    try:
        scale = float(scale)
    except ValueError as exc:
        raise DecodeError(f"{path}: PFM scale {scale!r} is not a number") from exc
    dtype = np.dtype("<f4" if scale < 0 else ">f4")
    count = width * height * channels
    body = raw[match.end():]
    if len(body) < count * 4:
        raise DecodeError(
            f"{path}: truncated PFM file: {len(body)} bytes of data for a {width}x{height}x{channels} "
            f"image that needs {count * 4}; replace the file"
        )
    data = np.frombuffer(body, dtype, count).astype(np.float32)
    shape = (height, width) if channels == 1 else (height, width, 3)
    return np.ascontiguousarray(np.flipud(data.reshape(shape)))


def _value(text):
    """A number as float, anything else as the stripped string."""
    try:
        return float(text)
    except ValueError:
        return text.strip()


def read_parameters_cfg(path):
    """Read an HCI ``parameters.cfg`` into one flat dictionary.

    Parameters
    ----------
    path : str or Path
        The INI file (sections ``intrinsics``, ``extrinsics``, ``meta``).

    Returns
    -------
    params : dict
        Every key of every section (``baseline_mm``, ``focal_length_mm``,
        ``disp_min``, ``num_cams_x``, ...); numbers as floats, other values
        as strings.

    Raises
    ------
    DecodeError
        If the file cannot be read or is not an INI file.

    Examples
    --------
    >>> import tempfile, os
    >>> path = os.path.join(tempfile.mkdtemp(), "parameters.cfg")
    >>> with open(path, "w") as f:
    ...     _ = f.write("[extrinsics]\\nbaseline_mm = 30.0\\n[meta]\\nscene = dino\\n")
    >>> read_parameters_cfg(path)
    {'baseline_mm': 30.0, 'scene': 'dino'}
    """
    path = Path(path)
    parser = configparser.ConfigParser(interpolation=None)
    try:
        with open(path, encoding="utf-8") as handle:
            parser.read_file(handle)
    except OSError as exc:
        raise DecodeError(f"{path}: cannot read the HCI parameters file ({exc.strerror})") from exc
    except (configparser.Error, UnicodeDecodeError) as exc:
        raise DecodeError(
            f"{path}: not an HCI parameters.cfg (INI) file ({exc}); fix or remove it"
        ) from exc
    return {key: _value(value) for section in parser.sections() for key, value in parser[section].items()}


def _check_camera_count(params, grid_shape, cfg_path):
    expected = params.get("num_cams_y"), params.get("num_cams_x")
    if all(isinstance(n, float) for n in expected) and tuple(int(n) for n in expected) != tuple(grid_shape):
        raise DecodeError(
            f"{cfg_path}: says {int(expected[0])}x{int(expected[1])} cameras but the views were read as a "
            f"{grid_shape[0]}x{grid_shape[1]} grid (grid=); leave grid out to use the file's grid"
        )


def hci_metadata(folder, grid_shape, image_shape):
    """Metadata of an HCI benchmark folder, disparity in this package's sign.

    Parameters
    ----------
    folder : Path
        The scene folder.
    grid_shape : tuple of int
        ``(U, V)`` of the views found.
    image_shape : tuple of int
        ``(Y, X)`` of one view.

    Returns
    -------
    meta : dict
        ``"nearer"`` (``"smaller"``: which disparities are in front, the
        rig's geometry; :func:`~napari_lfalias.depth_guided.occlusion_order`),
        ``"hci"`` (the parameters, when ``parameters.cfg`` exists),
        ``"disparity"`` ((Y, X) float32, the negated ground truth, when
        ``gt_disp_lowres.pfm`` exists) and ``"disparity_range"`` (from the
        ground truth, else from the parameters' ``disp_min``/``disp_max``).

    Raises
    ------
    DecodeError
        If a metadata file is unreadable or disagrees with the views.
    """
    folder = Path(folder)
    # the HCI rig's geometry, in this package's sign: smaller disparities are nearer (antinous's ground
    # truth judged so by the views at its depth edges: test_camera_array)
    meta = {"nearer": "smaller"}
    cfg_path = folder / PARAMETERS_NAME
    if cfg_path.is_file():
        params = read_parameters_cfg(cfg_path)
        _check_camera_count(params, grid_shape, cfg_path)
        meta["hci"] = params
        low, high = params.get("disp_min"), params.get("disp_max")
        if isinstance(low, float) and isinstance(high, float):
            meta["disparity_range"] = (-high, -low)
    gt_path = folder / GT_DISPARITY_NAME
    if gt_path.is_file():
        gt = read_pfm(gt_path)
        if gt.shape != tuple(image_shape):
            raise DecodeError(
                f"{gt_path}: disparity map is {gt.shape[1]}x{gt.shape[0]} but the views are "
                f"{image_shape[1]}x{image_shape[0]}; it belongs to another scene: replace or remove it"
            )
        disparity = -gt  # HCI's sign is the opposite of ours (module docstring)
        meta["disparity"] = disparity
        finite = disparity[np.isfinite(disparity)]
        if finite.size:
            meta["disparity_range"] = (float(finite.min()), float(finite.max()))
    return meta
