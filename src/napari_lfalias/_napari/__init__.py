"""The napari plugin: readers, sample data and widgets (manifest: ``napari_lfalias/napari.yaml``).

- :mod:`._reader` -- camera-array folders, lenslet captures (with their white
  image or grid model beside them, or given), Lytro files, light fields
  saved by napari-lfalias;
- :mod:`._sample_data` -- the synthetic brick room, the bundled GUV capture;
- :mod:`._widget` -- refocus, detect and reduce aliasing, live; its
  computations and caches in :mod:`._session`, its worker threads in
  :mod:`._jobs`, its output layers in :mod:`._layers`;
- :mod:`._conversion_widget` -- lenslet raw + white image to a light field;
- :mod:`._depth`, :mod:`._optics` -- metric depth of the focus plane.

Only this package imports napari and Qt; the numeric core never does. The
user guide is ``docs/napari.md``.
"""
