"""Numba kernels of the disparity estimator (:mod:`napari_lfalias.disparity`).

``sweep_costs`` is the plane sweep: for each (slope, image row segment)
work item, every view's feature planes are resampled bilinearly at
``p + slope * q_i`` (one vectorisable loop per view and channel), compared
with the reference (the mean of the central views at the same slope), and
the squared differences are summed per view group. The cost of a pixel is
the smallest group mean (occlusion-aware: a half of the aperture that does
not see an occluder wins).

``wls_rows`` solves the one-dimensional weighted-least-squares systems of
the fast global smoother (Min et al. 2014) along every row: tridiagonal,
solved by the Thomas algorithm, rows in parallel; a link between neighbours
weakens where the guide image or a trusted depth changes.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

__all__ = ["feature_planes", "sweep_costs", "agreeing_shares", "wls_rows", "box_mean_stack", "guided_windows", "subslope_offsets",
           "shear_slices", "unshear_min", "winner_scan", "relative_costs"]


@njit(cache=True, parallel=True)
def feature_planes(lum, weight, out):
    """``out (n, 3, Y, X)`` float32: the luminance ``lum (n, Y, X)`` and its central differences down the
    columns and along the rows times ``weight`` (float32, 0 on the first and last row or column); rows of
    every view in parallel, each page written once."""
    n, n_rows, n_cols = lum.shape
    for job in prange(n * n_rows):
        i, y = job // n_rows, job % n_rows
        row = lum[i, y]
        out[i, 0, y] = row
        down, along = out[i, 1, y], out[i, 2, y]
        if 0 < y < n_rows - 1:
            above, below = lum[i, y - 1], lum[i, y + 1]
            for x in range(n_cols):
                down[x] = (below[x] - above[x]) * weight
        else:
            down[:] = 0.0
        if n_cols == 0:
            continue
        along[0] = 0.0
        along[n_cols - 1] = 0.0
        for x in range(1, n_cols - 1):
            along[x] = (row[x + 1] - row[x - 1]) * weight


@njit(cache=True, inline="always")
def _taps(shift, n):
    """Integer part, fraction (snapped to 0 near whole pixels) and the output range ``[lo, hi)``
    of a shift along an axis of length ``n`` whose taps all lie inside (none for a shift of ``n`` or more)."""
    if not abs(shift) < n:
        return 0, 0.0, 0, 0
    base = int(np.floor(shift))
    frac = shift - base
    if frac > 1.0 - 1e-6:
        base += 1
        frac = 0.0
    elif frac < 1e-6:
        frac = 0.0
    lo = max(0, -base)
    hi = min(n, n - base - (1 if frac > 0.0 else 0))
    return base, frac, lo, max(hi, lo)


@njit(cache=True, inline="always")
def _add_view(features, valid, has_valid, i, by, fy, bx, fx, y0, y1, x_lo, x_hi, x0, weight, sums, count):
    """Add ``weight`` x the bilinear samples of view ``i`` to ``sums (rows, K, width)`` and its validity to
    ``count (rows, width)``, for tile rows ``y0 .. y1`` and columns ``x_lo .. x_hi`` (absolute)."""
    n_feat = features.shape[1]
    a = np.float32((1.0 - fy) * (1.0 - fx)) * weight
    b = np.float32((1.0 - fy) * fx) * weight
    c = np.float32(fy * (1.0 - fx)) * weight
    d = np.float32(fy * fx) * weight
    step_y = 1 if fy > 0.0 else 0
    step_x = 1 if fx > 0.0 else 0
    width = x_hi - x_lo
    seen = np.ones(width, np.float32)
    for y in range(y0, y1):
        r0 = y + by
        r = y - y0
        if has_valid:
            v0 = valid[i, r0, x_lo + bx:x_hi + bx + step_x]
            v1 = valid[i, r0 + step_y, x_lo + bx:x_hi + bx + step_x]
            for x in range(width):
                seen[x] = min(min(v0[x], v0[x + step_x]), min(v1[x], v1[x + step_x]))
        for k in range(n_feat):
            row0 = features[i, k, r0, x_lo + bx:x_hi + bx + step_x]
            row1 = features[i, k, r0 + step_y, x_lo + bx:x_hi + bx + step_x]
            out = sums[r, k, x_lo - x0:x_hi - x0]
            for x in range(width):
                out[x] += seen[x] * (a * row0[x] + b * row0[x + step_x] + c * row1[x] + d * row1[x + step_x])
        out_c = count[r, x_lo - x0:x_hi - x0]
        if has_valid:
            v0 = valid[i, r0, x_lo + bx:x_hi + bx + step_x]
            v1 = valid[i, r0 + step_y, x_lo + bx:x_hi + bx + step_x]
            for x in range(width):
                out_c[x] += weight * min(min(v0[x], v0[x + step_x]), min(v1[x], v1[x + step_x]))
        else:
            for x in range(width):
                out_c[x] += weight


@njit(cache=True, inline="always")
def _view_window(s, positions, i, n_rows, n_cols, y0, y1, x0, x1):
    """View ``i``'s taps at slope ``s`` and the part ``(ya, yb, xa, xb)`` of the tile ``y0 .. y1, x0 .. x1``
    where all of them lie inside it: ``(by, fy, bx, fx, ya, yb, xa, xb)``."""
    by, fy, ylo, yhi = _taps(s * positions[i, 0], n_rows)
    bx, fx, xlo, xhi = _taps(s * positions[i, 1], n_cols)
    return by, fy, bx, fx, max(y0, ylo), min(y1, yhi), max(x0, xlo), min(x1, xhi)


@njit(cache=True, inline="always")
def _mean_of_views(features, valid, has_valid, positions, s, weights, y0, y1, x0, x1, ref, ref_count):
    """``ref (rows, K, width)``: the weighted mean at slope ``s`` of the views with a ``weights (n,)`` above 0
    over the tile ``y0 .. y1, x0 .. x1`` (0 where none has a sample), and their summed weight ``ref_count``."""
    n_rows, n_cols = features.shape[2], features.shape[3]
    ref[:] = 0.0
    ref_count[:] = 0.0
    for i in range(weights.shape[0]):
        if weights[i] == 0.0:
            continue
        by, fy, bx, fx, ya, yb, xa, xb = _view_window(s, positions, i, n_rows, n_cols, y0, y1, x0, x1)
        if yb > ya and xb > xa:
            _add_view(features, valid, has_valid, i, by, fy, bx, fx, ya, yb, xa, xb, x0, np.float32(weights[i]),
                      ref[ya - y0:], ref_count[ya - y0:])
    for r in range(y1 - y0):
        for x in range(x1 - x0):
            inv = np.float32(1.0) / ref_count[r, x] if ref_count[r, x] > 0.0 else np.float32(0.0)
            for k in range(ref.shape[1]):
                ref[r, k, x] *= inv


@njit(cache=True, inline="always")
def _add_errors(features, valid, has_valid, i, by, fy, bx, fx, y0, y1, x_lo, x_hi, x0, ty0, ref, ref_count,
                groups, acc, cnt, scale):
    """Squared feature differences of view ``i``'s samples to ``ref``, times ``scale``, added to the groups
    ``groups`` of ``acc``/``cnt (G, rows, width)`` (tile origin ``ty0, x0``); rows ``y0 .. y1``, columns
    ``x_lo .. x_hi``."""
    n_feat = features.shape[1]
    a = np.float32((1.0 - fy) * (1.0 - fx))
    b = np.float32((1.0 - fy) * fx)
    c = np.float32(fy * (1.0 - fx))
    d = np.float32(fy * fx)
    step_y = 1 if fy > 0.0 else 0
    step_x = 1 if fx > 0.0 else 0
    width = x_hi - x_lo
    err = np.zeros(width, np.float32)
    keep = np.empty(width, np.float32)
    for y in range(y0, y1):
        r0 = y + by
        r = y - ty0
        rc = ref_count[r, x_lo - x0:x_hi - x0]
        for x in range(width):
            keep[x] = np.float32(1.0) if rc[x] > 0.0 else np.float32(0.0)
            err[x] = 0.0
        if has_valid:  # a sample counts by its weight (the least of its taps')
            v0 = valid[i, r0, x_lo + bx:x_hi + bx + step_x]
            v1 = valid[i, r0 + step_y, x_lo + bx:x_hi + bx + step_x]
            for x in range(width):
                keep[x] *= min(min(v0[x], v0[x + step_x]), min(v1[x], v1[x + step_x]))
        for k in range(n_feat):
            row0 = features[i, k, r0, x_lo + bx:x_hi + bx + step_x]
            row1 = features[i, k, r0 + step_y, x_lo + bx:x_hi + bx + step_x]
            rk = ref[r, k, x_lo - x0:x_hi - x0]
            for x in range(width):
                diff = a * row0[x] + b * row0[x + step_x] + c * row1[x] + d * row1[x + step_x] - rk[x]
                err[x] += diff * diff
        for x in range(width):
            err[x] *= scale
        for g in groups:
            acc_g = acc[g, r, x_lo - x0:x_hi - x0]
            cnt_g = cnt[g, r, x_lo - x0:x_hi - x0]
            for x in range(width):
                acc_g[x] += err[x] * keep[x]
                cnt_g[x] += keep[x]


@njit(cache=True)
def _cells(member):
    """The views split by the groups they belong to: ``(view_cell (n,), group_cells (G, C), group_size (G,),
    C)``. Every view adds its differences to its one cell and each group sums its cells afterwards: on a 9x9
    grid and nine groups, 17 cells instead of five group sums per view."""
    n, n_groups = member.shape
    signature = np.zeros((n, n_groups), np.bool_)
    view_cell = np.empty(n, np.int64)
    n_cells = 0
    for i in range(n):
        found = -1
        for c in range(n_cells):
            same = True
            for g in range(n_groups):
                if signature[c, g] != member[i, g]:
                    same = False
                    break
            if same:
                found = c
                break
        if found < 0:
            signature[n_cells] = member[i]
            found = n_cells
            n_cells += 1
        view_cell[i] = found
    group_cells = np.zeros((n_groups, n_cells), np.int64)
    group_size = np.zeros(n_groups, np.int64)
    for g in range(n_groups):
        for c in range(n_cells):
            if signature[c, g]:
                group_cells[g, group_size[g]] = c
                group_size[g] += 1
    return view_cell, group_cells, group_size, n_cells


@njit(cache=True, parallel=True, fastmath=True)
def sweep_costs(features, valid, has_valid, positions, slopes, ref_views, member, min_count, group_scale,
                border_rule, outside_penalty, tiles, first, order, view_scale, out):
    """Occlusion-aware matching cost of every tile at each of its slopes.

    Tile-major: a tile's views are read into the cache once and all its
    slopes are computed from there (a slope-major sweep would stream the
    whole light field from memory once per slope); tiles a few rows high
    keep every view's samples in the cache from one slope to the next.
    Along a tile row the taps are shifted slices, so the inner loops
    vectorise.

    Parameters
    ----------
    features : (n, K, Y, X) float32
        Feature planes of every view.
    valid : (n, Y, X) float32
        Weight of every sample in [0, 1] (0: not observed); ignored unless ``has_valid``.
    positions : (n, 2) float64
    slopes : (m,) float64
        Slopes in units of this level's pixels.
    ref_views : (r,) int64
        Views averaged into the reference (the central ones).
    member : (n, G) bool
        Group membership of every view (group 0: all of them).
    min_count : (G,) float32
        Fewest valid views a group needs to count.
    group_scale : (G,) float32
        Factor of each group's mean (a small group must fit that much
        better to win).
    border_rule : bool
        Where some views sample outside the image, a group counts at a
        pixel only if the share of its views that sample inside is the
        highest of any group there (a slope that pushes a group's outer
        views out, their differences the largest, cannot win by that), and
        the pixel's cost is multiplied by ``1 + outside_penalty * (share of
        all the views outside)`` (of two slopes that fit about equally
        well, the one more views see wins).
    outside_penalty : float32
        See ``border_rule``.
    tiles : (T, 4) int64
        ``(y0, y1, x0, x1)`` of every tile.
    first : (T + 1,) int64, order : (S,) int64
        Tile ``t`` needs the slopes ``order[first[t]:first[t + 1]]``.
    view_scale : (m, n) float32
        Factor of view ``i``'s squared differences at slope ``j``.
    out : (m, Y, X) float32
        Smallest group's weighted mean of the squared feature differences
        to the (weighted) reference; left as it is where a tile does not
        need a slope; ``inf`` where no group has enough weight. A sample
        counts where its four taps lie inside the view, with the least
        weight of its taps.
    """
    n, n_feat, n_rows, n_cols = features.shape
    n_groups = member.shape[1]
    view_cell, group_cells, group_size, n_cells = _cells(member)
    ref_weights = np.zeros(n, np.float32)
    for u in range(ref_views.shape[0]):
        ref_weights[ref_views[u]] = 1.0
    view_cells = [view_cell[i:i + 1] for i in range(n)]
    group_views = np.zeros(n_groups, np.float32)
    for i in range(n):
        for g in range(n_groups):
            if member[i, g]:
                group_views[g] += 1.0
    for t in prange(tiles.shape[0]):
        y0, y1, x0, x1 = tiles[t, 0], tiles[t, 1], tiles[t, 2], tiles[t, 3]
        height, width = y1 - y0, x1 - x0
        ref = np.empty((height, n_feat, width), np.float32)
        ref_count = np.empty((height, width), np.float32)
        acc = np.empty((n_cells, height, width), np.float32)
        cnt = np.empty((n_cells, height, width), np.float32)
        group_acc = np.empty(width, np.float32)
        group_cnt = np.empty(width, np.float32)
        best = np.empty(width, np.float32)
        inside = np.empty((n_cells, height, width), np.float32)  # views sampling inside, where some do not
        share = np.empty((n_groups, width), np.float32)  # of a group's views, those sampling inside
        most = np.empty(width, np.float32)
        for idx in range(first[t], first[t + 1]):
            j = order[idx]
            s = slopes[j]
            acc[:] = 0.0
            cnt[:] = 0.0
            _mean_of_views(features, valid, has_valid, positions, s, ref_weights, y0, y1, x0, x1, ref, ref_count)
            clipped = False  # some view samples outside the image in this tile
            for i in range(n):
                by, fy, bx, fx, ya, yb, xa, xb = _view_window(s, positions, i, n_rows, n_cols, y0, y1, x0, x1)
                covers = ya == y0 and yb == y1 and xa == x0 and xb == x1
                if not covers and not clipped and border_rule:
                    clipped = True
                    inside[:] = 0.0
                    for v in range(i):  # the views before covered the tile
                        inside[view_cell[v]] += 1.0
                if clipped:
                    inside[view_cell[i], max(ya - y0, 0):max(yb - y0, 0), max(xa - x0, 0):max(xb - x0, 0)] += 1.0
                if yb <= ya or xb <= xa:
                    continue
                _add_errors(features, valid, has_valid, i, by, fy, bx, fx, ya, yb, xa, xb, x0, y0, ref,
                            ref_count, view_cells[i], acc, cnt, view_scale[j, i])
            for r in range(height):
                best[:] = np.inf
                if clipped:
                    most[:] = 0.0
                    for g in range(n_groups):
                        share[g] = 0.0
                        for k in range(group_size[g]):
                            share[g] += inside[group_cells[g, k], r]
                        share[g] /= group_views[g]
                        for x in range(width):
                            most[x] = max(most[x], share[g, x])
                for g in range(n_groups):
                    # a group's sums are those of its cells
                    group_acc[:] = 0.0
                    group_cnt[:] = 0.0
                    for k in range(group_size[g]):
                        c = group_cells[g, k]
                        for x in range(width):
                            group_acc[x] += acc[c, r, x]
                            group_cnt[x] += cnt[c, r, x]
                    least = min_count[g]
                    scale = group_scale[g]
                    if clipped:
                        for x in range(width):
                            if share[g, x] < most[x] - np.float32(1e-4):
                                continue
                            if group_cnt[x] >= least:
                                value = scale * group_acc[x] / group_cnt[x]
                                if value < best[x]:
                                    best[x] = value
                    else:  # branch-free, so that it vectorises
                        for x in range(width):
                            count = group_cnt[x]
                            value = scale * group_acc[x] / max(count, least)
                            best[x] = min(best[x], value if count >= least else np.float32(np.inf))
                if clipped:
                    for x in range(width):
                        best[x] *= np.float32(1.0) + outside_penalty * (np.float32(1.0) - share[0, x])
                out[j, y0 + r, x0:x1] = best


@njit(cache=True, parallel=True, fastmath=True)
def agreeing_shares(features, valid, has_valid, positions, slopes, references, tiles, first, order, tolerance, out):
    """The share of the views that agree with each of several references, at every pixel of the tiles asked.

    Each view's samples are resampled once per slope and compared with
    every reference (a weighted mean of some views at the same slope): the
    focus test's mean of the central views and each of them alone, in one
    pass over the views.

    Parameters
    ----------
    features, valid, has_valid, positions, slopes
        As ``sweep_costs``.
    references : (R, n) float32
        Weight of each view in each reference's mean (0: not in it).
    tiles, first, order
        As ``sweep_costs``.
    tolerance : (Y, X) float32
        A view agrees where its squared feature difference is at most this.
    out : (m, R, Y, X) float32
        For slope ``j`` and reference ``r``, the agreeing views' weight over
        the weight of the views with a sample there (0 where the reference
        has none); left as it is where a tile does not need slope ``j``.
    """
    n, n_feat, n_rows, n_cols = features.shape
    n_refs = references.shape[0]
    for t in prange(tiles.shape[0]):
        y0, y1, x0, x1 = tiles[t, 0], tiles[t, 1], tiles[t, 2], tiles[t, 3]
        height, width = y1 - y0, x1 - x0
        ref = np.empty((n_refs, height, n_feat, width), np.float32)
        ref_count = np.empty((n_refs, height, width), np.float32)
        agree = np.empty((n_refs, height, width), np.float32)
        seen = np.empty((height, width), np.float32)
        sample = np.empty((n_feat, width), np.float32)
        keep = np.empty(width, np.float32)
        err = np.empty(width, np.float32)
        for idx in range(first[t], first[t + 1]):
            j = order[idx]
            s = slopes[j]
            agree[:] = 0.0
            seen[:] = 0.0
            for r in range(n_refs):
                _mean_of_views(features, valid, has_valid, positions, s, references[r], y0, y1, x0, x1, ref[r],
                               ref_count[r])
            for i in range(n):
                by, fy, bx, fx, ya, yb, xa, xb = _view_window(s, positions, i, n_rows, n_cols, y0, y1, x0, x1)
                if yb <= ya or xb <= xa:
                    continue
                a = np.float32((1.0 - fy) * (1.0 - fx))
                b = np.float32((1.0 - fy) * fx)
                c = np.float32(fy * (1.0 - fx))
                d = np.float32(fy * fx)
                step_y = 1 if fy > 0.0 else 0
                step_x = 1 if fx > 0.0 else 0
                w = xb - xa
                for y in range(ya, yb):
                    r0 = y + by
                    row = y - y0
                    if has_valid:
                        v0 = valid[i, r0, xa + bx:xb + bx + step_x]
                        v1 = valid[i, r0 + step_y, xa + bx:xb + bx + step_x]
                        for x in range(w):
                            keep[x] = min(min(v0[x], v0[x + step_x]), min(v1[x], v1[x + step_x]))
                    else:
                        keep[:w] = 1.0
                    for k in range(n_feat):
                        row0 = features[i, k, r0, xa + bx:xb + bx + step_x]
                        row1 = features[i, k, r0 + step_y, xa + bx:xb + bx + step_x]
                        for x in range(w):
                            sample[k, x] = a * row0[x] + b * row0[x + step_x] + c * row1[x] + d * row1[x + step_x]
                    tol = tolerance[y, xa:xb]
                    for r in range(n_refs):
                        err[:w] = 0.0
                        for k in range(n_feat):
                            rk = ref[r, row, k, xa - x0:xb - x0]
                            for x in range(w):
                                diff = sample[k, x] - rk[x]
                                err[x] += diff * diff
                        rc = ref_count[r, row, xa - x0:xb - x0]
                        ag = agree[r, row, xa - x0:xb - x0]
                        for x in range(w):
                            if rc[x] > 0.0 and err[x] <= tol[x]:
                                ag[x] += keep[x]
                    sn = seen[row, xa - x0:xb - x0]
                    for x in range(w):
                        sn[x] += keep[x]
            for r in range(n_refs):
                for row in range(height):
                    for x in range(width):
                        total = seen[row, x]
                        out[j, r, y0 + row, x0 + x] = agree[r, row, x] / total if total > 0.0 else np.float32(0.0)


@njit(cache=True, inline="always")
def _thomas(lower, diag, upper, rhs, out, c_work, d_work):
    """Solve a tridiagonal system (Thomas algorithm); ``lower[0]`` and ``upper[-1]`` are unused."""
    n = diag.shape[0]
    c_work[0] = upper[0] / diag[0]
    d_work[0] = rhs[0] / diag[0]
    for i in range(1, n):
        m = diag[i] - lower[i] * c_work[i - 1]
        c_work[i] = upper[i] / m
        d_work[i] = (rhs[i] - lower[i] * d_work[i - 1]) / m
    out[n - 1] = d_work[n - 1]
    for i in range(n - 2, -1, -1):
        out[i] = d_work[i] - c_work[i] * out[i + 1]


@njit(cache=True, parallel=True)
def wls_rows(values, guide, lam, sigma, depth, gate, inv_spread2, out):
    """``(I + lam L_w) u = f`` along every row, ``w = exp(-|dg|^2 / sigma^2 - min(gate) * dd^2 * inv_spread2)``
    from the guide's difference ``dg`` and the ``depth`` difference ``dd`` of neighbours (the lesser
    ``gate`` of the two).

    Parameters
    ----------
    values : (Y, X, K) float64
        Right-hand sides (K of them per row).
    guide : (Y, X, C) float64
        The image whose edges stop the smoothing.
    lam, sigma : float
    depth, gate : (Y, X) float64
        Values whose differences stop the smoothing too, and how far each
        is trusted (0: not at all; ``gate`` 0 everywhere leaves the guide alone).
    inv_spread2 : float
        ``1 / spread^2``: a ``depth`` step of ``spread`` between neighbours
        trusted fully weakens their link by ``e``.
    out : (Y, X, K) float64
    """
    n_rows, n_cols, n_k = values.shape
    n_ch = guide.shape[2]
    inv_s2 = 1.0 / (sigma * sigma)
    for y in prange(n_rows):
        link = np.zeros(n_cols)
        for x in range(n_cols - 1):
            dist = 0.0
            for c in range(n_ch):
                t = guide[y, x + 1, c] - guide[y, x, c]
                dist += t * t
            step = depth[y, x + 1] - depth[y, x]
            trust = min(gate[y, x], gate[y, x + 1])
            link[x] = lam * np.exp(-dist * inv_s2 - trust * step * step * inv_spread2)
        lower = np.zeros(n_cols)
        upper = np.zeros(n_cols)
        diag = np.ones(n_cols)
        for x in range(n_cols):
            if x > 0:
                lower[x] = -link[x - 1]
                diag[x] += link[x - 1]
            if x < n_cols - 1:
                upper[x] = -link[x]
                diag[x] += link[x]
        rhs = np.empty(n_cols)
        sol = np.empty(n_cols)
        c_work = np.empty(n_cols)
        d_work = np.empty(n_cols)
        for k in range(n_k):
            for x in range(n_cols):
                rhs[x] = values[y, x, k]
            _thomas(lower, diag, upper, rhs, sol, c_work, d_work)
            for x in range(n_cols):
                out[y, x, k] = sol[x]


@njit(cache=True, parallel=True)
def box_mean_stack(images, radius, out):
    """Mean over the ``(2 radius + 1)^2`` square around every pixel of every image ``(m, Y, X)``.

    Only pixels inside the image count (the window is cut at the borders,
    and the mean divides by the pixels it holds). Running sums in float64.
    """
    m, n_rows, n_cols = images.shape
    tmp = np.empty((m, n_rows, n_cols), np.float32)
    for job in prange(m * n_rows):
        k = job // n_rows
        y = job % n_rows
        row = images[k, y]
        acc = 0.0
        for x in range(min(radius, n_cols)):
            acc += row[x]
        for x in range(n_cols):
            if x + radius < n_cols:
                acc += row[x + radius]
            if x - radius - 1 >= 0:
                acc -= row[x - radius - 1]
            count = min(x + radius, n_cols - 1) - max(x - radius, 0) + 1
            tmp[k, y, x] = acc / count
    for k in prange(m):
        acc = np.zeros(n_cols)
        for y in range(min(radius, n_rows)):
            for x in range(n_cols):
                acc[x] += tmp[k, y, x]
        for y in range(n_rows):
            if y + radius < n_rows:
                add = tmp[k, y + radius]
                for x in range(n_cols):
                    acc[x] += add[x]
            if y - radius - 1 >= 0:
                sub = tmp[k, y - radius - 1]
                for x in range(n_cols):
                    acc[x] -= sub[x]
            inv = 1.0 / (min(y + radius, n_rows - 1) - max(y - radius, 0) + 1)
            for x in range(n_cols):
                out[k, y, x] = acc[x] * inv


@njit(cache=True, inline="always")
def _box_plane(src, radius, tmp, dst):
    """Mean over the ``(2 radius + 1)^2`` square around every pixel of ``src (h, w)``, the window cut at
    the borders (as :func:`box_mean_stack`), into ``dst``; ``tmp`` is scratch of the same shape."""
    n_rows, n_cols = src.shape
    for y in range(n_rows):
        acc = 0.0
        for x in range(min(radius, n_cols)):
            acc += src[y, x]
        for x in range(n_cols):
            if x + radius < n_cols:
                acc += src[y, x + radius]
            if x - radius - 1 >= 0:
                acc -= src[y, x - radius - 1]
            tmp[y, x] = acc / (min(x + radius, n_cols - 1) - max(x - radius, 0) + 1)
    acc_row = np.zeros(n_cols)  # the vertical pass row by row (contiguous memory)
    for y in range(min(radius, n_rows)):
        for x in range(n_cols):
            acc_row[x] += tmp[y, x]
    for y in range(n_rows):
        if y + radius < n_rows:
            for x in range(n_cols):
                acc_row[x] += tmp[y + radius, x]
        if y - radius - 1 >= 0:
            for x in range(n_cols):
                acc_row[x] -= tmp[y - radius - 1, x]
        inv = 1.0 / (min(y + radius, n_rows - 1) - max(y - radius, 0) + 1)
        for x in range(n_cols):
            dst[y, x] = acc_row[x] * inv


@njit(cache=True, inline="always")
def _up_index(i, n_in):
    """Linear upsampling by 2 (sample centres at half pixels): the two source samples of output ``i`` and
    the weight of the second."""
    where = (i + 0.5) / 2.0 - 0.5
    low = int(np.floor(where))
    low = min(max(low, 0), n_in - 1)
    high = min(low + 1, n_in - 1)
    frac = min(max(where - low, 0.0), 1.0)
    return low, high, frac


@njit(cache=True, parallel=True, fastmath=True)
def guided_windows(stack, y0, x0, guide, channels, mean, inverse, radius, out):
    """The fast guided filter (coefficients at half resolution) of every image of ``stack (m, h, w)``,
    the window of the full image at even offsets ``(y0, x0)``, one image per thread.

    ``guide (Y, X, C)``: the full-resolution guide; ``channels``, ``mean`` ``(C, y, x)``: the guide at
    half resolution and its box mean; ``inverse (y, x, C, C)``: the inverse of its regularised local
    covariance; ``radius``: the box radius at half resolution. Same result as
    ``napari_lfalias.disparity._GuidedFilter.window`` (the numpy reference).
    """
    m, height, width = stack.shape
    n_ch = channels.shape[0]
    hs, ws = (height + 1) // 2, (width + 1) // 2
    ys, xs = y0 // 2, x0 // 2
    for j in prange(m):
        small = np.empty((hs, ws), np.float32)
        for y in range(hs):
            ya, yb = 2 * y, min(2 * y + 1, height - 1)
            for x in range(ws):
                xa, xb = 2 * x, min(2 * x + 1, width - 1)
                small[y, x] = 0.25 * (stack[j, ya, xa] + stack[j, yb, xa] + stack[j, ya, xb] + stack[j, yb, xb])
        tmp = np.empty((hs, ws), np.float32)
        mean_p = np.empty((hs, ws), np.float32)
        _box_plane(small, radius, tmp, mean_p)
        cov = np.empty((n_ch, hs, ws), np.float32)
        product = np.empty((hs, ws), np.float32)
        for c in range(n_ch):
            for y in range(hs):
                for x in range(ws):
                    product[y, x] = small[y, x] * channels[c, ys + y, xs + x]
            _box_plane(product, radius, tmp, cov[c])
            for y in range(hs):
                for x in range(ws):
                    cov[c, y, x] -= mean[c, ys + y, xs + x] * mean_p[y, x]
        coef = np.empty((n_ch + 1, hs, ws), np.float32)  # a_0 .. a_{C-1}, b
        for y in range(hs):
            for x in range(ws):
                b = mean_p[y, x]
                for c in range(n_ch):
                    a = 0.0
                    for d in range(n_ch):
                        a += inverse[ys + y, xs + x, c, d] * cov[d, y, x]
                    coef[c, y, x] = a
                    b -= a * mean[c, ys + y, xs + x]
                coef[n_ch, y, x] = b
        smooth = np.empty((n_ch + 1, hs, ws), np.float32)
        for c in range(n_ch + 1):
            _box_plane(coef[c], radius, tmp, smooth[c])
        x_lo = np.empty(width, np.int64)
        x_hi = np.empty(width, np.int64)
        x_frac = np.empty(width, np.float32)
        for x in range(width):
            x_lo[x], x_hi[x], x_frac[x] = _up_index(x, ws)
        row = np.empty((n_ch + 1, width), np.float32)
        for y in range(height):
            ya, yb, fy = _up_index(y, hs)
            for c in range(n_ch + 1):  # the coefficients interpolated to this row, then along it
                for x in range(ws):
                    tmp[0, x] = smooth[c, ya, x] * (1 - fy) + smooth[c, yb, x] * fy
                for x in range(width):
                    fx = x_frac[x]
                    row[c, x] = tmp[0, x_lo[x]] * (1 - fx) + tmp[0, x_hi[x]] * fx
            for x in range(width):
                value = row[n_ch, x]
                for c in range(n_ch):
                    value += row[c, x] * guide[y0 + y, x0 + x, c]
                out[j, y, x] = value


@njit(cache=True, parallel=True)
def subslope_offsets(cost, best, radius, out):
    """The sub-step offset (in steps, within +-0.5) of the minimum of every pixel's cost curve: the
    vertex of the parabola through its costs at ``best - 1``, ``best`` and ``best + 1``, each
    averaged over the ``(2 radius + 1)^2`` window (non-finite costs skipped); 0 where the three do not
    bracket a minimum."""
    m, n_rows, n_cols = cost.shape
    for y in prange(n_rows):
        for x in range(n_cols):
            b = best[y, x]
            out[y, x] = 0.0
            if b < 1 or b > m - 2:
                continue
            sums = np.zeros(3)
            counts = np.zeros(3)
            for yy in range(max(0, y - radius), min(n_rows, y + radius + 1)):
                for xx in range(max(0, x - radius), min(n_cols, x + radius + 1)):
                    for k in range(3):
                        value = cost[b - 1 + k, yy, xx]
                        if np.isfinite(value):
                            sums[k] += value
                            counts[k] += 1.0
            if counts[0] == 0 or counts[1] == 0 or counts[2] == 0:
                continue
            c0, c1, c2 = sums[0] / counts[0], sums[1] / counts[1], sums[2] / counts[2]
            curvature = c0 - 2.0 * c1 + c2
            if curvature > 1e-9:
                out[y, x] = min(max(0.5 * (c0 - c2) / curvature, -0.5), 0.5)


@njit(cache=True, parallel=True)
def shear_slices(relative, y0, x0, j0, shear_y, shear_x, centre_y, centre_x, cap, out):
    """The cost of a window along slanted planes: ``out[k, y, x]`` is ``relative[t, y0 + y, x0 + x]`` at
    ``t = j0 + k + shear_y (y - centre_y) + shear_x (x - centre_x)`` (slope indices, linear between them;
    ``cap`` beyond the volume), so that a fronto-parallel filter of ``out`` aggregates every pixel's cost
    over the plane of that slant through it.

    Parameters
    ----------
    relative : (m, Y, X) float32
    y0, x0 : int
        Origin of the window ``out`` covers.
    j0 : int
        Slope index of ``out[0]`` at the centre.
    shear_y, shear_x : float
        Slant in slope indices per pixel.
    centre_y, centre_x : float
        Window coordinates where the shear is 0.
    cap : float
    out : (K, h, w) float32
    """
    m = relative.shape[0]
    n_k, height, width = out.shape
    for y in prange(height):
        for x in range(width):
            shift = j0 + shear_y * (y - centre_y) + shear_x * (x - centre_x)
            for k in range(n_k):
                t = k + shift
                low = int(np.floor(t))
                if low < 0 or low + 1 > m - 1:
                    out[k, y, x] = relative[m - 1, y0 + y, x0 + x] if (low == m - 1 and t - low < 1e-6) else cap
                    continue
                frac = t - low
                out[k, y, x] = (1.0 - frac) * relative[low, y0 + y, x0 + x] + frac * relative[low + 1, y0 + y, x0 + x]


@njit(cache=True, parallel=True)
def unshear_min(filtered, j0, shear_y, shear_x, centre_y, centre_x, y0, x0, inside, j_lo, j_hi, out):
    """Back from :func:`shear_slices`'s indices: ``out[j, y0 + y, x0 + x]`` becomes the least of itself and
    ``filtered`` at ``k = j - j0 - shear_y (y - centre_y) - shear_x (x - centre_x)`` (linear), for the slopes
    ``j_lo .. j_hi`` and the window pixels where ``inside (h, w)``."""
    n_k, height, width = filtered.shape
    for y in prange(height):
        for x in range(width):
            if not inside[y, x]:
                continue
            shift = j0 + shear_y * (y - centre_y) + shear_x * (x - centre_x)
            for j in range(j_lo, j_hi + 1):
                t = j - shift
                low = int(np.floor(t))
                if low < 0 or low + 1 > n_k - 1:
                    continue
                frac = t - low
                value = (1.0 - frac) * filtered[low, y, x] + frac * filtered[low + 1, y, x]
                if value < out[j, y0 + y, x0 + x]:
                    out[j, y0 + y, x0 + x] = value


@njit(cache=True, parallel=True)
def winner_scan(aggregated, apart, best, least, second, second_at):
    """Per pixel of ``aggregated (m, Y, X)``: the index of its least value (``best``), that value
    (``least``), the least value more than ``apart`` indices from it (``second``, ``inf`` if none) and
    where that is (``second_at``; -1 if none, or if it is not a local minimum of the curve: a valley's
    side, not a valley of its own)."""
    m, n_rows, n_cols = aggregated.shape
    for y in prange(n_rows):
        for x in range(n_cols):
            b = 0
            low = aggregated[0, y, x]
            for j in range(1, m):
                if aggregated[j, y, x] < low:
                    low = aggregated[j, y, x]
                    b = j
            other = np.inf
            at = -1
            for j in range(m):
                if abs(j - b) > apart and aggregated[j, y, x] < other:
                    other = aggregated[j, y, x]
                    at = j
            if at >= 0 and ((at > 0 and aggregated[at - 1, y, x] < other)
                            or (at < m - 1 and aggregated[at + 1, y, x] < other)):
                at = -1
            best[y, x] = b
            least[y, x] = low
            second[y, x] = other
            second_at[y, x] = at


@njit(cache=True, parallel=True)
def relative_costs(cost, eps, cap, out):
    """``min(log(c + eps) - min_s log(c + eps), cap)`` of every pixel's cost curve in ``cost (m, Y, X)``, in
    one pass; ``cap`` where a cost is not finite (not computed)."""
    m, n_rows, n_cols = cost.shape
    for y in prange(n_rows):
        best = np.empty(n_cols, np.float32)
        for x in range(n_cols):
            best[x] = np.inf
        for j in range(m):
            for x in range(n_cols):
                value = cost[j, y, x]
                if np.isfinite(value):
                    out[j, y, x] = np.log(value + eps)
                    if out[j, y, x] < best[x]:
                        best[x] = out[j, y, x]
                else:
                    out[j, y, x] = np.inf
        for x in range(n_cols):
            if not np.isfinite(best[x]):
                best[x] = 0.0
        for j in range(m):
            for x in range(n_cols):
                value = out[j, y, x] - best[x]
                out[j, y, x] = value if value < cap else cap
