"""Helpers of the accuracy tests (disparity, dense-aperture rendering, disparity-guided reduction)."""

import numpy as np
from scipy import ndimage

import napari_lfalias as lfa


def as_user_has_it(lf):
    """``lf`` without the ground truth a synthetic scene stores in its metadata.

    A synthetic light field's ``meta`` holds ``disparity`` and
    ``disparity_range``; :func:`napari_lfalias.estimate_disparity` searches
    around ``meta["disparity_range"]``, which for a single plane is the
    answer. Users' light fields carry no such thing, and neither may the
    tests' ones.
    """
    return lfa.LightField(lf.data, lf.positions, {"source": "test"}, weights=lf.weights)


def distance_from_depth_edges(disparity):
    """Distance (px) of every pixel from the nearest pixel whose 4-neighbour has another disparity."""
    edge = np.zeros(disparity.shape, bool)
    jumps_y = np.diff(disparity, axis=0) != 0
    jumps_x = np.diff(disparity, axis=1) != 0
    edge[:-1] |= jumps_y
    edge[1:] |= jumps_y
    edge[:, :-1] |= jumps_x
    edge[:, 1:] |= jumps_x
    if not edge.any():
        return np.full(disparity.shape, np.inf)
    return ndimage.distance_transform_edt(~edge)
