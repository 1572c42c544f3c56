"""Lenslet conversion widget: raw + white (+ dark) images in, a 4-D light field out.

"Calibrate" fits the microlens grid to the white image and draws it over
the white image: a Points layer with one circle per microlens, of the
lens' diameter, centred on the fitted centre, to check the calibration by
eye (the circles should sit on the bright lens discs). "Convert" decodes
the raw image into a light-field layer with that grid (calibrating first
if needed), which the main widget then works on. "Save grid" writes the
fitted grid as JSON, so the capture can later be opened directly (the
lenslet reader finds a ``*grid*.json`` beside it). Calibration and
conversion run in worker threads; errors are shown, never swallowed. A
progress bar and the status line follow the decoder's steps (calibration,
division by the white image, slicing in blocks of lens rows).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from qtpy.QtWidgets import (
    QComboBox,
    QFileDialog,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QProgressBar,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from ._controls import report_failure
from ._jobs import JobRunner
from ._layers import ROLE_KEY, lightfield_layer_data
from ._reader import capture_name, find_calibration_frames

__all__ = ["LensletConversionWidget", "FileField"]

_IMAGE_FILTER = "Images (*.tif *.tiff *.png *.dng *.lfr *.lfp *.raw);;All files (*)"
GRID_KINDS = ("auto", "rectangular", "hexagonal")


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


def _read_image(path):
    """The white image as the grid was fitted on it: grey, float32."""
    from ..decoders.sensor import read_sensor

    image = np.asarray(read_sensor(path), dtype=np.float32)
    return image if image.ndim == 2 else image.mean(axis=-1)


def _sensor_placement(image_path):
    """``scale`` and ``units`` of a sensor image: micrometres in the specimen when the optics are known."""
    from ._optics import read_microscope_optics, sensor_calibration

    where = sensor_calibration(read_microscope_optics(Path(image_path).parent))
    return {"scale": where.scale, "units": (where.unit, where.unit)}


class LensletConversionWidget(QWidget):
    """Calibrate a lenslet capture on its white image and decode it to a light field.

    Parameters
    ----------
    napari_viewer : napari.Viewer

    Attributes
    ----------
    grid : GridModel or None
        The grid fitted by the last calibration (used by "Convert" while
        the white and dark images and the grid kind stay the same).
    """

    def __init__(self, napari_viewer):
        super().__init__()
        self.viewer = napari_viewer
        self.raw_field = FileField("raw lenslet image")
        self.white_field = FileField("white (flat-field) image")
        self.dark_field = FileField("dark frame (optional)")
        self.kind_combo = QComboBox()
        self.kind_combo.addItems(GRID_KINDS)
        self.calibrate_button = QPushButton("Calibrate")
        self.convert_button = QPushButton("Convert")
        self.save_button = QPushButton("Save grid...")
        self.save_button.setEnabled(False)
        self.status = QLabel("")
        self.status.setWordWrap(True)
        self.progress = QProgressBar()
        self.progress.setVisible(False)
        self.jobs = JobRunner(on_progress=self._on_progress, on_error=self._on_error, on_idle=self._on_idle,
                              owner=self)
        self.grid = None
        self._grid_inputs = None  # (white, dark, kind) the grid was fitted with

        form = QFormLayout()
        form.addRow("raw", self.raw_field)
        form.addRow("white", self.white_field)
        form.addRow("dark", self.dark_field)
        form.addRow("grid", self.kind_combo)
        buttons = QHBoxLayout()
        for button in (self.calibrate_button, self.convert_button, self.save_button):
            buttons.addWidget(button)
        layout = QVBoxLayout(self)
        layout.addLayout(form)
        layout.addLayout(buttons)
        layout.addWidget(self.progress)
        layout.addWidget(self.status)
        layout.addStretch(1)

        self.raw_field.edit.editingFinished.connect(self._guess_frames)
        self.calibrate_button.clicked.connect(self.calibrate)
        self.convert_button.clicked.connect(self.convert)
        self.save_button.clicked.connect(self._ask_save_grid)

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

    def _kind(self):
        return self.kind_combo.currentText()

    def _kept_grid(self, white, dark):
        """The fitted grid if it was fitted on these inputs, else ``None``."""
        if self.grid is not None and self._grid_inputs == (white, dark, self._kind()):
            return self.grid
        return None

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
        kind = self._kind()

        def job():
            from ..decoders.lenslet import calibrate

            yield (0, 2)
            image = _read_image(white)
            yield (1, 2)
            grid = calibrate(white, dark=dark, kind=kind)
            return image, grid

        def done(result):
            image, grid = result
            self._keep_grid(grid, (white, dark, kind))
            self._show_grid(image, grid, white)

        return job(), done

    def _keep_grid(self, grid, inputs):
        self.grid, self._grid_inputs = grid, inputs
        self.save_button.setEnabled(True)

    def _show_grid(self, image, grid, white):
        """The white image and one circle per fitted microlens over it (in micrometres when the optics are known)."""
        where = _sensor_placement(white)
        self._replace_layer("white", lambda: self.viewer.add_image(
            image, name=f"white [{white.name}]", colormap="gray", metadata={ROLE_KEY: "white"}, **where))
        self._replace_layer("grid", lambda: self.viewer.add_points(
            grid.centres, name=f"microlens grid [{white.name}]", size=grid.pitch,
            face_color="transparent", border_color="red", border_width=0.06,
            metadata={ROLE_KEY: "grid", "grid": grid}, **where))
        self.status.setText(f"{white.name}: {grid.describe()}; RMS residual "
                            f"{grid.fit.get('rms_residual_px', float('nan')):.3g} px")

    def _replace_layer(self, role, add):
        for layer in list(self.viewer.layers):
            if (layer.metadata or {}).get(ROLE_KEY) == role:
                self.viewer.layers.remove(layer)
        return add()

    # -- saving the grid ----------------------------------------------------------------
    def _ask_save_grid(self):
        raw = self.raw_field.path()
        default = str(raw.with_name(f"{raw.stem}.grid.json")) if raw is not None else "grid.json"
        path, _ = QFileDialog.getSaveFileName(self, "Save the grid model", default, "JSON (*.json)")
        if path:
            self.save_grid(path, overwrite=True)  # the dialog asked before replacing a file

    def save_grid(self, path, overwrite=False):
        """Write the fitted grid as JSON (atomically), for ``lfa.load(..., grid=path)``.

        Returns
        -------
        Path or None
            The file written; ``None`` (with the reason shown) when there is
            no grid yet or the file could not be written.
        """
        from ..errors import LightFieldError
        from ..io_write import write_json

        if self.grid is None:
            self.status.setText("Calibrate first: there is no grid to save.")
            return None
        try:
            written = write_json(path, self.grid, overwrite=overwrite)
        except (OSError, LightFieldError) as error:  # OutputExistsError is both
            report_failure(self.status, "saving the grid", error)
            return None
        self.status.setText(f"grid saved to {written}")
        return written

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
        grid, kind = self._kept_grid(white, dark), self._kind()

        def job():
            from ..decoders.lenslet import load_lenslet_steps
            from ._optics import attach_optics

            options = {"dark": dark, "grid": grid}
            options = {key: value for key, value in options.items() if value is not None}
            if grid is None and kind != "auto":
                options["kind"] = kind
            lf = yield from load_lenslet_steps(raw, white, **options)  # yields (done, total, step)
            return attach_optics(lf, raw)

        def done(lf):
            if grid is None:
                self._keep_grid(lf.meta["grid"], (white, dark, kind))
            data, kwargs, _ = lightfield_layer_data(lf, capture_name(raw))
            self.viewer.add_image(data, **kwargs)
            self._frame_lightfield()
            rows, cols = lf.grid_shape
            self.status.setText(
                f"{raw.name}: {rows}x{cols} views of {lf.image_shape[0]}x{lf.image_shape[1]}"
            )

        return job(), done

    def _frame_lightfield(self):
        """Show the new light field alone: the white image and the grid drawn over it are hidden
        (the light field lies over them, one pixel per lens), and the view fits it."""
        for layer in self.viewer.layers:
            if (layer.metadata or {}).get(ROLE_KEY) in ("white", "grid"):
                layer.visible = False
        self.viewer.reset_view()

    # -- state ------------------------------------------------------------------------
    def _set_busy(self, busy):
        self.calibrate_button.setEnabled(not busy)
        self.convert_button.setEnabled(not busy)
        if busy:
            self.status.setText("working...")

    def _on_progress(self, slot, done, total, step=None):
        """Show a job's progress: the bar, and the decoder's step in the status line."""
        self.progress.setVisible(True)
        self.progress.setRange(0, max(int(total), 1))
        self.progress.setValue(int(done))
        if step is not None:
            self.status.setText(f"{slot}: {step} ({done}/{total})")

    def _on_idle(self):
        self.progress.setVisible(False)
        self._set_busy(False)

    def _on_error(self, slot, error):
        report_failure(self.status, slot, error)

    def shutdown(self):
        """Stop running jobs and wait for their threads."""
        return self.jobs.shutdown()

    def closeEvent(self, event):
        self.shutdown()
        super().closeEvent(event)
