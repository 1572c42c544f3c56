"""Which tiles of an image hold work: the sweeps, detections and renderings skip the others."""

import numpy as np

__all__ = ["tiles_holding"]


def tiles_holding(mask, tile):
    """``(TY, TX)`` bool: the tiles of ``tile`` px (an int, or ``(rows, columns)``) holding a pixel of
    ``mask (Y, X)``; the last row and column of tiles may stick out of the image.

    Examples
    --------
    >>> mask = np.zeros((5, 7), bool)
    >>> mask[4, 1] = True
    >>> tiles_holding(mask, (2, 3)).astype(int)
    array([[0, 0, 0],
           [0, 0, 0],
           [1, 0, 0]])
    """
    rows, cols = (tile, tile) if np.ndim(tile) == 0 else tile
    n_rows, n_cols = -(-mask.shape[0] // rows), -(-mask.shape[1] // cols)
    padded = np.zeros((n_rows * rows, n_cols * cols), bool)
    padded[:mask.shape[0], :mask.shape[1]] = mask
    return padded.reshape(n_rows, rows, n_cols, cols).any(axis=(1, 3))
