"""Aliasing detection and reduction guided by the light field's own disparity.

The paper's detector (Algorithm 1) flags pixels whose refocus changes when
a few views are dropped, and its reduction (Algorithm 2) replaces them by
a blur of the refocused image. Measured on data it had not seen, neither
holds: Cv is large wherever the views disagree for any reason (a smooth,
slightly defocused gradient; vignetting; noise), and no blur of the
refocused image is right where a defocused occluder partly hides an
in-focus surface (``benchmarks/results/accuracy.md``).

This module works from what aliasing *is*: the difference between the
sparse refocus and what a dense aperture would record.

- **Detection** (``method="depth"``). The disparity of every pixel is
  estimated once per light field
  (:func:`~napari_lfalias.disparity.estimate_disparity`); for each slope
  the dense-aperture rendering
  (:func:`~napari_lfalias.render.render_dense_aperture`) predicts the
  reference, and a pixel is aliased where the naive refocus differs from
  it by more than ``T`` in relative luminance after a light blur
  (``T = 0.02``: the paper's "minimal intensity of perceivable
  aliasing"), and the views really disagree there (their angular
  coefficient of variation exceeds :data:`MIN_ANGULAR_CV`: a pixel whose
  views agree is in focus, whatever a wrong disparity says)
  (:meth:`DepthGuide.predicted_errors`), unless the cautious score
  below finds next to nothing there (a quarter of ``T``, what the
  reduction's fringe asks of a pixel; :meth:`DepthGuide.flagged`).
- **Which pixels the reduction replaces** is decided more cautiously
  (:meth:`DepthGuide.scores`): a detector should find the aliasing, a
  reduction must not make a pixel worse. Until stop 32 one cautious score
  served both; measured on the pixels of the slopes at least 1 % aliased
  (fresh-a, 48 slopes / holdout, 16), the plain prediction detects better:
  ROC AUC 0.949 / 0.968 against 0.908 / 0.944, F1 at ``T`` 0.73 / 0.66
  against 0.61 / 0.60 (the cautious score's precision was 0.90, its recall
  0.53). Alone, though, the prediction flagged pixels on 4 of fresh-a's 23
  slopes with nothing aliased (F1 1 -> 0 there; over the benchmark's 388
  such slopes mean F1 0.63 -> 0.41); asking the cautious score for a
  quarter of ``T`` too leaves 1, and mean F1 over all of fresh-a's slopes
  0.63 (cautious score) -> 0.66 (prediction) -> 0.69 (both), holdout
  0.62 -> 0.68 -> 0.68 (a region the cautious score confirmed anywhere:
  0.68 / 0.66). On fresh-o, not used for the choice, mean AUC / F1 0.90 /
  0.56 -> 0.93 / 0.64; every split in results/accuracy.md (notes, stop
  32). Even the rendering with the *true* disparity predicts the
  aliasing only to F1 0.77 / 0.72 at ``T`` on those fresh-a / holdout
  slopes: the renderer's own error near ``T`` flips pixels, so no
  threshold on a rendering's prediction reaches an F1 of 0.8 there (at
  0.8 ``T`` the estimate's gains 0.02).
  An estimated depth edge may be a pixel or two off, and near a defocused
  occluder's outline the right blur depends on where the outline is: a
  pixel is replaced only where the naive refocus differs by more than ``T``
  from the rendering *and* from the renderings with the edges moved
  :data:`EDGE_TOLERANCE_PX` either way (chosen on the benchmark's tuning
  cases as the least that left none of them below the naive refocus).
  Only depth edges move (:func:`moved_edges`: where the disparity meets
  one at least a disparity bin away; a surface's own noise stays), those
  of the disparity the rendering uses (a surface the views show in focus
  at the slope, whatever the estimate says, so that the edge of an
  in-focus surface the estimate fattened an occluder over moves too), and
  the moved renderings share the rendering's bins, so they differ from it
  only around those edges, and are rendered there only. The outline of an
  occluder in focus moves out by its own blur only
  (:data:`IN_FOCUS_EDGE_PX`): the views show it sharp, and moved out by
  the full tolerance its in-focus rendering matched the naive refocus in a
  band around it, where the surface behind aliases (the most common scene:
  a subject in focus, the background aliased around it; stop 49, tune and
  fresh-a, 103 slopes: +8.17 -> +8.41 dB where aliased, none below the
  naive refocus).
  The naive refocus and a dense aperture record the same light through
  the same aperture and differ only in how they sample it, so their local
  means over a few ghost spacings (``|d - slope|`` times the view
  spacing) agree; a rendering whose local mean does not is wrong there (a
  misplaced depth edge, a surface the estimate misses), and its
  difference from the naive refocus is not aliasing. The rendering is
  compared with its local mean over :data:`CONSISTENCY_PERIODS` ghost
  spacings brought to the naive refocus's. The ghosts a pixel shows are
  not only its own surface's: the copies of a nearer, defocused surface
  lie over everything its blur reaches (:func:`ghosts_reaching`), and a
  window narrower than their spacing would give the rendering the naive
  refocus's copies and score them 0 (measured on HCI antinous, 3x3
  sub-grid: the copies of the statue's outline over the nearly in-focus
  wall behind it were the largest share, 45 %, of the missed aliased
  pixels). The window spans at least :data:`REACHING_PERIODS` of those
  copies' spacing too. Where the rendering's disparities are not sure
  (:data:`MIN_TRUST`) nothing is replaced; a periodic texture whose
  rendered disparity is one surface's counts as sure (:data:`PERIODIC_TRUST`:
  the views fit it a period away too, so its confidence is low however
  right its estimate, and the disparity rendered is the one of those
  nearest the slope that the views fit).
- **Reduction.** Those pixels take the rendering, with a soft edge, and so
  do the pixels connected to them whose score exceeds
  :data:`REPLACE_FRACTION` of ``T`` (below what a viewer perceives, the
  rendering is still closer to the dense aperture there) and exceeds how
  much the rendering itself changes with its depth edges moved
  (:meth:`DepthGuide.edge_spread`: near an outline the estimate misplaced
  by more than the edge tolerance, the rendering is no better than the
  naive refocus). So do the pixels, connected to those or not, whose
  score exceeds :data:`FAINT_FRACTION` of ``T`` and :data:`FAINT_MARGIN`
  times the edge spread: faint aliasing (the ghosts of a fine or dim
  texture, a fraction of ``T`` each but a pattern a viewer sees) that the
  rendering predicts whatever its edges, where its blur lies within what
  the views hold (:meth:`DepthGuide.within_support`). Near the image's edge, where
  the rendering's blur is cut off, a pixel is replaced only where the aliased
  region runs on to the edge (:meth:`DepthGuide.kept_off_the_edge`). Every other
  pixel keeps the naive refocus exactly. A light field with nothing aliased comes back
  unchanged.

:class:`DepthGuide` keeps the estimate and the rendering of the last slope,
so that a new threshold or a reduction after a detection costs nothing.
"""

from __future__ import annotations

import functools
import math
from dataclasses import replace

import numpy as np
from scipy import ndimage

from . import _validate
from .errors import ParameterError
from .lightfield import LightField
from .metrics import TRUTH_BLUR

__all__ = ["DepthGuide", "aperture_radius", "ghosts_reaching", "moved_edges", "predicted_error", "with_local_mean_of",
           "MIN_ANGULAR_CV", "THRESHOLD"]

#: Default threshold: the relative luminance difference a viewer perceives (the paper's T).
THRESHOLD = 0.02
#: The default reduction gives the rendering to the flagged pixels (predicted error above ``T``) and to
#: the pixels connected to them whose predicted error exceeds this share of ``T`` (hysteresis, as in
#: Canny's edge detector, at 4:1): an aliased region's fringe below what a viewer perceives is still
#: closer to the dense aperture rendered, and isolated pixels below ``T`` stay the naive refocus.
#: Measured (results/accuracy.md notes): the tune cases gain +5.6 (1: flagged only), +7.3 (0.5), +8.7
#: (0.25) and +9.7 dB (0.125) where aliased, none below the naive refocus; they cannot tell these apart
#: on harm. While the renderer blurred the views' samples twice (render._view_taps), 0.25 cost one real
#: sub-grid 0.26 dB on its clean pixels, and 0.5 was kept; since, 0.5 -> 0.25 gives tune +6.9 -> +9.0,
#: holdout +6.4 -> +8.3, real +4.1 -> +4.3 dB where aliased, none of them more than 0.05 dB below naive;
#: on the 1072 random slopes of fresh-a..l the two changes together gave +4.4 -> +5.2 dB where aliased,
#: 10 slopes below naive - 0.1 dB overall rather than 11, 13 on clean pixels rather than 16. The fringe
#: also needs the predicted error to exceed the rendering's
#: :meth:`DepthGuide.edge_spread` (results/accuracy.md notes: without it, an outline the estimate put 3-4 px
#: off cost a holdout case 0.22 dB on its clean pixels; the tune cases' gain where aliased +7.25 -> +7.09).
REPLACE_FRACTION = 0.25
#: Below ``T``, a pixel the reduction replaces without being connected to a flagged one: its score must exceed
#: this share of ``T`` and :data:`FAINT_MARGIN` times the rendering's :meth:`DepthGuide.edge_spread`. The
#: ghosts of a fine or dim texture differ from the dense aperture by a fraction of ``T`` each, but as a
#: pattern (fresh scene 1209 at 1.3, 7x7 views: a grid over the whole image at 45.9 dB, no pixel scoring
#: ``T``, the rendering 59.8 dB). Only where the rendering's blur lies within what the views hold
#: (:meth:`DepthGuide.within_support`). Chosen on tune, fresh-a and fresh-b (192 slopes; results/accuracy.md
#: notes, stop 38): without this rule +4.96 dB where aliased, one slope below naive - 0.1 dB; 1/16 to 1/5 of
#: ``T`` with margins 3 to 8 gave +6.1 to +6.4 dB, and at 1/8 and 4 none below naive - 0.1 dB (margin 1:
#: -1.04 dB on a slope whose naive refocus is 78 dB); kept off the image's edge, +6.12. Checked on fresh-c and
#: fresh-d before the full run (181 slopes): +5.82 -> +6.63 dB where aliased, slopes below naive - 0.1 dB
#: overall 3 -> 2, on clean pixels 5 -> 5. The full run, then not where the views weighed their samples
#: unevenly (1380 slopes): +5.75 -> +6.44 dB where aliased, below naive - 0.1 dB overall 12 -> 11, on clean
#: pixels 15 -> 13. Under calibrated vignetting the rule was left out from stop 38 to 40 (stop 39 measured it
#: taken: more slopes below naive, results/accuracy_faint_under_vignetting.md): the renderer weighed each
#: view's cell by the view's own weight, and the vignette's rendering was not sure enough for it. With the
#: vignette weighed across each cell (stop 41, ``_render_kernels._across_cell``) it is taken there too:
#: offline on the dumps of every weighted slope (``replacement_rules.py``-style), chosen on tune, holdout,
#: fresh-a and b (103 slopes) +7.39 -> +8.43 dB where aliased, below naive - 0.1 dB 2 -> 0 (fresh 309 at 1.2:
#: -0.84 -> -0.09); reported on fresh-c to f (149) +6.06 -> +7.72, below 0 -> 0, no slope more than 0.02 dB
#: worse.
FAINT_FRACTION = 0.125
#: See :data:`FAINT_FRACTION`.
FAINT_MARGIN = 4.0
#: Outside :meth:`DepthGuide.within_support` (near the image's edge, where the rendering's blur is cut off
#: on the outer side) a pixel is replaced only where at least this share of the supported pixels within the
#: blur's reach around it are replaced too (:meth:`DepthGuide.kept_off_the_edge`): the aliased region runs
#: on to the edge there, where alone it is the cut-off blur's bias that scores (fresh scene 1910 at 0.0, a
#: dim stripes wall 3.8 px per view step out of focus behind 3x3 views: its rendering 64.8 dB inside,
#: 38.8 dB on its four outermost rows against the naive refocus's 52; the image 1.45 dB below the naive
#: refocus, +0.13 dB with the rule). Where the naive refocus itself lacks views, the rendering stands.
#: Not chosen by measurement (a majority); results/accuracy.md notes, stop 48, say what it moved.
EDGE_MAJORITY = 0.5
#: Gaps of up to this many pixels between the pixels of an aliased region (those flagged and their fringe,
#: :data:`REPLACE_FRACTION`) are replaced too, where the rendering depends on where the depth edges are
#: (:meth:`DepthGuide.edge_spread`) less than the fringe's least score. The score is the blurred luminance
#: difference of the naive refocus from the rendering, and an aliasing pattern's difference crosses zero
#: between its crests: the region came out as stripes, and the blend (:meth:`DepthGuide.blend_weight`) gave
#: the pixels between them half the rendering or less, the naive refocus's stripes still showing (fresh
#: scene 617 at 1.8: +11.3 dB over the naive refocus, the rendering of every pixel +16.5). Chosen offline on
#: fresh-a and fresh-d (175 slopes; results/accuracy.md notes, stop 43): +8.14 -> +8.54 dB where aliased,
#: +2.96 -> +3.06 overall, slopes below naive - 0.1 dB unchanged (2 overall, 2 on clean pixels). Without the
#: edge gate +8.73 (fresh 302 at -1.9 +6.5 -> +8.1), but a wall a period off along an outline took more of
#: its wrong rendering (``test_the_occlusion_order_is_judged_with_the_surfaces_in_focus_...``: +2.9 -> +1.3
#: dB); ungated, 2 px gaps +8.73 and one more slope below naive on clean pixels, and gaps among the faint
#: pixels (:data:`FAINT_FRACTION`) closed too +8.85, but fresh 613 at 0.1 (a texture the rendering gets
#: 3 dB below the naive refocus's 56 dB) fell from +0.95 to -1.48 dB.
GAP_PX = 1
#: Where the estimate is unsure (confidence below :data:`MIN_TRUST`), a surface the views show in focus this
#: far (px per view step) either side of a slope counts in focus at it (:meth:`DepthGuide._in_focus`). The
#: focus test passes a fine texture only within about a tenth of a pixel per view step of its disparity, and
#: a surface missed there keeps the estimate's disparity: fresh scene 1805 (6x6 views, a fine checker wall at
#: -4.5 behind two grey-noise squares at 0.3 and 2.5) has the wall estimated at the squares' disparities over
#: a wide halo around them (confidence 0.01 median); the views show it in focus at -4.5 but not at -4.4, where
#: the rendering blurred the wall away on the halo: the default reduction 11.7 dB below the naive refocus
#: overall (results/accuracy.md notes, stop 44). With the band -4.9 dB; offline on 444 other slopes (fresh-a,
#: d, e, h and the unseen seeds 1800-1819) one changed by more than 0.01 dB (1006 at -4.8, +0.06). (Stop 45
#: found the rest: the focus test's mean of the central views spoilt within 3.5 px of the squares, the wall
#: estimated a period off with confidence beside them, :meth:`DepthGuide._in_band_surface`, and the
#: occlusion order judged wrong.) Not where
#: the estimate is sure: a fine stripes wall estimated right (fresh 607 at 4.9) passes the test at 5.0, its
#: period away, and without the gate the reduction lost its +5.4 dB there (with a band of 0.2 too).
FOCUS_BAND_PX = 0.1
#: ... where it passes on at least half the pixels of a window of this many px a side (in focus at the slope
#: or that near it): fresh scene 707's checker wall at -1.8 (estimated periods off) passes at -2.1 on 296
#: pixels, each alone in its 9x9 window, and taken at -2.2 they cost its clean pixels 0.08 dB (-0.03 ->
#: -0.10); 1805's halo passes on 84 % or more of the 5x5 window of each of its pixels (10th percentile).
FOCUS_BAND_WINDOW = 5
#: ... and, where the estimate is sure, where the surface they lie on is mostly estimated in the band
#: (:meth:`DepthGuide._in_band_surface`), on slopes where at least this share of the image is: a wall in
#: focus, not the stripe of a slanted floor every slope has (tested on most of the image's tiles, two
#: slopes: 0.4 s more a slope on the brick room 8x8 at 512 px).
IN_BAND_SHARE = 0.1
#: ... grown outwards this many px at a time (:meth:`DepthGuide._in_band_surface`).
IN_BAND_GROWTH = 8
#: The focus test matches by chance too: along a tile's or a brick's straight edge the views displaced along
#: it agree out of focus, and a flat patch's rim passes where its texture ends. Where the estimate does not
#: say so, a pixel the views show in focus is taken in focus (:meth:`DepthGuide._in_focus`) only where at
#: least this share of the textured pixels in the :data:`FOCUS_SURFACE_WINDOW` px square around it pass too:
#: a surface, not a speck (a plane in focus at a fractional disparity passes on about half its pixels). Fresh
#: scene 3207 at 0.7 (a tiles wall 2.7 px per view step out of focus, 5x5 views): 106 specks of 1 to 7 px
#: rendered in focus left rings of the wall's box around them, the rendering with the true disparity 62.60 dB
#: without the test and 56.34 with it (the naive refocus 62.50), and the faint rule replaced them: the default
#: reduction 0.72 dB below the naive refocus (0.05 above it now). Measured: results/focus_specks.md.
FOCUS_SURFACE_SHARE = 0.25
#: See :data:`FOCUS_SURFACE_SHARE`.
FOCUS_SURFACE_WINDOW = 15
#: Views whose luminance varies less than this (std / mean) agree: the pixel is in focus.
MIN_ANGULAR_CV = 0.01
#: Floor of the luminance a difference is divided by, as a fraction of the brightest.
DARK_FLOOR = 0.01
#: Renderings whose disparities have a confidence below this are not trusted to replace a pixel. At 0.05 a
#: periodic wall estimated a period off with confidence 0.1-0.5 (fresh scene 315) lost 3.2 dB on its clean
#: pixels; 0.3 changes no tune or holdout figure and costs the real sub-grids 0.17 dB where aliased.
MIN_TRUST = 0.3
#: The least confidence of a periodic texture's pixels whose rendered disparity is one surface's around them
#: (:meth:`DepthGuide._settled_periodic`): a sure estimate's (:data:`~napari_lfalias.baselines.SURE_CONFIDENCE`).
#: Found on fresh scene 1107 at -0.2 (a stripes square 3.8 px per view step out of focus, estimated right with
#: confidence 0.35, its rendering trusted on a third of it: +1.2 dB over the naive refocus where the whole
#: rendering is +8.0); chosen on fresh scenes 505, 617, 1107, 1206, 1402 and 707, and the holdout's
#: checkerboard (``benchmarks/results/accuracy_periodic_trust.md``, stop 42).
PERIODIC_TRUST = 0.5
#: A pixel's rendered disparity is one surface's where, over the :data:`SETTLED_WINDOW` px around it, at least
#: this share of the pixels lie within :data:`SETTLED_TOLERANCE` of those :data:`SETTLED_STEP` px away.
SETTLED_SHARE = 0.6
#: See :data:`SETTLED_SHARE`.
SETTLED_WINDOW = 9
#: See :data:`SETTLED_SHARE` (disparity, px per view step).
SETTLED_TOLERANCE = 0.25
#: See :data:`SETTLED_SHARE` (px).
SETTLED_STEP = 2
#: A periodic texture's rendering is trusted as a sure one only where its ghosts lie at least this far apart
#: (px; :meth:`DepthGuide._settled_periodic`).
SETTLED_MIN_GHOST_PX = 1.0
#: Nor within this many px more than ``|slope|`` times the aperture radius of the image's edge (see
#: :data:`SETTLED_MIN_GHOST_PX`).
SETTLED_BORDER_PX = 1
#: An :attr:`~napari_lfalias.disparity.DisparityEstimate.alternative` this many px (times the view spacing) or
#: more from the estimate is a period of a texture: the rendering takes whichever of the two is nearer the
#: slope (:meth:`DepthGuide._least_change`). Nearer alternatives are the two sides of one broad valley of the
#: cost (on HCI antinous 3x3 a median 1.2 px apart), where taking the nearer one put the wall 2.9 dB below the
#: naive refocus. 4 rather than 5: stripes of a 4.5 px period (fresh scene 412, 9x9 views) a period off lost
#: 2.7 dB at 5; 4 changes no real or holdout figure and costs tune 0.06 dB where aliased.
MIN_PERIOD_PX = 4.0
#: How far (px) an estimated depth edge may lie from the true one. A pixel is flagged only where the
#: naive refocus differs from the rendering with the edges where estimated *and* from those with the
#: edges moved this far either way: near a defocused occluder's outline the right blur depends on
#: where the outline is, and an edge a pixel or two off must not make a correct naive pixel look aliased.
EDGE_TOLERANCE_PX = 2
#: How far (px) the outline of an occluder in focus moves out in the renderings with the edges moved
#: (:func:`moved_edges`): its own blur, where the views mix it with the surface it hides, and not the full
#: :data:`EDGE_TOLERANCE_PX`: the views show that outline sharp, and the aliased surface behind lies beyond it.
IN_FOCUS_EDGE_PX = 1
#: Share of the image the views must show in focus at a slope, where the estimate has it a disparity bin or
#: more away, before the occlusion order is judged at that slope rather than once from the estimate
#: (:meth:`DepthGuide.larger_first`). Measured on the random scenes of fresh-a to fresh-l (1072 slopes, against
#: the scenes' true order): from 5 % to 30 %, 8 slopes, judged right at the slope 3 times, once 7; from 30 %
#: up, 4 slopes, 3 and 2 (and the holdout's checkerboard 3x3 at -3, 61 %: right at the slope only).
OVERRULED_SHARE = 0.3
#: Where the occlusion order of a light field whose estimate has periodic surfaces is judged
#: (:meth:`DepthGuide._order_where_a_period_is_in_focus`): at most this many of the disparities the periodic
#: pixels reach by whole periods, up to :data:`PERIODS_TRIED` either way, counted in bins of
#: :data:`PERIOD_SLOPE_BIN_PX` of motion per view step (:func:`_period_slopes`).
PERIOD_SLOPES = 3
PERIODS_TRIED = 2
PERIOD_SLOPE_BIN_PX = 0.25
#: Share of the image whose views fit a second disparity a period away (:meth:`DepthGuide._has_period`)
#: before the order is judged where a periodic surface is in focus: each slope tried costs a focus test and a
#: judgement of the order (0.2-0.3 s for a 6x6 light field at 256 px; the brick room's bricks make 1.5 % of it
#: periodic, and it is not tried there). On the random scenes whose order this changed, 50-75 % was periodic.
ORDER_PERIODIC_SHARE = 0.2
#: Pixels estimated within this (disparity) of a moved periodic surface are the same surface, when its outline
#: is judged (:meth:`DepthGuide._fronts_kept`); a surface a period off stays in front of what lies this much
#: farther.
OUTLINE_SAME_SURFACE = 0.5
#: How far (px) around a moved periodic surface its pixels left at the estimate are gathered to find its outline
#: (:meth:`DepthGuide._fronts_kept`): the edge of a periodic square where the views refuted its second fit.
OUTLINE_GROW_PX = 16
#: The band (px) each side of that outline whose pixels judge which side is in front (as
#: :func:`~napari_lfalias.baselines._larger_is_nearer` judges the whole image's order).
OUTLINE_BAND_PX = 3
#: How many periods from its estimate :meth:`DepthGuide._least_change` moves a pixel at most.
PERIODS_REACH = 4
#: A pixel moves by periods only where its views vary at the new disparity by at most this many times (plus
#: :data:`MIN_ANGULAR_CV`) what they vary at its estimate (:meth:`DepthGuide._least_change`).
PERIOD_FIT = 1.25
#: ... and by at most this (std / mean): measured, a fine checker in focus
#: varies by its interpolation error, 0.004-0.013 (fresh scene 700), while the pixels beside an outline
#: whose estimate and slope both fit badly vary by 0.17-0.32 (tune: tiles, lines, bricks at +5, where they
#: cost 0.9 dB where aliased). Sensor noise raises a right fit's variation: under a strong calibrated vignette
#: (fresh scene 1402, 3x3, a checker at -0.7 estimated two periods off) the views varied by 0.025 (median) to
#: 0.073 (90th percentile) at the right disparity, and at 0.05 less than half of the wall moved (1.7 dB below
#: the naive refocus at slope 1.0; -0.01 dB at 0.1, and fresh scenes 315, 412, 505, 700, 1119 and 1206, the
#: periodic walls above, unchanged or better). 0.1 lies between the two: about the geometric mean of 0.073
#: and 0.17.
PERIOD_MAX_CV = 0.1
#: How many steps of :data:`PERIOD_STEP` either way of a disparity a whole or half number of periods away
#: the views' fit is looked for (:meth:`DepthGuide._least_cv_near`): the period between an estimate and its
#: alternative is measured to a few tenths, and a disparity several periods away carries that error as many
#: times (fresh scene 1206: a checker wall at 3.8, estimated -16.2 with its second fit at -6.3, two periods
#: 9.9 apart: 3.5, the views vary by 0.09 there, by 0.016 at 3.75).
PERIOD_SEARCH = 4
#: The step (disparity) of that search.
PERIOD_STEP = 0.25
#: The tiles (px) over which a pixel without a period of its own takes its neighbours'
#: (:meth:`DepthGuide._periods`).
PERIOD_TILE = 32
#: The window, in ghost spacings, over which a rendering must have the naive refocus's local mean: the
#: detection compares the naive refocus with the rendering after making it so (module notes). One
#: spacing is a whole period of the ghosts; two keep the mean clear of the rounding of the window.
CONSISTENCY_PERIODS = 2
#: The window spans at least this many spacings of the copies of any nearer surface whose blur reaches the
#: pixel (:func:`ghosts_reaching`): one whole period of them is what a mean needs. Chosen on the tune split
#: (mean gain where aliased +7.27 dB without, +7.25 with one, +7.35 with two; F1 0.774, 0.773, 0.774; none
#: below the naive refocus), one rather than two because, with the occlusion order wrong, two let a wrongly
#: rendered outline be flagged (``test_a_rendering_wrong_along_an_outline_does_not_flag_clean_pixels``: 25
#: pixels) and one does not. Measured after the choice (tune_red, cached estimates): real +3.97 -> +4.34 dB
#: where aliased, F1 0.469 -> 0.488, AUC 0.867 -> 0.877; holdout +5.56 -> +5.68 dB, F1 0.701 -> 0.704;
#: lenslet unchanged; no case newly below naive - 0.1 dB.
REACHING_PERIODS = 1


def moved_edges(disparity, spacing, slope=None, larger_first=True):
    """``disparity`` with its depth edges moved :data:`EDGE_TOLERANCE_PX` px outwards and inwards: the
    larger disparities grown, then shrunk (grey dilation, erosion), where they meet disparities at
    least a disparity bin (:data:`~napari_lfalias.render.BIN_PX` px of blur at view ``spacing``) away;
    the rest of the map (a surface's own noise or slant) is left as it is.

    With ``slope``, the outline of an occluder in focus at it moves out by
    :data:`IN_FOCUS_EDGE_PX` only: where the nearer side (the larger
    disparities where ``larger_first``) growing further would bring a pixel
    into focus (under :data:`~napari_lfalias.render.IN_FOCUS_PX` of blur),
    the pixel takes the nearer side grown that far. The views show an
    in-focus outline sharp, its own blur a pixel wide; beyond it lies the
    surface behind, which is what aliases at that focus. Moved out by the
    full tolerance, the outline's in-focus rendering matched the naive
    refocus in a band around the occluder, and the aliased background there
    was left as it was (module notes). A defocused occluder's outline still
    moves the full tolerance either way, and with it the in-focus surface
    behind.

    Parameters
    ----------
    disparity : ndarray, shape (Y, X)
    spacing : float
        The distance between neighbouring views (units of disparity).
    slope : float, optional
        The focus; without it every outline moves the full tolerance.
    larger_first : bool
        Whether the larger disparities are in front.

    Returns
    -------
    grown, shrunk : ndarray, shape (Y, X)
        The larger disparities grown over the edges, and shrunk.

    Examples
    --------
    >>> import numpy as np
    >>> step = np.zeros((1, 9), np.float32)
    >>> step[:, 5:] = 2.0
    >>> grown, shrunk = moved_edges(step, 1.0)
    >>> grown[0].tolist(), shrunk[0].tolist()
    ([0.0, 0.0, 0.0, 2.0, 2.0, 2.0, 2.0, 2.0, 2.0], [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0, 2.0])
    >>> grown, shrunk = moved_edges(step, 1.0, slope=2.0)  # the nearer side in focus: its outline moves 1 px
    >>> grown[0].tolist(), shrunk[0].tolist()
    ([0.0, 0.0, 0.0, 0.0, 2.0, 2.0, 2.0, 2.0, 2.0], [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0, 2.0])
    """
    from .render import sharp_at

    grown, shrunk = _edges_moved(disparity, spacing, EDGE_TOLERANCE_PX)
    if slope is None:
        return grown, shrunk
    nearer = grown if larger_first else shrunk
    brought_into_focus = sharp_at(nearer, slope, spacing) & ~sharp_at(disparity, slope, spacing)
    if brought_into_focus.any():
        outline = _edges_moved(disparity, spacing, IN_FOCUS_EDGE_PX)[0 if larger_first else 1]
        nearer = np.where(brought_into_focus, outline, nearer)
    return (nearer, shrunk) if larger_first else (grown, nearer)


def _edges_moved(disparity, spacing, px):
    """:func:`moved_edges`'s grown and shrunk maps, the edges moved ``px`` px."""
    from .render import BIN_PX

    size = (2 * px + 1,) * 2
    grown, shrunk = ndimage.grey_dilation(disparity, size=size), ndimage.grey_erosion(disparity, size=size)
    edge = (grown - shrunk) * spacing >= BIN_PX
    return np.where(edge, grown, disparity), np.where(edge, shrunk, disparity)


#: How far (px) :func:`predicted_error` reads around a pixel: its Gaussian's radius (scipy's default
#: truncation at 4 sigma).
_ERROR_REACH = int(4.0 * TRUTH_BLUR + 0.5)


def predicted_error(naive, rendered):
    """The relative luminance difference of the naive refocus from the rendering, after a light blur:
    the ground-truth measure of aliasing (:func:`napari_lfalias.metrics.luminance_difference`),
    with the rendering standing in for the dense aperture.

    Examples
    --------
    >>> import numpy as np
    >>> a = np.full((8, 8, 1), 0.50, np.float32)
    >>> round(float(predicted_error(a * 1.02, a).max()), 3)
    0.02
    """
    from .metrics import luminance_difference

    return luminance_difference(naive, rendered)


#: What ``nearer`` may say: which disparities are in front, or ``"auto"`` (the light field's own
#: ``meta["nearer"]`` where its loader knows the camera, else judged from the views).
NEARER = ("auto", "larger", "smaller")


def occlusion_order(lf, nearer="auto"):
    """``nearer`` for ``lf``: as given, or for ``"auto"`` the light field's ``meta["nearer"]`` where it has one.

    Which side of a depth edge is in front is a property of the camera:
    the sign of its disparities against its view positions. A loader that
    knows the camera says so in ``meta["nearer"]`` (the HCI loader
    and the lenslet decoder: ``"smaller"``), and a user who knows it may set it, or pass
    ``nearer``; otherwise it stays ``"auto"`` and is judged from the views
    at the depth edges (:meth:`DepthGuide.larger_first`), which the views
    cannot always tell (``benchmarks/results/accuracy.md``: wrong on 8 of
    320 random scenes).

    Examples
    --------
    >>> import numpy as np
    >>> from napari_lfalias import LightField
    >>> lf = LightField(np.zeros((3, 3, 8, 8), np.float32), meta={"nearer": "smaller"})
    >>> occlusion_order(lf), occlusion_order(lf, "larger")
    ('smaller', 'larger')
    """
    nearer = _validate.one_of("nearer", nearer, NEARER)
    declared = lf.meta.get("nearer", "auto")
    if declared not in NEARER:
        raise ParameterError(f"lf.meta['nearer'] must be one of {', '.join(map(repr, NEARER))}, got {declared!r}")
    return declared if nearer == "auto" else nearer


class DepthGuide:
    """The disparity of a light field and its dense-aperture renderings, computed once and kept.

    Parameters
    ----------
    lf : LightField
        The light field (a lazy one is read once).
    disparity : ndarray (Y, X) or DisparityEstimate, optional
        A disparity you already have (a known depth map, or an estimate);
        default: :func:`~napari_lfalias.disparity.estimate_disparity` on
        first use.
    nearer : {"auto", "larger", "smaller"}
        Which disparities are in front (occlusion order); ``"auto"``: the
        light field's ``meta["nearer"]`` where it has one, else judged from
        the views (:func:`occlusion_order`).

    Examples
    --------
    >>> from napari_lfalias.synthetic import brick_room
    >>> scene = brick_room(n_views=4, size=48, seed=0)
    >>> guide = DepthGuide(scene.lightfield, scene.disparity)
    >>> guide.rendering(4.0).image.shape
    (48, 48, 3)
    """

    def __init__(self, lf, disparity=None, nearer="auto"):
        if not isinstance(lf, LightField):
            raise ParameterError(f"lf must be a napari_lfalias.LightField, got {type(lf).__name__}")
        self._data = lf.compute() if lf.is_lazy else lf
        self.lf, self._unit = _unit_scaled(self._data)
        self.nearer = occlusion_order(lf, nearer)
        self._given = disparity
        self._estimate = None
        self._alternative = None
        self._period = None
        self._fit_at_estimate = None  # (least angular cv near the estimate, where it was made)
        self._floor = None
        self._slope = None
        self._at_slope = {}  # what was made for self._slope, by name
        self._focus_test = None
        self._luminance = None
        self._larger_first = None
        self._period_slopes = None  # where a periodic surface may be in focus (_period_slopes)
        self._period_orders = {}  # {period slope: larger first, or None where the views overrule too little}

    @property
    def estimate(self):
        """The disparity and its confidence: ``(disparity (Y, X), confidence (Y, X))``."""
        if self._estimate is None:
            from .disparity import checked_estimate, estimate_disparity

            given = self._given
            if given is None:
                given = estimate_disparity(self.lf)
            disparity, confidence, self._alternative = checked_estimate(given, self.lf.image_shape)
            self._estimate = (disparity.astype(np.float32), confidence)
        return self._estimate

    def check_estimate(self):
        """Make the :attr:`estimate` now (a disparity given is checked, a bad one named, before any
        rendering), unless the light field has one view and none was given: one view cannot alias, so
        nothing of it is rendered and there is nothing to estimate."""
        if self.lf.n_views > 1 or self._given is not None:
            self.estimate

    def larger_first(self, slope):
        """Whether larger disparities are in front, at ``slope``.

        Which side of a depth edge is in front is a property of the camera
        (the sign of its disparities), not of the focus: with
        ``nearer="auto"`` it is judged once, from the views at the depth
        edges of the estimate (:func:`~napari_lfalias.baselines._larger_is_nearer`),
        counting only the estimate's sure pixels
        (:data:`~napari_lfalias.baselines.SURE_CONFIDENCE`): the edges an
        unsure estimate makes inside one surface (a smooth wall's noise, a
        periodic texture's patches a period off) outvoted the outlines
        (fresh scenes 1300, 1308, 1315). Nor do the pixels whose views fit
        a second disparity a period away count (:meth:`_has_period`),
        however sharp their cost: judged with them, the order was wrong on
        8 of the benchmark's 318 synthetic light fields, without them on 7
        (fresh scene 1319, a checker wall a period off on much of it: 0.52
        dB below the naive refocus at -3.5 -> 0.15; no other changed).
        Judged at every slope instead, with the surfaces the views show in
        focus put at the slope, 69 of 1072 slopes of the random scenes came
        out wrong, against 33 judged once:
        the pixels put at the slope make edges inside the surface they lie
        on, a fraction of a pixel high where the estimate has it nearly in
        focus (fresh scene 1418 at 5.0: 2.9 dB below the naive refocus; +0.0
        judged once). Where the two sides' spreads are alike, the order whose
        hidden samples explain the views decides: wrong on 4 of the 240
        random scenes' estimates, against 9 by the spreads alone (fresh
        scene 1113 at 4.4: 1.3 dB below the naive refocus; +0.0 now).

        The exception is an estimate the views overrule over a whole surface:
        where at least :data:`OVERRULED_SHARE` of the image is in focus at
        ``slope`` while the estimate has it a disparity bin or more away (a
        periodic wall estimated a period off), the order is judged at
        ``slope``, with those pixels put there (the holdout's checkerboard
        3x3 at -3, the wall estimated a period off: 6.4 dB below the naive
        refocus on its clean pixels judged once), and the rest of the image
        at the disparity the rendering uses (:meth:`_rendered_disparity`:
        a periodic surface moved by whole periods towards the slope where
        its views fit there, counted as sure). The part of a periodic wall
        the views do not show in focus (its ring around a defocused
        occluder, where some views see the occluder) otherwise kept its
        estimate a period off and made the edges that judged. Of the
        benchmark's 19 slopes judged this way, 8 changed order, all to the
        true one (fresh scene 1510 at 3.9, a 6x6 checker wall estimated a
        period off: 2.76 dB below the naive refocus -> 0.43; 1614 at -3.1:
        -0.28 -> +1.17, its clean pixels -0.91 -> +0.50); one is still
        wrong (fresh scene 1515 at 3.8). Regions off that surface where
        the estimate is unsure everywhere (:func:`_unsure_islands`: specks
        of the wall the focus test missed) are put at ``slope`` too: left at
        the estimate, each made an edge of its own whose sure side, the wall
        in focus, agreed across the views as an occluder's does (fresh scene
        2102 at 3.4, a checker wall estimated a period off behind a noise
        square: judged larger first from 3866 edge pixels, 720 at the true
        edges; 0.32 dB below the naive refocus).

        Where a fifth of the image or more is periodic
        (:data:`ORDER_PERIODIC_SHARE`), the estimate's edges cannot be
        trusted to judge the order once. The order is judged instead at the
        slopes the periodic pixels reach by whole periods
        (:func:`_period_slopes`) where the views overrule the estimate as
        above (:meth:`_order_where_a_period_is_in_focus`), and every slope
        takes the order judged at the nearest of them, one with an exception
        of its own too (fresh scene 2216, 4x4, a checker wall at -3.7:
        judged at -3.7 smaller first, 0.24 dB below the naive refocus; at
        its period slope -3.67 larger first, the scene's order, +0.32). The
        views cannot tell which of its periods a periodic wall lies at, and
        the order judged with the wall at one period can be the other's (a
        wall behind its occluders has the smaller disparity at one period,
        the larger at the next); the rendering moves a periodic surface by
        whole periods towards the slope (:meth:`_least_change`), so the
        nearest is the order of the surfaces as rendered. Fresh scene 1805
        (6x6, a checker wall at -4.5, in focus for the views at -4.5 and at
        3.6): at -4.4, 2.81 dB below the naive refocus judged once, +0.11
        so; 1902 at -0.2: -2.05 -> -0.14. The order changed on 30 of the
        1693 slopes of the random splits a to s (11 scenes; 22 to the
        scenes' own order, 8 away from it), and the reduction on the 28
        others by 0.05 dB at most; taking over the slopes with an exception
        of their own changed 4 more of the 1783 of a to t (2216 at -3.7, and
        three within 0.01 dB). (Taken at the period slope where the views
        overrule the most instead: 1805 at -4.4 stayed -2.81, the wall taken
        at 3.6.)
        """
        if self.nearer != "auto":
            return self.nearer == "larger"
        order = self._order_where_a_period_is_in_focus(slope)
        if order is not None:
            return order
        overruled = self._overruled(slope)
        if overruled.mean() >= OVERRULED_SHARE:
            return self._kept(slope, "larger first", lambda: self._order_at(slope, overruled))
        return self._order_judged_once()

    def _order_judged_once(self):
        """The occlusion order judged from the estimate, its pixels that fit a period away left out (made
        once)."""
        if self._larger_first is None:
            disparity, confidence = self.estimate
            self._larger_first = self._judge_order(disparity, np.where(self._has_period(), np.float32(0), confidence))
        return self._larger_first

    def _order_at(self, slope, overruled):
        """The occlusion order judged at ``slope``, with the ``overruled`` pixels (:meth:`_overruled`) and the
        regions off them where the estimate is unsure everywhere (:func:`_unsure_islands`) put at ``slope``,
        and the rest of the image at the disparity the rendering uses."""
        from .baselines import SURE_CONFIDENCE

        disparity, confidence = self.estimate
        rendered = self._rendered_disparity(slope)
        moved = overruled | (rendered != disparity)
        at_slope = overruled | _unsure_islands(overruled, moved | (confidence >= SURE_CONFIDENCE))
        return self._judge_order(np.where(at_slope, np.float32(slope), rendered),
                                 np.where(moved | at_slope, np.float32(1), confidence))

    def _order_where_a_period_is_in_focus(self, slope):
        """The occlusion order judged (:meth:`_order_at`) at the one of the estimate's :func:`_period_slopes`
        nearest ``slope`` where the views overrule it on at least :data:`OVERRULED_SHARE` of the image (a
        periodic surface the estimate may have a period off is in focus there), or ``None`` where there is
        none. Each period slope is judged once, the nearest first and only as far as needed (0.5-0.6 s for
        the two or three of a 6x6 light field at 256 px); what is made for it is not kept."""
        from .baselines import view_spacing

        if self._period_slopes is None:
            disparity, alternative = self.estimate[0], self.alternative
            self._period_slopes = [] if alternative is None else _period_slopes(
                disparity, alternative, self._has_period(), view_spacing(self.lf.positions))
        for candidate in sorted(self._period_slopes, key=lambda period_slope: abs(period_slope - slope)):
            if candidate not in self._period_orders:
                kept = (self._slope, self._at_slope)
                try:
                    self._slope, self._at_slope = None, {}
                    overruled = self._overruled(candidate)
                    self._period_orders[candidate] = (self._order_at(candidate, overruled)
                                                      if overruled.mean() >= OVERRULED_SHARE else None)
                finally:
                    self._slope, self._at_slope = kept
            if self._period_orders[candidate] is not None:
                return self._period_orders[candidate]
        return None

    def _has_period(self):
        """Where the views fit a second disparity a period of a texture away (:data:`MIN_PERIOD_PX`): the
        estimate there may be that period off, however sharp its cost."""
        from .baselines import view_spacing

        disparity, alternative = self.estimate[0], self.alternative
        if alternative is None:
            return np.zeros(disparity.shape, bool)
        period = np.where(np.isfinite(alternative), alternative - disparity, np.float32(0))
        return np.abs(period) * view_spacing(self.lf.positions) >= MIN_PERIOD_PX

    def _overruled(self, slope):
        """Where the views show a surface in focus at ``slope`` that the estimate puts a disparity bin
        (:data:`~napari_lfalias.render.BIN_PX` of motion per view step) or more away."""
        from .baselines import view_spacing
        from .render import BIN_PX

        away = np.abs(self.estimate[0] - np.float32(slope)) * view_spacing(self.lf.positions) >= BIN_PX
        return self._in_focus(slope) & away

    def _judge_order(self, disparity, confidence):
        from .baselines import _larger_is_nearer

        return _larger_is_nearer(np.ascontiguousarray(self.lf.views()), np.ascontiguousarray(self.lf.flat_positions()),
                                 disparity.astype(np.float64), confidence)

    def _keep(self, slope):
        if self._slope != slope:
            self._slope, self._at_slope = slope, {}

    def _kept(self, slope, name, make):
        """``make()`` for ``slope``, made once: what is kept is for the last slope only."""
        self._keep(slope)
        if name not in self._at_slope:
            self._at_slope[name] = make()
        return self._at_slope[name]

    def naive(self, slope):
        """The naive refocus (:func:`~napari_lfalias.refocus`) of the light field at ``slope`` (kept per
        slope)."""
        from .refocus import refocus

        slope = _validate.finite_float("slope", slope)
        return self._kept(slope, "naive", lambda: refocus(self._data, slope))

    def rendering(self, slope):
        """The dense-aperture :class:`~napari_lfalias.render.Rendering` at ``slope`` (kept per slope), without
        its ``trust`` (``None``: the :meth:`scored_rendering` has it, where a reduction reads it)."""
        slope = _validate.finite_float("slope", slope)
        return self._kept(slope, "rendering", lambda: self._in_data_units(
            self._renderer(slope).composite(self._layers(slope), trust=False)))

    def scored_rendering(self, slope):
        """The :meth:`rendering` at ``slope`` where :meth:`scores` and a reduction read it (kept per slope).

        That is within :meth:`_score_reach` of every pixel whose views
        disagree: elsewhere the score is 0 whatever the rendering says, and
        the reduction replaces only pixels with a score (and a soft edge of
        3 px, within that reach). There it is the rendering's layers
        composited on the tiles around those pixels, as the
        :meth:`edge_renderings` are (:meth:`~napari_lfalias.render.SlopeRenderer.composite`
        with ``within``; the whole image where the tiles would cover most of
        it); elsewhere it holds the naive refocus, with no trust. Made apart
        from the :meth:`rendering`, which has no trust.
        """
        slope = _validate.finite_float("slope", slope)
        return self._kept(slope, "scored rendering", lambda: self._in_data_units(self._raw_scored_rendering(slope)))

    def edge_renderings(self, slope):
        """The rendered images at ``slope`` with the depth edges of the disparity the :meth:`rendering` uses
        (the estimate, with what the views show in focus at ``slope``) moved :data:`EDGE_TOLERANCE_PX`
        outwards and inwards (:func:`moved_edges`; an occluder in focus at ``slope`` outwards by
        :data:`IN_FOCUS_EDGE_PX` only), in the bins of the :meth:`rendering`; kept per slope.

        They are rendered only where they differ from the :meth:`rendering`
        and :meth:`scores` reads them (within the reach of
        :func:`predicted_error`'s blur of a pixel whose views disagree and
        whose rendering is trusted); elsewhere they hold the rendering.
        """
        slope = _validate.finite_float("slope", slope)

        def make():
            rendering = self._raw_scored_rendering(slope)
            used = ndimage.maximum_filter(~self._scored_zero(slope), size=2 * self._score_reach(slope) + 1)
            if not used.any():
                return [self.scored_rendering(slope).image] * 2
            main, renderer = self._layers(slope), self._renderer(slope)
            larger_first = self.larger_first(slope)
            images = []
            for moved in moved_edges(self._rendered_disparity(slope), renderer.spacing, _rendered_slope(slope),
                                     larger_first):
                layers = renderer.layers(self._in_focus_at(slope, moved), self._confidence_at(slope),
                                         larger_first=larger_first, bins_of=main)
                within = used & layers.differs_from(main)
                images.append(self._in_data_units(renderer.composite(layers, within=within, elsewhere=rendering,
                                                                     trust=False)).image)
            return images

        try:
            return self._kept(slope, "edge renderings", make)
        finally:  # the shifted views and the bins, the largest arrays, are not needed any more
            for name in ("renderer", "layers"):
                self._at_slope.pop(name, None)

    def within_support(self, slope):
        """Where the rendering at ``slope`` blurs only samples the views hold, ``(Y, X)`` bool: pixels at
        least half the blur's reach (``|d - slope|`` times :func:`aperture_radius`) from the image's edge,
        less how far beyond the edge the views shifted for ``slope`` hold samples (``|slope|`` times that
        radius). Nearer the edge the blur is cut off on the outer side and biased wherever the surface
        has a gradient (a smooth texture at slope 0, 5x5 views, 64 px: 78.2 dB naive, 72.7 dB with its
        edge rendered); only the faint aliasing asks for this (:data:`FAINT_FRACTION`). Kept per slope."""
        slope = _validate.finite_float("slope", slope)

        def make():
            reach = self._blur_reach(slope)
            return _from_edge(reach.shape) + abs(slope) * aperture_radius(self.lf) >= 0.5 * reach

        return self._kept(slope, "within support", make)

    def _blur_reach(self, slope):
        """How far (px) the rendering at ``slope`` blurs each pixel, ``(Y, X)`` float64: ``|d - slope|`` times
        the :func:`aperture_radius`, ``d`` the rendered disparity (kept per slope)."""
        return self._kept(slope, "blur reach", lambda: np.abs(self._rendered_disparity(slope).astype(np.float64)
                                                              - slope) * aperture_radius(self.lf))

    def kept_off_the_edge(self, slope, replaced):
        """``replaced`` (``(Y, X)`` bool, pixels the reduction would replace at ``slope``) less those outside
        :meth:`within_support` around which fewer than :data:`EDGE_MAJORITY` of the supported pixels within
        the blur's reach are replaced: near the image's edge the rendering's blur is cut off, and a score
        there may be that cut's bias rather than aliasing; an aliased region that runs on to the edge keeps
        its edge. Nor are the pixels where the naive refocus lacks views (nearer the edge than ``|slope|``
        times the views' farthest offset from their centre: the views shifted beyond it hold no sample
        there) held back: there the rendering's stand-ins are the better guess (fresh scene 314 at 1.1,
        5x5 views: the naive refocus 10x the rendering's squared error on the outermost two rows). Where no
        supported pixel lies that near, or none anywhere, ``replaced`` is kept."""
        lacking = abs(slope) * _farthest_view(self.lf)
        supported = self.within_support(slope) | (_from_edge(replaced.shape) < lacking)
        outside = replaced & ~supported
        if not outside.any() or not supported.any():
            return replaced
        size = 2 * int(math.ceil(self._blur_reach(slope)[outside].max())) + 1
        taken = ndimage.uniform_filter((replaced & supported).astype(np.float32), size, mode="constant")
        held = ndimage.uniform_filter(supported.astype(np.float32), size, mode="constant")
        unjudged = held < np.float32(0.5 / size ** 2)  # no supported pixel within reach
        majority = taken >= np.float32(EDGE_MAJORITY) * held
        return replaced & (supported | majority | unjudged)

    def faint_where(self, slope):
        """Where the reduction may take the faint aliasing at ``slope`` (:data:`FAINT_FRACTION`), ``(Y, X)``
        bool: :meth:`within_support` (under calibrated vignetting too since stop 41: see the constant)."""
        return self.within_support(slope)

    def edge_spread(self, slope):
        """How much the rendering at ``slope`` depends on where its depth edges are: the largest
        :func:`predicted_error` of the :meth:`rendering` against its :meth:`edge_renderings`, ``(Y, X)``
        float32 (0 away from the depth edges; kept per slope)."""
        slope = _validate.finite_float("slope", slope)

        def make():
            from .metrics import _blurred_luminance, _relative_difference

            rendered = self.scored_rendering(slope).image
            spread = np.zeros(self.lf.image_shape, np.float32)
            reference = None  # predicted_error's blurred luminance of the rendering, made once
            for image in self.edge_renderings(slope):
                if image is not rendered:
                    reference = _blurred_luminance(rendered) if reference is None else reference
                    np.maximum(spread, _relative_difference(_blurred_luminance(image), reference), out=spread)
            return spread

        return self._kept(slope, "edge spread", make)

    def _score_reach(self, slope):
        """How far (px) around a pixel :meth:`scores` reads the renderings (the edge renderings must be
        exact that far around every pixel it scores): the blur of :func:`predicted_error` and the
        widest window the renderings' local means are taken over."""
        return _ERROR_REACH + self._consistency_windows(slope).widest // 2

    def _raw_scored_rendering(self, slope):
        from .render import Rendering

        def make():
            read = ndimage.maximum_filter(~self._agree(slope), size=2 * self._score_reach(slope) + 1)
            renderer, shape = self._renderer(slope), self.lf.image_shape
            naive = Rendering(renderer.naive, np.zeros(shape, np.float32), np.zeros(shape, np.float32))
            return renderer.composite(self._layers(slope), within=read, elsewhere=naive)

        return self._kept(slope, "raw scored rendering", make)

    def _layers(self, slope):
        """The :class:`~napari_lfalias.render.Layers` of the estimate at ``slope`` (kept per slope)."""
        return self._kept(slope, "layers", lambda: self._renderer(slope).layers(
            self._rendered_disparity(slope), self._confidence_at(slope), larger_first=self.larger_first(slope)))

    def _renderer(self, slope):
        """The unit-scaled light field's :class:`~napari_lfalias.render.SlopeRenderer` at ``slope``."""
        from .render import SlopeRenderer

        rendered_slope = _rendered_slope(slope)
        same = rendered_slope == slope and self.lf is self._data  # the renderer's naive refocus is ours

        def make():
            return SlopeRenderer(self.lf, rendered_slope, naive=self.naive(slope) if same else None)

        return self._kept(slope, "renderer", make)

    def _in_focus(self, slope):
        """The surfaces the views show in focus at ``slope``: in focus, whatever the estimate says; also
        those the views show in focus :data:`FOCUS_BAND_PX` either side of it, where the estimate is unsure
        (confidence below :data:`MIN_TRUST`) or the surface they lie on is mostly estimated in that band
        (:meth:`_in_band_surface`); kept per slope."""
        from .baselines import view_spacing

        def make():
            from .render import sharp_at

            test = self.focus_test
            found = test(slope)
            spacing = view_spacing(self.lf.positions)
            step = FOCUS_BAND_PX / spacing
            unsure = (self.estimate[1] < MIN_TRUST) & ~found & test.textured
            if unsure.any():
                near = test.at_any((slope - step, slope + step), where=unsure)
                # a surface's focus, not a pixel's chance match
                around = ndimage.uniform_filter((found | near).astype(np.float32), FOCUS_BAND_WINDOW)
                found |= near & (around >= 0.5)
            found |= self._in_band_surface(slope, step, found)
            if not found.any():
                return found
            textured = ndimage.uniform_filter(test.textured.astype(np.float32), FOCUS_SURFACE_WINDOW)
            passing = ndimage.uniform_filter(found.astype(np.float32), FOCUS_SURFACE_WINDOW)
            surface = passing >= np.float32(FOCUS_SURFACE_SHARE) * np.maximum(textured, np.float32(1e-6))
            return found & (surface | sharp_at(self.estimate[0], slope, spacing))

        return self._kept(slope, "in focus", make)

    def _in_band_surface(self, slope, step, found):
        """``(Y, X)`` bool: the pixels the estimate is sure of (:data:`MIN_TRUST`) a disparity bin or more from
        ``slope`` (:data:`~napari_lfalias.render.BIN_PX`), not in focus in ``found``, that the views show in
        focus at ``slope +- step``, where the surface they lie on (those pixels, ``found`` and the textured
        pixels estimated within 1.5 ``step`` of ``slope``, connected) is mostly estimated that near
        (:func:`_by_surface`).

        A periodic texture fits every disparity a period apart, and next to
        an occluder the estimate may take a period's alias with confidence
        (the views beyond the occluder's edge refute the truth there): a fine
        checker wall at -4.5, estimated so away from its occluders, came out
        at 3.5 up to 13 px around them, on 1345 pixels sure of it (fresh scene
        1805), and the rendering blurred it there. The views do not tell the
        two apart; the rest of the wall, estimated at the slope, does. A
        surface not estimated within the band keeps its estimate: a fine
        stripes wall estimated right (fresh scene 607 at 4.9) passes the test
        at 5.0, its period away.

        Only on slopes where :data:`IN_BAND_SHARE` of the image is estimated
        within the band, and grown outwards from there :data:`IN_BAND_GROWTH`
        px at a time while the views show more of it in focus: the test of
        every sure pixel cost 0.4 s a slope on the brick room (8x8, 512 px).
        """
        from .baselines import view_spacing
        from .render import BIN_PX

        textured = self.focus_test.textured
        off = np.abs(self.estimate[0] - slope)
        within = (off <= 1.5 * step) & textured
        if np.mean(within) < IN_BAND_SHARE:
            return np.zeros(found.shape, bool)
        away = off * view_spacing(self.lf.positions) >= BIN_PX
        untested = (self.estimate[1] >= MIN_TRUST) & ~found & textured & away
        near = np.zeros(found.shape, bool)
        surface = found | within
        while True:
            frontier = untested & ndimage.maximum_filter(surface, 2 * IN_BAND_GROWTH + 1)
            if not frontier.any():
                break
            untested &= ~frontier
            passed = self.focus_test.at_any((slope - step, slope + step), where=frontier)
            if not passed.any():
                break
            near |= passed
            surface |= passed
        return near & _by_surface(within, surface) if near.any() else near

    def _in_focus_at(self, slope, disparity):
        """``disparity`` with the surfaces the views show in focus at ``slope`` put at the rendered slope."""
        return np.where(self._in_focus(slope), np.float32(_rendered_slope(slope)), disparity)

    def _rendered_disparity(self, slope):
        """The disparity the :meth:`rendering` at ``slope`` uses: the estimate, with what the views show in
        focus there (kept per slope)."""
        return self._kept(slope, "rendered disparity", lambda: self._in_focus_at(slope, self._least_change(slope)))

    @property
    def alternative(self):
        """Where the views fit a second disparity about as well, that disparity (NaN elsewhere), or ``None``
        (:attr:`~napari_lfalias.disparity.DisparityEstimate.alternative`; a disparity given as an array has
        none)."""
        self.estimate  # noqa: B018 - made with the estimate
        return self._alternative

    def _least_change(self, slope, periods=True):
        """The estimate, with the :attr:`alternative` where that is nearer ``slope``: of two disparities the
        views cannot tell apart, the one whose rendering changes the naive refocus least.

        A surface (a connected region of the pixels whose alternative is nearer) moves to its alternative whole,
        where on most of it the views vary there about as little as at the estimate (:data:`PERIOD_FIT`), else
        not at all: taken pixel by pixel wherever the estimate found one, the second fit split a checker at -4.8
        by the phase of its texture (fresh scene 505 at slope 5: 59 % of it at 7.2, where its views varied 7x
        more), and the rendering drew it at two blurs, 3.2 dB below the naive refocus on its clean pixels. Two
        fits a period apart (at least :data:`MIN_PERIOD_PX` of motion per view step) mean that every whole
        number of periods apart may fit too, and where the two are two periods apart, so may the half numbers:
        the pixel moves to the one of those (up to :data:`PERIODS_REACH`) nearest ``slope``, the nearest half
        number first, then the nearest whole one, where the views agree there (found within
        :data:`PERIOD_SEARCH` steps of it) about as well as at the estimate (:data:`PERIOD_FIT`) and closely
        (:data:`PERIOD_MAX_CV`), on most of its surface (as above); in focus there, it is put at the slope. A
        pixel without an alternative of its own takes its neighbours' period (:meth:`_periods`).
        ``periods=False``: only the two fits. Measured (unseen, stop 24's code): a checker wall at 3.8 estimated
        two periods off was flattened, 21 dB below the naive refocus at 2.9 (fresh scene 1206; +0.1 dB with the
        periods); stripes at 4.5 whose two fits lay a period either side, 9.6 dB below it on the clean pixels at
        4.9 (1119; +1.0). A fine checker wall in focus at -2.4, estimated 9.6 with its second fit at 3.6, was
        rendered 6 px per view step out of focus, 4.4 dB below the naive refocus (fresh scene 700). On HCI
        antinous's 3x3 sub-grid at -1.53 the periods put the image 3.1 dB below it, both without the check of
        the views and with it when the occlusion order was judged with these pixels (it flipped):
        :meth:`larger_first` is judged from the estimate, not with them.

        The views tell the two apart at a surface's outline, where an
        occluder's moves with its true disparity: a moved surface the views
        show in front there keeps its estimate (:meth:`_fronts_kept`).
        """
        return self._fronts_kept(self._nearest_fits(slope, periods))

    def _nearest_fits(self, slope, periods):
        """:meth:`_least_change` before :meth:`_fronts_kept`: the fits nearest ``slope`` that the views allow."""
        disparity, alternative = self.estimate[0], self.alternative
        if alternative is None:
            return disparity
        from .baselines import view_spacing
        from .render import sharp_at

        spacing = view_spacing(self.lf.positions)
        nearer = self._has_period() & (np.abs(alternative - slope) < np.abs(disparity - slope))  # False where NaN
        if self._fit_at_estimate is None:  # the views' fit at the estimate, made once a pixel for every slope
            self._fit_at_estimate = (np.full(disparity.shape, np.inf, np.float32), np.zeros(disparity.shape, bool))
        at_estimate, asked = self._fit_at_estimate

        def fit_at_estimate(where):
            todo = where & ~asked
            if todo.any():
                at_estimate[todo] = self._least_cv_near(disparity, todo)[0][todo]
                asked[todo] = True
            return at_estimate

        if nearer.any():  # a surface moves to it whole, where the views fit it about as well on most of it
            at_alternative = self._least_cv_near(alternative, nearer)[0]
            fits = nearer & (at_alternative <= PERIOD_FIT * fit_at_estimate(nearer) + MIN_ANGULAR_CV)
            nearer = _by_surface(fits, nearer)
        best = np.where(nearer, alternative, disparity).astype(np.float32)
        if not periods:
            return best
        half = self._periods() / 2
        periodic = half > 0
        half[~periodic] = 1
        reach = 2 * PERIODS_REACH
        halves = np.clip(np.round((slope - disparity) / half), -reach, reach)
        wholes = 2 * np.round(halves / 2)
        candidates = [disparity + halves * half, disparity + wholes * half]
        closer = [periodic & (np.abs(c - slope) < np.abs(best - slope)) for c in candidates]
        closer[1] &= wholes != halves
        if not (closer[0] | closer[1]).any():
            return best
        at_estimate = fit_at_estimate(closer[0] | closer[1])
        undecided = np.ones(best.shape, bool)
        for candidate, tried in zip(candidates, closer):
            tried &= undecided
            at_candidate, candidate = self._least_cv_near(candidate, tried, reach=PERIOD_SEARCH)
            fits = tried & (at_candidate <= PERIOD_MAX_CV) & (at_candidate <= PERIOD_FIT * at_estimate + MIN_ANGULAR_CV)
            fits = _by_surface(fits, tried)  # a surface's fit, not one pixel's chance
            best[fits] = np.where(sharp_at(candidate, slope, spacing), np.float32(slope), candidate)[fits]
            undecided &= ~fits
        return best

    def _fronts_kept(self, moved_to):
        """``moved_to`` (the estimate, its periodic surfaces moved by :meth:`_nearest_fits`) with each moved
        surface put back at its estimate where its outline shows it in front, as only the estimate has it.

        Inside a periodic surface the views fit its estimate and a disparity
        a period away alike; at its outline they do not where the surface is
        the occluder: an occluder's outline moves with its true disparity,
        and every view sees its side of it. A moved surface (a connected
        region of at least :data:`~napari_lfalias.baselines.MIN_SURE_PIXELS`
        moved pixels without a step of the estimate between them, with the
        pixels estimated within :data:`OUTLINE_SAME_SURFACE` of it up to
        :data:`OUTLINE_GROW_PX` px around) is judged where it borders a surely
        estimated other surface (:data:`~napari_lfalias.baselines.SURE_CONFIDENCE`,
        no period), and only where its estimate puts it in front of that
        surface and its move does not. There the two disparity maps, the
        estimate and the estimate with the move, are each asked how well they
        explain the views on the :data:`OUTLINE_BAND_PX` px either side of the
        outline, every sample a nearer surface hides left out
        (:func:`~napari_lfalias.baselines._hidden_spread`, in the order the
        estimate was judged to have); where the move's spread is
        :data:`~napari_lfalias.baselines.CLEAR_SPREAD_RATIO` times the
        estimate's or more, the move is undone. A periodic wall whose estimate
        is the alias, in front of its occluder, fits its outline worse there
        than moved behind it, and moves.

        Measured (fresh-x, run before this rule; unseen): a checker square at
        -4.4 in front of a grey wall in focus at 3.8, estimated right on 80 %
        of it with a second fit a period away, was moved a period into focus
        and nothing of its aliasing was replaced (fresh scene 2609: +0.0 dB
        over the naive refocus where aliased; the true disparity's rendering
        +23.7). With the rule: +13.7.
        """
        from .baselines import MIN_SURE_PIXELS, SURE_CONFIDENCE, _depth_edges

        disparity, confidence = self.estimate
        moved = moved_to != disparity
        if not moved.any():
            return moved_to
        # one surface's pixels: no step of the estimate between them (a periodic wall moved with the square in
        # front of it are two)
        labels, count = ndimage.label(moved & ~_depth_edges(disparity, OUTLINE_SAME_SURFACE),
                                      structure=np.ones((3, 3), bool))
        if count == 0:
            return moved_to
        _, (nearest_y, nearest_x) = ndimage.distance_transform_edt(labels == 0, return_indices=True)
        labels = np.where(moved, labels[nearest_y, nearest_x], 0)  # the steps' own pixels to the surface beside
        sizes = np.bincount(labels.ravel(), minlength=count + 1)
        sure = (confidence >= SURE_CONFIDENCE) & ~self._has_period() & ~moved
        undone = np.zeros(count + 1, bool)
        margin = OUTLINE_GROW_PX + 2 * OUTLINE_BAND_PX + 1
        for k, box in enumerate(ndimage.find_objects(labels), start=1):
            if sizes[k] < MIN_SURE_PIXELS:
                continue
            window = tuple(slice(max(part.start - margin, 0), part.stop + margin) for part in box)
            undone[k] = self._in_front_at_outline(labels[window] == k, window, moved_to, moved, sure)
        if not undone.any():
            return moved_to
        return np.where(undone[labels], disparity, moved_to).astype(np.float32)

    def _in_front_at_outline(self, region, window, moved_to, moved, sure):
        """Whether the moved ``region`` (bool, over ``window`` of the image; ``moved_to``, ``moved`` and
        ``sure``: over the whole image, as :meth:`_fronts_kept` has them) is shown in front of the sure surface
        along its outline: its estimate has it so and its move not, and the views at the outline fit the
        estimate better than the move, each with the samples its nearer surfaces hide left out."""
        from .baselines import CLEAR_SPREAD_RATIO, MIN_SURE_PIXELS, _hidden_spread

        disparity = self.estimate[0]
        local = disparity[window]
        centre = float(np.median(local[region]))
        target = float(np.median(moved_to[window][region]))
        moved, sure = moved[window], sure[window]
        grown = ndimage.binary_dilation(region, iterations=OUTLINE_GROW_PX)
        same, _ = ndimage.label(region | (grown & ~moved & (np.abs(local - centre) <= OUTLINE_SAME_SURFACE)),
                                structure=np.ones((3, 3), bool))
        surface = np.isin(same, np.unique(same[region]))
        beside = ndimage.binary_dilation(surface, iterations=OUTLINE_BAND_PX) & ~surface
        other = beside & sure & (np.abs(local - centre) > max(OUTLINE_SAME_SURFACE, 0.5 * abs(target - centre)))
        if np.count_nonzero(other) < MIN_SURE_PIXELS // 4:
            return False
        behind = float(np.median(local[other]))
        larger_first = self._order_judged_once()
        sign = 1.0 if larger_first else -1.0
        if sign * (centre - behind) <= OUTLINE_SAME_SURFACE or sign * (target - behind) > OUTLINE_SAME_SURFACE:
            return False
        band = other | (surface & ndimage.binary_dilation(other, iterations=OUTLINE_BAND_PX))
        pixels = np.argwhere(band) + np.array([part.start for part in window])
        pixels = pixels[:: max(1, len(pixels) // 20_000)].astype(np.int64)
        views, positions = np.ascontiguousarray(self.lf.views()), np.ascontiguousarray(self.lf.flat_positions())
        as_moved = moved_to.astype(np.float64)
        as_estimated = as_moved.copy()
        as_estimated[window][region] = local[region]
        at_estimate = _hidden_spread(views, positions, as_estimated, pixels, larger_first)
        return _hidden_spread(views, positions, as_moved, pixels, larger_first) >= CLEAR_SPREAD_RATIO * at_estimate

    def _periods(self):
        """Each pixel's period (disparity): the distance from the estimate to its :attr:`alternative` where
        that is at least :data:`MIN_PERIOD_PX` of motion per view step, else the median of those periods in
        its tile of :data:`PERIOD_TILE` px where at least a tenth of the tile has one (a periodic wall's
        second fit is found on most of it, not all), else 0."""
        if self._period is None:
            disparity, alternative = self.estimate[0], self.alternative
            period = np.where(self._has_period(), np.abs(alternative - disparity), np.float32(0))
            filled = period.copy()
            for y in range(0, period.shape[0], PERIOD_TILE):
                for x in range(0, period.shape[1], PERIOD_TILE):
                    tile = period[y:y + PERIOD_TILE, x:x + PERIOD_TILE]
                    known = tile[tile > 0]
                    if known.size >= 0.1 * tile.size:
                        filled[y:y + PERIOD_TILE, x:x + PERIOD_TILE][tile == 0] = np.median(known)
            self._period = filled.astype(np.float32)
        return self._period.copy()

    def _least_cv_near(self, disparity, where, reach=1, step=PERIOD_STEP):
        """The least angular variation of the views (:meth:`angular_cv`'s measure, its dark floor the light
        field's brightest luminance rather than the refocus's) within ``reach`` steps of ``step`` of each
        pixel's own ``disparity`` (on multiples of ``step``) on ``where`` (inf elsewhere), and the disparity
        where it is. A disparity a few periods from the estimate carries the error of each
        period that many times: a few steps either way find the views' fit again."""
        from .refocus import _run

        least = np.full(disparity.shape, np.inf, np.float32)
        at = disparity.astype(np.float32, copy=True)
        ys, xs = np.nonzero(where)
        if ys.size == 0:
            return least, at
        lum = self._luminance_lf
        weights = lum.flat_weights()
        views = np.ascontiguousarray(lum.views(), np.float32)
        valid = np.ones((1, 1, 1), np.float32) if weights is None else np.ascontiguousarray(weights, np.float32)
        positions = np.ascontiguousarray(lum.flat_positions(), np.float64)
        offsets = np.array(sorted(range(-reach, reach + 1), key=abs), np.float64)
        tried = (np.round(disparity[ys, xs].astype(np.float64) / step)[:, None] + offsets) * step
        cv = np.empty(tried.shape)
        _run("points_cv", views, valid, weights is not None, positions, ys.astype(np.float64),
             xs.astype(np.float64), tried, float(self._dark_floor), cv)
        best_cv = np.full(ys.size, np.inf)
        best_at = disparity[ys, xs].astype(np.float64)
        for column in range(offsets.size):  # the offset nearest the pixel's own wins a tie
            better = cv[:, column] < best_cv
            best_cv[better], best_at[better] = cv[better, column], tried[better, column]
        least[ys, xs], at[ys, xs] = best_cv, best_at
        return least, at

    @property
    def _dark_floor(self):
        """:data:`DARK_FLOOR` of the light field's brightest luminance."""
        if self._floor is None:
            peak = float(self._luminance_lf.data.max(initial=0.0))
            self._floor = np.float32(max(DARK_FLOOR * peak, float(np.finfo(np.float32).tiny)))
        return self._floor

    def _confidence_at(self, slope):
        """The confidence the renderings at ``slope`` weigh their disparities by (kept per slope): the
        estimate's, 1 where the views show the surface in focus, and at least :data:`PERIODIC_TRUST` on a
        periodic surface whose rendered disparity is one surface's (:meth:`_settled_periodic`)."""

        def make():
            confidence = self.estimate[1]
            settled = self._settled_periodic(slope)
            if settled is not None:
                confidence = np.where(settled, np.maximum(confidence, np.float32(PERIODIC_TRUST)), confidence)
            return np.where(self._in_focus(slope), np.float32(1), confidence)

        return self._kept(slope, "confidence", make)

    def _settled_periodic(self, slope):
        """The pixels of a periodic texture (:meth:`_periods`) whose rendering at ``slope`` is trusted as a
        sure estimate's (:data:`PERIODIC_TRUST`), ``(Y, X)`` bool, or ``None`` where there is no periodic
        texture.

        The estimate's confidence is low on a periodic texture however
        right it is: the views fit a period away too. Its rendered disparity
        is the one of those :meth:`_least_change` chose, the nearest the
        slope that the views fit, so the rendering changes the naive refocus
        least of them. It is trusted where that disparity is one surface's
        around the pixel (:data:`SETTLED_SHARE`; not where it jumps between
        periods from pixel to pixel: a checker wall through noise and a
        strong vignette, fresh scene 1402, 1.0: -0.01 -> -5.63 dB), where its
        ghosts lie at least :data:`SETTLED_MIN_GHOST_PX` apart (a wall nearly
        in focus gains little and its rendering's own error shows: fresh
        707 at -2.2) and where every view holds its own sample (not within
        ``|slope|`` times the :func:`aperture_radius` and
        :data:`SETTLED_BORDER_PX` of the image's edge: there the rendering
        stands in for the samples a view lacks by another view's of the
        same surface, which depends on which of its periods the surface is
        at; the holdout's checkerboard, 3x3 at +4, a period off, lost 1.0
        dB on its clean pixels along the border).
        """
        if self.alternative is None:
            return None
        periodic = self._periods() > 0
        if not periodic.any():
            return None
        from .baselines import view_spacing

        disparity = self._rendered_disparity(slope)
        step, (rows, cols) = SETTLED_STEP, disparity.shape
        grown = np.pad(disparity, step, mode="edge")
        agree = np.zeros(disparity.shape, np.float32)
        for dy, dx in ((-step, 0), (step, 0), (0, -step), (0, step)):
            neighbour = grown[step + dy:step + dy + rows, step + dx:step + dx + cols]
            agree += np.abs(disparity - neighbour) < SETTLED_TOLERANCE
        share = ndimage.uniform_filter(agree / np.float32(4), SETTLED_WINDOW, mode="nearest")
        ghosts = np.abs(disparity - np.float32(slope)) * view_spacing(self.lf.positions)
        settled = periodic & (share >= SETTLED_SHARE) & (ghosts >= SETTLED_MIN_GHOST_PX)
        margin = int(math.ceil(abs(slope) * aperture_radius(self.lf))) + SETTLED_BORDER_PX
        settled[:margin] = settled[rows - margin:] = False
        settled[:, :margin] = settled[:, cols - margin:] = False
        return settled

    def _in_data_units(self, rendering):
        if self._unit == 1.0:
            return rendering
        return replace(rendering, image=rendering.image / np.float32(self._unit))

    @property
    def focus_test(self):
        """The :class:`~napari_lfalias.disparity.FocusTest` of the light field (made on first use)."""
        if self._focus_test is None:
            from .disparity import FocusTest

            self._focus_test = FocusTest(self.lf, self._luminance_lf)
        return self._focus_test

    @property
    def _luminance_lf(self):
        """The light field's luminance (:meth:`~napari_lfalias.LightField.luminance`), made once: the focus
        test and the angular variation of every slope read it."""
        if self._luminance is None:
            self._luminance = self.lf.luminance()
        return self._luminance

    def angular_cv(self, slope):
        """The angular coefficient of variation of the views' luminance at ``slope``, ``(Y, X)``."""
        return self._kept(slope, "angular cv", lambda: self._angular_cv_of(slope))

    def _angular_cv_of(self, slope):
        from .refocus import view_moments

        moments = view_moments(self._luminance_lf, slope)
        mean = moments.mean[..., 0]
        floor = max(DARK_FLOOR * float(mean.max(initial=0.0)), float(np.finfo(np.float32).tiny))
        return np.sqrt(np.maximum(moments.variance[..., 0], 0)) / np.maximum(mean, floor)

    def _agree(self, slope):
        """Where the views agree at ``slope`` (their score is 0 whatever the renderings say)."""
        return self._kept(slope, "agree", lambda: self.angular_cv(slope) <= MIN_ANGULAR_CV)

    def _scored_zero(self, slope):
        """Where :meth:`scores` is 0 whatever the renderings say: the views agree, or the rendering is
        not trusted."""
        return self._agree(slope) | (self.scored_rendering(slope).trust < MIN_TRUST)

    def predicted_errors(self, slope, naive):
        """The :func:`predicted_error` of ``naive`` at ``slope`` against the rendering, 0 where the views
        agree; ``(Y, X)`` float32: what the detection reports (where it exceeds ``T``, the aliasing the
        rendering predicts). Where the views agree everywhere, nothing is rendered.

        The reduction replaces pixels by the more cautious :meth:`scores`; as a detector of aliasing this
        plain prediction ranks and finds the aliased pixels better (module notes)."""
        slope = _validate.finite_float("slope", slope)
        agree = self._agree(slope)
        if agree.all():
            return np.zeros(self.lf.image_shape, np.float32)
        error = predicted_error(naive, self.scored_rendering(slope).image).astype(np.float32)
        error[agree] = 0.0
        return error

    def flagged(self, slope, threshold=THRESHOLD):
        """The pixels the detection flags at ``slope``, ``(Y, X)`` bool: those whose
        :meth:`predicted_errors` of the naive refocus exceed ``threshold`` and whose cautious
        :meth:`scores` exceeds :data:`REPLACE_FRACTION` of it (what the reduction's fringe asks of a
        pixel): where the cautious score finds next to nothing, the prediction is the rendering's doubt
        (a misplaced edge, a wrong local mean), not aliasing. Measured (module notes): of the slopes with
        no aliased pixel the prediction alone flagged some on 4 in 23 (fresh-a), this rule on 1."""
        above = self.refocus_errors(slope) > np.float32(threshold)
        if not above.any():
            return above
        return above & (self.cautious_scores(slope) > np.float32(REPLACE_FRACTION * threshold))

    def refocus_errors(self, slope):
        """:meth:`predicted_errors` of the naive refocus at ``slope`` (kept per slope)."""
        slope = _validate.finite_float("slope", slope)
        return self._kept(slope, "predicted errors", lambda: self.predicted_errors(slope, self.naive(slope)))

    def cautious_scores(self, slope):
        """:meth:`scores` of the naive refocus at ``slope`` (kept per slope)."""
        slope = _validate.finite_float("slope", slope)
        return self._kept(slope, "scores", lambda: self.scores(slope, self.naive(slope)))

    def scores(self, slope, naive):
        """Predicted error of ``naive`` at ``slope`` (the least against the rendering and its
        :meth:`edge_renderings`), set to 0 where the views agree or the rendering is not trusted;
        ``(Y, X)`` float32: where it exceeds ``T``, the reduction replaces the pixel. Where the views
        agree everywhere, nothing is rendered."""
        slope = _validate.finite_float("slope", slope)
        if self._agree(slope).all():
            return np.zeros(self.lf.image_shape, np.float32)
        from .metrics import _blurred_luminance, _relative_difference

        windows = self._consistency_windows(slope)
        naive_means = windows.means(naive)
        seen = _blurred_luminance(naive)  # predicted_error's, made once for the three renderings

        def error(image):
            return _relative_difference(seen, _blurred_luminance(windows.with_mean_of(naive_means, image)))

        score = error(self.scored_rendering(slope).image)
        for image in self.edge_renderings(slope):
            np.minimum(score, error(image), out=score)
        score[self._scored_zero(slope)] = 0.0
        return score

    def _consistency_windows(self, slope):
        """The :class:`_Windows` around each pixel at ``slope``: :data:`CONSISTENCY_PERIODS` spacings of its own
        surface's ghosts, or :data:`REACHING_PERIODS` of those of a nearer surface whose blur reaches it
        (:func:`ghosts_reaching`), whichever is wider (kept per slope)."""
        from .baselines import view_spacing

        def make():
            spacing = view_spacing(self.lf.positions)
            disparity = self._rendered_disparity(slope)  # the windows of the surfaces that were rendered
            own = np.abs(disparity.astype(np.float64) - slope) * spacing
            reaching = ghosts_reaching(disparity, slope, spacing, aperture_radius(self.lf) / spacing,
                                       self.larger_first(slope))
            half = np.maximum(np.rint(0.5 * CONSISTENCY_PERIODS * own), np.rint(0.5 * REACHING_PERIODS * reaching))
            half = np.minimum(half, max(self.lf.image_shape))
            return _Windows((2 * half + 1).astype(np.int64))

        return self._kept(slope, "consistency windows", make)

    @staticmethod
    def blend_weight(mask):
        """The share ``(Y, X)`` of the rendering each pixel takes: at least a half on the ``mask``, the
        edge softened over about a pixel on either side (0 elsewhere: those pixels stay the naive
        refocus exactly)."""
        weight = ndimage.gaussian_filter(mask.astype(np.float32), 0.7)
        weight = np.where(mask, np.maximum(weight, 0.5), weight).astype(np.float32)
        weight[weight < 0.02] = 0.0
        return weight

    @staticmethod
    def blend(naive, rendered, mask, weight=None):
        """``naive`` with ``rendered`` in the ``mask`` pixels, by :meth:`blend_weight` (``weight``: that of
        ``mask``, where already made)."""
        if not mask.any():
            return naive.copy()
        weight = DepthGuide.blend_weight(mask) if weight is None else weight
        return (naive + weight[..., None] * (rendered - naive)).astype(np.float32)


def ghosts_reaching(disparity, slope, spacing, radius, larger_first=True):
    """The widest ghost spacing (px) at each pixel at ``slope``: of its own surface, or of any nearer one whose
    blur reaches it.

    A surface whose copies in the naive refocus lie ``g`` px apart is
    blurred by a dense aperture over ``radius * g`` px on either side
    (``radius``: the aperture's half width in view spacings), and its
    copies lie over that reach too, over the farther surfaces seen there
    (a farther surface's copies do not cover a nearer one).

    Parameters
    ----------
    disparity : ndarray, shape (Y, X)
    slope : float
    spacing : float
        The distance between neighbouring views (units of disparity).
    radius : float
        Half the aperture's width, in view spacings.
    larger_first : bool
        Whether larger disparities are nearer.

    Returns
    -------
    ndarray, shape (Y, X), float64: at least the pixel's own ``|disparity -
    slope| * spacing``, within a pixel below the widest spacing of the
    nearer surfaces that reach it.

    Examples
    --------
    A defocused point (copies 2 px apart) in front of an in-focus surface reaches 3 px either side:

    >>> import numpy as np
    >>> disparity = np.zeros((1, 9))
    >>> disparity[0, 4] = 2.0
    >>> ghosts_reaching(disparity, 0.0, 1.0, 1.5)[0].tolist()
    [0.0, 2.0, 2.0, 2.0, 2.0, 2.0, 2.0, 2.0, 0.0]

    Behind the in-focus surface, it reaches nothing:

    >>> ghosts_reaching(disparity, 0.0, 1.0, 1.5, larger_first=False)[0].tolist()
    [0.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0]
    """
    disparity = np.asarray(disparity, np.float64)
    depth = disparity if larger_first else -disparity  # larger: nearer
    widest = np.abs(disparity - slope) * spacing
    sides = np.floor(widest) * np.sign(disparity - slope)  # whole px of spacing, on either side of the focus
    for side in np.unique(sides[np.abs(sides) >= 1.0]):
        at, level = sides == side, abs(side)
        size = 2 * int(math.ceil(level * radius)) + 1
        reached = ndimage.maximum_filter(at.view(np.uint8), size=size).astype(bool)
        behind = depth < depth[at].min()
        np.maximum(widest, np.where(reached & behind, level, 0.0), out=widest)
    return widest


def aperture_radius(lf):
    """Half the width of ``lf``'s aperture (units of disparity): from the centre of its views (those with any
    weight) out to the far edge of the outermost view's cell, along the wider axis.

    Examples
    --------
    >>> import numpy as np
    >>> from napari_lfalias import LightField
    >>> aperture_radius(LightField(np.zeros((5, 3, 4, 4, 1), np.float32)))  # 5 views a unit apart: 2 + 1/2
    2.5
    """
    from .baselines import view_spacing

    return _farthest_view(lf) + 0.5 * view_spacing(lf.positions)


def _farthest_view(lf):
    """How far (units of disparity) the view farthest from the centre of ``lf``'s views lies from it, along
    either axis; only views with any weight count (a lenslet capture's black corner views hold no sample)."""
    positions = lf.flat_positions().astype(np.float64)
    if lf.weights is not None:
        seen = lf.weights.reshape(len(positions), -1).max(axis=1) > 0
        positions = positions[seen] if seen.any() else positions
    return float(np.abs(positions - positions.mean(axis=0)).max(initial=0.0))


def with_local_mean_of(naive, image, windows):
    """``image`` with its mean over each pixel's window made that of ``naive``.

    Parameters
    ----------
    naive, image : ndarray, shape (Y, X, C)
    windows : ndarray of int, shape (Y, X)
        Odd side of the square window around each pixel (1: the pixel is
        left as it is); cut at the image's edges.

    Returns
    -------
    ndarray, shape (Y, X, C), float32

    Examples
    --------
    >>> import numpy as np
    >>> naive = np.tile(np.array([0.0, 0.0, 0.9], np.float32), 4)[None, :, None]  # ghosts 3 px apart
    >>> too_bright = np.full_like(naive, 0.5)
    >>> with_local_mean_of(naive, too_bright, np.full((1, 12), 3))[0, 1:-1, 0].round(2)
    array([0.3, 0.3, 0.3, 0.3, 0.3, 0.3, 0.3, 0.3, 0.3, 0.3], dtype=float32)
    """
    windows = _Windows(windows)
    return windows.with_mean_of(windows.means(naive), image)


class _Windows:
    """Square windows of odd side ``sides (Y, X)`` around every pixel, cut at the edges; means over them."""

    def __init__(self, sides):
        rows, cols = sides.shape
        half = sides // 2
        y, x = np.mgrid[:rows, :cols]
        bounds = (np.maximum(y - half, 0), np.minimum(y + half + 1, rows), np.maximum(x - half, 0),
                  np.minimum(x + half + 1, cols))  # ends excluded
        self.y0, self.y1, self.x0, self.x1 = (np.ascontiguousarray(bound, np.int64) for bound in bounds)
        self.single = sides <= 1
        self.widest = int(sides.max(initial=1))

    def means(self, values):
        """The mean of ``values (Y, X, C)`` over each pixel's window (a summed-area table: any side costs
        the same), float64."""
        from ._baseline_kernels import window_means

        values = np.ascontiguousarray(values)
        out = np.empty(values.shape, np.float64)
        window_means(values, self.y0, self.y1, self.x0, self.x1, out)
        return out

    def with_mean_of(self, target_means, image):
        """``image`` with its window means made ``target_means``; single-pixel windows left as they are."""
        shift = self.means(image) - target_means
        shift[self.single] = 0.0
        return (image - shift).astype(np.float32)


def _period_slopes(disparity, alternative, periodic, spacing, periods=PERIODS_TRIED, most=PERIOD_SLOPES):
    """Where the ``periodic`` pixels' surfaces may lie: the disparities (``most`` of them, the commonest
    first, each more than two bins of :data:`PERIOD_SLOPE_BIN_PX` of motion per view step from those before
    it) that the most of them reach by whole periods (``alternative - disparity``, up to ``periods`` either
    way), within the estimate's range (its 1st to 99th percentile, widened by 1); none where less than
    :data:`ORDER_PERIODIC_SHARE` of the image is periodic.

    Examples
    --------
    >>> import numpy as np
    >>> disparity = np.array([[-4.5, -4.5, 3.5, 1.0]], np.float32)  # a wall at -4.5 or 3.5, period 8
    >>> alternative = np.array([[3.5, 3.5, -4.5, np.nan]], np.float32)
    >>> [round(s, 2) for s in _period_slopes(disparity, alternative, np.isfinite(alternative), 1.0)]
    [-4.5, 3.5]
    """
    if periodic.mean() < ORDER_PERIODIC_SHARE:
        return []
    base = disparity[periodic].astype(np.float64)
    period = alternative[periodic].astype(np.float64) - base
    low, high = np.percentile(disparity, [1, 99]) + np.array([-1.0, 1.0])
    reached = np.concatenate([base + k * period for k in range(-periods, periods + 1)])
    reached = reached[(reached >= low) & (reached <= high)]
    width = PERIOD_SLOPE_BIN_PX / spacing
    counts, edges = np.histogram(reached, np.arange(low, high + width, width))
    found = []
    for i in np.argsort(-counts, kind="stable"):
        if counts[i] == 0 or len(found) == most:
            break
        if all(abs(i - j) > 2 for j, _ in found):
            found.append((i, float(np.median(reached[(reached >= edges[i]) & (reached < edges[i + 1])]))))
    return [slope for _, slope in found]


def _unsure_islands(surface, sure):
    """The regions off ``surface`` ((Y, X) bool) with no ``sure`` pixel, ``(Y, X)`` bool: connected pixels
    that ``surface`` and the image's edge enclose, where nothing is known of them but an unsure estimate.

    Examples
    --------
    >>> import numpy as np
    >>> surface = np.ones((5, 7), bool)
    >>> surface[1:4, 1:3] = surface[2, 5] = False  # a region of six pixels and a speck
    >>> sure = np.zeros((5, 7), bool)
    >>> sure[2, 1] = True  # one pixel of the region is sure
    >>> _unsure_islands(surface, sure).astype(int)
    array([[0, 0, 0, 0, 0, 0, 0],
           [0, 0, 0, 0, 0, 0, 0],
           [0, 0, 0, 0, 0, 1, 0],
           [0, 0, 0, 0, 0, 0, 0],
           [0, 0, 0, 0, 0, 0, 0]])
    """
    labels, count = ndimage.label(~surface)
    known = np.zeros(count + 1, bool)
    known[labels[sure]] = True
    known[0] = True  # the surface itself
    return ~known[labels]


def _from_edge(shape):
    """``(Y, X)`` int: each pixel's distance (px) from the nearest edge of an image of ``shape``."""
    rows, cols = shape
    y, x = np.arange(rows)[:, None], np.arange(cols)[None]
    return np.minimum(np.minimum(y, rows - 1 - y), np.minimum(x, cols - 1 - x))


def _rendered_slope(slope):
    """The slope the renderer renders for ``slope``: a view shifted ``MAX_SHIFT`` pixels sees nothing, as at
    any larger slope, and float32 holds it."""
    from ._kernels import MAX_SHIFT

    return float(np.clip(slope, -MAX_SHIFT, MAX_SHIFT))


#: Data peaks within which the renderer's float32 sums neither overflow nor lose the data to underflow.
_SAFE_PEAKS = (2.0**-60, 2.0**60)


def _unit_scaled(lf):
    """``lf`` and 1, or, for data beyond :data:`_SAFE_PEAKS`, a copy times a power of two and that power."""
    from ._numerics import unit_scale

    peak = max(float(lf.data.max(initial=0.0)), -float(lf.data.min(initial=0.0)))  # no |data| copy
    if _SAFE_PEAKS[0] <= peak <= _SAFE_PEAKS[1] or not peak:
        return lf, 1.0
    unit = unit_scale(peak)
    scaled = LightField(lf.data * np.float32(unit), lf.positions, lf.meta, weights=lf.weights)
    return scaled, unit


def _by_surface(mask, among):
    """The connected regions of ``among`` (8-connected) where most of their pixels are ``mask``, whole: a
    surface's choice, not each pixel's."""
    labels, count = ndimage.label(among, structure=np.ones((3, 3), bool))
    if count == 0:
        return np.zeros(among.shape, bool)
    votes = np.bincount(labels.ravel(), weights=mask.ravel().astype(np.float64), minlength=count + 1)
    sizes = np.bincount(labels.ravel(), minlength=count + 1)
    won = votes > 0.5 * sizes
    won[0] = False
    return won[labels]
