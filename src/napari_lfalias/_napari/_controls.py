"""Small Qt controls the widgets share."""

from __future__ import annotations

import math

from qtpy.QtCore import Qt, Signal
from qtpy.QtWidgets import QHBoxLayout, QLabel, QSlider, QWidget

__all__ = ["LogSlider"]


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
        """The value at the slider's position (float)."""
        return float(f"{self._to_value(self.slider.value()):.4g}")

    def setValue(self, value):
        """Move the slider to the step nearest ``value``."""
        self.slider.setValue(self._to_position(value))
        self._show()

    def _show(self):
        self.label.setText(f"{self.value():.4g}")

    def _on_slider(self, _position):
        self._show()
        self.valueChanged.emit(self.value())
