"""LightField: validation of data, positions and weights; scaling; luminance; subsets."""

import numpy as np
import pytest

from napari_lfalias import LightField
from napari_lfalias.errors import LightFieldError, ParameterError
from napari_lfalias.lightfield import REC709, regular_positions


def _data(shape=(3, 4, 5, 6, 3), seed=0):
    return np.random.default_rng(seed).random(shape, dtype=np.float32)


def test_regular_positions_are_centred_grid_steps():
    positions = regular_positions(3, 4)
    assert positions.shape == (3, 4, 2)
    np.testing.assert_array_equal(positions[0, 0], [-1.0, -1.5])
    np.testing.assert_array_equal(positions[2, 3], [1.0, 1.5])
    np.testing.assert_allclose(positions.mean(axis=(0, 1)), 0)
    lf = LightField(_data())
    np.testing.assert_array_equal(lf.positions, positions)


@pytest.mark.parametrize("shape", [(3, 4, 5), (2, 3, 4, 5, 3, 1), (5,)])
def test_wrong_number_of_dimensions(shape):
    with pytest.raises(ParameterError, match=r"\(U, V, Y, X\).*dimensions"):
        LightField(np.zeros(shape, np.float32))


@pytest.mark.parametrize("channels", [2, 4])
def test_wrong_number_of_channels(channels):
    with pytest.raises(ParameterError, match="1 or 3 channels"):
        LightField(np.zeros((2, 2, 4, 4, channels), np.float32))


def test_missing_channel_axis_is_added():
    lf = LightField(np.zeros((2, 3, 4, 5), np.float32))
    assert lf.shape == (2, 3, 4, 5, 1) and lf.n_channels == 1
    assert lf.grid_shape == (2, 3) and lf.image_shape == (4, 5) and lf.n_views == 6


def test_non_numeric_and_complex_data_are_refused():
    with pytest.raises(ParameterError, match="numeric"):
        LightField(np.zeros((2, 2, 4, 4), bool))
    with pytest.raises(ParameterError, match="real"):
        LightField(np.zeros((2, 2, 4, 4), complex))


def test_positions_shape_must_match_the_grid():
    data = _data()
    with pytest.raises(ParameterError, match=r"positions must have shape \(U, V, 2\) = \(3, 4, 2\)"):
        LightField(data, positions=np.zeros((4, 3, 2)))
    with pytest.raises(ParameterError, match="positions"):
        LightField(data, positions=np.zeros((3, 4)))


def test_positions_must_be_finite():
    positions = regular_positions(3, 4)
    positions[1, 1, 0] = np.inf
    with pytest.raises(ParameterError, match="positions must be finite"):
        LightField(_data(), positions=positions)


def test_irregular_positions_are_kept():
    positions = regular_positions(3, 4) + 0.1 * np.arange(24).reshape(3, 4, 2)
    lf = LightField(_data(), positions=positions)
    np.testing.assert_array_equal(lf.positions, positions)
    np.testing.assert_array_equal(lf.flat_positions()[5], positions[1, 1])


def test_nan_is_refused_with_advice():
    data = _data()
    data[1, 2, 3, 4, 0] = np.nan
    data[0, 0, 0, 0, :] = np.inf
    with pytest.raises(ParameterError, match=r"4 NaN/Inf samples.*nonfinite='mask'") as info:
        LightField(data)
    assert isinstance(info.value, LightFieldError)


def test_nonfinite_mask_gives_zero_weight():
    data = _data()
    data[1, 2, 3, 4, 0] = np.nan
    data[0, 0, 0, 0, :] = -np.inf
    lf = LightField(data, nonfinite="mask")
    assert np.all(np.isfinite(lf.data))
    assert lf.data[1, 2, 3, 4, 0] == 0
    assert lf.weights.shape == (3, 4, 5, 6)
    assert lf.weights[1, 2, 3, 4] == 0 and lf.weights[0, 0, 0, 0] == 0
    assert lf.weights.sum() == lf.weights.size - 2
    np.testing.assert_array_equal(lf.data[1, 2, 3, 4, 1:], data[1, 2, 3, 4, 1:])  # other channels kept


def test_nonfinite_option_is_checked():
    with pytest.raises(ParameterError, match="nonfinite"):
        LightField(_data(), nonfinite="ignore")


def test_weights_are_checked():
    with pytest.raises(ParameterError, match=r"weights must have shape"):
        LightField(_data(), weights=np.ones((3, 4, 5)))
    with pytest.raises(ParameterError, match=r"weights must be finite and lie in \[0, 1\]"):
        LightField(_data(), weights=np.full((3, 4, 5, 6), 2.0))


@pytest.mark.parametrize("dtype, top", [(np.uint8, 255), (np.uint16, 65535), (np.int16, 32767)])
def test_integer_data_are_scaled_by_their_maximum(dtype, top):
    data = np.array([0, top // 2, top], dtype).reshape(1, 1, 1, 3, 1)
    lf = LightField(data)
    assert lf.data.dtype == np.float32
    np.testing.assert_allclose(lf.data.ravel(), [0, (top // 2) / top, 1.0], rtol=1e-6)


def test_float64_becomes_float32_unscaled():
    data = _data().astype(np.float64) * 3
    lf = LightField(data)
    assert lf.data.dtype == np.float32
    np.testing.assert_allclose(lf.data, data, rtol=1e-6)


def test_luminance_uses_rec709():
    data = _data()
    lum = LightField(data).luminance()
    assert lum.shape == (3, 4, 5, 6, 1)
    expected = 0.2126 * data[..., 0] + 0.7152 * data[..., 1] + 0.0722 * data[..., 2]
    np.testing.assert_allclose(lum.data[..., 0], expected, rtol=1e-5, atol=1e-6)
    assert REC709.sum() == pytest.approx(1.0)
    grey = LightField(data[..., :1])
    assert grey.luminance() is grey


def test_luminance_of_data_in_memory_and_lazy_data_is_the_same():
    # in memory the sums run on every core, lazily chunk by chunk (the channels split over two chunks here):
    # the same float32 sums, left to right, as numpy's element-wise float32 arithmetic makes them
    da = pytest.importorskip("dask.array")
    data = np.random.default_rng(2).uniform(-0.5, 3.0, (3, 4, 33, 35, 3)).astype(np.float32)
    in_memory = LightField(data).luminance().data
    lazy = LightField(da.from_array(data, chunks=(1, 2, 33, 35, 2))).luminance().data.compute()
    np.testing.assert_array_equal(in_memory, lazy)
    left_to_right = data[..., 0] * REC709[0] + data[..., 1] * REC709[1] + data[..., 2] * REC709[2]
    np.testing.assert_array_equal(in_memory[..., 0], left_to_right)


def test_luminance_does_not_depend_on_the_memory_layout():
    # a light-field TIFF is read as (U, V, C, Y, X) planes with C moved last: a strided array. numpy's matmul
    # rounds strided float32 data differently from contiguous data; the estimate read from a saved file
    # must be the estimate of the array that was saved
    data = np.random.default_rng(3).uniform(0.0, 1.0, (3, 4, 40, 48, 3)).astype(np.float32)
    strided = np.moveaxis(np.ascontiguousarray(np.moveaxis(data, -1, 2)), 2, -1)
    assert not strided.flags.c_contiguous and np.array_equal(strided, data)
    np.testing.assert_array_equal(LightField(strided).luminance().data, LightField(data).luminance().data)


def test_subset_keeps_positions_weights_and_meta():
    weights = np.random.default_rng(1).random((3, 4, 5, 6)).astype(np.float32)
    lf = LightField(_data(), meta={"source": "x"}, weights=weights)
    sub = lf.subset(rows=slice(1, 3), cols=[0, 3])
    assert sub.shape == (2, 2, 5, 6, 3)
    np.testing.assert_array_equal(sub.data[1, 1], lf.data[2, 3])
    np.testing.assert_array_equal(sub.positions[1, 1], lf.positions[2, 3])
    np.testing.assert_array_equal(sub.weights[0, 1], weights[1, 3])
    assert sub.meta == {"source": "x"} and sub.meta is not lf.meta


def test_views_are_row_major():
    lf = LightField(_data())
    views = lf.views()
    assert views.shape == (12, 5, 6, 3)
    np.testing.assert_array_equal(views[6], lf.data[1, 2])


def test_lazy_data_stay_lazy_until_computed():
    da = pytest.importorskip("dask.array")
    data = _data()
    lf = LightField(da.from_array((data * 255).astype(np.uint8), chunks=(1, 1, 5, 6, 3)))
    assert lf.is_lazy and "lazy" in repr(lf)
    computed = lf.compute()
    assert not computed.is_lazy
    np.testing.assert_allclose(computed.data, (data * 255).astype(np.uint8) / np.float32(255))


def test_float64_values_beyond_float32_are_named_not_called_nan():
    data = np.full((2, 2, 4, 4, 1), 0.5)
    data[1, 0, 2, 3, 0] = -1e300
    with pytest.raises(ParameterError, match=r"1 finite float64 values beyond float32's range.*1e\+300"):
        LightField(data)
    data[1, 0, 2, 3, 0] = 1e30  # within float32: kept
    assert LightField(data).data[1, 0, 2, 3, 0] == np.float32(1e30)
