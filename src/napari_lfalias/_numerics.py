"""Scaling data so that float32 arithmetic neither overflows nor underflows."""

import math

__all__ = ["unit_scale", "SAFE_PEAKS"]

#: Peaks within which float32 squares and sums of the data stay far from overflow and underflow.
SAFE_PEAKS = (2.0**-16, 2.0**16)
#: Largest exponent of a scale: ``2**126`` and ``2**-126`` are normal float32 numbers (a subnormal
#: peak, below ``2**-126``, is brought up as far as a float32 scale goes).
_MAX_EXPONENT = 126


def unit_scale(peak):
    """A power of two that brings ``peak`` near 1; 1 where it is safe already (or 0, or not finite).

    A power of two is exact in float32 (short of subnormals), so results
    scaled back are those of the unscaled arithmetic, where that does not
    overflow.

    Examples
    --------
    >>> unit_scale(3.0), unit_scale(1e30) == 2.0**-100, unit_scale(1e-40) == 2.0**126
    (1.0, True, True)
    """
    if not 0 < peak < math.inf or SAFE_PEAKS[0] <= peak <= SAFE_PEAKS[1]:
        return 1.0
    return 2.0 ** min(_MAX_EXPONENT, max(-_MAX_EXPONENT, -round(math.log2(peak))))
