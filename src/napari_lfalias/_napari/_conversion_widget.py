"""Lenslet conversion widget: raw + white (+ dark) images in, a 4-D light field out.

"Calibrate" fits the microlens grid to the white image and draws it over
the white image (a Points layer of the microlens centres), to check the
calibration by eye. "Convert" decodes the raw image with that white image
into a light-field layer, which the main widget then works on. Both run in
worker threads.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from qtpy.QtWidgets import (
    QFileDialog,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from ._jobs import JobRunner
from ._layers import lightfield_layer_data
from ._reader import find_calibration_frames

__all__ = ["LensletConversionWidget", "FileField", "grid_centres"]

ROLE_KEY = "lfalias"
_IMAGE_FILTER = "Images (*.tif *.tiff *.png *.dng *.lfr *.lfp *.raw);;All files (*)"


class FileField(QWidget):
    """A path box with a browse button."""

    def __init__(self, caption, parent=None):
        super().__init__(parent)
        self._caption = caption
        self.edit = QLineEdit()
        self.edit.setPlaceholderText(caption)
        browse = QPushButton("...")
        browse.setMaximumWidth(32)
        browse.clicked.connect(self._browse)
        layout = QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.edit)
        layout.addWidget(browse)

    def _browse(self):
        path, _ = QFileDialog.getOpenFileName(self, self._caption, self.edit.text(), _IMAGE_FILTER)
        if path:
            self.set_path(path)

    def path(self):
        """The path typed or chosen, or ``None`` when the box is empty."""
        text = self.edit.text().strip()
        return Path(text) if text else None

    def set_path(self, path):
        """Show ``path`` (``None`` clears the box)."""
        self.edit.setText("" if path is None else str(path))


def grid_centres(grid):
    """The ``(n, 2)`` (row, col) microlens centres of a fitted grid model."""
    for name in ("centres", "centers", "lens_centres", "lens_centers"):
        value = getattr(grid, name, None)
        if value is not None:
            value = value() if callable(value) else value
            return np.asarray(value, dtype=np.float64).reshape(-1, 2)
    raise AttributeError(f"{type(grid).__name__} exposes no microlens centres")


def _read_image(path):
    from ..decoders.sensor import read_sensor

    image = np.asarray(read_sensor(path), dtype=np.float32)
    return image if image.ndim == 2 else image.mean(axis=-1)


class LensletConversionWidget(QWidget):
    """Calibrate a lenslet capture on its white image and decode it to a light field.

    Parameters
    ----------
    napari_viewer : napari.Viewer
    """

    def __init__(self, napari_viewer):
        super().__init__()
        self.viewer = napari_viewer
        self.raw_field = FileField("raw lenslet image")
        self.white_field = FileField("white (flat-field) image")
        self.dark_field = FileField("dark frame (optional)")
        self.calibrate_button = QPushButton("Calibrate")
        self.convert_button = QPushButton("Convert")
        self.status = QLabel("")
        self.status.setWordWrap(True)
        self.jobs = JobRunner(on_error=self._on_error, on_idle=self._on_idle)
        self.grid = None

        form = QFormLayout()
        form.addRow("raw", self.raw_field)
        form.addRow("white", self.white_field)
        form.addRow("dark", self.dark_field)
        buttons = QHBoxLayout()
        buttons.addWidget(self.calibrate_button)
        buttons.addWidget(self.convert_button)
        layout = QVBoxLayout(self)
        layout.addLayout(form)
        layout.addLayout(buttons)
        layout.addWidget(self.status)
        layout.addStretch(1)

        self.raw_field.edit.editingFinished.connect(self._guess_frames)
        self.calibrate_button.clicked.connect(self.calibrate)
        self.convert_button.clicked.connect(self.convert)

    # -- inputs ---------------------------------------------------------------------
    def _guess_frames(self):
        """Fill in the white and dark frames found beside the raw image, if empty."""
        raw = self.raw_field.path()
        if raw is None or self.white_field.path() is not None:
            return
        frames = find_calibration_frames(raw)
        if frames is not None:
            self.white_field.set_path(frames[0])
            self.dark_field.set_path(frames[1])

    def _frames(self):
        white, dark = self.white_field.path(), self.dark_field.path()
        if white is None:
            self.status.setText("Choose the white (flat-field) image first.")
            return None
        if not self._exists(white) or (dark is not None and not self._exists(dark)):
            return None
        return white, dark

    def _exists(self, path):
        if path.is_file():
            return True
        self.status.setText(f"{path}: no such file; choose an existing image.")
        return False

    # -- calibration ------------------------------------------------------------------
    def calibrate(self):
        """Fit the microlens grid to the white image (in a worker) and draw it."""
        self._set_busy(True)
        self.jobs.submit("calibrate", self._calibrate_job)

    def _calibrate_job(self):
        frames = self._frames()
        if frames is None:
            return None
        white, dark = frames

        def job():
            from ..decoders.lenslet import calibrate

            yield (0, 2)
            image = _read_image(white)
            yield (1, 2)
            grid = calibrate(white, dark=dark)
            return image, grid

        def done(result):
            image, grid = result
            self.grid = grid
            self._show_grid(image, grid, white)

        return job(), done

    def _show_grid(self, image, grid, white):
        centres = grid_centres(grid)
        name = f"white [{white.name}]"
        self._replace_layer("white", name, lambda: self.viewer.add_image(
            image, name=name, colormap="gray", metadata={ROLE_KEY: "white"}))
        self._replace_layer("grid", f"microlens centres [{white.name}]", lambda: self.viewer.add_points(
            centres, name=f"microlens centres [{white.name}]", size=max(1.0, _pitch(grid) / 4),
            face_color="red", border_width=0, metadata={ROLE_KEY: "grid"}))
        self.status.setText(f"{len(centres)} microlenses fitted on {white.name}")

    def _replace_layer(self, role, name, add):
        for layer in list(self.viewer.layers):
            if (layer.metadata or {}).get(ROLE_KEY) == role:
                self.viewer.layers.remove(layer)
        return add()

    # -- conversion -------------------------------------------------------------------
    def convert(self):
        """Decode the raw image to a light-field layer (in a worker)."""
        self._set_busy(True)
        self.jobs.submit("convert", self._convert_job)

    def _convert_job(self):
        raw = self.raw_field.path()
        if raw is None:
            self.status.setText("Choose the raw lenslet image first.")
            return None
        frames = self._frames()
        if frames is None or not self._exists(raw):
            return None
        white, dark = frames

        def job():
            from .. import load

            yield (0, 1)
            options = {"white": white}
            if dark is not None:
                options["dark"] = dark
            lf = load(raw, **options)
            yield (1, 1)
            return lf

        def done(lf):
            data, kwargs, _ = lightfield_layer_data(lf, raw.stem)
            self.viewer.add_image(data, **kwargs)
            rows, cols = lf.grid_shape
            self.status.setText(
                f"{raw.name}: {rows}x{cols} views of {lf.image_shape[0]}x{lf.image_shape[1]}"
            )

        return job(), done

    # -- state ------------------------------------------------------------------------
    def _set_busy(self, busy):
        self.calibrate_button.setEnabled(not busy)
        self.convert_button.setEnabled(not busy)
        if busy:
            self.status.setText("working...")

    def _on_idle(self):
        self._set_busy(False)

    def _on_error(self, slot, error):
        from napari.utils.notifications import show_error

        message = f"{slot} failed: {error}"
        self.status.setText(message)
        show_error(message)

    def shutdown(self):
        """Stop running jobs and wait for their threads."""
        return self.jobs.shutdown()

    def closeEvent(self, event):
        self.shutdown()
        super().closeEvent(event)


def _pitch(grid):
    for name in ("pitch", "spacing", "lens_pitch"):
        value = getattr(grid, name, None)
        if value is not None:
            return float(np.mean(value))
    return 8.0
