"""The :class:`LightField` container: views, their positions, and metadata."""

from __future__ import annotations

import numpy as np

from .errors import NonFiniteError, ParameterError

__all__ = ["LightField", "regular_positions", "REC709"]

#: Rec. 709 luminance weights for (R, G, B).
REC709 = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
#: What ``nonfinite`` may say: refuse NaN or Inf samples, or give them weight 0.
NONFINITE = ("raise", "mask")


def _rec709(colour):
    """The luminance ``(..., 1)`` float32 of ``colour (..., 3)``, on every core.

    The same float32 sums (``R * 0.2126 + G * 0.7152 + B * 0.0722``, left to
    right) whatever the array's layout or chunks: numpy's matmul rounds
    contiguous and strided data differently, and differently again by
    version, so an estimate of a light field read from a TIFF (its colour
    planes moved last: a strided array) or loaded lazily would differ in
    the last bits from that of the array that was saved.
    """
    from .refocus import _run

    lum = np.empty(colour.shape[:-1] + (1,), np.float32)
    # a strided array one row of views at a time: a contiguous copy of a row, not of the whole light field
    parts = [(colour, lum)] if colour.flags.c_contiguous or colour.ndim < 3 else zip(colour, lum)
    for part, out in parts:
        _run("rec709", np.ascontiguousarray(part, np.float32).reshape(-1, 3), REC709, out.reshape(-1))
    return lum


def regular_positions(n_rows, n_cols):
    """View positions of a regular ``n_rows x n_cols`` grid, centred on 0.

    Parameters
    ----------
    n_rows, n_cols : int
        Number of view rows ``U`` and view columns ``V``.

    Returns
    -------
    positions : ndarray, shape (U, V, 2), float64
        ``(y, x)`` of each view in units of the grid step:
        ``(u - (U - 1) / 2, v - (V - 1) / 2)``.
    """
    u = np.arange(n_rows, dtype=np.float64) - (n_rows - 1) / 2
    v = np.arange(n_cols, dtype=np.float64) - (n_cols - 1) / 2
    return np.stack(np.meshgrid(u, v, indexing="ij"), axis=-1)


def _is_lazy(array):
    return not isinstance(array, np.ndarray) and hasattr(array, "compute")


def _as_array(name, value, dtype=None):
    """``np.asarray(value, dtype)``, or a ParameterError naming ``name`` for ragged or non-numeric input."""
    try:
        return np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{name} must be a regular array of numbers; {' '.join(str(exc).split())}") from exc


def _as_float32_views(data):
    """Return ``data`` as a 5-D float32 array (numpy or dask), ints scaled to [0, 1]."""
    if not _is_lazy(data):
        data = _as_array("data", data)
    if data.ndim == 4:
        data = data[..., None]
    if data.ndim != 5:
        raise ParameterError(
            "data must have shape (U, V, Y, X) or (U, V, Y, X, C); "
            f"got an array with {data.ndim} dimensions, shape {tuple(data.shape)}"
        )
    if data.shape[-1] not in (1, 3):
        raise ParameterError(
            f"data must have 1 or 3 channels in its last axis, got shape {tuple(data.shape)}"
        )
    if min(data.shape[:4]) < 1:
        raise ParameterError(f"data has an empty axis: shape {tuple(data.shape)}")
    dtype = np.dtype(data.dtype)
    if dtype == np.bool_ or not (np.issubdtype(dtype, np.number)):
        raise ParameterError(f"data must be numeric, got dtype {dtype}")
    if np.issubdtype(dtype, np.complexfloating):
        raise ParameterError("data must be real, got a complex array")
    if np.issubdtype(dtype, np.integer):
        scale = np.float32(np.iinfo(dtype).max)
        return data.astype(np.float32) / scale
    if dtype.itemsize <= 4 or _is_lazy(data):
        return data.astype(np.float32, copy=False)
    with np.errstate(over="ignore"):
        out = data.astype(np.float32)
    if not np.isfinite(out).all():
        overflowed = np.isinf(out) & np.isfinite(data)
        if overflowed.any():
            largest = float(np.max(np.abs(data[overflowed])))
            raise ParameterError(
                f"data holds {int(overflowed.sum())} finite {dtype} values beyond float32's range "
                f"(largest magnitude {largest:.3g} > {float(np.finfo(np.float32).max):.3g}); "
                "scale the data into float32's range first")
    return out


class LightField:
    """A 4-D light field: a grid of views with their positions and metadata.

    Parameters
    ----------
    data : array_like, shape (U, V, Y, X[, C])
        View ``(u, v)`` is ``data[u, v]``. Stored as float32 with linear
        intensity, nominally in [0, 1]; integer input is divided by its
        dtype's maximum. A missing channel axis is added (``C = 1``).
        A dask array is kept lazy.
    positions : array_like, shape (U, V, 2), optional
        ``(y, x)`` position of each view in units of the grid step, centred
        on 0. Defaults to the regular grid of :func:`regular_positions`.
    meta : dict, optional
        Free-form metadata (source, ground-truth disparity, grid model, ...).
        ``meta["nearer"]`` (``"larger"`` or ``"smaller"``), where set, is
        which disparities are in front: every rendering of the light field
        orders occlusions so (:func:`~napari_lfalias.depth_guided.occlusion_order`).
    nonfinite : {"raise", "mask"}
        What to do with NaN or Inf samples: raise a ``ParameterError``
        (default), or give them zero weight (see ``weights``). Lazy data
        are checked when they are computed (:meth:`compute`).
    weights : array_like, shape (U, V, Y, X), optional
        Validity weight of each sample in [0, 1] (for example vignetting
        in a lenslet decode). Weight 0 means "not observed". ``None`` means
        every sample has weight 1.

    Raises
    ------
    ParameterError
        If the shapes are inconsistent, positions are not finite, or the
        data hold NaN/Inf and ``nonfinite="raise"``.

    Examples
    --------
    >>> import numpy as np
    >>> lf = LightField(np.zeros((3, 3, 8, 8, 3), np.float32))
    >>> lf.shape
    (3, 3, 8, 8, 3)
    >>> lf.positions[0, 0].tolist()
    [-1.0, -1.0]
    """

    def __init__(self, data, positions=None, meta=None, *, nonfinite="raise", weights=None):
        data = _as_float32_views(data)
        n_rows, n_cols = data.shape[:2]
        if positions is None:
            positions = regular_positions(n_rows, n_cols)
        positions = _as_array("positions", positions, np.float64)
        if positions.shape != (n_rows, n_cols, 2):
            raise ParameterError(
                f"positions must have shape (U, V, 2) = ({n_rows}, {n_cols}, 2) to match data, "
                f"got {positions.shape}"
            )
        if not np.all(np.isfinite(positions)):
            raise ParameterError("positions must be finite")
        if weights is not None:
            weights = _as_array("weights", weights, np.float32)
            if weights.shape != tuple(data.shape[:4]):
                raise ParameterError(
                    f"weights must have shape (U, V, Y, X) = {tuple(data.shape[:4])}, got {weights.shape}"
                )
            if not np.all(np.isfinite(weights)) or weights.min() < 0 or weights.max() > 1:
                raise ParameterError("weights must be finite and lie in [0, 1]")
        if nonfinite not in NONFINITE:
            raise ParameterError(f"nonfinite must be 'raise' or 'mask', got {nonfinite!r}")
        self._nonfinite = nonfinite
        if not _is_lazy(data):
            bad = ~np.isfinite(data)
            if bad.any():
                if nonfinite == "raise":
                    raise NonFiniteError(
                        f"data holds {int(bad.sum())} NaN/Inf samples; clean them, or pass "
                        "nonfinite='mask' to give them zero weight"
                    )
                bad_sample = bad.any(axis=-1)
                data = np.where(bad, np.float32(0), data)
                weights = np.ones(data.shape[:4], np.float32) if weights is None else weights.copy()
                weights[bad_sample] = 0
        self.data = data
        self.positions = positions
        self.weights = weights
        self.meta = dict(meta) if meta else {}

    @classmethod
    def _derived(cls, data, positions, meta=None, weights=None, nonfinite="raise"):
        """A light field made by this package from a validated one: no checks, no copies.

        ``data`` must be a 5-D float32 array (numpy or dask) of finite
        values, ``positions`` and ``weights`` of matching shapes.
        """
        lf = cls.__new__(cls)
        lf.data, lf.positions, lf.weights = data, positions, weights
        lf.meta = dict(meta) if meta else {}
        lf._nonfinite = nonfinite
        return lf

    # -- shape helpers -------------------------------------------------
    @property
    def shape(self):
        """``(U, V, Y, X, C)``."""
        return tuple(self.data.shape)

    @property
    def grid_shape(self):
        """``(U, V)``: the number of view rows and columns."""
        return tuple(self.data.shape[:2])

    @property
    def image_shape(self):
        """``(Y, X)``: the size of one view."""
        return tuple(self.data.shape[2:4])

    @property
    def n_views(self):
        """Number of views ``U * V``."""
        return int(self.data.shape[0] * self.data.shape[1])

    @property
    def n_channels(self):
        """Number of channels ``C`` (1 or 3)."""
        return int(self.data.shape[4])

    @property
    def is_lazy(self):
        """True when :attr:`data` is a dask array read on demand."""
        return _is_lazy(self.data)

    def compute(self):
        """Return a light field whose data are an in-memory numpy array.

        NaN and Inf samples are checked now, as ``nonfinite`` said when the
        light field was made (refused, or given weight 0).
        """
        if not self.is_lazy:
            return self
        return LightField(np.asarray(self.data.compute()), self.positions, self.meta, weights=self.weights,
                          nonfinite=self._nonfinite)

    def views(self):
        """Return the data as ``(n, Y, X, C)`` in-memory views, row-major over (U, V).

        For lazy data, use ``compute().views()`` with ``compute().flat_weights()``
        when NaN samples may have been masked (their weights are known only then).
        """
        data = np.asarray(self.compute().data)
        return data.reshape((-1,) + data.shape[2:])

    def flat_positions(self):
        """Return the positions as ``(n, 2)``, in the same order as :meth:`views`."""
        return self.positions.reshape(-1, 2)

    def flat_weights(self):
        """Return the sample weights as ``(n, Y, X)``, or ``None`` if all are 1."""
        return None if self.weights is None else self.weights.reshape((-1,) + self.image_shape)

    def luminance(self):
        """Return a one-channel light field: Rec. 709 luminance of colour data."""
        if self.n_channels == 1:
            return self
        data = self.data if self.is_lazy else np.asarray(self.data)
        if data.shape[-1] != 3:
            lum = (data @ REC709)[..., None]  # numpy's error for a channel count Rec. 709 has no weights for
        elif self.is_lazy:
            data = data.rechunk({data.ndim - 1: -1})
            lum = data.map_blocks(_rec709, chunks=data.chunks[:-1] + ((1,),), dtype=np.float32)
        else:
            lum = _rec709(data)
        return LightField._derived(lum, self.positions, self.meta, self.weights, self._nonfinite)

    def subset(self, rows=slice(None), cols=slice(None)):
        """Return the light field of a sub-grid of views, keeping their positions.

        Parameters
        ----------
        rows, cols : slice or sequence of int
            The view rows and columns to keep (numpy indexing).
        """
        data = self.data[rows][:, cols]
        positions = self.positions[rows][:, cols]
        weights = None if self.weights is None else self.weights[rows][:, cols]
        meta = dict(self.meta)
        return LightField(data, positions, meta, weights=weights, nonfinite=self._nonfinite)

    def __repr__(self):
        lazy = ", lazy" if self.is_lazy else ""
        return f"LightField(shape={self.shape}{lazy}, source={self.meta.get('source', '?')!r})"
