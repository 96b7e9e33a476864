"""The FAP layer's compiled per-tick kernels (numba), defined at module level so that numba's disk
cache keeps them (functions built in a closure that call one another were compiled afresh in every
process). Imported only through :mod:`core.layers.fap.kernels`, which loads it lazily."""

from __future__ import annotations

import numba
import numpy as np

_JIT = numba.njit(cache=True, nogil=True)


@_JIT
def add_active_columns(x_flat, indptr, rows, data, scaled):  # pragma: no cover - compiled
    """x_flat (3n,) += F @ scaled with F (3n, 68) given by its CSC arrays, skipping the
    columns whose value is 0 (a slider tick on a face at rest reads one column). Each row
    gets its terms in column order, from x_flat's own value: a fixed order, so the same
    state always gives the same vertices."""
    for j in range(scaled.shape[0]):
        v = scaled[j]
        if v == 0.0:
            continue
        for k in range(indptr[j], indptr[j + 1]):
            x_flat[rows[k]] += data[k] * v


@_JIT
def _interp(x, xp, fp):  # pragma: no cover - compiled
    """np.interp for one x (xp increasing), the same sums: numba's own checks every xp on
    each call. The interval is guessed as if xp were evenly spaced (the profiles are), then
    corrected."""
    n = xp.shape[0]
    if x <= xp[0]:
        return fp[0]
    if x >= xp[n - 1]:
        return fp[n - 1]
    lo = min(max(int((x - xp[0]) / (xp[n - 1] - xp[0]) * (n - 1)), 0), n - 2)
    while xp[lo] > x:
        lo -= 1
    while xp[lo + 1] <= x:
        lo += 1
    slope = (fp[lo + 1] - fp[lo]) / (xp[lo + 1] - xp[lo])
    return slope * (x - xp[lo]) + fp[lo]


@_JIT
def lip_overlap(x, upper_rim, lower_rim, taper_mm, out):  # pragma: no cover - compiled
    """``lip_contact.LipContact._overlap`` into ``out`` (len(lower_rim),): how far each lower-rim
    vertex of ``x`` is above the upper rim at its x, tapered over ``taper_mm`` next to the rim's
    ends; -inf beyond them."""
    m = upper_rim.shape[0]
    ux = np.empty(m)
    uy = np.empty(m)
    for i in range(m):
        ux[i] = x[upper_rim[i], 0]
        uy[i] = x[upper_rim[i], 1]
    order = np.argsort(ux, kind="mergesort")   # stable: ties keep the rim's order, as numpy's path does
    sx = ux[order]
    sy = uy[order]
    first, last = sx[0], sx[m - 1]
    for j in range(lower_rim.shape[0]):
        lx, ly = x[lower_rim[j], 0], x[lower_rim[j], 1]
        if lx < first or lx > last:
            out[j] = -np.inf
            continue
        taper = min(max(min(lx - first, last - lx) / taper_mm, 0.0), 1.0)
        out[j] = (ly - _interp(lx, sx, sy)) * taper


@_JIT
def _sheet_cell(x, v, ox, oz, cell, nx, nz):  # pragma: no cover - compiled
    ix = min(max(np.int64((x[v, 0] - ox) / cell), 0), nx - 1)
    iz = min(max(np.int64((x[v, 2] - oz) / cell), 0), nz - 1)
    return ix * nz + iz


@_JIT
def lip_sheet_overlap(x, upper, lower, ox, oz, cell, nx, nz, below, above):  # pragma: no cover - compiled
    """``lip_contact.LipContact._sheet_overlap`` into ``below`` (len(upper),) and ``above``
    (len(lower),): how far each upper-lip vertex is below the lower lip's highest vertex in its
    (x, z) cell of the grid (origin ox, oz; nx x nz cells of ``cell`` mm), and each lower-lip vertex
    above the upper lip's lowest; -inf where the other lip has none there."""
    top = np.full(nx * nz, -np.inf)
    bottom = np.full(nx * nz, np.inf)
    for j in range(lower.shape[0]):
        k = _sheet_cell(x, lower[j], ox, oz, cell, nx, nz)
        top[k] = max(top[k], x[lower[j], 1])
    for i in range(upper.shape[0]):
        k = _sheet_cell(x, upper[i], ox, oz, cell, nx, nz)
        bottom[k] = min(bottom[k], x[upper[i], 1])
    for i in range(upper.shape[0]):
        below[i] = top[_sheet_cell(x, upper[i], ox, oz, cell, nx, nz)] - x[upper[i], 1]
    for j in range(lower.shape[0]):
        above[j] = x[lower[j], 1] - bottom[_sheet_cell(x, lower[j], ox, oz, cell, nx, nz)]


@_JIT
def lip_sheet_spread(indptr, indices, falloff, depth, separation, out):  # pragma: no cover - compiled
    """``lip_contact._spread`` into ``out`` (k,), zeroed here: for each vertex with ``depth`` > 0,
    (depth / 2 + separation) x the falloff of each neighbour (CSR ``indptr``, ``indices``,
    ``falloff``), the largest at each vertex."""
    out[:] = 0.0
    for i in range(depth.shape[0]):
        if depth[i] <= 0.0:
            continue
        give = 0.5 * depth[i] + separation
        for k in range(indptr[i], indptr[i + 1]):
            value = give * falloff[k]
            j = indices[k]
            if value > out[j]:
                out[j] = value


@_JIT
def _map_radius(rx, ry, rz, radii, step, reach):  # pragma: no cover - compiled
    """The eyeball's radius map ``radii`` (m, m) mm read bilinearly in direction (rx, ry, rz)
    from its centre, 0 outside the map: ``eyeball_surface.map_radius`` for one direction, the
    same sums."""
    m = radii.shape[0]
    planar = np.sqrt(rx * rx + ry * ry)
    theta = np.arctan2(planar, rz)
    scale = theta / planar if planar > 0.0 else 0.0
    fu = (rx * scale + reach) / step
    fv = (ry * scale + reach) / step
    i, j = np.floor(fu), np.floor(fv)
    if not (i >= 0.0 and j >= 0.0 and i < m - 1 and j < m - 1):
        return 0.0
    tu, tv = fu - i, fv - j
    a, b = int(i), int(j)
    return ((radii[a, b] * (1.0 - tu) + radii[a + 1, b] * tu) * (1.0 - tv)
            + (radii[a, b + 1] * (1.0 - tu) + radii[a + 1, b + 1] * tu) * tv)


@_JIT
def close_lids_over_eyeball(x, lid, rest, shift, centre, rest_clearance, full_clearance, ramp, slide, bulge,
                            radii, max_radius, step, reach, turn_start, turn_end):  # pragma: no cover - compiled
    """One eye's lid guard (``FapDeformer._close_lids``; numpy: ``_guard_clearance`` then
    ``eyeball_surface.push_outside``, the same sums). Each vertex ``x[lid[i]]`` gets its clearance,
    from ``rest_clearance[i]`` to ``full_clearance[i]`` (mm) by the larger of ``ramp`` and how far it
    slid from ``rest[i]`` (k, 3) after the ball's ``shift`` (3,) in units of ``slide`` mm, plus
    ``bulge`` x the slide past ``slide`` mm; then, if inside the guard surface (the radius map
    ``radii`` (m, m) mm about ``centre``, cells of ``step`` rad reaching ``reach`` rad, largest
    ``max_radius``, plus the clearance), it is pushed onto it: forward (+z), turning radial between
    ``turn_start`` and ``turn_end`` rad off the gaze axis. Two passes: a push forward turns the
    vertex toward the cornea, which is higher."""
    for i in range(lid.shape[0]):
        v = lid[i]
        dx = x[v, 0] - rest[i, 0] - shift[0]
        dy = x[v, 1] - rest[i, 1] - shift[1]
        dz = x[v, 2] - rest[i, 2] - shift[2]
        slid = np.sqrt(dx * dx + dy * dy + dz * dz) / slide
        clearance = rest_clearance[i] + (full_clearance[i] - rest_clearance[i]) * min(max(ramp, slid), 1.0)
        if bulge != 0.0:
            clearance = clearance + bulge * max(slid - 1.0, 0.0) * slide
        for _ in range(2):
            rx, ry, rz = x[v, 0] - centre[0], x[v, 1] - centre[1], x[v, 2] - centre[2]
            length = np.sqrt(rx * rx + ry * ry + rz * rz)
            if not length < max_radius + clearance:     # outside the ball's largest radius: no lookup
                break
            need = _map_radius(rx, ry, rz, radii, step, reach) + clearance
            if not length < need:
                break
            # eyeball_surface.push_direction, then the push along it onto the guard surface
            planar = np.sqrt(rx * rx + ry * ry)
            w = min(max((np.arctan2(planar, rz) - turn_start) / (turn_end - turn_start), 0.0), 1.0)
            w = w * w * (3.0 - 2.0 * w)
            inv = 1.0 / max(length, 1e-300)
            dx, dy, dz = w * rx * inv, w * ry * inv, w * rz * inv + (1.0 - w)
            norm = np.sqrt(dx * dx + dy * dy + dz * dz)
            dx, dy, dz = dx / norm, dy / norm, dz / norm
            along = rx * dx + ry * dy + rz * dz
            t = -along + np.sqrt(max(along * along - length * length + need * need, 0.0))
            x[v, 0] += t * dx
            x[v, 1] += t * dy
            x[v, 2] += t * dz


@_JIT
def push_out_of_row(x, skin, rest, slack_squared, clearance, rotation, shift, turned, centre,
                    y0, height, n_angles, n_heights, angle_scale, height_scale, table,
                    reach_squared, slack_filter, pushed, offsets):  # pragma: no cover
    """Push guarded ``skin`` (k,) vertices of ``x`` out of one row of teeth (in place); see
    ``teeth_guard.TeethGuard.apply`` for the arguments' meaning. The row's rest frame is
    ``local = (x - shift) @ rotation`` when ``turned``, else ``x - shift``. Writes the pushed
    vertices into ``pushed`` (k,) and their offsets into ``offsets`` (k, 3); returns how many."""
    count = 0
    half = 0.5 * height
    for i in range(skin.shape[0]):
        v = skin[i]
        px, py, pz = x[v, 0] - shift[0], x[v, 1] - shift[1], x[v, 2] - shift[2]
        if turned:
            lx = px * rotation[0, 0] + py * rotation[1, 0] + pz * rotation[2, 0]
            ly = px * rotation[0, 1] + py * rotation[1, 1] + pz * rotation[2, 1]
            lz = px * rotation[0, 2] + py * rotation[1, 2] + pz * rotation[2, 2]
        else:
            lx, ly, lz = px, py, pz
        h = ly - y0
        if not abs(h - half) < half:
            continue
        dx, dz = lx - centre[0], lz - centre[2]
        squared = dx * dx + dz * dz
        if not squared < reach_squared:
            continue
        if slack_filter:
            ox, oy, oz = lx - rest[i, 0], ly - rest[i, 1], lz - rest[i, 2]
            if ox * ox + oy * oy + oz * oz < slack_squared[i]:
                continue
        a = np.int64((np.arctan2(dx, dz) + np.pi) * angle_scale) % n_angles
        need = table[a * n_heights + np.int64(h * height_scale)] + clearance[i]
        radius = np.sqrt(squared)
        if not radius < need:
            continue
        scale = need / max(radius, 1e-9)
        mx, my, mz = centre[0] + dx * scale, ly, centre[2] + dz * scale
        if turned:
            ox = mx * rotation[0, 0] + my * rotation[0, 1] + mz * rotation[0, 2] + shift[0]
            oy = mx * rotation[1, 0] + my * rotation[1, 1] + mz * rotation[1, 2] + shift[1]
            oz = mx * rotation[2, 0] + my * rotation[2, 1] + mz * rotation[2, 2] + shift[2]
        else:
            ox, oy, oz = mx + shift[0], my + shift[1], mz + shift[2]
        pushed[count] = i
        offsets[count, 0] = ox - x[v, 0]
        offsets[count, 1] = oy - x[v, 1]
        offsets[count, 2] = oz - x[v, 2]
        x[v, 0], x[v, 1], x[v, 2] = ox, oy, oz
        count += 1
    return count


@_JIT
def spread_pushes(x, watched, slots, offsets, indptr, indices, data):  # pragma: no cover
    """Move the watched vertices around pushed ones part way (in place): ``slots`` (k,) are
    the pushed vertices' places in ``watched`` (m,), ``offsets`` (k, 3) mm their pushes, and
    the spread matrix (m, m) is given by its CSC arrays; a pushed vertex takes the others' spread
    on top of its own push, not its own again (continuous as its push falls to 0)."""
    m = watched.shape[0]
    around = np.zeros((m, 3))
    reached = np.zeros(m, np.bool_)
    for j in range(slots.shape[0]):
        s = slots[j]
        for e in range(indptr[s], indptr[s + 1]):
            r = indices[e]
            if r == s:
                continue
            w = data[e]
            around[r, 0] += w * offsets[j, 0]
            around[r, 1] += w * offsets[j, 1]
            around[r, 2] += w * offsets[j, 2]
            reached[r] = True
    for r in range(m):
        if reached[r]:
            v = watched[r]
            x[v, 0] += around[r, 0]
            x[v, 1] += around[r, 1]
            x[v, 2] += around[r, 2]


@_JIT
def rotate_rows(x, rows, centre, rotation, target):  # pragma: no cover - compiled
    """x[rows] = (x[rows] - centre) @ rotation.T + target, in place (an eyeball's gaze: turned
    about ``centre``, which goes to ``target``)."""
    for r in rows:
        px, py, pz = x[r, 0] - centre[0], x[r, 1] - centre[1], x[r, 2] - centre[2]
        for c in range(3):
            x[r, c] = px * rotation[c, 0] + py * rotation[c, 1] + pz * rotation[c, 2] + target[c]


@_JIT
def rows_equal(x, rows, seen):  # pragma: no cover - compiled
    """Whether x[rows] (k, 3) equals ``seen`` (k, 3) exactly (stops at the first difference)."""
    for i in range(rows.shape[0]):
        r = rows[i]
        if x[r, 0] != seen[i, 0] or x[r, 1] != seen[i, 1] or x[r, 2] != seen[i, 2]:
            return False
    return True


@_JIT
def put_rows(x, rows, values):  # pragma: no cover - compiled
    """x[rows] = values (k, 3), in place."""
    for i in range(rows.shape[0]):
        r = rows[i]
        x[r, 0], x[r, 1], x[r, 2] = values[i, 0], values[i, 1], values[i, 2]


@_JIT
def _ramp(value, start, full):  # pragma: no cover - compiled
    r = (value - start) / (full - start)
    return 0.0 if r < 0.0 else (1.0 if r > 1.0 else r)


@_JIT
def strain_severity(x, rest, tris, inv, rest_normals, measurable, big0, big1, small0, small1, turn0, turn1,
                    last_x, last_out, out):  # pragma: no cover - compiled
    """out[t] (T,) = the surface guard's severity of skin triangle t in the pose x (n, 3)
    (``surface_guard.SurfaceGuard.severity``; 0 where no corner moved from ``rest``): its largest and
    smallest principal stretch against its rest frame (inverse (a, b, d) per row of ``inv``) and the
    cosine of its turn from its rest normal, each ramped to 0..1, the largest of the three. Triangles
    none of whose corners differ from ``last_x`` keep ``last_out`` (the last call's pose and result;
    a slider moves one region): pass an empty ``last_x`` to measure every triangle."""
    n = x.shape[0]
    moved = np.zeros(n, np.bool_)
    changed = np.ones(n, np.bool_)
    remember = last_x.shape[0] == n
    for v in range(n):
        moved[v] = x[v, 0] != rest[v, 0] or x[v, 1] != rest[v, 1] or x[v, 2] != rest[v, 2]
        if remember:
            changed[v] = x[v, 0] != last_x[v, 0] or x[v, 1] != last_x[v, 1] or x[v, 2] != last_x[v, 2]
    for t in range(tris.shape[0]):
        i0, i1, i2 = tris[t, 0], tris[t, 1], tris[t, 2]
        if remember and not (changed[i0] or changed[i1] or changed[i2]):
            out[t] = last_out[t]
            continue
        out[t] = 0.0
        if not measurable[t] or not (moved[i0] or moved[i1] or moved[i2]):
            continue
        e1x, e1y, e1z = x[i1, 0] - x[i0, 0], x[i1, 1] - x[i0, 1], x[i1, 2] - x[i0, 2]
        e2x, e2y, e2z = x[i2, 0] - x[i0, 0], x[i2, 1] - x[i0, 1], x[i2, 2] - x[i0, 2]
        l1 = np.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
        if l1 < 1e-12:
            l1 = 1e-12
        along = (e2x * e1x + e2y * e1y + e2z * e1z) / l1
        across = np.sqrt(max(e2x * e2x + e2y * e2y + e2z * e2z - along * along, 0.0))
        # F = [[l1, along], [0, across]] @ [[a, b], [0, d]]; its singular values in closed form.
        a, b, d = inv[t, 0], inv[t, 1], inv[t, 2]
        f00, f01, f11 = l1 * a, l1 * b + along * d, across * d
        s1 = f00 * f00 + f01 * f01 + f11 * f11
        s2 = np.sqrt(max((f00 * f00 + f01 * f01 - f11 * f11) ** 2 + 4.0 * (f01 * f11) ** 2, 0.0))
        big = np.sqrt(max((s1 + s2) / 2.0, 0.0))
        small = np.sqrt(max((s1 - s2) / 2.0, 0.0))
        if a == 0.0 and d == 0.0:
            big, small = 1.0, 1.0
        nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
        nn = np.sqrt(nx * nx + ny * ny + nz * nz)
        if nn < 1e-12:
            nn = 1e-12
        turn = (nx * rest_normals[t, 0] + ny * rest_normals[t, 1] + nz * rest_normals[t, 2]) / nn
        out[t] = max(_ramp(big, big0, big1), _ramp(small, small0, small1), _ramp(turn, turn0, turn1))


@_JIT
def _next_ring(order, where, start, count, indptr, indices):  # pragma: no cover - compiled
    """Append to ``order`` (and mark in ``where``) the unmarked neighbours of order[start:count];
    the new count."""
    for i in range(start, count):
        v = order[i]
        for k in range(indptr[v], indptr[v + 1]):
            w = indices[k]
            if where[w] < 0:
                where[w] = count
                order[count] = w
                count += 1
    return count


@_JIT
def guard_smooth(x, rest, indptr, indices, weights, held, taper, strength, rings, steps):  # pragma: no cover - compiled
    """The surface guard's smoothing (``surface_guard.SurfaceGuard.apply`` after the severity), in
    place: ``strength`` (n,) the per-vertex severity (0 where no breaking triangle touches), spread
    over ``rings`` rings falling off by 1 / (rings + 1) a ring, times ``taper``; then x_v += a_v ·
    ((P^steps u)_v − u_v), u = x − rest, P the neighbours' mean weighted by ``weights`` (CSR rows
    ``indptr``/``indices``; held rows keep their value). Returns how many vertices moved."""
    n = x.shape[0]
    where = np.full(n, -1, np.int64)          # position in ``order`` or -1
    order = np.empty(n, np.int64)
    count = 0
    for v in range(n):
        if strength[v] > 0.0:
            where[v] = count
            order[count] = v
            count += 1
    # Grow the region ring by ring, spreading the strength (a Jacobi max: each ring reads the last).
    step = 1.0 / (rings + 1)
    start = 0
    for _ in range(rings):
        start, count = count, _next_ring(order, where, start, count, indptr, indices)
        spread = np.empty(count)
        for i in range(count):
            v = order[i]
            best = strength[v]
            for k in range(indptr[v], indptr[v + 1]):
                s = strength[indices[k]] - step
                if s > best:
                    best = s
            spread[i] = best
        for i in range(count):
            strength[order[i]] = spread[i]
    # Only the region's vertices with a strength left after the taper move: they seed the support.
    region = 0
    for i in range(count):
        v = order[i]
        strength[v] *= taper[v]
        if strength[v] > 0.0:
            order[region] = v
            where[v] = region
            region += 1
        else:
            where[v] = -1
    count = region
    # The support of P^steps at the region: ``steps`` more rings; ends[r] = where ring r ends in ``order``.
    ends = np.empty(steps + 1, np.int64)
    ends[0] = count
    start = 0
    for r in range(steps):
        start, count = count, _next_ring(order, where, start, count, indptr, indices)
        ends[r + 1] = count
    # The support's own rows (local indices, contiguous): each step reads them in order. A neighbour
    # beyond the support keeps its displacement through every step: its share is a constant.
    u = np.empty((count, 3))
    for i in range(count):
        v = order[i]
        for c in range(3):
            u[i, c] = x[v, c] - rest[v, c]
    row = np.empty(count + 1, np.int64)
    col = np.empty(indptr[order[:count] + 1].sum() - indptr[order[:count]].sum(), np.int64)
    wts = np.empty(col.shape[0])
    inv_total = np.empty(count)
    beyond = np.zeros((count, 3))
    k_out = 0
    for i in range(count):
        v = order[i]
        row[i] = k_out
        total = 0.0
        for k in range(indptr[v], indptr[v + 1]):
            w = indices[k]
            wt = weights[k]
            total += wt
            j = where[w]
            if j >= 0:
                col[k_out] = j
                wts[k_out] = wt
                k_out += 1
            else:
                for c in range(3):
                    beyond[i, c] += wt * (x[w, c] - rest[w, c])
        inv_total[i] = 1.0 / total
    row[count] = k_out
    smooth = u.copy()
    nxt = np.empty((count, 3))
    for step in range(steps):
        # Step ``step`` is needed only within steps - 1 - step rings of the region (a pyramid: the
        # last step reads the region alone; 40 % fewer vertex updates on a strained composite).
        for i in range(ends[steps - 1 - step]):
            if held[order[i]]:
                nxt[i, 0], nxt[i, 1], nxt[i, 2] = smooth[i, 0], smooth[i, 1], smooth[i, 2]
                continue
            a0, a1, a2 = beyond[i, 0], beyond[i, 1], beyond[i, 2]
            for k in range(row[i], row[i + 1]):
                j = col[k]
                wt = wts[k]
                a0 += wt * smooth[j, 0]
                a1 += wt * smooth[j, 1]
                a2 += wt * smooth[j, 2]
            f = inv_total[i]
            nxt[i, 0], nxt[i, 1], nxt[i, 2] = a0 * f, a1 * f, a2 * f
        smooth, nxt = nxt, smooth
    moved = 0
    for i in range(region):
        v = order[i]
        a = strength[v]
        if a > 0.0:
            moved += 1
            for c in range(3):
                x[v, c] += a * (smooth[i, c] - u[i, c])
    return moved
