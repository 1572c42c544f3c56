"""Where the bundled sample data live, installed or in a source checkout."""

from pathlib import Path

__all__ = ["sample_data_dir"]


def sample_data_dir():
    """Return the folder of the bundled sample captures.

    In a wheel it is ``napari_lfalias/sample_data``; in an editable install
    it is ``sample_data/`` at the root of the source checkout.
    """
    here = Path(__file__).resolve().parent
    for candidate in (here / "sample_data", here.parent.parent / "sample_data"):
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError("the bundled sample_data folder is missing from this installation")
