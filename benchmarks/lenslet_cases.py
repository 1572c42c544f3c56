"""Lenslet cases of the accuracy benchmark: synthetic plenoptic captures through the decoder.

Each case renders a layered scene (:func:`napari_lfalias.synthetic.layered_scene`:
occluders in front of a textured background, a few pixels of disparity per
view) into a lenslet raw image with its white image and dark frame
(:func:`napari_lfalias.synthetic.render_lenslet`: rectangular or hexagonal
microlenses at a real pitch and a small rotation, main-lens vignetting, the
soft-edged microlens disc that leaves the corner views dim or black, sensor
noise, a Bayer mosaic or a grey sensor), writes them as 16-bit TIFFs and
loads them as a user does, ``lfa.load(raw, white=..., dark=...)``: the
views the methods see are what the decoder makes of the capture.

The nearer layer has the smaller disparity, as in every plenoptic camera
(``decoders/lenslet.py``, module notes; ``tests/test_lenslet_optics.py``
traces it), and the decoder declares that order (``meta["nearer"]``).
Before stop 47 four of the five cases put the larger disparity in front, an
order no such camera records; they were mirrored in depth (every disparity
and slope negated), which moved their results by less than 1 dB
(``results/accuracy.md``, stop 47 notes).

Ground truth in the decoded geometry
------------------------------------
The forward model uses ``scale=1``: a decoded pixel is one scene pixel, and
the decoded disparity of every layer is its scene disparity. The decoder's
output pixel ``(i, j)`` is placed in the scene through the grid it fitted
(``lf.meta["grid"]``, ``lens_window``) and the true grid of the rendering
(an affine map; its deviation from a pure shift, i.e. the calibration's
geometric error, is recorded in ``Case.extra["geometry_error_px"]``).
View ``(u, v)`` sits at aperture position ``q = positions[u, v]`` sensor
pixels from its lens centre, where the white image's transmission is
``t(q)`` (the rendering's microlens disc with its soft rim and inner
fall-off). The views the decoder keeps (those with any weight: the disc of
radius ``pitch / 2``) each own the cell ``[q - 1/2, q + 1/2]^2`` of the
aperture. The outermost pixel or two of the decoded views, which some
kept views do not see (lenses partly off the sensor), are cropped: there
the refocus averages part of the aperture only.

- ``reference(slope)``: the integral over the union of those cells, weighted
  by ``t(q)``, of the scene evaluated exactly at ``p + slope * q``
  (:meth:`~napari_lfalias.synthetic.SyntheticScene.aperture_refocus`, dense
  midpoint rule: ``m`` samples per cell and axis so that no layer moves more
  than 1/4 px between samples), times the exposure; Rec. 709 luminance for a
  grey sensor.
- ``comb(slope)``: the same integral by one sample per view (the midpoint
  rule at the views' own positions, weights ``t(q)``): the decoded views'
  refocus without noise, decoding or interpolation error. The truth of
  aliasing compares it with the reference, so only the angular sampling
  differs.

What separates the naive refocus of the decoded light field from
``comb`` is the camera, not aliasing: the decoder's resampling, noise,
16-bit quantisation, demosaicing and the white image's spatial vignetting
in the weights. Measured at ``size=256`` (``python benchmarks/lenslet_cases.py``,
PSNR of ``refocus(lf, slope)`` against ``comb(slope)`` over each case's
slopes; "in focus": against the reference on a layer's pixels at its own
disparity, away from other layers' blur):

=================================  ==============  ========
case                               naive vs comb   in focus
=================================  ==============  ========
rect 9x9, Bayer (layers +-1)       38.4-41.6 dB    36.0 dB
hex 11x11, Bayer (layers -1..1.5)  45.3-45.6 dB    44.9 dB
rect 7x7, grey (layers +-1)        44.9-54.2 dB    --
hex 9x9, grey (layers +-1)         46.5-55.3 dB    45.8 dB
rect 11x11, Bayer, deep (+-2.5)    28.1-30.1 dB    25.5-26.1 dB
=================================  ==============  ========

Two decoder effects set these floors. Lens centres fall between sensor
pixels, so the decoder interpolates between neighbouring pixels under a
lens, which are neighbouring *views*: a layer at disparity ``d`` is blurred
by up to ``|d|`` px in every view (the deep case: on a grey, noise-free
version its in-focus agreement is 29 dB, and 48 dB once the lens centres
sit on pixel centres, pitch 10 and no rotation). And demosaicing reaches
across the rim of the microlens disc: the diagonal rim views of a Bayer
capture come out 14 to 15 % too dark in red and blue (7 % in green), which
tints the refocus by about 2 %. Both are part of what
a user gets, so the benchmark keeps them; the truth of aliasing
(``comb`` against ``reference``) does not see them. The reference converges:
doubling its aperture samples changes it by at most 1e-4 on every slope.
"""

from __future__ import annotations

import math
import tempfile

import numpy as np

import napari_lfalias as lfa
from napari_lfalias.errors import ParameterError
from napari_lfalias.lightfield import REC709
from napari_lfalias.synthetic import layered_scene, render_lenslet
from napari_lfalias.synthetic.lenslet import _disc

from accuracy_cases import Case

#: Microlens disc diameter (fraction of the pitch) and its soft rim (px) in every case.
FILL, EDGE = 0.96, 1.5
#: Largest motion (px) of any layer between neighbouring aperture samples of the reference.
MAX_STEP = 0.25


class LensletGroundTruth:
    """The dense-aperture reference and the views' comb of a decoded lenslet capture (see the module notes)."""

    def __init__(self, scene, capture, lf):
        if capture.scale != 1.0:
            raise ParameterError(f"the lenslet cases render at scale=1 (a decoded pixel is a scene pixel), "
                                 f"got a capture at scale={capture.scale}")
        self.scene, self.capture = scene, capture
        self.exposure = capture.exposure
        self.grey = capture.bayer is None
        self.shape = lf.image_shape
        self.origin, self.geometry_error = self._origin(capture, lf)
        self.positions = np.asarray(lf.positions, np.float64) * float(lf.meta.get("view_step_px", 1.0))
        self.on = views_kept(lf)
        self.rim = FILL * capture.grid.pitch / 2.0

    @staticmethod
    def _origin(capture, lf):
        """Scene (y, x) of decoded pixel (0, 0), and the largest deviation (px) of the decoded grid from a shift."""
        model = lf.meta["grid"]
        y0, y1, x0, x1 = lf.meta["lens_window"]
        rows, cols = np.meshgrid(np.arange(y0, y1, dtype=np.float64), np.arange(x0, x1, dtype=np.float64),
                                 indexing="ij")
        scene_y, scene_x = capture._scene_points(model.pixel_centres(rows, cols).reshape(-1, 2))
        index = np.stack([rows.ravel() - y0, cols.ravel() - x0], axis=-1)
        offset = np.array([np.median(scene_y - index[:, 0]), np.median(scene_x - index[:, 1])])
        error = np.hypot(scene_y - index[:, 0] - offset[0], scene_x - index[:, 1] - offset[1]).max()
        return tuple(offset), float(error)

    def _transmission(self, aperture_y, aperture_x):
        """The white image's relative transmission on the grid of aperture positions (M, L)."""
        return _disc(np.hypot(aperture_y[:, None], aperture_x[None, :]), self.rim, EDGE)

    def _image(self, slope, aperture_y, aperture_x, weights):
        image = self.scene.aperture_refocus(slope, aperture_y, aperture_x, weights, self.origin, self.shape)
        image = self.exposure * image
        return (image @ REC709[:, None] if self.grey else image).astype(np.float32)

    def samples_per_view(self, slope, max_step=MAX_STEP):
        spread = max(abs(d - slope) for d in self.scene.layers_disparity.values())
        return max(1, math.ceil(spread / max_step))

    def reference(self, slope, samples_per_view=None):
        """The dense-aperture refocus at ``slope`` (Y, X, C) float32 (``m`` samples per view cell and axis)."""
        m = self.samples_per_view(slope) if samples_per_view is None else int(samples_per_view)
        offsets = (np.arange(m) + 0.5) / m - 0.5
        aperture_y = (self.positions[:, 0, 0][:, None] + offsets).ravel()
        aperture_x = (self.positions[0, :, 1][:, None] + offsets).ravel()
        cell_on = np.repeat(np.repeat(self.on, m, axis=0), m, axis=1)
        return self._image(slope, aperture_y, aperture_x, self._transmission(aperture_y, aperture_x) * cell_on)

    def comb(self, slope):
        """The views' own refocus, exactly evaluated (one sample per view, same weights) (Y, X, C) float32."""
        aperture_y, aperture_x = self.positions[:, 0, 0], self.positions[0, :, 1]
        return self._image(slope, aperture_y, aperture_x, self._transmission(aperture_y, aperture_x) * self.on)

    def disparity(self):
        """True disparity (Y, X) at the centre of the aperture, in the decoded geometry (nearest scene pixel)."""
        oy, ox = self.origin
        rows = np.clip(np.round(oy + np.arange(self.shape[0])).astype(int), 0, self.scene.size - 1)
        cols = np.clip(np.round(ox + np.arange(self.shape[1])).astype(int), 0, self.scene.size - 1)
        return self.scene.disparity[np.ix_(rows, cols)]


def views_kept(lf):
    """``(U, V)`` bool: the views the decoder keeps (any weight; the others lie outside the microlens disc)."""
    return lf.weights.reshape(lf.grid_shape + (-1,)).max(axis=-1) > 0


def without_partial_border(lf):
    """``lf`` less the border pixels some kept view does not see (lenses partly off the sensor), same margin all round.

    There the naive refocus averages a part of the aperture only, which the
    dense reference of the whole aperture cannot match; ``lens_window``
    follows the crop.
    """
    seen = (lf.weights[views_kept(lf)] > 0).all(axis=0)
    height, width = seen.shape
    margin = next(m for m in range(min(height, width) // 2) if seen[m:height - m, m:width - m].all())
    inner = (slice(None), slice(None), slice(margin, height - margin), slice(margin, width - margin))
    y0, y1, x0, x1 = lf.meta["lens_window"]
    meta = dict(lf.meta, lens_window=[y0 + margin, y1 - margin, x0 + margin, x1 - margin])
    return lfa.LightField(lf.data[inner], lf.positions, meta, weights=lf.weights[inner])


def _sensor_shape(size, pitch, kind):
    row_step = pitch * (math.sqrt(3) / 2 if kind == "hexagonal" else 1.0)
    column_step = row_step if kind == "hexagonal" else pitch
    return int(math.ceil((size + 2) * row_step)), int(math.ceil((size + 2) * column_step))


def capture_case(name, split, layers, slopes, *, size, kind, pitch, rotation, bayer=None, noise=0.003,
                 vignetting=0.4, seed=0, notes=""):
    """A Case: ``layers`` of :func:`layered_scene` rendered through a lenslet camera and decoded as a user does."""
    reach = max(abs(d) for d, _, _ in layers) * pitch / 2.0
    scene = layered_scene(layers, n_views=int(math.ceil(pitch)) + 1, size=size + 2 * int(math.ceil(reach)) + 16,
                          seed=seed, name=name)
    capture = render_lenslet(scene, shape=_sensor_shape(size, pitch, kind), pitch=pitch, rotation=rotation,
                             kind=kind, scale=1.0, vignetting=vignetting, fill=FILL, edge=EDGE, bayer=bayer,
                             noise=noise, seed=seed)
    with tempfile.TemporaryDirectory() as folder:
        files = capture.write(folder)
        lf = lfa.load(files["raw"], white=files["white"], dark=files["dark"], bayer=bayer)
    lf = without_partial_border(lf)
    lf.meta["source"] = name
    truth = LensletGroundTruth(scene, capture, lf)
    return Case(name, split, lf, list(slopes), truth.reference, truth.disparity(), notes, comb=truth.comb,
                extra={"truth": truth, "geometry_error_px": truth.geometry_error})


def lenslet_cases(size=256):
    """The lenslet cases (see the module notes); ``size`` is about the decoded views' width and height.

    The layers lie within the depth range of a plenoptic camera (1 to 1.5
    px of disparity per view from the microlens plane), so the decoded
    views are sharp; the slopes refocus 3 to 6 px per view away from them
    (ghost spacing 3 to 6 px: the thin mortar and line textures alias
    visibly), and one slope per case is at or next to a layer's focus,
    where the reduction should change nothing. The last case is deeper
    (+-2.5 px): there the decoder's interpolation between neighbouring
    views blurs the in-focus layers (see the module notes).
    """
    common = {"size": size}
    return [
        # -- chosen on --------------------------------------------------------------------------
        capture_case("lenslet rect 9x9, Bayer: grey noise over bricks", "tune",
                     [(-1.0, "grey", (0.25, 0.7, 0.3, 0.75)), (1.0, "bricks", None)], [-1.0, -4.0, 4.5],
                     kind="rectangular", pitch=9.4, rotation=-0.3, bayer="RGGB", noise=0.003, vignetting=0.4,
                     seed=31, notes="rectangular grid, RGGB, noise, vignetting 0.4", **common),
        # -- holdout: never used to choose -------------------------------------------------------
        capture_case("lenslet hex 11x11, Bayer: tiles, lines, bricks", "holdout",
                     [(-1.5, "tiles", (0.15, 0.5, 0.15, 0.55)), (0.0, "lines", (0.5, 0.85, 0.45, 0.85)),
                      (1.0, "bricks", None)], [0.0, -5.0, 4.0], kind="hexagonal", pitch=11.3, rotation=0.4,
                     bayer="RGGB", noise=0.003, vignetting=0.5, seed=32,
                     notes="Illum-like hexagonal grid (11x11 views, 97 inside the disc), RGGB, noise, "
                           "vignetting 0.5", **common),
        capture_case("lenslet rect 7x7, grey: lines over noise", "holdout",
                     [(-1.0, "lines", (0.2, 0.75, 0.25, 0.7)), (1.0, "noise", None)], [0.75, -5.0, 4.0],
                     kind="rectangular", pitch=7.6, rotation=0.6, noise=0.004, vignetting=0.35, seed=33,
                     notes="small pitch (7x7 views, 45 inside the disc), grey sensor, noise", **common),
        capture_case("lenslet hex 9x9, grey: noise over lines", "holdout",
                     [(-1.0, "noise", (0.3, 0.7, 0.3, 0.7)), (1.0, "lines", None)], [1.0, -5.0, 4.0],
                     kind="hexagonal", pitch=9.9, rotation=-0.7, noise=0.002, vignetting=0.5, seed=34,
                     notes="hexagonal grid, grey sensor, a line-textured wall behind", **common),
        capture_case("lenslet rect 11x11, Bayer, deep: bricks over grey noise", "holdout",
                     [(-2.5, "bricks", (0.25, 0.75, 0.2, 0.7)), (2.5, "grey", None)], [-2.5, 2.5],
                     kind="rectangular", pitch=10.3, rotation=0.2, bayer="GRBG", noise=0.003, vignetting=0.4,
                     seed=35, notes="5 px per view between the layers: the decoder blurs whichever is in focus",
                     **common),
    ]


def _in_focus_pixels(truth, disparity, shape):
    """Pixels of the layer at ``disparity`` whose neighbourhood no other layer's blur reaches."""
    from scipy import ndimage

    spread = max(abs(d - disparity) for d in truth.scene.layers_disparity.values())
    reach = int(math.ceil(spread * np.abs(truth.positions).max())) + 4
    layer = truth.disparity() == disparity
    return ndimage.binary_erosion(layer, iterations=reach, border_value=1) & ndimage.binary_erosion(
        np.ones(shape, bool), iterations=4, border_value=0)


def main(argv=None):
    """Print, per case and slope, the decoder's residual, the aliasing, and the reference's convergence."""
    import argparse

    from napari_lfalias import metrics

    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("--size", type=int, default=256)
    args = parser.parse_args(argv)
    for case in lenslet_cases(args.size):
        truth = case.extra["truth"]
        print(f"{case.name}: {case.lightfield.shape}, {int(truth.on.sum())} views kept, "
              f"calibration geometry error {truth.geometry_error:.4f} px")
        for slope in case.slopes:
            naive, comb, reference = lfa.refocus(case.lightfield, slope), case.comb(slope), case.reference(slope)
            m = truth.samples_per_view(slope)
            finer = np.abs(truth.reference(slope, 2 * m) - reference).max()
            aliased = case.truth(slope, naive)
            line = (f"  slope {slope:+.2f}: naive vs comb {metrics.psnr(naive, comb):.1f} dB (clean "
                    f"{metrics.psnr(naive, comb, mask=~aliased):.1f}); comb vs reference "
                    f"{metrics.psnr(comb, reference):.1f} dB, {aliased.mean():.1%} aliased; reference m={m} vs 2m: "
                    f"max {finer:.1e}")
            if slope in truth.scene.layers_disparity.values():
                focus = _in_focus_pixels(truth, slope, naive.shape[:2])
                line += (f"; in focus ({focus.sum()} px) naive vs reference "
                         f"{metrics.psnr(naive, reference, mask=focus):.1f} dB")
            print(line, flush=True)


if __name__ == "__main__":
    main()
