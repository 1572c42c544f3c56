"""Small Qt controls and helpers the widgets share."""

from __future__ import annotations

import math

from qtpy.QtCore import Qt, Signal
from qtpy.QtWidgets import QDoubleSpinBox, QHBoxLayout, QSlider, QWidget

__all__ = ["LogSlider", "report_failure", "in_gui_words", "PLUGIN_MENU"]


#: The plugin's name in napari's menus (``display_name`` of ``napari.yaml``).
PLUGIN_MENU = "Light fields (4-D): view folders, lenslet and Lytro captures"

#: Library and command-line wording -> what a napari user does instead (regular expressions).
_GUI_WORDS = (
    (r"pass --overwrite \(overwrite=True\) to replace it|pass (?:--overwrite|overwrite=True) to replace it",
     "choose another name, or agree to replace it when the save dialog asks"),
    (r"pass white=\.\.\. \(lfalias: --white\), or grid=\.\.\. from an earlier calibration",
     "open it together with its white image (select both and use File > Open Files as Stack...), "
     f"or calibrate and convert it in Plugins > {PLUGIN_MENU} > Lenslet conversion"),
    (r"\(or pass grid=\(U, V\) for a smaller grid\)", "(or open a folder that holds a full grid of views)"),
    (r"--white, --dark and --grid do not apply", "a white image, dark frame or grid does not apply"),
    (r" ?\(lfalias: --[a-z-]+\)", ""),
)
#: The library's parameter names -> the controls that set them.
_CONTROL_NAMES = {
    "gamma": "relaxation \u03b3",
    "n_patterns": "patterns N",
    "threshold": "threshold T",
    "max_level": "coarsest level",
    "keep_in_focus": "keep in-focus layer",
    "slope": "focus",
}


def in_gui_words(text):
    """``text`` (a library message) with command-line flags and Python parameters in GUI words.

    Examples
    --------
    >>> in_gui_words("max_level: the light field is too small for 9 levels")
    'coarsest level: the light field is too small for 9 levels'
    >>> in_gui_words("out.tif: output exists; pass --overwrite (overwrite=True) to replace it")
    'out.tif: output exists; choose another name, or agree to replace it when the save dialog asks'
    >>> in_gui_words("out.tif: output exists; pass overwrite=True to replace it")
    'out.tif: output exists; choose another name, or agree to replace it when the save dialog asks'
    """
    import re

    for pattern, replacement in _GUI_WORDS:
        text = re.sub(pattern, replacement, text)
    for name, control in _CONTROL_NAMES.items():
        text = re.sub(rf"\b{name}\b(?!=)", control, text)
    return text


def report_failure(status, what, error):
    """Show that ``what`` failed: in the widget's ``status`` label and as a napari notification.

    Parameters
    ----------
    status : QLabel
        The widget's status line.
    what : str
        What failed ("reduce", "calibrate", "saving the grid", ...).
    error : Exception
        The error; its message (which names the file or parameter) is shown
        in GUI words (:func:`in_gui_words`).

    Returns
    -------
    str
        The message shown.
    """
    from napari.utils.notifications import show_error

    message = f"{what} failed: {in_gui_words(str(error))}"
    status.setText(message)
    show_error(message)
    return message


class LogSlider(QWidget):
    """A horizontal slider over a logarithmic range, with a box beside it to type the value.

    Parameters
    ----------
    low, high : float
        The range, ``0 < low < high``.
    value : float
        The initial value.
    steps : int
        Number of slider steps between ``low`` and ``high``.
    decimals : int
        Decimals the box shows and accepts.
    parent : QWidget, optional
    """

    #: Emitted with the new value (float) when the slider moves or a typed value is entered.
    valueChanged = Signal(float)

    def __init__(self, low, high, value, steps=400, decimals=5, parent=None):
        super().__init__(parent)
        self._log_low = math.log10(low)
        self._log_high = math.log10(high)
        self._steps = steps
        self.slider = QSlider(Qt.Orientation.Horizontal)
        self.slider.setRange(0, steps)
        self.spin = QDoubleSpinBox()
        self.spin.setDecimals(decimals)
        self.spin.setRange(low, high)
        self.spin.setKeyboardTracking(False)  # a typed value counts once it is entered, not per keystroke
        self.spin.setMinimumWidth(80)
        layout = QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.slider)
        layout.addWidget(self.spin)
        self.slider.valueChanged.connect(self._on_slider)
        self.spin.valueChanged.connect(self._on_typed)
        self.setValue(value)

    def setToolTip(self, text):
        """Show ``text`` over the slider and the box."""
        super().setToolTip(text)
        self.slider.setToolTip(text)
        self.spin.setToolTip(text)

    def _to_value(self, position):
        fraction = position / self._steps
        return 10 ** (self._log_low + fraction * (self._log_high - self._log_low))

    def _to_position(self, value):
        fraction = (math.log10(value) - self._log_low) / (self._log_high - self._log_low)
        return int(round(min(max(fraction, 0.0), 1.0) * self._steps))

    def value(self):
        """The value: as set by :meth:`setValue` or typed, or at the step the user moved to."""
        return self._value

    def setValue(self, value):
        """Set ``value`` exactly (the slider shows the nearest step)."""
        value = float(value)
        changed = value != getattr(self, "_value", None)
        self._value = value
        self._show()
        if changed:
            self.valueChanged.emit(value)

    def _show(self):
        for widget, shown in ((self.slider, self._to_position(self._value)), (self.spin, self._value)):
            widget.blockSignals(True)
            widget.setValue(shown)
            widget.blockSignals(False)

    def _on_slider(self, position):
        self._value = float(f"{self._to_value(position):.3g}")
        self._show()
        self.valueChanged.emit(self._value)

    def _on_typed(self, value):
        if value != self._value:
            self.setValue(value)
