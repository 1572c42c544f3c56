"""Synthetic layered scenes: determinism, ground truth consistent with the rendering, aliasing."""

import numpy as np
import pytest
from scipy import ndimage

from napari_lfalias import LightField, ParameterError, refocus
from napari_lfalias.synthetic import SyntheticScene, brick_room, layered_scene, textured_plane, textureless_plane


@pytest.fixture(scope="module")
def small_room():
    return brick_room(n_views=5, size=64, seed=0)


@pytest.fixture(scope="module")
def room():
    # big enough that part of the wall lies beyond the defocused cube's blur
    return brick_room(n_views=8, size=192, seed=0)


def test_brick_room_light_field_and_ground_truth(small_room):
    lf = small_room.lightfield
    assert isinstance(lf, LightField)
    assert lf.shape == (5, 5, 64, 64, 3) and lf.data.dtype == np.float32
    np.testing.assert_array_equal(lf.positions, LightField(lf.data).positions)
    assert 0.0 <= lf.data.min() and lf.data.max() <= 1.0
    assert lf.data.std() > 0.1  # textured
    disparity = small_room.disparity
    assert disparity.shape == (64, 64) and disparity.dtype == np.float32
    layers = small_room.layers_disparity
    assert set(layers) == {"back_wall", "cube_front"}
    assert abs(layers["cube_front"] - layers["back_wall"]) >= 4
    assert set(np.unique(disparity)) == set(layers.values())
    assert lf.meta["source"] == "synthetic"
    np.testing.assert_array_equal(lf.meta["disparity"], disparity)
    assert lf.meta["disparity_range"] == (min(layers.values()), max(layers.values()))
    assert small_room.lightfield is lf  # cached


def test_same_seed_same_scene_other_seed_other_scene(small_room):
    again = brick_room(n_views=5, size=64, seed=0)
    np.testing.assert_array_equal(again.lightfield.data, small_room.lightfield.data)
    np.testing.assert_array_equal(again.reference(1.0), small_room.reference(1.0))
    other = brick_room(n_views=5, size=64, seed=1)
    assert np.abs(other.lightfield.data - small_room.lightfield.data).max() > 0.1


def test_render_view_equals_the_light_field_views(small_room):
    lf = small_room.lightfield
    for u, v in ((0, 0), (2, 2), (4, 1)):
        view = small_room.render_view(lf.positions[u, v])
        np.testing.assert_allclose(view, lf.data[u, v], atol=1e-5)


def test_views_warped_by_the_true_disparity_match_the_centre_view():
    # integer positions and disparities: the warp is whole pixels, no interpolation
    scene = brick_room(n_views=5, size=128, seed=2, wall_disparity=-1.0, cube_disparity=2.0)
    lf = scene.lightfield
    disparity = scene.disparity
    centre = scene.render_view((0.0, 0.0))
    step = 3.0
    n = lf.image_shape[0]
    rows, cols = np.mgrid[:n, :n]
    for u, v in ((0, 0), (0, 4), (3, 1), (4, 4)):
        q = lf.positions[u, v]
        # pixels whose neighbourhood stays on one layer in this view (no occlusion change, no soft edge)
        reach = int(step * np.abs(q).max()) + 12
        flat = ndimage.minimum_filter(disparity, reach * 2 + 1) == ndimage.maximum_filter(disparity, reach * 2 + 1)
        ys = rows + (disparity * q[0]).astype(int)
        xs = cols + (disparity * q[1]).astype(int)
        inside = (ys >= 0) & (ys < n) & (xs >= 0) & (xs < n) & flat
        assert inside.sum() > 1000 and (inside & (disparity == 2.0)).sum() > 20
        warped = lf.data[u, v][ys[inside], xs[inside]]
        np.testing.assert_allclose(warped, centre[inside], atol=5e-4)  # mask tails, see scenes._lowpass
        # the wrong disparity does not match
        ys_wrong = np.clip(rows + (-disparity * q[0]).astype(int), 0, n - 1)
        xs_wrong = np.clip(cols + (-disparity * q[1]).astype(int), 0, n - 1)
        assert np.abs(lf.data[u, v][ys_wrong[inside], xs_wrong[inside]] - centre[inside]).max() > 0.1


@pytest.mark.parametrize("disparity", [1.3, -0.75, 2.0])
def test_reference_of_a_single_plane_at_its_disparity_is_its_texture(disparity):
    scene = textured_plane(n_views=4, size=48, seed=3, disparity=disparity)
    texture = scene.render_view((0.0, 0.0))
    np.testing.assert_allclose(scene.reference(disparity), texture, atol=1e-5)
    # out of focus, the plane is blurred
    assert np.abs(scene.reference(disparity + 1.0) - texture).max() > 0.05


def test_bilinear_reference_with_one_sample_per_view_is_the_refocus(small_room):
    for slope in (-4.0, 0.35, 4.0):
        reference = small_room.reference(slope, samples_per_view=1, interpolation="bilinear")
        np.testing.assert_allclose(reference, refocus(small_room.lightfield, slope), atol=1e-5)


def test_reference_converges_as_the_aperture_gets_denser(small_room):
    fine = small_room.reference(0.5, samples_per_view=64)
    errors = [np.abs(small_room.reference(0.5, samples_per_view=m) - fine).max() for m in (2, 8, 32)]
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 0.01
    assert small_room.aperture_samples(0.5) >= 14  # 3.5 px per view step / 0.25 px


def test_brick_room_is_angularly_aliased_out_of_focus_only(room):
    lf = room.lightfield
    layers = room.layers_disparity
    cube = room.disparity == layers["cube_front"]
    beyond_blur = ~ndimage.binary_dilation(cube, structure=np.ones((3, 3)), iterations=40)
    cube_inside = ndimage.binary_erosion(cube, iterations=10)
    assert beyond_blur.sum() > 5000 and cube_inside.sum() > 2000

    # focused on the cube: the cube agrees, the wall's bricks alias visibly
    diff = np.abs(refocus(lf, layers["cube_front"]) - room.reference(layers["cube_front"])).max(-1)
    assert diff[cube_inside].max() < 5e-4
    assert diff[beyond_blur].mean() > 0.03

    # focused on the wall: the wall agrees, the defocused cube aliases
    diff = np.abs(refocus(lf, layers["back_wall"]) - room.reference(layers["back_wall"])).max(-1)
    assert diff[beyond_blur].max() < 5e-4
    assert diff[cube].mean() > 20 * diff[beyond_blur].mean()
    assert diff[cube].mean() > 0.005


def test_textureless_plane_is_constant_away_from_its_object():
    scene = textureless_plane(n_views=5, size=64, seed=0, wall_colour=(0.3, 0.5, 0.7))
    lf = scene.lightfield
    assert set(scene.layers_disparity) == {"object", "wall"}
    thing = scene.disparity == scene.layers_disparity["object"]
    assert 0.02 < thing.mean() < 0.2
    reach = int(abs(scene.layers_disparity["object"] - scene.layers_disparity["wall"]) * 3) + 10
    far = ~ndimage.binary_dilation(thing, structure=np.ones((3, 3)), iterations=reach)
    assert far.sum() > 500
    # band-limited masks have tails: constant to 1e-3 beyond the object's reach
    np.testing.assert_allclose(lf.data[:, :, far], np.broadcast_to([0.3, 0.5, 0.7], lf.data[:, :, far].shape),
                               atol=1e-3)
    for slope in scene.layers_disparity.values():
        np.testing.assert_allclose(scene.reference(slope)[far], np.broadcast_to([0.3, 0.5, 0.7], (far.sum(), 3)),
                                   atol=1e-3)
    assert lf.data[:, :, thing].std() > 0.1


def test_custom_scene_from_planes(small_room):
    scene = SyntheticScene(small_room.layers[1:], n_views=3, size=32, name="wall only")
    assert scene.lightfield.shape == (3, 3, 32, 32, 3)
    assert scene.layers_disparity == {"back_wall": small_room.layers_disparity["back_wall"]}


@pytest.mark.parametrize(
    "kwargs, name",
    [({"n_views": 0}, "n_views"), ({"size": 4}, "size"), ({"seed": -1}, "seed"), ({"seed": 1.5}, "seed"),
     ({"wall_disparity": np.nan}, "wall_disparity")],
)
def test_bad_parameters_are_parameter_errors(kwargs, name):
    with pytest.raises(ParameterError, match=name):
        brick_room(**kwargs)


def test_bad_reference_and_view_arguments(small_room):
    with pytest.raises(ParameterError, match="slope"):
        small_room.reference(np.inf)
    with pytest.raises(ParameterError, match="interpolation"):
        small_room.reference(0.0, interpolation="cubic")
    with pytest.raises(ParameterError, match="samples_per_view"):
        small_room.reference(0.0, samples_per_view=0)
    with pytest.raises(ParameterError, match="pos"):
        small_room.render_view(1.0)
    with pytest.raises(ParameterError, match="wall_colour"):
        textureless_plane(wall_colour=(2, 0, 0))


# -- refocus over any aperture ------------------------------------------------------------------------


def _cells(n_views, m):
    """Aperture positions of ``m`` samples per view cell and axis (the midpoint rule of ``reference``)."""
    centres = np.arange(n_views) - (n_views - 1) / 2
    return (centres[:, None] + (np.arange(m) + 0.5) / m - 0.5).ravel()


def test_a_uniform_square_aperture_is_the_reference(small_room):
    q = _cells(5, 6)
    for slope in (-4.0, 1.3):
        image = small_room.aperture_refocus(slope, q, q, np.ones((q.size, q.size)))
        np.testing.assert_allclose(image, small_room.reference(slope, samples_per_view=6), atol=2e-5)


def test_origin_and_shape_select_a_window_of_the_scene(small_room):
    q = _cells(5, 4)
    slope = 2.0
    full = small_room.reference(slope, samples_per_view=4)
    window = small_room.aperture_refocus(slope, q, q, np.ones((q.size, q.size)), origin=(5.0, 7.0), shape=(30, 40))
    assert window.shape == (30, 40, 3)
    inner = (slice(6, -6), slice(6, -6))  # beyond the border validity of |slope| * 2.5 px
    np.testing.assert_allclose(window[inner], full[5:35, 7:47][inner], atol=2e-5)


def test_a_disc_aperture_keeps_the_plane_in_focus_sharp_and_blurs_it_elsewhere():
    scene = textured_plane(n_views=5, size=64, seed=3, disparity=1.5)
    q = _cells(5, 8)
    disc = (np.hypot(q[:, None], q[None, :]) <= 2.5).astype(float)
    texture = scene.render_view((0.0, 0.0))[10:50, 12:52]
    sharp = scene.aperture_refocus(1.5, q, q, disc, origin=(10.0, 12.0), shape=(40, 40))
    np.testing.assert_allclose(sharp, texture, atol=1e-4)
    # a sub-pixel origin moves the scene exactly: the view at q = (-1/3, 0) sees it 0.5 px further down
    moved = scene.aperture_refocus(1.5, q, q, disc, origin=(10.5, 12.0), shape=(40, 40))
    np.testing.assert_allclose(moved, scene.render_view((-1 / 3, 0.0))[10:50, 12:52], atol=1e-4)
    assert np.abs(moved - sharp).max() > 0.05
    blurred = scene.aperture_refocus(-0.5, q, q, disc, origin=(10.0, 12.0), shape=(40, 40))
    square = scene.aperture_refocus(-0.5, q, q, np.ones_like(disc), origin=(10.0, 12.0), shape=(40, 40))

    def detail(image):
        return np.abs(np.diff(image, axis=1)).mean()

    assert detail(blurred) < 0.5 * detail(texture)
    assert np.abs(blurred - square)[10:30, 10:30].max() > 0.01  # the aperture's shape is the blur's shape


def test_aperture_refocus_rejects_bad_input(small_room):
    q = np.zeros(3)
    with pytest.raises(ParameterError, match=r"transmission must be non-negative, shape \(3, 3\)"):
        small_room.aperture_refocus(0.0, q, q, np.ones((3, 2)))
    with pytest.raises(ParameterError, match="transmission must be non-negative"):
        small_room.aperture_refocus(0.0, q, q, -np.ones((3, 3)))
    with pytest.raises(ParameterError, match="reach outside the scene"):
        small_room.aperture_refocus(0.0, q, q, np.ones((3, 3)), origin=(40.0, 0.0), shape=(30, 30))


# -- the reference through a vignetted camera ---------------------------------------------------------

@pytest.mark.parametrize("slope", [0.0, -2.0, 3.0])
def test_the_vignetted_reference_weighs_every_ray_where_it_lands(slope):
    """Against brute force: every aperture sample's exact view, weighed by the fall-off at its aperture
    position and at the pixel where it lands (measured: within 4e-8 inside the border; at the border the brute
    force takes a landing beyond the last pixel as invalid, the reference as its bilinear share)."""
    from napari_lfalias import regular_positions
    from napari_lfalias.synthetic import layered_scene
    from napari_lfalias.synthetic.camera import vignetted_reference

    size, n, strength, m = 40, 3, 0.8, 2
    scene = layered_scene([(3.0, "stripes", (0.2, 0.7, 0.3, 0.8)), (-2.0, "bricks", None)], n_views=n, size=size,
                          seed=3)
    aperture = scene.aperture_positions(m)
    q_max2 = float(np.max(np.sum(regular_positions(n, n) ** 2, axis=-1)))
    pixels = np.arange(size)
    num, den = np.zeros((size, size, 3)), np.zeros((size, size))
    for a, q_y in enumerate(aperture):
        for b, q_x in enumerate(aperture):
            one = np.zeros((aperture.size, aperture.size))
            one[a, b] = 1.0
            view = scene.aperture_refocus(slope, aperture, aperture, one)
            land_y, land_x = pixels + slope * q_y, pixels + slope * q_x
            valid = ((land_y >= 0) & (land_y <= size - 1))[:, None] & ((land_x >= 0) & (land_x <= size - 1))[None]
            rho_p2 = ((((land_y - (size - 1) / 2) / (size / 2)) ** 2)[:, None]
                      + (((land_x - (size - 1) / 2) / (size / 2)) ** 2)[None]) / 2
            weight = valid / (1 + strength * ((q_y ** 2 + q_x ** 2) / q_max2 + rho_p2)) ** 2
            num += weight[..., None] * view
            den += weight
    brute = num / den[..., None]
    reference = vignetted_reference(scene, slope, strength, samples_per_view=m)
    inner = (slice(6, -6), slice(6, -6))
    np.testing.assert_allclose(reference[inner], brute[inner], rtol=0, atol=1e-6)
    assert np.abs(scene.reference(slope, m) - brute)[inner].max() > 1e-3  # the uniform aperture is not it


def test_a_layered_scene_draws_its_textures_for_the_disparities_it_is_given():
    """``textures_for``: the textures of the scene with those disparities (their period spans the view and
    the largest motion); the layers' own by default, a named error when not a list of numbers."""
    layers = [(2.0, "noise", (0.3, 0.7, 0.3, 0.7)), (-1.0, "checker", None)]
    own = layered_scene(layers, n_views=3, size=32, seed=4)
    same = layered_scene(layers, n_views=3, size=32, seed=4, textures_for=[2.0, -1.0])
    np.testing.assert_array_equal(own.lightfield.data, same.lightfield.data)
    wider = layered_scene(layers, n_views=3, size=32, seed=4, textures_for=[9.0, -1.0])  # a longer period
    assert not np.array_equal(own.lightfield.data, wider.lightfield.data)
    for bad, match in ((2.0, "sequence"), ([], "at least one"), ([1.0, np.nan], r"textures_for\[1\]")):
        with pytest.raises(ParameterError, match=match):
            layered_scene(layers, n_views=3, size=32, textures_for=bad)
