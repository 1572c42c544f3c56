"""Pieces of the ``lfalias`` command line (the entry point is :mod:`napari_lfalias.cli`)."""
