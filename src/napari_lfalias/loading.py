"""``load``: one entry point for every supported light-field source."""

from __future__ import annotations

from pathlib import Path

from .errors import DecodeError

__all__ = ["load"]

#: File suffixes of Lytro containers (read through imageio's Lytro plugin).
LYTRO_SUFFIXES = {".lfr", ".lfp", ".raw"}


def load(path, **options):
    """Load a light field from a folder of views or a lenslet capture.

    Parameters
    ----------
    path : str or Path
        - a folder of views (HCI benchmark ``input_CamNNN.png``, Stanford
          ``out_RR_CC_y_x.png``, names with row/column indices, or a plain
          sorted list with ``grid=(U, V)``): see
          :func:`napari_lfalias.decoders.camera_array.load_camera_array`;
        - a lenslet raw image (TIFF, PNG, camera raw, DNG) with
          ``white=...``, or a Lytro LFR/LFP/RAW file: see
          :func:`napari_lfalias.decoders.lenslet.load_lenslet`.
    **options
        Passed to the decoder (``grid``, ``lazy``, ``white``, ``dark``, ...).

    Returns
    -------
    LightField

    Raises
    ------
    DecodeError
        If the path does not exist or is not a recognised light-field source.
    """
    path = Path(path)
    if not path.exists():
        raise DecodeError(f"{path}: no such file or folder")
    if path.is_dir():
        from .decoders.camera_array import load_camera_array

        return load_camera_array(path, **options)
    from .decoders.lenslet import load_lenslet

    return load_lenslet(path, **options)
