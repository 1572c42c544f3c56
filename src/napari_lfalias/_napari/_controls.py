"""Small Qt controls and helpers the widgets share."""

from __future__ import annotations

import math

from qtpy.QtCore import Qt, Signal
from qtpy.QtWidgets import QHBoxLayout, QLabel, QSlider, QWidget

__all__ = ["LogSlider", "report_failure"]


def report_failure(status, what, error):
    """Show that ``what`` failed: in the widget's ``status`` label and as a napari notification.

    Parameters
    ----------
    status : QLabel
        The widget's status line.
    what : str
        What failed ("reduce", "calibrate", "saving the grid", ...).
    error : Exception
        The error; its message (which names the file or parameter) is shown.

    Returns
    -------
    str
        The message shown.
    """
    from napari.utils.notifications import show_error

    message = f"{what} failed: {error}"
    status.setText(message)
    show_error(message)
    return message


class LogSlider(QWidget):
    """A horizontal slider over a logarithmic range, with its value shown beside it.

    Parameters
    ----------
    low, high : float
        The range, ``0 < low < high``.
    value : float
        The initial value.
    steps : int
        Number of slider steps between ``low`` and ``high``.
    parent : QWidget, optional
    """

    #: Emitted with the new value (float) when the slider moves.
    valueChanged = Signal(float)

    def __init__(self, low, high, value, steps=400, parent=None):
        super().__init__(parent)
        self._log_low = math.log10(low)
        self._log_high = math.log10(high)
        self._steps = steps
        self.slider = QSlider(Qt.Orientation.Horizontal)
        self.slider.setRange(0, steps)
        self.label = QLabel()
        self.label.setMinimumWidth(56)
        layout = QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.slider)
        layout.addWidget(self.label)
        self.slider.valueChanged.connect(self._on_slider)
        self.setValue(value)

    def _to_value(self, position):
        fraction = position / self._steps
        return 10 ** (self._log_low + fraction * (self._log_high - self._log_low))

    def _to_position(self, value):
        fraction = (math.log10(value) - self._log_low) / (self._log_high - self._log_low)
        return int(round(min(max(fraction, 0.0), 1.0) * self._steps))

    def value(self):
        """The value: as set by :meth:`setValue`, or at the step the user moved to."""
        return self._value

    def setValue(self, value):
        """Set ``value`` exactly (the slider shows the nearest step)."""
        value = float(value)
        changed = value != getattr(self, "_value", None)
        self._value = value
        self.slider.blockSignals(True)
        self.slider.setValue(self._to_position(value))
        self.slider.blockSignals(False)
        self._show()
        if changed:
            self.valueChanged.emit(value)

    def _show(self):
        self.label.setText(f"{self._value:.4g}")

    def _on_slider(self, position):
        self._value = float(f"{self._to_value(position):.3g}")
        self._show()
        self.valueChanged.emit(self._value)
