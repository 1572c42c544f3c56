"""The main widget: refocus a light field, detect and reduce angular aliasing live.

Controls follow DESIGN section 6: a light-field layer, the focus (slope),
the relaxation gamma, N, T, the method, the pyramid depth and the seed;
their defaults are the library's (:func:`~._session.library_defaults`).
Outputs are layers tagged ``layer.metadata["lfalias"]`` (``"refocus"``,
``"cv"``, ``"mask"``, ``"level"``, ``"fused"``, ``"disparity"``,
``"antialiased"``), updated in place and laid out by the rules of
:mod:`._layers`: the aliased pixels as a translucent mask over the
refocused image, the Cv and the disparity hidden until asked for (then
opaque, with a colorbar and contrast that follows them), the reduced
result beside the refocused image with its level map (legend in the
widget) and, with the dense-aperture method, the anti-aliased rendering
(hidden, in the same place). Each output's parameters are in
``layer.metadata["lfalias_params"]``; the reduced, level and anti-aliased
layers belong to one focus and are removed when the refocus moves on.

The method is the library's: by default the disparity-guided one
(``"depth"``). Its disparity is estimated once per light field in a
worker that reports each stage and stops between two of them on Cancel
(:meth:`~._session.AliasingSession.disparity`), then handed to the
session's detector; "Reduce aliasing" uses it. The focus stays live
throughout: the live Cv and mask use the exact Cv
(:data:`~napari_lfalias.presets.INTERACTIVE_METHOD`, one pass per focus
change) unless a Cv method is chosen; after a disparity-guided reduction
the mask shows the pixels it replaced, and a line in the widget always
says which detection the mask shows.

Focus and T are live: moving the focus refocuses and (exact method)
re-detects in a worker thread, both shown together (one redraw); a large
light field shows a half-resolution preview first. Moving T only
re-thresholds the kept Cv, in the GUI thread. Monte Carlo detection and
reduction run in workers with progress; a newer request or Cancel stops a
running job at its next step, and a result computed for parameters that
have changed since is dropped, with a message when it is a reduction. The
computations and their caches are in :mod:`._session` (one
:class:`~napari_lfalias.detect.AliasingDetector` per light field).
"""

from __future__ import annotations

import numpy as np
from qtpy.QtCore import Qt, QTimer, Signal
from qtpy.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDoubleSpinBox,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QProgressBar,
    QPushButton,
    QSizePolicy,
    QSpinBox,
    QVBoxLayout,
    QWidget,
)
from superqt import QLabeledDoubleSlider

from . import _warmup
from ._controls import LogSlider, report_failure
from ._depth import depth_label
from ._jobs import JobRunner
from ._layers import (
    PARAMS_KEY,
    ROLES,
    SOURCE_KEY,
    adaptive_limits,
    find_output_layer,
    lightfield_layers,
    lightfield_of,
    output_layers,
    placement,
    show_output,
)
from ._session import CV_METHODS, AliasingSession, DetectionParams, Preview, focus_range
from ._wording import (
    METHODS,
    ORDERS,
    TOOLTIPS,
    disparity_summary,
    level_legend,
    mask_description,
    order_text,
    stage_text,
    threshold_meaning,
)

__all__ = ["AliasingWidget", "METHODS", "TOOLTIPS"]

PROGRESS_STEPS = 100
#: How often the widget looks at the kernels' warm-up while it runs (ms).
WARMUP_POLL_MS = 250
#: Outputs that belong to one focus: removed when the refocused image moves to another.
FOCUS_RESULTS = ("fused", "level", "antialiased")


def scale_bar(viewer):
    """The viewer's scale bar (``viewer.canvas.overlays`` since napari 0.9, ``viewer.scale_bar`` before)."""
    canvas = getattr(viewer, "canvas", None)
    overlays = getattr(canvas, "overlays", None)
    return overlays.scale_bar if overlays is not None else viewer.scale_bar


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
        _warmup.start()
        self.viewer = napari_viewer
        self.session = None
        self.source = None
        self._source_layer = None
        self._followed = set()  # ids of the light-field layers whose renames are followed
        self._closed = False
        self._first_result = False  # the first focus job of a light field (reads it, makes its caches)
        self._reduce_waiting = False  # "Reduce aliasing" was pressed; it starts once the disparity is ready
        self._status_text = ""
        self.jobs = JobRunner(
            on_progress=self._on_progress, on_error=self._on_error, on_idle=self._on_idle, owner=self
        )
        self._build()
        self.viewer.layers.events.inserted.connect(self._refresh_layers)
        self.viewer.layers.events.removed.connect(self._refresh_layers)
        self._warm_timer = QTimer(self)
        self._warm_timer.setInterval(WARMUP_POLL_MS)
        self._warm_timer.timeout.connect(self._show_warmup)
        self._warm_timer.start()
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
        self.threshold_hint = QLabel("")
        self.threshold_hint.setWordWrap(True)
        self.method_combo = QComboBox()
        for text, method in METHODS.items():
            self.method_combo.addItem(text, method)
        self.method_combo.setCurrentIndex(self.method_combo.findData(defaults.method))
        self.order_combo = QComboBox()
        self.order_combo.addItem(order_text(None), "auto")
        for text, nearer in ORDERS.items():
            self.order_combo.addItem(text, nearer)
        self.order_combo.setCurrentIndex(self.order_combo.findData(defaults.nearer))
        self.mask_source = QLabel("")
        self.disparity_state = QLabel("not estimated")
        self.level_spin = QSpinBox()
        self.level_spin.setRange(1, 8)
        self.level_spin.setValue(defaults.max_level)
        self.seed_spin = QSpinBox()
        self.seed_spin.setRange(0, 2**31 - 1)
        self.seed_spin.setValue(defaults.seed)
        self.keep_check = QCheckBox("keep in-focus layer")
        self.keep_check.setChecked(defaults.keep_in_focus)
        self.beside_check = QCheckBox("reduced image beside the refocused one")
        self.beside_check.setChecked(True)
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
        self.legend = QLabel("")
        self.legend.setVisible(False)
        for label in (self.status, self.legend, self.threshold_hint, self.depth_label, self.mask_source,
                      self.disparity_state):
            # long messages wrap instead of widening the dock (and shrinking the canvas)
            label.setWordWrap(True)
            label.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Preferred)

        tips = (
            (self.layer_combo, "layer"), (self.focus_slider, "focus"), (self.depth_label, "depth"),
            (self.gamma_spin, "gamma"),
            (self.n_spin, "n"), (self.threshold_slider, "threshold"), (self.threshold_hint, "threshold"),
            (self.method_combo, "method"), (self.order_combo, "nearer"), (self.level_spin, "level"),
            (self.seed_spin, "seed"),
            (self.mask_source, "mask"), (self.disparity_state, "disparity"),
            (self.keep_check, "keep"), (self.live_check, "live"), (self.update_button, "detect"),
            (self.reduce_button, "reduce"), (self.cancel_button, "cancel"), (self.beside_check, "beside"),
        )
        for widget, key in tips:
            widget.setToolTip(TOOLTIPS[key])

        form = QFormLayout()
        form.addRow("light field", self.layer_combo)
        form.addRow("focus (px per view)", self.focus_slider)
        form.addRow("", self.depth_label)
        form.addRow("relaxation \u03b3", self.gamma_spin)
        form.addRow("threshold T", self.threshold_slider)
        form.addRow("", self.threshold_hint)
        form.addRow("method", self.method_combo)
        form.addRow("in front", self.order_combo)
        form.addRow("mask shows", self.mask_source)
        form.addRow("disparity", self.disparity_state)
        form.addRow("patterns N", self.n_spin)
        form.addRow("seed", self.seed_spin)
        form.addRow("coarsest level", self.level_spin)
        form.addRow("", self.keep_check)
        form.addRow("", self.beside_check)
        for row in range(form.rowCount()):  # the row labels explain themselves too
            label = form.itemAt(row, QFormLayout.ItemRole.LabelRole)
            field = form.itemAt(row, QFormLayout.ItemRole.FieldRole)
            if label is not None and field is not None and label.widget() is not None:
                label.widget().setToolTip(field.widget().toolTip())
        buttons = QHBoxLayout()
        for widget in (self.live_check, self.update_button, self.reduce_button, self.cancel_button):
            buttons.addWidget(widget)
        layout = QVBoxLayout(self)
        layout.addLayout(form)
        layout.addLayout(buttons)
        layout.addWidget(self.progress)
        layout.addWidget(self.status)
        layout.addWidget(self.legend)
        layout.addStretch(1)

        self.layer_combo.currentIndexChanged.connect(lambda _index: self._on_layer_chosen())
        self.focus_slider.valueChanged.connect(self._on_focus)
        self.threshold_slider.valueChanged.connect(self._on_threshold)
        self.gamma_spin.valueChanged.connect(self._on_detection_params)
        self.method_combo.currentIndexChanged.connect(self._on_method)
        for spin in (self.n_spin, self.seed_spin):  # what only Monte Carlo uses
            spin.valueChanged.connect(self._on_sampling_params)
        self.level_spin.valueChanged.connect(self._on_reduction_params)
        self.order_combo.currentIndexChanged.connect(self._on_reduction_params)
        self.keep_check.toggled.connect(self._on_reduction_params)
        self.beside_check.toggled.connect(self._place_outputs)
        self.live_check.toggled.connect(self._on_live)
        self.update_button.clicked.connect(self.update_now)
        self.reduce_button.clicked.connect(self.reduce)
        self.cancel_button.clicked.connect(self.cancel)
        self._enable_controls()
        self._show_threshold_meaning()
        self._show_mask_source(self.params().live_method)

    # -- the light-field layer ---------------------------------------------------
    def _refresh_layers(self, event=None):
        if self._closed:
            return
        layers = lightfield_layers(self.viewer)
        for layer in layers:
            if id(layer) not in self._followed:
                layer.events.name.connect(self._on_renamed)
                self._followed.add(id(layer))
        current = self._source_layer if self._source_layer in layers else None
        if current is None and layers and event is not None and getattr(event, "type", "") == "inserted":
            current = layers[-1]
        elif current is None and layers:
            current = layers[0]
        self.layer_combo.blockSignals(True)
        self.layer_combo.clear()
        self.layer_combo.addItems([layer.name for layer in layers])
        if current is not None:
            self.layer_combo.setCurrentIndex(layers.index(current))
        self.layer_combo.blockSignals(False)
        if current is not self._source_layer or (current is None and self.session is not None):
            self._on_layer_chosen()

    def _chosen_layer(self):
        layers = lightfield_layers(self.viewer)
        index = self.layer_combo.currentIndex()
        return layers[index] if 0 <= index < len(layers) else None

    def _on_renamed(self, event):
        """Follow a light-field layer's new name: in the chooser, and in its outputs."""
        if self._closed:
            return
        layer = event.source
        if layer is self._source_layer and layer.name != self.source:
            old, self.source = self.source, layer.name
            for output in output_layers(self.viewer, old):
                output.metadata[SOURCE_KEY] = self.source
                default = f"{ROLES[output.metadata['lfalias']].title} [{old}]"
                if output.name == default:  # a name the user chose stays
                    output.name = f"{ROLES[output.metadata['lfalias']].title} [{self.source}]"
        self._refresh_layers()

    def _on_layer_chosen(self):
        layer = self._chosen_layer()
        if layer is self._source_layer and self.session is not None:
            return
        self._stop_reduction("another light field was chosen")
        self.jobs.cancel()
        self._close_session()
        self.disparity_state.setText("not estimated")
        lf = lightfield_of(layer) if layer is not None else None
        if lf is None:
            self._source_layer = None
            self._set_status("Open a light field (File > Open, or File > Open Sample).")
            return
        self.session = AliasingSession(lf)
        self.source = layer.name
        self._source_layer = layer
        self._first_result = True
        self._show_declared_order(lf)
        low, high = focus_range(lf)
        self.focus_slider.blockSignals(True)
        self.focus_slider.setRange(low, high)
        self.focus_slider.setValue(float(np.clip(0.0, low, high)))
        self.focus_slider.blockSignals(False)
        self._show_depth()
        self._show_threshold_meaning()
        live = self.live_check.isChecked()
        then = ("preparing it (once per layer: reading it, its luminance and tile ranges)..." if live
                else "press Detect")
        self._set_status(f"{layer.name}: {lf.grid_shape[0]}x{lf.grid_shape[1]} views of "
                         f"{lf.image_shape[0]}x{lf.image_shape[1]}; {then}")
        if live:
            self.update_now()  # the first result starts the disparity estimate (dense-aperture method)

    # -- parameters -----------------------------------------------------------------
    @property
    def slope(self):
        """The focus slope the controls show."""
        return float(self.focus_slider.value())

    @property
    def method(self):
        """The library's name of the chosen method (``"depth"``, ``"analytic"`` or ``"monte_carlo"``)."""
        return self.method_combo.currentData()

    def set_method(self, method):
        """Choose the method by the library's name (``"depth"``, ``"analytic"`` or ``"monte_carlo"``)."""
        self.method_combo.setCurrentIndex(self.method_combo.findData(method))

    @property
    def nearer(self):
        """The occlusion order chosen, by the library's name (``"auto"``, ``"larger"`` or ``"smaller"``)."""
        return self.order_combo.currentData()

    def set_nearer(self, nearer):
        """Choose the occlusion order by the library's name (``"auto"``, ``"larger"`` or ``"smaller"``)."""
        self.order_combo.setCurrentIndex(self.order_combo.findData(nearer))

    def params(self):
        """The detection parameters the controls show."""
        return DetectionParams(
            gamma=float(self.gamma_spin.value()),
            n_patterns=int(self.n_spin.value()),
            threshold=float(self.threshold_slider.value()),
            method=self.method,
            seed=int(self.seed_spin.value()),
            max_level=int(self.level_spin.value()),
            keep_in_focus=self.keep_check.isChecked(),
            nearer=self.nearer,
        )

    def _show_depth(self):
        # the light field as opened: its metadata, never its (maybe lazy) pixels
        text = depth_label(self.session.source_lf, self.slope) if self.session is not None else ""
        self.depth_label.setText(text)
        self.depth_label.setVisible(bool(text))

    def _show_declared_order(self, lf):
        """Back to ``"auto"`` for a new light field (an order is its camera's), saying what that means for it."""
        declared = lf.meta.get("nearer")
        self.order_combo.blockSignals(True)
        self.order_combo.setItemText(0, order_text(declared if declared in ORDERS.values() else None))
        self.order_combo.setCurrentIndex(0)
        self.order_combo.blockSignals(False)

    def _show_threshold_meaning(self):
        """What T means for this light field (:func:`~._wording.threshold_meaning`)."""
        if self.session is None:
            self.threshold_hint.setText("")
            return
        self.threshold_hint.setText(threshold_meaning(
            self.session.source_lf.n_views, float(self.gamma_spin.value()), self.threshold_slider.value(),
            guided=self.method not in CV_METHODS))

    def _show_mask_source(self, method, slope=None):
        """Say which detection the mask layer shows (a live Cv ``method``, or ``"depth"`` at ``slope``)."""
        self.mask_source.setText(mask_description(method, slope, int(self.n_spin.value())))

    def _enable_controls(self):
        """Enable the controls the chosen method uses (N and seed: Monte Carlo; pyramid: Cv methods)."""
        monte_carlo = self.method == "monte_carlo"
        for spin in (self.n_spin, self.seed_spin):
            spin.setEnabled(monte_carlo)
        for control in (self.level_spin, self.keep_check):
            control.setEnabled(self.method in CV_METHODS)
        self.order_combo.setEnabled(self.method not in CV_METHODS)

    # -- reactions to the controls --------------------------------------------------
    def _on_focus(self, _value=None):
        self.jobs.bump()
        self._stop_reduction(f"the focus moved to {self.slope:.2f}")
        self._show_depth()
        if self.live_check.isChecked():
            self.refocus()

    def _on_threshold(self, _value=None):
        self._show_threshold_meaning()
        if self.session is None:
            return
        self._stop_reduction("T changed")
        detection = self.session.detection(self.slope, self.params())
        if detection is not None:
            self._show_detection(detection, self.slope, with_cv=False)
        elif self.live_check.isChecked():
            self.detect()  # nothing kept for these parameters yet

    def _on_detection_params(self, _value=None):
        self._show_threshold_meaning()
        self.jobs.bump()
        self._stop_reduction("the detection parameters changed")
        if self.live_check.isChecked():
            self.detect()

    def _on_method(self, _index=None):
        self._enable_controls()
        self._on_detection_params()
        if self.method not in CV_METHODS and self.live_check.isChecked():
            self.estimate_disparity()

    def _on_sampling_params(self, _value=None):
        if self.method == "monte_carlo":  # the exact Cv depends on neither N nor the seed
            self._on_detection_params()

    def _on_reduction_params(self, _value=None):
        self._stop_reduction("the reduction parameters changed")

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
            if self._first_result:
                self._set_busy_bar(True)

    def detect(self):
        """Detect aliasing with the current controls (reusing the shifted views)."""
        self.jobs.submit("detect", self._detect_job)
        self._busy("detect")

    def reduce(self):
        """Reduce aliasing with the current controls and method in a worker.

        A reduction already running is stopped (and said so); this one
        replaces it. With the disparity-guided method and no disparity yet,
        the disparity is estimated first (:meth:`estimate_disparity`) and
        the reduction starts when it is ready.
        """
        if self.session is not None and self.method not in CV_METHODS and self.session.estimate is None:
            self._reduce_waiting = True
            self.estimate_disparity()
            self.cancel_button.setEnabled(True)
            self._set_status(f"reducing aliasing at slope {self.slope:.2f} once the disparity is ready "
                             "(estimated once per light field)...")
            return
        replaced = self.jobs.busy("reduce")
        self.jobs.submit("reduce", self._reduce_job)
        if self._busy("reduce"):
            note = " (the running reduction was stopped)" if replaced else ""
            self._set_status(f"reducing aliasing at slope {self.slope:.2f}...{note}")

    def estimate_disparity(self):
        """Estimate the light field's disparity in a worker, once per light field.

        Progress is reported per stage (the bar and the *disparity* line);
        Cancel stops it between two stages. Nothing is done if the
        estimate is kept or already running. When it is ready it goes to
        the session's detector (for "Reduce aliasing" with the
        dense-aperture method) and to the disparity layer.
        """
        if self.session is None or self.session.estimate is not None or self.jobs.busy("disparity"):
            return
        self.jobs.submit("disparity", self._disparity_job, lasting=True)  # the same for every focus and T
        if self._busy("disparity"):
            self.disparity_state.setText(stage_text(0, 5, "starting"))

    def cancel(self):
        """Stop running jobs (the disparity estimate too); their results are dropped.

        A job stops at its next step; a step already running in a numba
        kernel (the reduction's solve, a stage of the disparity estimate)
        ends in the background, and its result is dropped.
        """
        self._reduce_waiting = False
        if self.jobs.busy("disparity"):
            self.disparity_state.setText("cancelled; it is estimated again when needed")
        self.jobs.cancel()
        self._set_status("cancelled")

    def _stop_reduction(self, reason):
        """Stop a running (or waiting) reduction whose parameters no longer hold, and say so
        (status and notification)."""
        from napari.utils.notifications import show_info

        waiting, self._reduce_waiting = self._reduce_waiting, False
        if self.jobs.stop("reduce") or waiting:
            message = f"reduction stopped: {reason}; press Reduce aliasing to reduce with the new settings"
            self._set_status(message)
            show_info(message)

    def shutdown(self):
        """Stop running jobs, wait for their threads, and stop following the viewer.

        Returns
        -------
        bool
            True if every worker ended.
        """
        self._closed = True
        self._warm_timer.stop()
        for emitter in (self.viewer.layers.events.inserted, self.viewer.layers.events.removed):
            emitter.disconnect(self._refresh_layers)
        for layer in self.viewer.layers:
            layer.events.name.disconnect(self._on_renamed)
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
        exact = params.live_method == "analytic"
        job = self.session.focus(slope, params, detect=exact)
        shown = []

        def early(value):  # a preview, or the image while the Cv waits for a running reduction
            if isinstance(value, Preview):
                self._show_preview(value, slope, params)
            else:
                self._show_refocus(value, slope)
                shown.append(True)

        def done(result):
            image, detection = result
            if not shown:
                self._show_refocus(image, slope)
            if detection is not None:
                self._show_detection(detection, slope)
            else:
                self.detect()  # Monte Carlo: in its own slot, with progress
            first, self._first_result = self._first_result, False
            if first and self.method not in CV_METHODS:
                self.estimate_disparity()  # after the first refocus, which it would slow down

        return job, done, early

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
        shown = []

        def reduced_first(reduced):  # the dense-aperture method: the reduction before the anti-aliased image
            self._show_reduction(reduced, slope, params)
            shown.append(True)

        def done(reduced):
            if params != self.params() or slope != self.slope:
                self._set_status("reduction dropped: the settings changed while it ran; press Reduce "
                                 "aliasing again")
                return
            if not shown:
                self._show_reduction(reduced, slope, params)
            if reduced.antialiased is not None:
                self._show("antialiased", self._image(reduced.antialiased), self._meta(slope, params),
                           contrast_limits=self._source_contrast())

        return job, done, reduced_first

    def _disparity_job(self):
        session = self.session
        if session is None:
            return None

        def done(estimate):
            if session is not self.session:  # another light field was chosen meanwhile
                return
            self._show_disparity(estimate)
            if self._reduce_waiting:
                self._reduce_waiting = False
                self.reduce()

        return session.disparity(), done

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
        first = find_output_layer(self.viewer, role, self.source) is None
        kwargs.update(placement(self._source_layer, role, self.beside_check.isChecked()))
        layer = show_output(self.viewer, role, data, self.source, params=params, **kwargs)
        if first:
            self._first_layer(layer, role)
        self.outputs_updated.emit(role, params)
        return layer

    def _first_layer(self, layer, role):
        """A new output layer: stop drawing what it covers, and frame what is to be seen."""
        if role == "refocus":
            self._source_layer.visible = False  # the opaque refocused image covers the views
            earlier = [self.viewer.layers.index(other) for other in output_layers(self.viewer, self.source)
                       if other is not layer]
            if earlier:  # made after an output that lies over it (a quick disparity): go under it
                self.viewer.layers.move(self.viewer.layers.index(layer), min(earlier))
        if role in ("refocus", "fused"):
            if placement(self._source_layer, role)["units"][0] != "pixel":
                scale_bar(self.viewer).visible = True
            self.viewer.reset_view()

    def _source_contrast(self):
        return list(self._source_layer.contrast_limits)

    def _show_refocus(self, image, slope, **extra):
        self._show("refocus", self._image(image), self._meta(slope, **extra),
                   contrast_limits=self._source_contrast())
        self._drop_results_not_at(slope)

    def _drop_results_not_at(self, slope):
        """Remove the outputs of one focus (:data:`FOCUS_RESULTS`) made at another slope than ``slope``."""
        from napari.utils.notifications import show_info

        stale = [layer for layer in output_layers(self.viewer, self.source)
                 if layer.metadata["lfalias"] in FOCUS_RESULTS
                 and (layer.metadata.get(PARAMS_KEY) or {}).get("slope") != float(slope)]
        if not stale:
            return
        old = stale[0].metadata[PARAMS_KEY]["slope"]
        for layer in stale:
            self.viewer.layers.remove(layer)
        self.legend.setVisible(False)
        show_info(f"the reduced result of focus {old:.2f} was removed: the focus moved to {slope:.2f}; "
                  "press Reduce aliasing for this focus")

    def _show_preview(self, preview, slope, params):
        """The coarse first result of a focus change (refined by the full one)."""
        self._show_refocus(preview.image, slope, preview=preview.level)
        if preview.cv is not None:
            meta = self._meta(slope, params, preview=preview.level, method=params.live_method)
            self._show("cv", preview.cv, meta,
                       contrast_limits=adaptive_limits(preview.cv, at_least=2 * params.threshold))
            self._show("mask", preview.mask.astype(np.uint8), meta)
            self._show_mask_source(params.live_method)
        self._set_status(f"slope {slope:.2f}: preview at 1/{2**preview.level} of the resolution...")
        QTimer.singleShot(0, preview.shown.set)  # after the canvas' repaint, which is already queued

    def _show_detection(self, detection, slope, with_cv=True):
        """Show the Cv map and the mask (only the mask when just T changed).

        A job's result was thresholded at the T of its start; T may have
        moved since (T changes do not make results stale): show the
        detection at the T the controls show now.
        """
        params = self.params()
        detection = self.session.detection(slope, params) or detection
        meta = self._meta(slope, params, method=params.live_method)
        if with_cv:
            self._show("cv", detection.cv, meta,
                       contrast_limits=adaptive_limits(detection.cv, at_least=2 * params.threshold))
        else:
            cv_layer = find_output_layer(self.viewer, "cv", self.source)
            if cv_layer is not None:
                cv_layer.metadata[PARAMS_KEY] = meta
        self._show("mask", detection.mask.astype(np.uint8), meta)
        self._show_mask_source(params.live_method)
        aliased = float(np.mean(detection.mask)) * 100
        self._set_status(f"slope {slope:.2f}: {aliased:.1f}% of pixels aliased (magenta; T = "
                         f"{params.threshold:.4g}; the Cv layer is hidden until you show it)")

    def _show_reduction(self, reduced, slope, params):
        """The reduced image and its level map; with the dense-aperture method also the reduction's own
        detection as the mask."""
        reduction = reduced.reduction
        meta = self._meta(slope, params)
        self._show("fused", self._image(reduction.image), meta, contrast_limits=self._source_contrast())
        self._show("level", reduction.level, meta)
        highest = int(np.max(reduction.level))
        self.legend.setText(level_legend(max(highest, 1)))
        self.legend.setVisible(True)
        side = "right" if self.beside_check.isChecked() else "over the refocused image"
        share = float(np.mean(reduction.level > 0))
        if params.method in CV_METHODS:
            self._set_status(f"reduced at slope {slope:.2f} ({side}): {share:.1%} of pixels from levels up "
                             f"to {highest}")
            return
        from ..depth_guided import FAINT_FRACTION, REPLACE_FRACTION

        self._show("mask", reduction.detections[0].mask.astype(np.uint8), meta)
        self._show_mask_source(params.method, slope)
        if reduced.larger_first is not None:  # say what "auto" judged, so that a user can overrule it
            self.order_combo.setItemText(0, order_text(None, judged="larger" if reduced.larger_first else "smaller",
                                                       slope=slope))
        self._set_status(f"reduced at slope {slope:.2f} ({side}): {share:.1%} of pixels take what a dense "
                         f"aperture records (of the flagged ones, magenta, those the rendering is sure of, and "
                         f"those next to them above T/{1 / REPLACE_FRACTION:g} where it does not hinge on its depth "
                         f"edges, and the faint aliasing above T/{1 / FAINT_FRACTION:g} it is sure of); the whole "
                         "anti-aliased rendering goes to a hidden layer")

    def _show_disparity(self, estimate):
        params = {"disparity_range": [float(v) for v in estimate.disparity_range],
                  "seconds": float(sum(estimate.params.get("seconds", {}).values()))}
        self._show("disparity", estimate.disparity, params,
                   contrast_limits=adaptive_limits(estimate.disparity, from_zero=False))
        self.disparity_state.setText(disparity_summary(estimate))

    def _place_outputs(self, _checked=None):
        """Move the outputs beside (or over) the refocused image, as the check box says."""
        if self._source_layer is None:
            return
        for layer in output_layers(self.viewer, self.source):
            layer.translate = placement(self._source_layer, layer.metadata["lfalias"],
                                        self.beside_check.isChecked())["translate"]
        self.viewer.reset_view()

    # -- status and progress ------------------------------------------------------------------
    def _set_status(self, text):
        self._status_text = text
        if not (_warmup.state() == "compiling" and self.jobs.busy()):
            self.status.setText(text)

    def _show_warmup(self):
        """While the kernels compile, say so (with a busy bar) instead of looking idle."""
        state = _warmup.state()
        if state == "compiling" and not self._closed:
            self.status.setText("compiling the numeric kernels (first use only; they are cached for "
                                "next time)...")
            self._set_busy_bar(True)
        elif state == "ready":
            self._warm_timer.stop()
            if self.status.text() != self._status_text:
                self.status.setText(self._status_text)
            if not self.jobs.busy():
                self._set_busy_bar(False)

    def _set_busy_bar(self, busy):
        """An indeterminate (busy) bar, or back to a 0..100 bar."""
        if busy:
            self.progress.setRange(0, 0)
        elif self.progress.maximum() == 0:
            self.progress.setRange(0, PROGRESS_STEPS)
            self.progress.setValue(PROGRESS_STEPS)

    # QProgressBar.setValue repaints at once, and a synchronous repaint of the
    # dock also redraws the canvas (~40 ms in software OpenGL): the bar is
    # left alone by the short focus jobs and moved only by detection and
    # reduction.
    def _busy(self, slot):
        busy = self.jobs.busy(slot)
        if busy:
            self.cancel_button.setEnabled(True)
            self._set_busy_bar(False)
            self.progress.setValue(0)
        return busy

    def _on_progress(self, slot, done, total, stage=None):
        if slot != "focus" and self.progress.maximum() != 0:
            self.progress.setValue(int(PROGRESS_STEPS * done / max(total, 1)))
        if slot == "disparity" and stage is not None:
            self.disparity_state.setText(stage_text(done, total, stage))

    def _on_error(self, slot, error):
        what = "estimating the disparity" if slot == "disparity" else slot
        message = report_failure(self.status, what, error)
        self._status_text = self.status.text()
        if slot == "disparity":
            self._reduce_waiting = False  # the reduction that waited for it cannot run
            self.disparity_state.setText(message)

    def _on_idle(self):
        self.cancel_button.setEnabled(False)
        if _warmup.state() != "compiling":
            self._set_busy_bar(False)
        if self.progress.value() != PROGRESS_STEPS:
            self.progress.setValue(PROGRESS_STEPS)
