"""Errors raised by napari-lfalias.

Every error is a :class:`LightFieldError`, so a script can catch them all in
one clause. Messages name the file or parameter at fault, say what was wrong,
and say what to do about it.
"""

__all__ = [
    "LightFieldError",
    "ParameterError",
    "DecodeError",
    "CalibrationError",
    "OutputExistsError",
    "NonFiniteError",
    "LightFieldWarning",
    "DarkFrameError",
    "WhiteImageError",
]


class LightFieldError(Exception):
    """Base class of every error this package raises on purpose."""


class ParameterError(LightFieldError, ValueError):
    """A parameter or array given to the API is out of range or malformed."""


class DecodeError(LightFieldError, ValueError):
    """A file or folder could not be read as a light field.

    The message names the file and the reason (missing view, mixed sizes,
    unreadable or truncated file, unsupported format).
    """


class CalibrationError(LightFieldError, ValueError):
    """A lenslet grid could not be fitted, or a grid model is inconsistent."""


class NonFiniteError(ParameterError):
    """Data hold NaN or Inf samples and were not asked to mask them (``nonfinite="mask"``)."""


class OutputExistsError(LightFieldError, FileExistsError):
    """An output file exists and replacing it was not asked for."""


class LightFieldWarning(UserWarning):
    """Something a user should know about an input that was still read (views missing from a grid, ...)."""


class DarkFrameError(DecodeError):
    """A dark frame that cannot belong to the capture (it leaves nothing of it: the capture itself, say)."""


class WhiteImageError(DecodeError):
    """A white image that does not fit the capture (colour for a grey capture, NaN pixels), or a
    folder of white images with none for the capture's camera settings."""
