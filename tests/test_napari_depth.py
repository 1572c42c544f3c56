"""Metric depth of the focus plane from HCI-style camera parameters."""

import configparser

import numpy as np
import pytest

import napari_lfalias as lfa
from napari_lfalias._napari._depth import depth_label, depth_of_slope

pytestmark = pytest.mark.napari


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
