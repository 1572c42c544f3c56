"""Metric depth of the focus plane from HCI-style camera parameters."""

import configparser

import numpy as np
import pytest

import napari_lfalias as lfa
from napari_lfalias._napari._depth import depth_label, depth_of_slope

pytestmark = pytest.mark.napari

from test_napari_jobs import no_leaked_worker_threads  # noqa: E402,F401  (autouse: no thread outlives a test)


def _lightfield(meta):
    return lfa.LightField(np.zeros((3, 3, 8, 8, 1), np.float32), meta=meta)


@pytest.fixture
def dino(lf_data):
    config = configparser.ConfigParser()
    config.read(lf_data / "hci_parameters_cfg_examples" / "training_dino_parameters.cfg")
    return {section: {k: float(v) for k, v in config[section].items() if k != "version"}
            for section in ("intrinsics", "extrinsics")}


def test_zero_slope_is_the_focus_distance(dino):
    lf = _lightfield({"hci": dino})
    assert depth_of_slope(lf, 0.0) == pytest.approx(dino["extrinsics"]["focus_distance_m"])


def test_depth_follows_the_hci_disparity_to_depth_relation(dino):
    # HCI: a point at depth Z has disparity d_hci = (b f W / s) (1/Z - 1/D), positive in
    # front of the focus plane; this package's slope is -d_hci.
    intr, extr = dino["intrinsics"], dino["extrinsics"]
    scale_mm = extr["baseline_mm"] * intr["focal_length_mm"] * intr["image_resolution_x_px"] / intr["sensor_size_mm"]
    lf = _lightfield({"hci": dino})
    for depth_m in (4.0, 6.0, 9.0, 20.0):
        d_hci = scale_mm * (1.0 / (depth_m * 1e3) - 1.0 / (extr["focus_distance_m"] * 1e3))
        assert depth_of_slope(lf, -d_hci) == pytest.approx(depth_m, rel=1e-9)
    # nearer planes for negative slopes, farther for positive ones; beyond infinity: unknown
    assert depth_of_slope(lf, -1.0) < extr["focus_distance_m"] < depth_of_slope(lf, 0.5)
    assert depth_of_slope(lf, 1e6) is None


def test_no_calibration_no_depth():
    lf = _lightfield({"source": "synthetic"})
    assert depth_of_slope(lf, 1.0) is None
    assert depth_label(lf, 1.0) == ""
    calibrated = _lightfield({"depth_of_disparity": lambda d: 2.0 + d})
    assert depth_label(calibrated, 0.5) == "depth 2.5 m"


def test_widget_shows_the_depth_of_an_hci_scene(make_napari_viewer, lf_data, tmp_path):
    import shutil

    import imageio.v3 as iio

    from napari_lfalias._napari._layers import lightfield_layer_data
    from napari_lfalias._napari._widget import AliasingWidget

    folder = tmp_path / "dino"
    folder.mkdir()
    views = np.random.default_rng(0).integers(0, 255, (81, 16, 16, 3), dtype=np.uint8)
    for i, view in enumerate(views):
        iio.imwrite(folder / f"input_Cam{i:03d}.png", view)
    shutil.copy(lf_data / "hci_parameters_cfg_examples" / "training_dino_parameters.cfg",
                folder / "parameters.cfg")
    lf = lfa.load(folder)
    viewer = make_napari_viewer()
    data, kwargs, _ = lightfield_layer_data(lf, "dino")
    viewer.add_image(data, **kwargs)
    widget = AliasingWidget(viewer)
    viewer.window.add_dock_widget(widget)
    # the focus range is the scene's disp_min..disp_max (in this package's sign)
    assert (widget.focus_slider.minimum(), widget.focus_slider.maximum()) == (-1.9, 1.9)
    widget.live_check.setChecked(False)
    widget.focus_slider.setValue(0.0)
    assert widget.depth_label.text() == "depth 6.9 m"
    widget.focus_slider.setValue(-1.0)
    assert widget.depth_label.text() == f"depth {depth_of_slope(lf, -1.0):.3g} m"
    assert depth_of_slope(lf, -1.0) < 6.9
    assert widget.shutdown()


# -- light-field microscopes -------------------------------------------------------------

GUV_OPTICS = {"ulens_pitch_um": 100.0, "pixel_size_um": 6.5, "magnification": 60.0, "na": 1.2,
              "medium_index": 1.35}


def test_microscope_offset_follows_the_paraxial_relation():
    from napari_lfalias._napari._depth import microscope_offset_um

    lf = _lightfield({"microscope": GUV_OPTICS, "grid": None})
    # no fitted grid: pitch 100 / 6.5 px, so 7.69 views from the lens' centre to its rim;
    # one decoded pixel is 100 / 60 um in the specimen; z = d n r s / NA
    per_slope = 1.35 * (100 / 6.5 / 2) * (100 / 60) / 1.2
    assert microscope_offset_um(lf, 0.0) == 0.0
    assert microscope_offset_um(lf, 0.5) == pytest.approx(0.5 * per_slope)
    assert microscope_offset_um(lf, -1.0) == pytest.approx(-per_slope)
    assert depth_label(lf, 0.5) == f"z \u2248 +{0.5 * per_slope:.3g} \u00b5m from the native object plane"
    # a missing number: no depth rather than a wrong one
    partial = _lightfield({"microscope": {k: v for k, v in GUV_OPTICS.items() if k != "na"}})
    assert depth_label(partial, 0.5) == ""


def test_optics_are_read_from_napari_lf_metadata_or_a_readme(tmp_path, lf_data):
    import json

    from napari_lfalias._napari._optics import read_microscope_optics

    assert read_microscope_optics(lf_data / "napari_lf_guv") == GUV_OPTICS  # its README summary
    (tmp_path / "metadata.txt").write_text(json.dumps({"calibrate": {
        "ulens_pitch": 125.0, "pixel_size": 4.55, "objective_magnification": 20,
        "objective_na": 0.5, "medium_index": 1.33}}))
    assert read_microscope_optics(tmp_path)["na"] == 0.5
    (tmp_path / "metadata.txt").write_text(json.dumps({"calibrate": {"ulens_pitch": 125.0}}))
    assert read_microscope_optics(tmp_path) is None
    (tmp_path / "metadata.txt").write_text("not json")
    assert read_microscope_optics(tmp_path) is None


def test_widget_shows_the_axial_position_for_the_guv_sample(make_napari_viewer):
    from napari_lfalias._napari._depth import microscope_offset_um
    from napari_lfalias._napari._widget import AliasingWidget

    viewer = make_napari_viewer()
    viewer.open_sample("napari-lfalias", "guv")
    widget = AliasingWidget(viewer)
    viewer.window.add_dock_widget(widget)
    widget.live_check.setChecked(False)
    lf = viewer.layers[0].metadata["lightfield"]
    # no disparities in the metadata: +/- 1 px per view step (15 views of 28 px)
    assert (widget.focus_slider.minimum(), widget.focus_slider.maximum()) == (-1.0, 1.0)
    widget.focus_slider.setValue(0.5)
    offset = microscope_offset_um(lf, 0.5)
    assert 6.0 < offset < 8.5  # the fitted pitch (15.40 px) sets r, about 14.4 um per px per view
    assert widget.depth_label.text() == f"z \u2248 +{offset:.3g} \u00b5m from the native object plane"
    assert widget.shutdown()
