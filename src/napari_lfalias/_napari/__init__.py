"""The napari plugin: readers, sample data and widgets (manifest: ``napari_lfalias/napari.yaml``).

- :mod:`._reader` -- camera-array folders, lenslet captures (with a white
  image beside them), Lytro files, light fields saved by napari-lfalias;
- :mod:`._sample_data` -- the synthetic brick room, the bundled GUV capture;
- :mod:`._widget` -- refocus, detect and reduce aliasing, live;
- :mod:`._conversion_widget` -- lenslet raw + white image to a light field.

Only this package imports napari and Qt; the numeric core never does.
"""
