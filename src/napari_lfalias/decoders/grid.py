"""The lenslet grid model: where every microlens centre lies on the sensor.

A :class:`GridModel` is an ideal lattice (rectangular or hexagonal) with a
pitch, a rotation and an offset, fitted to a white image by
:func:`napari_lfalias.decoders.calibration.calibrate`. In the model's frame
the lens rows run along the unit vector ``e_x = (sin r, cos r)`` and the
rows follow each other along ``e_y = (cos r, -sin r)`` (``(y, x)`` image
coordinates, ``r`` the rotation), so lens ``(i, j)`` is centred at::

    offset + i * row_step * e_y + (j + s_i / 2) * pitch * e_x

with ``row_step`` the distance between lens rows (``row_spacing``; by
default ``pitch`` on a rectangular grid and ``pitch * sqrt(3) / 2`` on a
hexagonal one, but fitted on its own, as LFToolbox fits its horizontal and
vertical spacings, since real arrays and renderings are not always exactly
regular), and ``s_i = 1`` on the shifted rows of a hexagonal grid
(``i % 2 == hex_shift_row``), 0 otherwise. A hexagonal grid whose lens
rows run vertically is modelled on the transposed image
(``transposed=True``): its ``(y, x)`` are the image's ``(x, y)``.

The decoder's output pixel ``(y, x)`` sits at :meth:`GridModel.pixel_centres`:
``offset + y * row_step * e_y + x * pitch * e_x``, the lens ``(y, x)``
itself, on a rectangular grid, and ``offset + row_step * (y * e_y + x * e_x)``,
square pixels of side ``row_step``, on a hexagonal one.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field

import numpy as np

from ..errors import CalibrationError

__all__ = ["GridModel", "GRID_KINDS", "JSON_FORMAT", "DISTORTION_TERMS", "distortion_terms"]

GRID_KINDS = ("rectangular", "hexagonal")
#: ``format`` entry of a grid model's JSON.
JSON_FORMAT = "napari-lfalias lenslet grid"
_JSON_VERSION = 1
_SQRT3_2 = math.sqrt(3.0) / 2.0
#: Monomials ``y^a x^b`` (a + b <= 3) of the distortion polynomial, in this order.
DISTORTION_TERMS = ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2), (3, 0), (2, 1), (1, 2), (0, 3))


def distortion_terms(points, shape):
    """Monomials ``(..., len(DISTORTION_TERMS))`` of points normalised to [-1, 1] over an image of ``shape``."""
    points = np.asarray(points, np.float64)
    half = np.asarray(shape, np.float64) / 2.0
    y = (points[..., 0] - half[0]) / half[0]
    x = (points[..., 1] - half[1]) / half[1]
    one = np.ones_like(y)
    ys, xs = [one, y, y * y, y * y * y], [one, x, x * x, x * x * x]
    return np.stack([ys[a] * xs[b] for a, b in DISTORTION_TERMS], axis=-1)


def _check_distortion(value):
    if value is None or len(value) == 0:
        return ()
    try:
        coeffs = tuple(tuple(float(c) for c in axis) for axis in value)
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"grid distortion must be two lists of numbers ({exc})") from exc
    if len(coeffs) != 2 or any(len(axis) != len(DISTORTION_TERMS) for axis in coeffs):
        raise CalibrationError(f"grid distortion must be two lists of {len(DISTORTION_TERMS)} coefficients")
    if not all(math.isfinite(c) for axis in coeffs for c in axis):
        raise CalibrationError("grid distortion coefficients must be finite")
    return coeffs


@dataclass(frozen=True)
class GridModel:
    """A calibrated microlens grid (see the module notes for the geometry).

    Parameters
    ----------
    kind : {"rectangular", "hexagonal"}
        Lattice of the microlens array.
    pitch : float
        Distance between neighbouring lens centres along a row, in pixels.
    rotation : float
        Angle of the lens rows from the image's x axis, in degrees,
        positive towards +y (clockwise on screen).
    offset : tuple of float
        ``(y, x)`` of the lattice origin: the centre of lens ``(0, 0)``
        (plus ``pitch / 2`` along the row when row 0 is a shifted row).
    n_rows, n_cols : int
        Lens rows and lenses per row covering the image.
    image_shape : tuple of int
        ``(height, width)`` of the image the model was fitted on.
    hex_shift_row : int
        0 or 1: rows ``i`` with ``i % 2 == hex_shift_row`` are shifted by
        half a pitch along the row (hexagonal grids only; 0 otherwise).
    transposed : bool
        True when the model describes the transposed image (hexagonal
        grids whose rows run vertically).
    distortion : tuple
        Empty for an ideal lattice, else two sequences of
        ``DISTORTION_TERMS`` coefficients: a cubic polynomial (y, x)
        displacement of the lens centres, in pixels, over the image's
        normalised coordinates (see :meth:`displacement`).
    fit : dict
        Facts about the fit (lenses used, residual); informative only.
    row_spacing : float, optional
        Distance between lens rows in pixels; default the regular lattice's
        (``pitch``, or ``pitch * sqrt(3) / 2`` on a hexagonal grid). Within
        0.75 to 1.33 times that.

    Examples
    --------
    >>> grid = GridModel("rectangular", pitch=10.0, rotation=0.0, offset=(5.0, 5.0),
    ...                  n_rows=4, n_cols=6, image_shape=(40, 60))
    >>> grid.centres[:2].tolist()
    [[5.0, 5.0], [5.0, 15.0]]
    >>> GridModel.from_json(grid.to_json()) == grid
    True
    """

    kind: str
    pitch: float
    rotation: float
    offset: tuple
    n_rows: int
    n_cols: int
    image_shape: tuple
    hex_shift_row: int = 0
    transposed: bool = False
    distortion: tuple = ()
    fit: dict = field(default_factory=dict, compare=False)
    row_spacing: float | None = None

    def __post_init__(self):
        if self.kind not in GRID_KINDS:
            raise CalibrationError(f"grid kind must be one of {GRID_KINDS}, got {self.kind!r}")
        numbers = {"pitch": self.pitch, "rotation": self.rotation}
        for name, value in numbers.items():
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
                raise CalibrationError(f"grid {name} must be a number, got {value!r}")
            if not math.isfinite(float(value)):
                raise CalibrationError(f"grid {name} must be finite, got {value!r}")
        if not float(self.pitch) >= 2.0:
            raise CalibrationError(f"grid pitch must be at least 2 pixels, got {self.pitch!r}")
        offset = tuple(float(v) for v in np.asarray(self.offset, np.float64).ravel())
        if len(offset) != 2 or not all(math.isfinite(v) for v in offset):
            raise CalibrationError(f"grid offset must be two finite numbers (y, x), got {self.offset!r}")
        shape = tuple(int(v) for v in np.asarray(self.image_shape).ravel())
        if len(shape) != 2 or min(shape) < 1:
            raise CalibrationError(f"grid image_shape must be (height, width), got {self.image_shape!r}")
        if int(self.n_rows) < 1 or int(self.n_cols) < 1:
            raise CalibrationError(f"grid must have at least one lens, got {self.n_rows} x {self.n_cols}")
        if int(self.hex_shift_row) not in (0, 1):
            raise CalibrationError(f"hex_shift_row must be 0 or 1, got {self.hex_shift_row!r}")
        object.__setattr__(self, "pitch", float(self.pitch))
        object.__setattr__(self, "rotation", float(self.rotation))
        object.__setattr__(self, "offset", offset)
        object.__setattr__(self, "image_shape", shape)
        object.__setattr__(self, "n_rows", int(self.n_rows))
        object.__setattr__(self, "n_cols", int(self.n_cols))
        object.__setattr__(self, "hex_shift_row", int(self.hex_shift_row) if self.is_hexagonal else 0)
        object.__setattr__(self, "transposed", bool(self.transposed))
        object.__setattr__(self, "fit", dict(self.fit or {}))
        object.__setattr__(self, "distortion", _check_distortion(self.distortion))
        object.__setattr__(self, "row_spacing", self._checked_row_spacing())

    def _checked_row_spacing(self):
        regular = self.pitch * (_SQRT3_2 if self.is_hexagonal else 1.0)
        if self.row_spacing is None:
            return regular
        value = self.row_spacing
        if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)) \
                or not math.isfinite(float(value)):
            raise CalibrationError(f"grid row_spacing must be a finite number, got {value!r}")
        if not 0.75 * regular <= float(value) <= 1.33 * regular:
            raise CalibrationError(
                f"grid row_spacing {float(value):.4g} px is not within 0.75 to 1.33 times the regular "
                f"{self.kind} spacing {regular:.4g} px for pitch {self.pitch:.4g} px"
            )
        return float(value)

    # -- geometry ------------------------------------------------------------
    @property
    def is_hexagonal(self):
        """True for a hexagonal grid."""
        return self.kind == "hexagonal"

    @property
    def row_step(self):
        """Distance between lens rows in pixels (the decoded pixel's height; its width too on a hexagonal grid)."""
        return self.row_spacing

    @property
    def column_step(self):
        """Distance between decoded pixels along the lens rows: ``pitch`` (rectangular) or ``row_step`` (hexagonal)."""
        return self.row_step if self.is_hexagonal else self.pitch

    @property
    def axes(self):
        """Unit vectors ``(e_y, e_x)`` of the model frame, as (y, x) pairs (model coordinates)."""
        angle = math.radians(self.rotation)
        e_x = np.array([math.sin(angle), math.cos(angle)])
        e_y = np.array([math.cos(angle), -math.sin(angle)])
        return e_y, e_x

    @property
    def model_shape(self):
        """``(height, width)`` of the image in model coordinates (swapped when transposed)."""
        return self.image_shape[::-1] if self.transposed else self.image_shape

    def row_shifts(self):
        """``(n_rows,)`` half-pitch shift flags ``s_i`` (0 or 1) of the lens rows."""
        rows = np.arange(self.n_rows)
        if not self.is_hexagonal:
            return np.zeros(self.n_rows, np.int64)
        return (rows % 2 == self.hex_shift_row).astype(np.int64)

    def lens_grid(self):
        """Centres of every lens ``(n_rows, n_cols, 2)``, ``(y, x)`` in model coordinates."""
        e_y, e_x = self.axes
        rows = np.arange(self.n_rows, dtype=np.float64)[:, None]
        cols = np.arange(self.n_cols, dtype=np.float64)[None, :] + 0.5 * self.row_shifts()[:, None]
        along = (cols * self.pitch)[..., None] * e_x
        across = (rows * self.row_step)[..., None] * e_y
        ideal = np.asarray(self.offset) + along + across
        return ideal + self.displacement(ideal)

    def displacement(self, points):
        """Distortion ``(..., 2)`` of the lens centres at model points ``(..., 2)`` (zeros without one)."""
        points = np.asarray(points, np.float64)
        if not self.distortion:
            return np.zeros_like(points)
        terms = distortion_terms(points, self.model_shape)
        return np.stack([terms @ np.asarray(self.distortion[0]), terms @ np.asarray(self.distortion[1])], axis=-1)

    def _to_image(self, points):
        return points[..., ::-1] if self.transposed else points

    @property
    def centres(self):
        """``(n, 2)`` (row, col) image coordinates of the lens centres inside the image.

        Row-major over the lens grid; lenses whose centre falls outside the
        image (corners of a rotated grid) are left out.
        """
        points = self._to_image(self.lens_grid().reshape(-1, 2))
        height, width = self.image_shape
        inside = (
            (points[:, 0] >= -0.5) & (points[:, 0] <= height - 0.5)
            & (points[:, 1] >= -0.5) & (points[:, 1] <= width - 0.5)
        )
        return points[inside]

    @property
    def n_lenses(self):
        """Number of lens centres inside the image."""
        return int(len(self.centres))

    def output_shape(self):
        """``(Y, X)`` of the decoded views before trimming: one pixel per lens row and ``row_step`` along it."""
        if not self.is_hexagonal:
            return self.n_rows, self.n_cols
        last = (self.n_cols - 1 + 0.5) * self.pitch / self.row_step
        return self.n_rows, int(math.floor(last + 1e-9)) + 1

    def pixel_centres(self, rows, cols):
        """Model ``(y, x)`` of decoded pixels ``(rows, cols)`` (arrays that broadcast), on the ideal lattice.

        Examples
        --------
        >>> grid = GridModel("hexagonal", 10.0, 0.0, (0.0, 0.0), 3, 3, (30, 30))
        >>> grid.pixel_centres(np.array([1]), np.array([2])).round(3).tolist()
        [[8.66, 17.321]]
        """
        e_y, e_x = self.axes
        rows = np.asarray(rows, np.float64)[..., None]
        cols = np.asarray(cols, np.float64)[..., None]
        return np.asarray(self.offset) + rows * self.row_step * e_y + cols * self.column_step * e_x

    # -- JSON ----------------------------------------------------------------
    def to_dict(self):
        """The model as JSON-ready types."""
        out = {"format": JSON_FORMAT, "version": _JSON_VERSION}
        out.update(asdict(self))
        out["offset"] = list(self.offset)
        out["image_shape"] = list(self.image_shape)
        out["distortion"] = [list(c) for c in self.distortion]
        return out

    def to_json(self):
        """The model as JSON text (read back by :meth:`from_json`).

        Returns
        -------
        str
        """
        return json.dumps(self.to_dict(), indent=2)

    @classmethod
    def from_dict(cls, data):
        """Build a model from :meth:`to_dict` output; raises CalibrationError when malformed."""
        if not isinstance(data, dict):
            raise CalibrationError(f"a grid model must be a JSON object, got {type(data).__name__}")
        if data.get("format", JSON_FORMAT) != JSON_FORMAT:
            raise CalibrationError(f"not a lenslet grid model (format {data.get('format')!r})")
        names = ("kind", "pitch", "rotation", "offset", "n_rows", "n_cols", "image_shape")
        missing = [name for name in names if name not in data]
        if missing:
            raise CalibrationError(f"grid model JSON lacks {', '.join(missing)}")
        options = {name: data[name] for name in names}
        for name in ("hex_shift_row", "transposed", "distortion", "fit", "row_spacing"):
            if name in data:
                options[name] = data[name]
        try:
            return cls(**options)
        except (TypeError, ValueError) as exc:
            raise CalibrationError(f"malformed grid model JSON ({exc})") from exc

    @classmethod
    def from_json(cls, text):
        """Read a model written by :meth:`to_json`.

        Parameters
        ----------
        text : str
            The JSON text.

        Returns
        -------
        GridModel

        Raises
        ------
        CalibrationError
            If the text is not JSON or not a grid model.
        """
        try:
            data = json.loads(text)
        except (TypeError, ValueError) as exc:
            raise CalibrationError(f"grid model is not valid JSON ({exc})") from exc
        return cls.from_dict(data)

    def describe(self):
        """One line for messages: kind, pitch (and row spacing), rotation, lens count."""
        return (f"{self.kind} grid, pitch {self.pitch:.3f} px, row spacing {self.row_step:.3f} px, "
                f"rotation {self.rotation:+.3f} deg, {self.n_rows} x {self.n_cols} lenses")
