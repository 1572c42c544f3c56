"""Numba kernels of the dense-aperture renderer (:mod:`napari_lfalias.render`).

- ``view_bins``: the centre-of-aperture disparity map forward-warped
  into every view (each centre pixel splats onto the four pixels around
  where it lands; the nearer surface wins), holes (disocclusions) filled
  along the view's offset from the farther side; then, for every view, the
  disparity bin of the surface its sample at ``p + slope * q_i`` shows
  (nearest pixel), the confidence there, and whether the centre's map
  landed there (else the view sees what the centre does not); -1 outside
  the view.
- ``disoccluded_in_focus``: those samples the centre does not see, counted
  to a surface behind the in-focus one, counted in focus where they agree
  and their surface does not explain them.
- ``views_differ``: where two such sets of views' bins differ.
- ``in_focus_colour`` (``in_focus_colour_near``: for bins that another
  set's are but here and there): the colour of the in-focus background the views
  show at each pixel (what fills the cells an occluder's blur uncovers).
- ``single_surface``, ``group_sums``: the bin every view shows at a pixel
  at full weight, and the views' samples summed by groups (the pixels of
  one surface are composited by summing the views first, then boxing).
- ``composite_views``: per view, its shifted samples are split into the
  disparity bins; each bin (premultiplied colour, coverage, confidence)
  is blurred by its own box (the footprint of one view's cell of the
  aperture at that disparity) and composited front to back. Views are
  spread over a few threads, each with its own accumulators.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ._baseline_kernels import box_image_into

__all__ = ["view_bins", "disoccluded_in_focus", "views_differ", "in_focus_colour", "in_focus_colour_near",
           "sampled_lines", "composite_views", "single_surface", "group_sums"]


@njit(cache=True)
def _fill_run(warped, nearness, y, x, end):
    """Fill the unfilled run ``[x, end)`` of row ``y`` of a warped view (``warped``: the flat index of the
    sample each pixel shows, -1: none yet) from the nearer filled neighbour that is farther away in depth (a
    disocclusion shows the background; ``nearness``: :func:`_splat_view`'s): that on its left, or on its
    right where the left one is nearer (or where there is none on the left); a run with no neighbour
    stays unfilled."""
    n_cols = warped.shape[1]
    left = x - 1
    right = end if end < n_cols else -1
    if left < 0 and right < 0:
        return
    pick = left
    if left < 0 or (right >= 0 and nearness[warped[y, left]] > nearness[warped[y, right]]):
        pick = right
    for k in range(x, end):
        warped[y, k] = warped[y, pick]


@njit(cache=True)
def _fill_row(warped, nearness, y):
    """Fill the unfilled runs of row ``y`` (:func:`_fill_run`); a row with nothing filled stays as it is."""
    n_cols = warped.shape[1]
    x = 0
    while x < n_cols:
        if warped[y, x] >= 0:
            x += 1
            continue
        end = x + 1  # the run is [x, end)
        while end < n_cols and warped[y, end] < 0:
            end += 1
        _fill_run(warped, nearness, y, x, end)
        x = end


@njit(cache=True)
def _splat_cells(disparity, nearness, q_y, q_x, cells):
    """Forward-warp ``disparity (Y, X)`` into the view at ``(q_y, q_x)``, one cell per landing spot: a
    sample moving to ``t`` lands on the four pixels from ``floor(t)``; cell ``floor(t) + 1`` of ``cells
    (Y + 1, X + 1)`` keeps the largest key of the samples moving there: their ``nearness`` (flat, uint32)
    in the high half, their flat index counted down in the low half (of equals, the first in raster
    order wins); 0: none."""
    n_rows, n_cols = disparity.shape
    cells[:] = 0
    last = np.uint64(0xFFFFFFFF)
    for y in range(n_rows):
        for x in range(n_cols):
            d = disparity[y, x]
            ty = y + d * q_y
            tx = x + d * q_x
            if not (-1.0 <= ty < n_rows and -1.0 <= tx < n_cols):
                continue  # none of its four pixels is in the view (tested on floats: no integer overflow)
            j = int(np.floor(ty)) + 1
            k = int(np.floor(tx)) + 1
            i = y * n_cols + x
            key = (np.uint64(nearness[i]) << np.uint64(32)) | (last - np.uint64(i))
            if key > cells[j, k]:
                cells[j, k] = key


@njit(cache=True)
def _splat_view(disparity, nearness, q_y, q_x, warped, cells):
    """Forward-warp ``disparity (Y, X)`` into the view at ``(q_y, q_x)``: ``warped (Y, X)`` int32 gets the flat
    index of the sample each pixel shows (-1: none). Each sample lands
    on the four pixels around where it moves, the nearest (largest ``nearness``: the disparities' order,
    flat uint32, larger for the nearer surface) winning, of equals the first in raster order. A sample is
    kept once, in the cell of its landing spot (:func:`_splat_cells`, scratch ``cells (Y + 1, X + 1)``
    uint64); a pixel then takes the largest key of its four cells: a quarter of the stores of landing on
    every pixel."""
    n_rows, n_cols = disparity.shape
    _splat_cells(disparity, nearness, q_y, q_x, cells)
    last = np.uint64(0xFFFFFFFF)
    for y in range(n_rows):
        for x in range(n_cols):
            key = max(max(cells[y, x], cells[y, x + 1]), max(cells[y + 1, x], cells[y + 1, x + 1]))
            warped[y, x] = np.int32(last - (key & last)) if key != 0 else -1


@njit(cache=True, inline="always")
def _first_landed(landed, y, x, step_y, step_x):
    """The first pixel ``(y + k step_y, x + k step_x)``, k = 1, 2, ..., rounded, that ``landed`` holds, as
    ``(y, x)`` (-1, -1: none before the image's edge)."""
    n_rows, n_cols = landed.shape
    k = 1
    while True:
        yy = int(np.floor(y + k * step_y + 0.5))
        xx = int(np.floor(x + k * step_x + 0.5))
        if yy < 0 or yy >= n_rows or xx < 0 or xx >= n_cols:
            return -1, -1
        if landed[yy, xx]:
            return yy, xx
        k += 1


@njit(cache=True)
def _fill_along_offset(warped, nearness, landed, q_y, q_x):
    """Fill each unfilled pixel of a warped view (``warped``, ``nearness``: as :func:`_splat_view` makes and
    reads them) from the first pixel something landed in (``landed``: where ``warped`` held a sample before
    the fill)
    along the view's offset ``(q_y, q_x)``, either way: the one farther in depth, where both exist. A
    disocclusion opens along the offset, between the occluder and what lies behind it, and shows the
    latter (across a horizontal edge of an occluder, for a view above or below the centre, that is the
    surface above or below the edge, not what lies to either side of the occluder)."""
    scale = max(abs(q_y), abs(q_x))
    if scale == 0.0:
        return
    step_y, step_x = q_y / scale, q_x / scale
    n_rows, n_cols = warped.shape
    for y in range(n_rows):
        for x in range(n_cols):
            if landed[y, x]:
                continue
            ahead_y, ahead_x = _first_landed(landed, y, x, step_y, step_x)
            behind_y, behind_x = _first_landed(landed, y, x, -step_y, -step_x)
            if ahead_y < 0 and behind_y < 0:
                continue
            if behind_y < 0 or (ahead_y >= 0 and nearness[warped[behind_y, behind_x]]
                                > nearness[warped[ahead_y, ahead_x]]):
                warped[y, x] = warped[ahead_y, ahead_x]
            else:
                warped[y, x] = warped[behind_y, behind_x]


@njit(cache=True)
def _warp_view(disparity, nearness, q_y, q_x, warped, landed, cells):
    """Forward-warp ``disparity (Y, X)`` into the view at ``(q_y, q_x)``: ``warped (Y, X)``, the flat index
    of the sample each pixel shows (:func:`_splat_view`, with ``nearness`` and scratch ``cells``), holes
    filled along the view's offset (:func:`_fill_along_offset`); what that leaves (a walk that leaves the
    image both ways) is filled along its row, and the rows nothing landed in along the columns; a view
    nothing lands in stays -1. ``landed (Y, X)`` says where something landed (elsewhere the view sees
    what the centre does not)."""
    n_rows, n_cols = disparity.shape
    _splat_view(disparity, nearness, q_y, q_x, warped, cells)
    for y in range(n_rows):
        for x in range(n_cols):
            landed[y, x] = warped[y, x] >= 0
    _fill_along_offset(warped, nearness, landed, q_y, q_x)
    empty = False
    for y in range(n_rows):
        _fill_row(warped, nearness, y)
        empty = empty or warped[y, 0] < 0  # a row is filled whole, or had nothing to fill from
    if empty:
        for x in range(n_cols):
            _fill_row(warped.T, nearness, x)


@njit(cache=True, inline="always")
def _bin_of(d, edges):
    """``searchsorted(edges, d, side="right") - 1`` clipped to the bins, for ``edges`` evenly spaced but
    for the outer two (made infinite): a guess from the spacing, corrected against the edges."""
    n_bins = edges.shape[0] - 1
    b = 0
    step = edges[2] - edges[1] if n_bins > 2 else 0.0
    if step > 0.0:
        guess = (d - edges[1]) / step + 1.0
        if guess >= n_bins - 1:
            b = n_bins - 1
        elif guess > 0.0:
            b = int(guess)
    while b > 0 and edges[b] > d:
        b -= 1
    while b < n_bins - 1 and edges[b + 1] <= d:
        b += 1
    return b


@njit(cache=True)
def _source_bins(disparity, edges):
    """The bin (int16) of every pixel of ``disparity (Y, X)``."""
    n_rows, n_cols = disparity.shape
    out = np.empty((n_rows, n_cols), np.int16)
    for y in range(n_rows):
        for x in range(n_cols):
            out[y, x] = _bin_of(disparity[y, x], edges)
    return out


@njit(cache=True)
def _sample_row(warped, landed, source_bins, confidence, y, sy, columns, out_bins, out_confidence, out_landed):
    """Row ``y`` of a view's sampled bins, confidence and landed flags: those of the samples row ``sy`` of
    the warped view (``warped``: flat indices into ``source_bins`` and ``confidence``) shows at
    ``columns``."""
    n_cols = warped.shape[1]
    out_bins[y] = -1
    out_confidence[y] = 0.0
    out_landed[y] = False
    if sy < 0 or sy >= warped.shape[0]:
        return
    for x in range(out_bins.shape[1]):
        sx = columns[x]
        if sx < 0 or sx >= n_cols:
            continue
        i = warped[sy, sx]
        if i < 0:
            continue
        out_bins[y, x] = source_bins[i]
        out_confidence[y, x] = confidence[i]
        out_landed[y, x] = landed[sy, sx]


@njit(cache=True)
def _shifted_bins_view(warped, landed, source_bins, confidence, dy, dx, out_bins, out_confidence, out_landed):
    """The bin ``(Y', X')`` of the surface a view's sample at ``p + (dy, dx)`` shows (nearest pixel of the
    warped view ``warped``, flat indices into ``source_bins`` and ``confidence``; -1 outside the view),
    its confidence, and whether it landed there."""
    n_rows, n_cols = warped.shape
    if not (abs(dy) < n_rows + 1.0 and abs(dx) < n_cols + 1.0):  # the view sees none of the image
        out_bins[:] = -1
        out_confidence[:] = 0.0
        out_landed[:] = False
        return
    columns = np.empty(out_bins.shape[1], np.int64)
    for x in range(out_bins.shape[1]):
        columns[x] = int(np.floor(x + dx + 0.5))
    for y in range(out_bins.shape[0]):
        _sample_row(warped, landed, source_bins, confidence, y, int(np.floor(y + dy + 0.5)), columns, out_bins,
                    out_confidence, out_landed)


@njit(cache=True, parallel=True)
def view_bins(disparity, confidence, nearness, positions, slope, edges, n_chunks, out_bins, out_confidence,
              out_landed):
    """For every view at ``positions (n, 2)``, the bin ``(n, Y', X')`` int16 of the surface its sample at
    ``p + slope * q_i`` shows, that surface's confidence, and whether a pixel of the disparity landed
    there (else the view sees what the centre of the aperture does not): ``disparity (Y, X)``
    forward-warped into the view (:func:`_warp_view`; ``nearness (Y, X)`` uint32 orders its samples,
    larger for the nearer surface), then sampled at the shift (:func:`_shifted_bins_view`) with the bin
    and ``confidence (Y, X)`` of the sample it shows; the views in ``n_chunks`` parallel chunks (one per
    thread: each makes its scratch once). The disparity may reach ``e`` px further than the output on
    every side (``Y = Y' + 2 e``): output pixel ``p`` is its pixel ``p + e``."""
    n_rows, n_cols = disparity.shape
    source_bins = _source_bins(disparity, edges).ravel()
    flat_confidence, flat_nearness = confidence.ravel(), nearness.ravel()
    extra = (n_rows - out_bins.shape[1]) // 2
    n = positions.shape[0]
    for chunk in prange(n_chunks):  # a thread's scratch made once, not per view: fresh pages cost as much
        warped = np.empty((n_rows, n_cols), np.int32)
        landed = np.empty((n_rows, n_cols), np.bool_)
        cells = np.empty((n_rows + 1, n_cols + 1), np.uint64)
        for i in range(chunk, n, n_chunks):
            q_y, q_x = positions[i, 0], positions[i, 1]
            _warp_view(disparity, flat_nearness, q_y, q_x, warped, landed, cells)
            _shifted_bins_view(warped, landed, source_bins, flat_confidence, slope * q_y + extra,
                               slope * q_x + extra, out_bins[i], out_confidence[i], out_landed[i])


@njit(cache=True, inline="always")
def _disoccluded_behind(bins, landed, weights, behind, i, y, x):
    """Whether view ``i``'s sample at ``(y, x)`` shows what the centre does not (not ``landed``) and is counted
    to a bin ``behind`` the in-focus one, with weight."""
    k = bins[i, y, x]
    return k >= 0 and not landed[i, y, x] and behind[k] and weights[i, y, x] > 0.0


@njit(cache=True, parallel=True)
def disoccluded_in_focus(values, weights, bins, landed, hidden, behind, sharp, least, agree, floor, positions, centres,
                         slope, checks, loose, others):
    """Give the in-focus bin ``sharp`` to the samples that show what the centre of the aperture does not (not
    ``landed``), counted to a bin ``behind`` the in-focus one, at the pixels where the centre sees a surface
    in front of the in-focus one (``hidden (Y, X)``), where at least ``least`` of them agree and
    their bin does not explain them. Agree: the standard deviation of their colour (root mean over the
    channels) at most ``loose`` times their mean colour's (``floor`` at least) where some of them can be
    checked against their bin, ``agree`` times where none can. Explained: each of the ``checks`` views
    nearest (``others (n, n - 1)``, each view's others nearest first) that shows the same point of the bin's
    surface (at ``p + (slope - centre) (q_i - q_j)``, a sample of that bin) shows it in about the same colour
    (within ``loose``); the bin does not explain them where most of those checked differ. ``positions (n,
    2)``, ``centres (K,)``: the views' and the bins'. ``bins (n, Y, X)`` is changed in place."""
    n, n_rows, n_cols = bins.shape
    n_ch = values.shape[3]
    # decided over the bins as they came in, then changed: a check reads other pixels' bins
    relabel = np.zeros((n_rows, n_cols), np.bool_)
    for y in prange(n_rows):
        total = np.zeros(n_ch, np.float64)
        squares = np.zeros(n_ch, np.float64)
        for x in range(n_cols):
            if not hidden[y, x]:
                continue
            count = 0
            weight = 0.0
            total[:] = 0.0
            squares[:] = 0.0
            for i in range(n):
                if not _disoccluded_behind(bins, landed, weights, behind, i, y, x):
                    continue
                w = weights[i, y, x]
                count += 1
                weight += w
                for c in range(n_ch):
                    v = values[i, y, x, c]
                    total[c] += w * v
                    squares[c] += w * v * v
            if count < least:
                continue
            spread = 0.0
            level = 0.0
            for c in range(n_ch):
                mean = total[c] / weight
                spread += max(squares[c] / weight - mean * mean, 0.0)
                level += abs(mean)
            level = max(level / n_ch, floor)
            checked = 0
            unexplained = 0
            for i in range(n):
                if not _disoccluded_behind(bins, landed, weights, behind, i, y, x):
                    continue
                k = bins[i, y, x]
                for m in range(min(checks, others.shape[1])):
                    j = others[i, m]
                    sy = int(np.floor(y + (slope - centres[k]) * (positions[i, 0] - positions[j, 0]) + 0.5))
                    sx = int(np.floor(x + (slope - centres[k]) * (positions[i, 1] - positions[j, 1]) + 0.5))
                    if not (0 <= sy < n_rows and 0 <= sx < n_cols) or bins[j, sy, sx] != k \
                            or not weights[j, sy, sx] > 0.0:
                        continue
                    checked += 1
                    differ = 0.0
                    for c in range(n_ch):
                        differ += abs(values[i, y, x, c] - values[j, sy, sx, c])
                    if differ / n_ch > loose * level:
                        unexplained += 1
            if checked > 0:
                if 2 * unexplained <= checked or np.sqrt(spread / n_ch) > loose * level:
                    continue
            elif np.sqrt(spread / n_ch) > agree * level:
                continue
            relabel[y, x] = True
    for y in prange(n_rows):
        for x in range(n_cols):
            if not relabel[y, x]:
                continue
            for i in range(n):
                if _disoccluded_behind(bins, landed, weights, behind, i, y, x):
                    bins[i, y, x] = sharp


@njit(cache=True, parallel=True)
def views_differ(bins, other_bins, confidence, other_confidence, out):
    """``out (Y, X)`` bool: whether any view's bin or confidence ``(n, Y, X)`` differs between the two."""
    n, n_rows, n_cols = bins.shape
    for y in prange(n_rows):
        out[y] = False
        for i in range(n):
            for x in range(n_cols):
                if bins[i, y, x] != other_bins[i, y, x] or confidence[i, y, x] != other_confidence[i, y, x]:
                    out[y, x] = True


@njit(cache=True, inline="always")
def _in_focus_colour_at(values, weights, bins, shows, share, least, y, x, colour, out_fill, out_has_fill):
    """:func:`in_focus_colour` at one pixel (``colour (C,)`` float32 scratch)."""
    n, n_ch = bins.shape[0], values.shape[3]
    colour[:] = 0.0
    total = np.float32(0.0)
    every = np.float32(0.0)
    for i in range(n):
        w = weights[i, y, x]
        every += w
        k = bins[i, y, x]
        if k < 0 or not shows[k] or not w > 0.0:
            continue
        total += w
        for c in range(n_ch):
            colour[c] += w * values[i, y, x, c]
    has = total >= share * max(every, least)
    out_has_fill[y, x] = has
    for c in range(n_ch):
        out_fill[y, x, c] = colour[c] / total if has else colour[c]


@njit(cache=True, parallel=True)
def in_focus_colour(values, weights, bins, shows, fill_share, out_fill, out_has_fill):
    """The weighted mean colour ``(Y, X, C)`` of the samples whose bin ``shows`` an in-focus background,
    and ``(Y, X)`` whether they hold at least ``fill_share`` of the pixel's whole sample weight (the
    colour is the plain weighted sum elsewhere). Sums run over the views in order, in float32."""
    n_rows, n_cols = bins.shape[1], bins.shape[2]
    share = np.float32(fill_share)
    least = np.float32(1e-6)
    for y in prange(n_rows):
        colour = np.zeros(values.shape[3], np.float32)
        for x in range(n_cols):
            _in_focus_colour_at(values, weights, bins, shows, share, least, y, x, colour, out_fill, out_has_fill)


@njit(cache=True, parallel=True)
def in_focus_colour_near(values, weights, bins, shows, fill_share, other_bins, other_fill, other_has_fill, out_fill,
                         out_has_fill):
    """:func:`in_focus_colour` for views' bins that are another's, ``other_bins`` (whose outputs are
    ``other_fill``, ``other_has_fill``), but here and there: made where any view's bin differs, the
    other's elsewhere (the same result)."""
    n, n_rows, n_cols = bins.shape
    share = np.float32(fill_share)
    least = np.float32(1e-6)
    for y in prange(n_rows):
        colour = np.zeros(values.shape[3], np.float32)
        differs = np.zeros(n_cols, np.bool_)
        for i in range(n):  # view by view: each view's row read in one pass
            for x in range(n_cols):
                differs[x] |= bins[i, y, x] != other_bins[i, y, x]
        for x in range(n_cols):
            if differs[x]:
                _in_focus_colour_at(values, weights, bins, shows, share, least, y, x, colour, out_fill,
                                    out_has_fill)
            else:
                out_has_fill[y, x] = other_has_fill[y, x]
                out_fill[y, x] = other_fill[y, x]


@njit(cache=True)
def _bin_boxes(bins, n_bins, origin, n_rows, n_cols):
    """The bounding box ``(K, 4)`` (y_lo, y_hi, x_lo, x_hi; y_hi < 0: empty) of each bin's samples, those a
    view lacks too (their boxes take stand-ins), in the window of ``n_rows x n_cols`` at ``origin`` of the
    grid of ``bins`` (its coordinates)."""
    boxes = np.empty((n_bins, 4), np.int64)
    boxes[:, 0] = n_rows
    boxes[:, 1] = -1
    boxes[:, 2] = n_cols
    boxes[:, 3] = -1
    for y in range(n_rows):
        for x in range(n_cols):
            k = bins[y + origin[0], x + origin[1]]
            if k < 0:
                continue
            boxes[k, 0] = min(boxes[k, 0], y)
            boxes[k, 1] = max(boxes[k, 1], y)
            boxes[k, 2] = min(boxes[k, 2], x)
            boxes[k, 3] = max(boxes[k, 3], x)
    return boxes


@njit(cache=True, inline="always")
def _accumulate(num, den, blurred, trust, y, x, t, colour, visible, confidence, blur, with_trust):
    """Add a layer's cell at ``(y, x)`` (colour ``colour``, coverage ``visible``) by the weight ``t``; its
    confidence to ``trust`` where ``with_trust``."""
    for c in range(num.shape[2]):
        num[y, x, c] += t * colour[c]
    den[y, x] += t * visible
    if blur:
        blurred[y, x] += t * visible
    if with_trust:
        trust[y, x] += t * confidence


@njit(cache=True)
def _stand_in(stack_values, stack_weights, stack_bins, others, i, k, r, positions, y, x, colour):
    """Whether another view shows the surface of bin ``k`` where view ``i`` lacks its sample at ``(y, x)``
    (of the whole grid); if so, its colour (bilinear; all four taps of that view hold a sample of that bin)
    into ``colour``.

    A point the view would show at ``p`` lies in view ``j``'s shifted samples at ``p + r (q_j - q_i)``
    (``r``: the surface's disparity less the slope); ``others``: the other views, nearest ``i`` first."""
    n_rows, n_cols = stack_bins.shape[1], stack_bins.shape[2]
    for j in others:
        sy = y + r * (positions[j, 0] - positions[i, 0])
        sx = x + r * (positions[j, 1] - positions[i, 1])
        y0, x0 = int(np.floor(sy)), int(np.floor(sx))
        if y0 < 0 or x0 < 0 or y0 + 1 >= n_rows or x0 + 1 >= n_cols:
            continue
        whole = True
        for yy in range(y0, y0 + 2):
            for xx in range(x0, x0 + 2):
                if not (stack_weights[j, yy, xx] > 0.0 and stack_bins[j, yy, xx] == k):
                    whole = False
        if not whole:
            continue
        fy, fx = sy - y0, sx - x0
        for c in range(colour.shape[0]):
            colour[c] = ((1.0 - fy) * ((1.0 - fx) * stack_values[j, y0, x0, c] + fx * stack_values[j, y0, x0 + 1, c])
                         + fy * ((1.0 - fx) * stack_values[j, y0 + 1, x0, c] + fx * stack_values[j, y0 + 1, x0 + 1, c]))
        return True
    return False


@njit(cache=True)
def _may_stand_in(known, z0, z, position, sampled, others, i, r):
    """Whether another view may stand in (:func:`_stand_in`) on line ``z`` of the grid along one axis:
    whether the two lines its taps fall on lie in the grid and each holds a sample of that view
    (``sampled (n, size)``: which lines of each view do; ``position``: the views' coordinate on the
    axis). ``known``: the answers so far for the lines from ``z0`` on (0: not yet asked, 1: yes, 2: no).
    A sample lacking where no view passes this test on both axes is passed over without looking for a
    stand-in."""
    if known[z - z0] == 0:
        size = sampled.shape[1]
        known[z - z0] = 2
        for j in others:
            s0 = int(np.floor(z + r * (position[j] - position[i])))
            if s0 >= 0 and s0 + 1 < size and sampled[j, s0] and sampled[j, s0 + 1]:
                known[z - z0] = 1
                break
    return known[z - z0] == 1


@njit(cache=True, parallel=True)
def sampled_lines(weights, rows, cols):
    """Which rows ``(n, Y)`` of each view's ``weights (n, Y, X)`` hold a sample, and a superset of its columns
    that do ``(n, X)``: those between the first and the last sample of some row (what
    :func:`_may_stand_in` needs: it never says no where a view may stand in)."""
    n_cols = weights.shape[2]
    for i in prange(weights.shape[0]):
        rows[i] = False
        cols[i] = False
        for y in range(weights.shape[1]):
            first = 0
            while first < n_cols and not weights[i, y, first] > 0.0:
                first += 1
            if first == n_cols:
                continue
            last = n_cols - 1
            while not weights[i, y, last] > 0.0:
                last -= 1
            rows[i, y] = True
            cols[i, first:last + 1] = True


@njit(cache=True, inline="always")
def _validity(z, size):
    """The validity of a view's sample at ``z`` of its own ``size`` px (its bilinear taps inside: 1 within the
    image, falling to 0 one pixel beyond its edge), as the naive refocus and the dense references weigh it."""
    return min(max(min(z + 1.0, size - z), 0.0), 1.0)


@njit(cache=True)
def _data_weight(weights, y, x, origin, window, own, image_shape):
    """The weight of a view's data at ``(y, x)`` of the window ``window (rows, cols)`` at ``origin`` of the
    grid (``weights``: the whole grid's) whatever its own sample's validity there: its weight there over that
    validity, or where it has no sample (beyond its own image), its weight at the nearest pixel of the window
    it samples; ``own``: the view's shift (grid pixel + ``own``: where in its image the view samples it)."""
    u_y, u_x = y + origin[0] + own[0], x + origin[1] + own[1]
    valid = _validity(u_y, image_shape[0]) * _validity(u_x, image_shape[1])
    if valid > 0.0:
        return weights[y + origin[0], x + origin[1]] / valid
    y_in = int(np.floor(min(max(u_y, 0.0), image_shape[0] - 1.0) - own[0] - origin[0] + 0.5))
    x_in = int(np.floor(min(max(u_x, 0.0), image_shape[1] - 1.0) - own[1] - origin[1] + 0.5))
    if y_in < 0 or x_in < 0 or y_in >= window[0] or x_in >= window[1]:
        return 0.0
    valid = _validity(y_in + origin[0] + own[0], image_shape[0]) * _validity(x_in + origin[1] + own[1], image_shape[1])
    return weights[y_in + origin[0], x_in + origin[1]] / valid if valid > 0.0 else 0.0


@njit(cache=True)
def _field_taps(u, a, n, f, size, out):
    """Weights ``out (2 n + 3,)`` of a box's taps ``-(n + 1) .. n + 1`` (``n`` full taps each side of the centre,
    end taps of weight ``f``) where the tap at offset ``t`` stands for the virtual view whose sample lies at
    ``u + a t`` in its own image of ``size`` px: each tap by the share of it whose view holds that sample (the
    bilinear validity of a view's sample, 1 inside, falling to 0 one pixel beyond the edge). Returns whether
    every tap holds its sample (``out`` is then the box's own taps)."""
    half = n + 0.5 + f
    full = u - abs(a) * half >= 0.0 and u + abs(a) * half <= size - 1.0
    steps = 8
    for t in range(2 * n + 3):
        d = t - (n + 1)
        lo, hi = max(d - 0.5, -half), min(d + 0.5, half)
        out[t] = 0.0
        if hi <= lo:
            continue
        if full:
            out[t] = hi - lo
            continue
        step = (hi - lo) / steps
        for m in range(steps):
            z = u + a * (lo + (m + 0.5) * step)
            out[t] += step * _validity(z, size)
    return full


@njit(cache=True, inline="always")
def _tap_sum(taps, first, source, out):
    """``out (C,)`` = the sum of ``taps[t] * source[first + t]`` over the taps that fall in ``source (N, C)``."""
    for c in range(out.shape[0]):
        out[c] = 0.0
    for t in range(taps.shape[0]):
        j = first + t
        w = taps[t]
        if w <= 0.0 or j < 0 or j >= source.shape[0]:
            continue
        for c in range(out.shape[0]):
            out[c] += w * source[j, c]


#: A bin's box is summed pixel by pixel (:func:`_box_scatter`) where that costs less than this share of the
#: separable passes over its layer (an outline's few pixels in a box around the whole image).
SCATTER_SHARE = 2.0


@njit(cache=True, inline="always")
def _box_weight(offset, n, f):
    """The weight of a box's tap ``offset`` px from its centre: 1 within ``n``, ``f`` at ``n + 1``."""
    return f if abs(offset) == n + 1 else 1.0


@njit(cache=True)
def _box_scatter(layer, ny, fy, nx, fx, n_ch, hides, out):
    """:func:`~napari_lfalias._baseline_kernels.box_image_into` of a sparse ``layer (Y, X, K)`` into ``out``,
    where it counts: each pixel of the bin (coverage, plane ``n_ch``) adds its colour, coverage and
    confidence to the box around it; with ``hides``, the hidden plane (the last) is summed only where
    the bin covers something, the only pixels whose composite reads it."""
    n_rows, n_cols, n_k = layer.shape
    n_spread = n_k - 1 if hides else n_k
    out[:] = 0.0
    for y in range(n_rows):
        for x in range(n_cols):
            if not layer[y, x, n_ch] > 0.0:
                continue
            for ty in range(max(y - ny - 1, 0), min(y + ny + 2, n_rows)):
                wy = _box_weight(ty - y, ny, fy)
                for tx in range(max(x - nx - 1, 0), min(x + nx + 2, n_cols)):
                    w = np.float32(wy * _box_weight(tx - x, nx, fx))
                    for c in range(n_spread):
                        out[ty, tx, c] += w * layer[y, x, c]
    if not hides:
        return
    for y in range(n_rows):
        for x in range(n_cols):
            if not out[y, x, n_ch] > 0.0:
                continue
            hidden = np.float32(0.0)
            for ty in range(max(y - ny - 1, 0), min(y + ny + 2, n_rows)):
                wy = _box_weight(ty - y, ny, fy)
                for tx in range(max(x - nx - 1, 0), min(x + nx + 2, n_cols)):
                    if layer[ty, tx, n_k - 1] > 0.0:
                        hidden += np.float32(wy * _box_weight(tx - x, nx, fx)) * layer[ty, tx, n_k - 1]
            out[y, x, n_k - 1] = hidden


@njit(cache=True)
def _no_taps(taps):
    """Which rows of ``taps (m, T)`` weigh nothing (all taps <= 0)."""
    out = np.ones(taps.shape[0], np.bool_)
    for m in range(taps.shape[0]):
        for t in range(taps.shape[1]):
            if taps[m, t] > 0.0:
                out[m] = False
                break
    return out


@njit(cache=True, inline="always")
def _mark_taps(taps, first, out):
    """Mark in ``out`` the entries ``first + t`` that :func:`_tap_sum` reads: those its taps weigh."""
    for t in range(taps.shape[0]):
        j = first + t
        if taps[t] > 0.0 and 0 <= j < out.shape[0]:
            out[j] = True


@njit(cache=True)
def _with_moments(layer, n_planes, first):
    """Set the moment planes of ``layer (Y, X, K)``: for each of its first ``n_planes`` planes ``L``, the
    planes ``first + 2 c`` and ``first + 2 c + 1`` hold ``y L`` and ``x L`` (the layer's own coordinates).
    Boxed, they give a box's first moments about each pixel ``p``: ``box(y L) - p_y box(L)`` is the sum
    of ``t_y L(p + t)`` over the box's taps ``t`` (:func:`_across_cell`)."""
    for y in range(layer.shape[0]):
        for x in range(layer.shape[1]):
            for c in range(n_planes):
                value = layer[y, x, c]
                layer[y, x, first + 2 * c] = y * value
                layer[y, x, first + 2 * c + 1] = x * value


@njit(cache=True, inline="always")
def _inside(own, image_shape, j, y, x):
    """Whether view ``j``'s sample at ``(y, x)`` of the grid lies inside its image (:func:`_validity` 1)."""
    return _validity(y + own[j, 0], image_shape[0]) >= 1.0 and _validity(x + own[j, 1], image_shape[1]) >= 1.0


#: The weights' slopes across the aperture (:func:`_weight_slopes`) are taken at the centre of each block of
#: this many pixels a side: a vignette changes little over a few pixels, and at every pixel they cost as much
#: as the rest of a vignetted composite (8x8 views).
SLOPE_BLOCK = 4


@njit(cache=True)
def _weight_slopes(weights, neighbours, positions, own, image_shape, i, origin, n_rows, n_cols, out):
    """How the sample weights change across the aperture at view ``i`` (per unit of view position), on
    both axes over the window of ``n_rows x n_cols`` at ``origin`` of the grid, at the centre of each block
    of :data:`SLOPE_BLOCK` px a side, into ``out (2, by, bx)``: the difference of the weights of its
    neighbours before and after it on the axis (``neighbours (n, 2, 2)``, -1: none), or of one neighbour's
    and its own at the grid's edge, each neighbour where its sample lies inside its image with a weight
    > 0; 0 where fewer than two views are left or the view's own sample is not inside. Across the cell
    (half a view step either way) the weight is not let fall below 0."""
    for by in range(out.shape[1]):
        gy = min(by * SLOPE_BLOCK + SLOPE_BLOCK // 2, n_rows - 1) + origin[0]
        for bx in range(out.shape[2]):
            gx = min(bx * SLOPE_BLOCK + SLOPE_BLOCK // 2, n_cols - 1) + origin[1]
            y, x = by, bx
            out[0, y, x] = 0.0
            out[1, y, x] = 0.0
            w = weights[i, gy, gx]
            if not (w > 0.0 and _inside(own, image_shape, i, gy, gx)):
                continue
            for axis in range(2):
                before, after = neighbours[i, axis, 0], neighbours[i, axis, 1]
                if before >= 0 and not (weights[before, gy, gx] > 0.0 and _inside(own, image_shape, before, gy, gx)):
                    before = -1
                if after >= 0 and not (weights[after, gy, gx] > 0.0 and _inside(own, image_shape, after, gy, gx)):
                    after = -1
                if before < 0 and after < 0:
                    continue
                step = 1.0
                if before < 0:
                    before = i
                elif after < 0:
                    after = i
                else:
                    step = 0.5
                span = positions[after, axis] - positions[before, axis]
                slope = (weights[after, gy, gx] - weights[before, gy, gx]) / span
                bound = 2.0 * w / abs(step * span)
                out[axis, y, x] = min(max(slope, -bound), bound)


@njit(cache=True, inline="always")
def _across_cell(cell, ly, lx, slope_y, slope_x, wr, first, out):
    """A blurred cell's colour and coverage ``out (C + 1,)`` under the sample weights across view ``i``'s
    aperture cell, where those vary (a vignette); returns whether they do.

    The box's tap at offset ``t`` stands for the view at ``q_i - t / r``
    (:func:`_composite_view`), whose weight at the pixel is, to first
    order, ``w - g . t / r`` for the weight ``w`` the cell counts by and
    its slope ``g`` across the aperture (``slopes``, :func:`_weight_slopes`). Weighted
    so, the box mean of a plane ``L`` is ``w (box(L) - g . m / (w r))``
    for the box's first moments ``m`` about the pixel (:func:`_with_moments`);
    ``out`` holds the bracket's share of ``w``, so the cell still counts by
    ``w``. Counted by ``w`` alone, each view weighed its cell by its own
    sample's weight: with a calibrated vignette the rendering with the true
    disparity was 12 dB less exact than without one (fresh 1402 of the
    accuracy benchmark at slope 1.0: 44.9 dB against 56.9; 51.3 weighed
    so). The weights between the views are interpolated linearly: on a
    one-dimensional model of the benchmark's fall-off
    (``benchmarks/results/vignette_cell_weights.md``) a cell weighed so
    erred 1.4 to 15 times less than at a constant weight, and less than
    under a parabola through three views; a cubic spline through all of
    them erred up to half as much on five views, more on three.

    ``(ly, lx)``: the pixel in the layer whose box means (and their moments
    from plane ``first`` on) ``cell`` holds; ``wr``: ``w r``.
    """
    if wr == 0.0 or (slope_y == 0.0 and slope_x == 0.0):
        return False
    for c in range(out.shape[0]):
        plain = cell[c]
        moment_y = cell[first + 2 * c] - ly * plain
        moment_x = cell[first + 2 * c + 1] - lx * plain
        out[c] = plain - (slope_y * moment_y + slope_x * moment_x) / wr
    return out[out.shape[0] - 1] > 0.0


@njit(cache=True)
def _composite_view(values, weights, bins, confidence, order, occluders, taps, box_taps, fill, has_fill, num, den,
                    blurred, trust, with_trust, covers, seen, slopes, scratch, whole, i, origin):
    """Composite one view's bins front to back into the accumulators (one thread).

    The bin at ``order[o]`` is seen through the bins ``order[:occluders[o] + 1]``
    (those clearly nearer); bins of about the same depth, parts of one
    surface, add up instead of hiding each other. What no bin covers of the
    view's cell (a surface this view does not see behind an occluder's
    blurred edge) is the in-focus surface the other views see there,
    ``fill``, where ``has_fill``. Where a clearly nearer bin hides a
    blurred bin in this view, the hidden surface goes on behind it with
    the colour of what is seen of it nearby: its blur reaches under the
    occluder, which is what the rays between the views see there (left out,
    the occluder's colour took the gap: a halo along its outline). A
    blurred bin's box stands for the views of the view's cell: its tap at
    offset ``t`` for the one at ``q_i - t / r``, which samples the pixel at
    ``p + slope * q_i - slope * t / r`` of its own image. Where that lies
    beyond the image the tap counts by its validity there, as the naive
    refocus and a dense aperture count a view's samples, and the cell by
    the share of its box that counts (:func:`_field_taps`; whatever its own
    sample's validity, :func:`_data_weight`). Where the view itself has no
    sample under a tap that counts (beyond its own image), the tap takes
    what another view shows of its surface there (:func:`_stand_in`).
    Cutting the box at the view's own samples holds only for a surface at
    disparity 0, keeping it whole only at slope 0: each was off at the
    image's edge elsewhere (the lenslet captures at slope +-5, the
    camera-array noise wall at slope -1). Layers hold unit coverage; the
    view's cell at a pixel counts by the weight of the view's sample there,
    and where the light field's weights vary across the aperture (``graded``:
    a vignette) its box weighs each tap as the weights vary between the
    view and its neighbours (:func:`_across_cell`). A bin in focus (no blur)
    is its samples as they are: it is added without a layer. Which bins are blurred is
    ``taps (K, 4)``'s; the box each is blurred by in this view is
    ``box_taps (K, 4)``'s (narrowed by the blur the view's resampling gave
    it, :func:`napari_lfalias.render._view_taps`).

    ``values``, ``weights``, ``bins``, ``confidence``, ``fill`` and
    ``has_fill`` are the view's over the whole grid, read in the window at
    ``origin``; the accumulators and ``seen`` are the window's.
    ``with_trust``: whether the confidence is composited into ``trust`` (a
    plane of the layers less where not).

    ``covers (K, Y, X)``, ``seen (Y, X)``, ``slopes (2, Y / b, X / b)``
    (where ``graded``; ``b``: :data:`SLOPE_BLOCK`) and ``scratch (3, Y * X * P)`` (``P``: ``C + 3``, and
    ``2 (C + 1)`` more where ``graded``) are scratch: each bin's blurred
    coverage (within its reach), the share of the cell the bins composited
    so far leave free, brought up to ``occluders[o]`` as ``o`` advances
    (``occluders`` never decreases along ``order``), the view's weights'
    slopes across the aperture (:func:`_weight_slopes`), and a blurred bin's
    layer, its box sum and the box's intermediate pass. ``whole``: ``(values, weights, bins, positions,
    residual, others, own, image_shape, slope, sampled_rows, sampled_cols,
    neighbours, graded)``: every view over the whole grid, the bins'
    disparities less the slope ``(K,)``, each view's others nearest first
    ``(n, n - 1)``, each view's shift ``(n, 2)`` (grid pixel + ``own[i]``:
    where view ``i`` samples it in its own image), the image's ``(Y, X)``,
    the slope, which rows ``(n, Y)`` and columns ``(n, X)`` of each view may
    hold a sample (:func:`sampled_lines`), each view's neighbours on each
    axis ``(n, 2, 2)`` (:func:`_weight_slopes`), and whether the light field
    has weights of its own (:attr:`~napari_lfalias.refocus.ShiftedStack.graded`);
    ``i``: this view; ``origin``: where this
    window's ``(0, 0)`` lies in the whole grid.
    """
    n_rows, n_cols = seen.shape
    n_ch = values.shape[2]
    oy, ox = origin[0], origin[1]  # the window in the grid, read as np.uint64(y + oy), np.uint64(x + ox):
    # unsigned, numba leaves out the negative-index wrap of each read (signed, the kernel took 5-15 % longer)
    n_order = order.shape[0]
    all_values, all_weights, all_bins, positions, residual, others, own, image_shape, slope, sampled_rows, \
        sampled_cols, neighbours, graded = whole
    boxes = _bin_boxes(bins, taps.shape[0], origin, n_rows, n_cols)
    rank = np.empty(n_order, np.int64)  # each bin's position in order
    for o in range(n_order):
        rank[order[o]] = o
    reach = np.full((n_order, 4), -1, np.int64)  # each bin's blurred extent y0, y1, x0, x1 (exclusive ends)
    ramped = np.empty(n_ch + 1, np.float32)  # a cell's colour and coverage under its aperture's weights
    sloped = False  # whether slopes holds this view's
    one = np.float32(1.0)
    seen[:] = 1.0
    lagged = -1  # seen holds the bins order[:lagged + 1]
    for o in range(n_order):
        k = order[o]
        while lagged < occluders[o]:
            lagged += 1
            y0, y1, x0, x1 = reach[lagged, 0], reach[lagged, 1], reach[lagged, 2], reach[lagged, 3]
            for y in range(y0, y1):
                for x in range(x0, x1):
                    seen[y, x] *= 1.0 - covers[lagged, y, x]
        y_lo, y_hi, x_lo, x_hi = boxes[k, 0], boxes[k, 1], boxes[k, 2], boxes[k, 3]
        if y_hi < 0:
            continue
        blur = taps[k, 0] > 0 or taps[k, 1] > 0.0 or taps[k, 2] > 0 or taps[k, 3] > 0.0
        ny, fy, nx, fx = box_taps[k, 0], box_taps[k, 1], box_taps[k, 2], box_taps[k, 3]
        hides = occluders[o] >= 0
        reach_y = int(ny) + 1 if blur else 0
        reach_x = int(nx) + 1 if blur else 0
        if blur and hides:  # a box within reach of a sample reads the hidden plane as far again
            reach_y, reach_x = 2 * reach_y, 2 * reach_x
        y0, y1 = max(0, y_lo - reach_y), min(n_rows, y_hi + reach_y + 1)
        x0, x1 = max(0, x_lo - reach_x), min(n_cols, x_hi + reach_x + 1)
        reach[o, 0], reach[o, 1], reach[o, 2], reach[o, 3] = y0, y1, x0, x1
        if not blur:  # the samples themselves, unit coverage
            for y in range(y0, y1):
                for x in range(x0, x1):
                    gy, gx = np.uint64(y + oy), np.uint64(x + ox)
                    if bins[gy, gx] != k or not weights[gy, gx] > 0.0:
                        covers[o, y, x] = 0.0
                        continue
                    covers[o, y, x] = 1.0
                    t = (seen[y, x] if occluders[o] >= 0 else 1.0) * weights[gy, gx]
                    if t > 0.0:
                        _accumulate(num, den, blurred, trust, y, x, t, values[gy, gx], one, confidence[gy, gx], False,
                                    with_trust)
            continue
        # planes: the colour, the coverage, with_trust the confidence, where graded the moments of the colour
        # and coverage (_with_moments), and where hides the last: where nearer bins hide this one
        moments = n_ch + 1 + (1 if with_trust else 0)
        n_layer = moments + (2 * (n_ch + 1) if graded else 0) + (1 if hides else 0)
        size = (y1 - y0) * (x1 - x0) * n_layer
        scratch[0, :size] = 0.0
        layer = scratch[0, :size].reshape((y1 - y0, x1 - x0, n_layer))
        held = 0  # the layer's pixels that hold something
        rows_in = np.zeros(y_hi + 1 - y_lo, np.int8)  # where another view may stand in (_may_stand_in)
        cols_in = np.zeros(x_hi + 1 - x_lo, np.int8)
        for y in range(y_lo, y_hi + 1):
            for x in range(x_lo, x_hi + 1):
                gy, gx = np.uint64(y + oy), np.uint64(x + ox)
                if bins[gy, gx] != k:
                    continue
                if weights[gy, gx] > 0.0:
                    for c in range(n_ch):
                        layer[y - y0, x - x0, c] = values[gy, gx, c]
                elif not (_may_stand_in(rows_in, y_lo + origin[0], y + origin[0], positions[:, 0], sampled_rows,
                                        others[i], i, residual[k])
                          and _may_stand_in(cols_in, x_lo + origin[1], x + origin[1], positions[:, 1], sampled_cols,
                                            others[i], i, residual[k])
                          and _stand_in(all_values, all_weights, all_bins, others[i], i, k, residual[k], positions,
                                        y + origin[0], x + origin[1], layer[y - y0, x - x0, :n_ch])):
                    continue
                layer[y - y0, x - x0, n_ch] = 1.0
                if with_trust:
                    layer[y - y0, x - x0, n_ch + 1] = confidence[gy, gx]
                held += 1
        if hides:  # where a clearly nearer bin hides this one in this view, this surface goes on behind it
            for y in range(y0, y1):
                for x in range(x0, x1):
                    gy, gx = np.uint64(y + oy), np.uint64(x + ox)
                    b = bins[gy, gx]
                    if b >= 0 and rank[b] <= occluders[o] and weights[gy, gx] > 0.0:
                        layer[y - y0, x - x0, n_layer - 1] = 1.0
        if graded:
            _with_moments(layer, n_ch + 1, moments)
            if not sloped:  # the weights' slopes across the aperture, once a view
                _weight_slopes(all_weights, neighbours, positions, own, image_shape, i, origin, n_rows, n_cols,
                               slopes)
                sloped = True
        summed = scratch[1, :size].reshape((y1 - y0, x1 - x0, n_layer))
        box = (2 * int(ny) + 3) * (2 * int(nx) + 3)
        spread = held * box * (1 + box if hides else 1)  # the scatter, and the gather of the hidden plane
        if spread < SCATTER_SHARE * size:
            _box_scatter(layer, int(ny), fy, int(nx), fx, n_ch, hides, summed)
        else:
            box_image_into(layer, int(ny), fy, int(nx), fx, summed, scratch[2, :size].reshape(summed.shape))
        area = np.float32((2 * ny + 1 + 2 * fy) * (2 * nx + 1 + 2 * fx))
        means = scratch[1, :size]  # the box sums become means in place
        for j in range(size):
            means[j] /= area
        # a box stands for the views between this view's neighbours: where some of them lack their sample
        # (beyond the image's edge, as this view's own may) their taps do not count
        a = -slope / residual[k]
        tap_y = np.empty((y1 - y0, 2 * int(ny) + 3))
        tap_x = np.empty((x1 - x0, 2 * int(nx) + 3))
        full_y = np.empty(y1 - y0, np.bool_)
        full_x = np.empty(x1 - x0, np.bool_)
        for y in range(y0, y1):
            full_y[y - y0] = _field_taps(y + origin[0] + own[i, 0], a, int(ny), fy, image_shape[0], tap_y[y - y0])
        for x in range(x0, x1):
            full_x[x - x0] = _field_taps(x + origin[1] + own[i, 1], a, int(nx), fx, image_shape[1], tap_x[x - x0])
        # the taps are separable: the pixels whose box reaches beyond an image sum along x (into the box
        # pass's scratch, free now), then along y. A pixel whose taps along either axis are all 0 (no view
        # of its cell holds a sample) sums to 0; the rows the others read are those their taps weigh: in a
        # column cut off, those of any row, elsewhere those of the rows cut off
        if not (full_y.all() and full_x.all()):  # else the box sums stand as they are
            across = scratch[2, :size].reshape((y1 - y0, x1 - x0, n_layer))
            none_y, none_x = _no_taps(tap_y), _no_taps(tap_x)
            reads = np.zeros(y1 - y0, np.bool_)  # by the rows cut off
            reads_any = np.zeros(y1 - y0, np.bool_)  # by any row
            for y in range(y1 - y0):
                if not none_y[y]:
                    _mark_taps(tap_y[y], y - int(ny) - 1, reads_any)
                    if not full_y[y]:
                        _mark_taps(tap_y[y], y - int(ny) - 1, reads)
            for yy in range(y0, y1):
                for x in range(x0, x1):
                    if not none_x[x - x0] and (reads_any[yy - y0] if not full_x[x - x0] else reads[yy - y0]):
                        _tap_sum(tap_x[x - x0], x - x0 - int(nx) - 1, layer[yy - y0], across[yy - y0, x - x0])
            for y in range(y0, y1):
                for x in range(x0, x1):
                    if full_y[y - y0] and full_x[x - x0]:
                        continue
                    if none_y[y - y0] or none_x[x - x0]:
                        summed[y - y0, x - x0] = 0.0
                        continue
                    _tap_sum(tap_y[y - y0], y - y0 - int(ny) - 1, across[:, x - x0], summed[y - y0, x - x0])
                    for c in range(n_layer):  # over the whole box: the cell counts by the share that holds samples
                        summed[y - y0, x - x0, c] /= area
        for y in range(y0, y1):
            for x in range(x0, x1):
                visible = summed[y - y0, x - x0, n_ch]
                # what the nearer bins hide of this surface has the colour of what is seen of it nearby
                scale = (visible + summed[y - y0, x - x0, n_layer - 1]) / visible if hides and visible > 0.0 else 1.0
                cover = min(visible * scale, 1.0)
                covers[o, y, x] = cover
                if cover <= 0.0:
                    continue
                w = weights[np.uint64(y + oy), np.uint64(x + ox)]
                if not (full_y[y - y0] and full_x[x - x0]):  # the cell's valid share is in its coverage already
                    w = _data_weight(weights, y, x, origin, seen.shape, own[i], image_shape)
                t = (seen[y, x] if occluders[o] >= 0 else 1.0) * w  # the cell counts by its weight
                if t <= 0.0:
                    continue
                t *= scale
                cell = summed[y - y0, x - x0]
                if graded and _inside(own, image_shape, i, y + origin[0], x + origin[1]) and _across_cell(
                        cell, y - y0, x - x0, slopes[0, y // SLOPE_BLOCK, x // SLOPE_BLOCK],
                        slopes[1, y // SLOPE_BLOCK, x // SLOPE_BLOCK], w * residual[k], moments, ramped):
                    cell, visible = ramped, ramped[n_ch]
                _accumulate(num, den, blurred, trust, y, x, t, cell, visible,
                            summed[y - y0, x - x0, n_ch + 1] if with_trust else 0.0, True, with_trust)
    while lagged < n_order - 1:  # what every bin leaves free
        lagged += 1
        y0, y1, x0, x1 = reach[lagged, 0], reach[lagged, 1], reach[lagged, 2], reach[lagged, 3]
        for y in range(y0, y1):
            for x in range(x0, x1):
                seen[y, x] *= 1.0 - covers[lagged, y, x]
    for y in range(n_rows):
        for x in range(n_cols):
            gy, gx = np.uint64(y + oy), np.uint64(x + ox)
            t = seen[y, x] * weights[gy, gx]
            if t > 0.0 and has_fill[gy, gx]:
                _accumulate(num, den, blurred, trust, y, x, t, fill[gy, gx], one, one, False, with_trust)


@njit(cache=True, parallel=True)
def composite_views(values, weights, bins, confidence, order, occluders, taps, view_taps, fill, has_fill, grid,
                    origin, n_chunks, num, den, blurred, trust, with_trust):
    """Every view's layered composite over a window of the grid, summed: ``num (n_chunks, Y, X, C)`` and
    the coverage ``den``, the coverage of blurred bins ``blurred`` and, where ``with_trust``, the
    confidence-weighted coverage ``trust`` (each ``(n_chunks, Y, X)``, the window's size; ``trust`` left as
    it is otherwise), one chunk of views per thread.

    ``values (n, Y', X', C)``, ``weights``, ``bins`` and ``confidence (n, Y', X')``: the views over the
    whole grid, read in the window at ``origin`` (``(y, x)``, its ``(0, 0)`` in the grid) in place, as are
    ``fill (Y', X', C)`` and ``has_fill (Y', X')``. ``taps (K, 4)``: the box of each bin as
    ``(n_y, f_y, n_x, f_x)`` (see
    :func:`napari_lfalias.baselines._box_taps`), ``view_taps (n, K, 4)``: the box each view blurs it by
    (see :func:`_composite_view`); ``order``: bins front to back; ``occluders``: for each
    position in ``order``, the last position whose bins hide it (-1: none); ``fill`` and ``has_fill``: the
    in-focus surface behind occluders' edges; ``grid``: what else the stand-ins of samples a view lacks
    read and how a vignette's cells are weighed, ``whole`` of :func:`_composite_view` less its first three (the
    views over the grid).
    """
    n = bins.shape[0]
    n_rows, n_cols = den.shape[1], den.shape[2]
    for chunk in prange(n_chunks):
        covers = np.empty((order.shape[0], n_rows, n_cols), np.float32)
        seen = np.empty((n_rows, n_cols), np.float32)
        planes = values.shape[3] + 3 + (2 * (values.shape[3] + 1) if grid[-1] else 0)
        scratch = np.empty((3, n_rows * n_cols * planes), np.float32)
        blocks = ((n_rows + SLOPE_BLOCK - 1) // SLOPE_BLOCK, (n_cols + SLOPE_BLOCK - 1) // SLOPE_BLOCK)
        slopes = np.empty((2,) + blocks if grid[-1] else (2, 1, 1), np.float32)
        for i in range(chunk, n, n_chunks):
            _composite_view(values[i], weights[i], bins[i], confidence[i], order, occluders, taps, view_taps[i],
                            fill, has_fill, num[chunk], den[chunk], blurred[chunk], trust[chunk], with_trust, covers,
                            seen, slopes, scratch, (values, weights, bins) + grid, i, origin)


@njit(cache=True, parallel=True)
def single_surface(bins, weights, out):
    """``out (Y, X)`` int16: the bin that every view's sample shows at ``(y, x)`` with weight exactly 1 (of
    ``bins`` and ``weights (n, Y, X)``), -1 where the views' bins differ or a weight is not 1."""
    n, n_rows, n_cols = bins.shape
    for y in prange(n_rows):
        row = out[y]
        for x in range(n_cols):
            row[x] = bins[0, y, x] if weights[0, y, x] == 1.0 else -1
        for i in range(1, n):
            view_bins, view_weights = bins[i, y], weights[i, y]
            for x in range(n_cols):
                if view_bins[x] != row[x] or view_weights[x] != 1.0:
                    row[x] = -1


@njit(cache=True, parallel=True)
def group_sums(values, confidence, group, origin, out):
    """``out (G, Y, X, C + 1)`` float32: the colour ``values (n, Y', X', C)`` and the confidence ``(n, Y',
    X')`` of the views of each group (``group (n,)``: each view's, ``0 .. G - 1``) summed, over the window of
    ``out``'s ``Y x X`` at ``origin`` of the views' grid."""
    n, n_ch = values.shape[0], values.shape[3]
    n_rows, n_cols = out.shape[1], out.shape[2]
    for y in prange(n_rows):
        out[:, y] = 0.0
        gy = np.uint64(y + origin[0])
        for i in range(n):
            total = out[group[i], y]
            for x in range(n_cols):
                gx = np.uint64(x + origin[1])
                for c in range(n_ch):
                    total[x, c] += values[i, gy, gx, c]
                total[x, n_ch] += confidence[i, gy, gx]
