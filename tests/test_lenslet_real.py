"""Real light-field microscope captures (napari-LF, BSD-3): GUV (bundled) and ant leg."""

import numpy as np
import pytest

import napari_lfalias as lfa
from napari_lfalias.decoders import calibrate, load_lenslet

GUV_FILES = ("Lightfield_GUVExperim1.tif", "Radiometry_GUVExperim1.tif", "DarkFrame_GUVExperim1.tif")
#: Documented pitches: 100 um lenses on 6.5 um pixels; 125 um lenses on 4.55 um effective pixels.
GUV_PITCH = 100 / 6.5
ANTLEG_PITCH = 125 / 4.55


@pytest.fixture(scope="module")
def guv(lf_data):
    folder = lf_data / "napari_lf_guv"
    return [folder / name for name in GUV_FILES]


@pytest.fixture(scope="module")
def guv_lf(guv):
    raw, white, dark = guv
    return lfa.load(raw, white=white, dark=dark)


@pytest.fixture(scope="module")
def antleg(lf_data):
    folder = lf_data / "napari_lf_antleg"
    grid = calibrate(folder / "radiometry_frame.png")
    return grid, load_lenslet(folder / "light_field.png", white=folder / "radiometry_frame.png", grid=grid)


def _correlation(a, b):
    a, b = a.ravel() - a.mean(), b.ravel() - b.mean()
    return float(a @ b / np.sqrt((a @ a) * (b @ b)))


def test_guv_grid_matches_the_documented_pitch(guv_lf):
    grid = guv_lf.meta["grid"]
    assert grid.kind == "rectangular"
    assert abs(grid.pitch - GUV_PITCH) < 0.05  # PlenoptiCam: 15.39 px
    assert abs(grid.rotation) < 1.0
    assert 700 <= grid.n_lenses <= 850  # 436 / 15.4 = 28.3 lenses a side
    assert grid.fit["rms_residual_px"] < 0.25


def test_guv_views_show_the_vesicle(guv_lf):
    assert guv_lf.shape == (15, 15, 28, 28, 1)
    centre = guv_lf.data[7, 7, ..., 0]
    # the membrane is a bright ring around a darker lumen, on a dark background
    y, x = np.mgrid[0:28, 0:28]
    radius = np.hypot(y - 13.5, x - 13.5)
    ring = centre[(radius > 6.5) & (radius < 9.5)].mean()
    lumen = centre[radius < 4].mean()
    outside = centre[radius > 11].mean()
    assert ring > 1.8 * lumen and ring > 2 * outside
    # neighbouring views see the same specimen; views far apart in the aperture less so
    assert _correlation(guv_lf.data[7, 7], guv_lf.data[7, 8]) > 0.9
    assert _correlation(guv_lf.data[7, 7], guv_lf.data[8, 7]) > 0.9
    assert _correlation(guv_lf.data[7, 7], guv_lf.data[7, 8]) > _correlation(guv_lf.data[7, 7], guv_lf.data[7, 12])


def test_guv_refocus_and_the_bundled_copy(guv_lf):
    from napari_lfalias._paths import sample_data_dir

    folder = sample_data_dir() / "guv"
    for name in GUV_FILES + ("LICENSE", "PROVENANCE.md"):
        assert (folder / name).is_file(), name
    bundled = lfa.load(folder / GUV_FILES[0], white=folder / GUV_FILES[1], dark=folder / GUV_FILES[2])
    np.testing.assert_array_equal(bundled.data, guv_lf.data)
    image = lfa.refocus(guv_lf, 0.0)
    assert image.shape == (28, 28, 1) and np.isfinite(image).all() and image.max() > 0


def test_antleg_grid_and_views(antleg):
    grid, lf = antleg
    assert grid.kind == "rectangular"
    assert abs(grid.pitch - ANTLEG_PITCH) < 0.15
    assert abs(grid.rotation) < 1.0
    # the relay optics bend the grid by about a pixel: a distortion is fitted and halves the residual
    assert grid.distortion and grid.fit["rms_residual_after_distortion_px"] < 0.5 * grid.fit["rms_residual_px"]
    assert lf.grid_shape == (27, 27) and lf.image_shape[0] >= 75 and lf.image_shape[1] >= 90
    centre = lf.data[13, 13, ..., 0]
    # the leg is bright against a dark background: strong contrast, not a flat image
    assert np.percentile(centre, 99) > 3 * np.percentile(centre, 50)
    assert _correlation(lf.data[13, 13], lf.data[13, 14]) > 0.95
    assert _correlation(lf.data[13, 13], lf.data[14, 13]) > 0.95
    # the dark strip on the sensor's left edge gets no weight
    assert lf.weights[13, 13].min() == 0 or lf.meta["lens_window"][2] > 0


def test_the_dense_antleg_capture_has_nothing_for_the_default_reduction_to_remove(antleg):
    """All 27x27 views of a real microscope capture sample the aperture densely: its sensor noise, the dark
    corner views and the sensor's dark strip are not aliasing. Its 3x3 sub-grid (one view per 9x9 cell of
    the aperture) does alias where the leg is out of focus (ghosts 9 view steps apart), and the default
    reduction brings it nearer the refocus of all 729 views (the sub-grid protocol), clean pixels included.
    Measured at slope 1.5: +1.0 dB overall, +0.9 on the clean pixels; with renderings trusted from a
    confidence of 0.05 (before stop 21) +11.7 overall but -2.8 on the clean pixels."""
    _, lf = antleg
    estimate = lfa.estimate_disparity(lf)
    for slope in (0.0, 0.5):
        reduced = lfa.reduce_aliasing(lf, slope, disparity=estimate)
        assert not reduced.detections[0].mask.any(), slope
        np.testing.assert_array_equal(reduced.image, reduced.refocused)
    sparse = lf.subset([4, 13, 22], [4, 13, 22])
    sparse = lfa.LightField(sparse.data, sparse.positions, weights=sparse.weights)
    naive, reference = lfa.refocus(sparse, 1.5), lfa.refocus(lf, 1.5)
    reduced = lfa.reduce_aliasing(sparse, 1.5)
    assert reduced.detections[0].mask.mean() > 0.05  # measured: 0.14
    clean = ~lfa.metrics.aliased_pixels(naive, reference)
    gains = [lfa.metrics.psnr(reduced.image, reference, mask=m) - lfa.metrics.psnr(naive, reference, mask=m)
             for m in (None, clean)]
    assert gains[0] > 0.5 and gains[1] >= -0.1, gains
