"""The main widget: refocus a light field, detect and reduce angular aliasing live.

Controls follow DESIGN section 6: a light-field layer, the focus (slope),
gamma, N, T, the method, the pyramid depth and the seed. Outputs are layers
tagged ``layer.metadata["lfalias"]`` (``"refocus"``, ``"cv"``, ``"mask"``,
``"level"``, ``"fused"``) and updated in place. Each output's parameters are
in ``layer.metadata["lfalias_params"]``.

Focus and T are live: moving the focus refocuses and (exact method)
re-detects in a worker thread, both shown together (one redraw), or the
refocused image first when the Cv has to wait for a running reduction;
moving T only re-thresholds the kept Cv, in the GUI thread. Monte
Carlo detection and reduction run in workers with progress; a newer request
or the Cancel button stops a running job at its next step, and a result
computed for parameters that have changed since is dropped. The
computations and their caches are in :mod:`._session` (one
:class:`~napari_lfalias.detect.AliasingDetector` per light field).
"""

from __future__ import annotations

import numpy as np
from qtpy.QtCore import Qt, Signal
from qtpy.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDoubleSpinBox,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QProgressBar,
    QPushButton,
    QSpinBox,
    QVBoxLayout,
    QWidget,
)
from superqt import QLabeledDoubleSlider

from ._controls import LogSlider, report_failure
from ._jobs import JobRunner
from ._depth import depth_label
from ._layers import PARAMS_KEY, find_output_layer, lightfield_layers, lightfield_of, show_output
from ._session import AliasingSession, DetectionParams, focus_range

__all__ = ["AliasingWidget"]

METHODS = ("analytic", "monte_carlo")
PROGRESS_STEPS = 100


class AliasingWidget(QWidget):
    """Refocus and angular-aliasing detection/reduction of a light-field layer.

    Parameters
    ----------
    napari_viewer : napari.Viewer
        The viewer whose light-field layers (Image layers with a
        ``metadata["lightfield"]``) the widget works on.

    Attributes
    ----------
    outputs_updated : Signal(str, dict)
        Emitted with the role and the parameters each time an output layer
        has new data.
    """

    outputs_updated = Signal(str, dict)

    def __init__(self, napari_viewer):
        super().__init__()
        self.viewer = napari_viewer
        self.session = None
        self.source = None
        self._source_layer = None
        self._closed = False
        self.jobs = JobRunner(
            on_progress=self._on_progress, on_error=self._on_error, on_idle=self._on_idle
        )
        self._build()
        self.viewer.layers.events.inserted.connect(self._refresh_layers)
        self.viewer.layers.events.removed.connect(self._refresh_layers)
        self._refresh_layers()

    # -- construction -------------------------------------------------------------
    def _build(self):
        defaults = DetectionParams()
        self.layer_combo = QComboBox()
        self.focus_slider = QLabeledDoubleSlider(Qt.Orientation.Horizontal)
        self.focus_slider.setDecimals(2)
        self.focus_slider.setSingleStep(0.01)
        self.depth_label = QLabel("")
        self.gamma_spin = QDoubleSpinBox()
        self.gamma_spin.setRange(0.01, 0.99)
        self.gamma_spin.setSingleStep(0.05)
        self.gamma_spin.setValue(defaults.gamma)
        self.n_spin = QSpinBox()
        self.n_spin.setRange(2, 100000)
        self.n_spin.setValue(defaults.n_patterns)
        self.threshold_slider = LogSlider(1e-4, 1.0, defaults.threshold)
        self.method_combo = QComboBox()
        self.method_combo.addItems(METHODS)
        self.level_spin = QSpinBox()
        self.level_spin.setRange(1, 8)
        self.level_spin.setValue(defaults.max_level)
        self.seed_spin = QSpinBox()
        self.seed_spin.setRange(0, 2**31 - 1)
        self.seed_spin.setValue(defaults.seed)
        self.keep_check = QCheckBox("keep in-focus layer")
        self.keep_check.setChecked(defaults.keep_in_focus)
        self.keep_check.setToolTip("Reduce: keep the in-focus surface sharp where a defocused occluder "
                                   "partly hides it (beyond the paper; pays off at low T)")
        self.live_check = QCheckBox("live")
        self.live_check.setChecked(True)
        self.update_button = QPushButton("Detect")
        self.reduce_button = QPushButton("Reduce aliasing")
        self.cancel_button = QPushButton("Cancel")
        self.cancel_button.setEnabled(False)
        self.progress = QProgressBar()
        self.progress.setRange(0, PROGRESS_STEPS)
        self.progress.setValue(PROGRESS_STEPS)
        self.status = QLabel("")
        self.status.setWordWrap(True)

        form = QFormLayout()
        form.addRow("light field", self.layer_combo)
        form.addRow("focus (slope, px)", self.focus_slider)
        form.addRow("", self.depth_label)
        form.addRow("gamma", self.gamma_spin)
        form.addRow("N patterns", self.n_spin)
        form.addRow("threshold T", self.threshold_slider)
        form.addRow("method", self.method_combo)
        form.addRow("max level", self.level_spin)
        form.addRow("seed", self.seed_spin)
        form.addRow("", self.keep_check)
        buttons = QHBoxLayout()
        for widget in (self.live_check, self.update_button, self.reduce_button, self.cancel_button):
            buttons.addWidget(widget)
        layout = QVBoxLayout(self)
        layout.addLayout(form)
        layout.addLayout(buttons)
        layout.addWidget(self.progress)
        layout.addWidget(self.status)
        layout.addStretch(1)

        self.layer_combo.currentTextChanged.connect(self._on_layer_chosen)
        self.focus_slider.valueChanged.connect(self._on_focus)
        self.threshold_slider.valueChanged.connect(self._on_threshold)
        for signal in (
            self.gamma_spin.valueChanged,
            self.n_spin.valueChanged,
            self.method_combo.currentTextChanged,
            self.seed_spin.valueChanged,
        ):
            signal.connect(self._on_detection_params)
        self.live_check.toggled.connect(self._on_live)
        self.update_button.clicked.connect(self.update_now)
        self.reduce_button.clicked.connect(self.reduce)
        self.cancel_button.clicked.connect(self.cancel)

    # -- the light-field layer ---------------------------------------------------
    def _refresh_layers(self, event=None):
        if self._closed:
            return
        names = [layer.name for layer in lightfield_layers(self.viewer)]
        current = self.layer_combo.currentText()
        self.layer_combo.blockSignals(True)
        self.layer_combo.clear()
        self.layer_combo.addItems(names)
        if current in names:
            self.layer_combo.setCurrentText(current)
        elif names and event is not None and getattr(event, "type", "") == "inserted":
            self.layer_combo.setCurrentText(names[-1])
        self.layer_combo.blockSignals(False)
        chosen = self.layer_combo.currentText() or None
        if chosen != self.source:
            self._on_layer_chosen(chosen or "")

    def _on_layer_chosen(self, name):
        self.jobs.cancel()
        self._close_session()
        layer = self.viewer.layers[name] if name and name in self.viewer.layers else None
        lf = lightfield_of(layer) if layer is not None else None
        if lf is None:
            self.session, self.source = None, None
            self.status.setText("Open a light field (File > Open, or File > Open Sample).")
            return
        self.session = AliasingSession(lf)
        self.source = name
        self._source_layer = layer
        low, high = focus_range(lf)
        self.focus_slider.blockSignals(True)
        self.focus_slider.setRange(low, high)
        self.focus_slider.setValue(float(np.clip(0.0, low, high)))
        self.focus_slider.blockSignals(False)
        self._show_depth()
        self.status.setText(f"{name}: {lf.grid_shape[0]}x{lf.grid_shape[1]} views of "
                            f"{lf.image_shape[0]}x{lf.image_shape[1]}")
        if self.live_check.isChecked():
            self.update_now()

    # -- parameters -----------------------------------------------------------------
    @property
    def slope(self):
        """The focus slope the controls show."""
        return float(self.focus_slider.value())

    def params(self):
        """The detection parameters the controls show."""
        return DetectionParams(
            gamma=float(self.gamma_spin.value()),
            n_patterns=int(self.n_spin.value()),
            threshold=float(self.threshold_slider.value()),
            method=self.method_combo.currentText(),
            seed=int(self.seed_spin.value()),
            max_level=int(self.level_spin.value()),
            keep_in_focus=self.keep_check.isChecked(),
        )

    def _show_depth(self):
        # the light field as opened: its metadata, never its (maybe lazy) pixels
        text = depth_label(self.session.source_lf, self.slope) if self.session is not None else ""
        self.depth_label.setText(text)
        self.depth_label.setVisible(bool(text))

    # -- reactions to the controls --------------------------------------------------
    def _on_focus(self, _value=None):
        self.jobs.bump()
        self._show_depth()
        if self.live_check.isChecked():
            self.refocus()

    def _on_threshold(self, _value=None):
        if self.session is None:
            return
        detection = self.session.detection(self.slope, self.params())
        if detection is not None:
            self._show_detection(detection, self.slope, with_cv=False)
        elif self.live_check.isChecked():
            self.detect()  # nothing kept for these parameters yet

    def _on_detection_params(self, _value=None):
        self.jobs.bump()
        if self.live_check.isChecked():
            self.detect()

    def _on_live(self, checked):
        if checked:
            self.update_now()

    # -- requests ---------------------------------------------------------------------
    def update_now(self):
        """Refocus and detect with the current controls."""
        self.refocus()

    def refocus(self):
        """Refocus on the current slope; with the exact method, detect there too."""
        self.jobs.submit("focus", self._focus_job)
        if self.jobs.busy("focus"):
            self.cancel_button.setEnabled(True)

    def detect(self):
        """Detect aliasing with the current controls (reusing the shifted views)."""
        self.jobs.submit("detect", self._detect_job)
        self._busy("detect")

    def reduce(self):
        """Reduce aliasing with the current controls (Algorithm 2) in a worker."""
        self.jobs.submit("reduce", self._reduce_job)
        if self._busy("reduce"):
            self.status.setText(f"reducing aliasing at slope {self.slope:.2f}...")

    def cancel(self):
        """Stop running jobs; their results are dropped.

        A job stops at its next step; a step already running in a numba
        kernel (the reduction's solve) ends in the background, and its
        result is dropped.
        """
        self.jobs.cancel()
        self.status.setText("cancelled")

    def shutdown(self):
        """Stop running jobs, wait for their threads, and stop following the viewer.

        Returns
        -------
        bool
            True if every worker ended.
        """
        self._closed = True
        for emitter in (self.viewer.layers.events.inserted, self.viewer.layers.events.removed):
            emitter.disconnect(self._refresh_layers)
        ended = self.jobs.shutdown()
        if ended:
            self._close_session()
        return ended

    def _close_session(self):
        if self.session is not None:
            self.session.close()
        self.session, self.source = None, None

    def closeEvent(self, event):
        self.shutdown()
        super().closeEvent(event)

    # -- jobs (made when their slot is free, so they read the controls then) ----------
    def _focus_job(self):
        if self.session is None:
            return None
        slope, params = self.slope, self.params()
        exact = params.method == "analytic"
        job = self.session.focus(slope, params, detect=exact)
        shown = []

        def refocused(image):  # early, while the Cv waits for a running reduction
            self._show_refocus(image, slope)
            shown.append(True)

        def done(result):
            image, detection = result
            if not shown:
                self._show_refocus(image, slope)
            if detection is not None:
                self._show_detection(detection, slope)
            else:
                self.detect()  # Monte Carlo: in its own slot, with progress

        return job, done, refocused

    def _detect_job(self):
        if self.session is None:
            return None
        slope, params = self.slope, self.params()
        job = self.session.detect(slope, params)
        return job, lambda detection: self._show_detection(detection, slope)

    def _reduce_job(self):
        if self.session is None:
            return None
        slope, params = self.slope, self.params()
        job = self.session.reduce(slope, params)

        def done(reduction):
            if params != self.params():
                return  # T or the depth changed while it ran: stale
            self._show_reduction(reduction, slope, params)

        return job, done

    # -- outputs ---------------------------------------------------------------------------
    def _meta(self, slope, params=None, **extra):
        values = {"slope": float(slope)}
        if params is not None:
            values.update(vars(params))
        values.update(extra)
        return values

    def _image(self, image):
        return image[..., 0] if image.ndim == 3 and image.shape[-1] == 1 else image

    def _show(self, role, data, params, **kwargs):
        layer = show_output(self.viewer, role, data, self.source, params=params, **kwargs)
        self.outputs_updated.emit(role, params)
        return layer

    def _source_contrast(self):
        return list(self._source_layer.contrast_limits)

    def _show_refocus(self, image, slope):
        first = find_output_layer(self.viewer, "refocus", self.source) is None
        self._show(
            "refocus", self._image(image), self._meta(slope), contrast_limits=self._source_contrast()
        )
        if first:
            # the opaque refocused image covers the views: stop drawing them
            self._source_layer.visible = False

    def _show_detection(self, detection, slope, with_cv=True):
        """Show the Cv map and the mask (only the mask when just T changed).

        A job's result was thresholded at the T of its start; T may have
        moved since (T changes do not make results stale): show the
        detection at the T the controls show now.
        """
        params = self.params()
        detection = self.session.detection(slope, params) or detection
        meta = self._meta(slope, params)
        if with_cv:
            cv_layer = self._show("cv", detection.cv, meta)
            if not cv_layer.metadata.get("lfalias_scaled"):
                # T sits in the lower part of the colour range, the Cv spread above it
                top = max(2 * params.threshold, float(np.percentile(detection.cv, 99.5)), 1e-6)
                cv_layer.contrast_limits = [0.0, top]
                cv_layer.metadata["lfalias_scaled"] = True
        else:
            cv_layer = find_output_layer(self.viewer, "cv", self.source)
            if cv_layer is not None:
                cv_layer.metadata[PARAMS_KEY] = meta
        self._show("mask", detection.mask.astype(np.uint8), meta)
        aliased = float(np.mean(detection.mask)) * 100
        self.status.setText(f"slope {slope:.2f}: {aliased:.1f}% of pixels aliased (T = {params.threshold:.4g})")

    def _show_reduction(self, reduction, slope, params):
        meta = self._meta(slope, params)
        self._show("fused", self._image(reduction.image), meta,
                   contrast_limits=self._source_contrast())
        self._show("level", reduction.level, meta)
        self.status.setText(
            f"reduced at slope {slope:.2f}: levels up to {int(np.max(reduction.level))}"
        )

    # -- progress -----------------------------------------------------------------------------
    # QProgressBar.setValue repaints at once, and a synchronous repaint of the
    # dock also redraws the canvas (~40 ms in software OpenGL): the bar is
    # left alone by the short focus jobs and moved only by detection and
    # reduction.
    def _busy(self, slot):
        busy = self.jobs.busy(slot)
        if busy:
            self.cancel_button.setEnabled(True)
            self.progress.setValue(0)
        return busy

    def _on_progress(self, slot, done, total):
        if slot != "focus":
            self.progress.setValue(int(PROGRESS_STEPS * done / max(total, 1)))

    def _on_error(self, slot, error):
        report_failure(self.status, slot, error)

    def _on_idle(self):
        self.cancel_button.setEnabled(False)
        if self.progress.value() != PROGRESS_STEPS:
            self.progress.setValue(PROGRESS_STEPS)
