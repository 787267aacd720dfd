"""The drawn membrane of a spring sheet (issue: endoscopic realism): the mesentery of
seed 001 (§3.1-3.2, Fig. 5-6), a few rows of masses from the intestine to the root,
drawn as the tensor-product Catmull-Rom surface (Catmull & Rom 1974) through its
masses instead of as their grid of flat triangles. The surface passes through every
mass, is C1 between them, and is sampled ``across`` times finer between rows and
``along`` times between columns; each sample's normal is the cross product of the
surface's own partial derivatives, so the membrane shades smoothly without facets.
It is drawn with a thickness: two layers, half of it to either side of the surface,
facing away from each other, and a rim joining them around the border (a closed
shell), so that its edges show as tissue and each side is lit as itself.

One row beyond each edge of the grid is extrapolated quadratically (3 P_edge - 3 P_next
+ P_after), so the end spans follow the parabola through the last three rows instead
of flattening (linear extrapolation erred 0.37 mm on a 5 cm cylinder sampled every
18°, the flat triangles 0.6 mm).
"""

import taichi as ti


@ti.func
def catmull_rom(t):
    """The four uniform Catmull-Rom weights of the points around a span at ``t`` in
    [0, 1] and their derivatives d/dt: (weights, slopes), vec4 each."""
    t2, t3 = t * t, t * t * t
    weights = 0.5 * ti.Vector(
        [-t3 + 2.0 * t2 - t, 3.0 * t3 - 5.0 * t2 + 2.0, -3.0 * t3 + 4.0 * t2 + t, t3 - t2]
    )
    slopes = 0.5 * ti.Vector(
        [
            -3.0 * t2 + 4.0 * t - 1.0,
            9.0 * t2 - 10.0 * t,
            -9.0 * t2 + 8.0 * t + 1.0,
            3.0 * t2 - 2.0 * t,
        ]
    )
    return weights, slopes


@ti.func
def _extended(k, size):
    """Line k of an axis of ``size`` grid lines, k in [-1, size], as a combination of
    real lines: (indices, weights), three each. Inside, the line itself; one beyond an
    edge, the quadratic extrapolation 3 P_edge - 3 P_next + P_after (linear, 2 P_edge -
    P_next, on an axis of two lines)."""
    edge = ti.math.clamp(k, 0, size - 1)
    inward = edge - k  # +1 beyond the first line, -1 beyond the last, else 0
    indices = ti.Vector(
        [
            edge,
            ti.math.clamp(edge + inward, 0, size - 1),
            ti.math.clamp(edge + 2 * inward, 0, size - 1),
        ]
    )
    weights = ti.Vector([1.0, 0.0, 0.0])
    if inward != 0:
        weights = ti.Vector([3.0, -3.0, 1.0]) if size >= 3 else ti.Vector([2.0, -1.0, 0.0])
    return indices, weights


@ti.func
def grid_point(points: ti.template(), first, rows, cols, r, c):
    """Point (r, c) of the row-major ``rows`` x ``cols`` grid ``points[first + r cols +
    c]``, extrapolated one row or column beyond each edge (:func:`_extended`)."""
    row_lines, row_weights = _extended(r, rows)
    col_lines, col_weights = _extended(c, cols)
    point = ti.Vector([0.0, 0.0, 0.0])
    for a in ti.static(range(3)):
        for b in ti.static(range(3)):
            point += (
                row_weights[a] * col_weights[b] * points[first + row_lines[a] * cols + col_lines[b]]
            )
    return point


@ti.func
def membrane_sample(points: ti.template(), first, rows, cols, across, along, i, j):
    """Sample (i, j) of the membrane through the ``rows`` x ``cols`` grid of
    ``points`` from ``first``: its point, partial derivatives along the rows and the
    columns, and unit normal (their cross product)."""
    r, c = ti.min(i // across, rows - 2), ti.min(j // along, cols - 2)
    weights_r, slopes_r = catmull_rom(i / across - r)
    weights_c, slopes_c = catmull_rom(j / along - c)
    point = ti.Vector([0.0, 0.0, 0.0])
    d_row, d_col = point, point
    for a in ti.static(range(4)):
        for b in ti.static(range(4)):
            q = grid_point(points, first, rows, cols, r - 1 + a, c - 1 + b)
            point += weights_r[a] * weights_c[b] * q
            d_row += slopes_r[a] * weights_c[b] * q
            d_col += weights_r[a] * slopes_c[b] * q
    return point, d_row, d_col, d_row.cross(d_col).normalized(1e-12)


@ti.func
def rim_sample(k, fine_rows, fine_cols):
    """The k-th sample around the border of a fine_rows x fine_cols grid (first row
    forwards, last column, last row backwards, first column; each corner once) and
    the side it lies on: (i, j, side), sides 0-3 in that order."""
    across, down = fine_cols - 1, fine_rows - 1
    i, j, side = 0, k, 0
    if k >= across + down + across:
        i, j, side = down - (k - 2 * across - down), 0, 3
    elif k >= across + down:
        i, j, side = down, across - (k - across - down), 2
    elif k >= across:
        i, j, side = k - across, across, 1
    return i, j, side


@ti.kernel
def membrane_vertices(
    points: ti.template(),
    first: ti.i32,
    rows: ti.i32,
    cols: ti.i32,
    across: ti.i32,
    along: ti.i32,
    half_thickness: ti.f32,
    positions: ti.template(),
    normals: ti.template(),
    offset: ti.i32,
):
    """The membrane through the ``rows`` x ``cols`` grid of ``points`` starting at
    ``first`` (row-major), as a shell ``2 half_thickness`` [m] thick, into
    ``positions`` and unit ``normals`` from ``offset``: the S = ((rows - 1) ``across`` +
    1) x F samples, F = (cols - 1) ``along`` + 1 (sample (i, j) lies i / across rows
    and j / along columns from the first point), moved by half_thickness along the
    surface's normal (the front, at offset + i F + j), then moved against it with the
    normal reversed (the back, at offset + S + i F + j), then the rim around the
    border (:func:`rim_sample`, R samples): front corners at offset + 2 S + k, back
    ones at offset + 2 S + R + k, each with the outward normal across the border and
    the very position of the front or back sample it joins (the shell is watertight
    to the bit, so it can be drawn one-sided)."""
    fine_rows, fine_cols = (rows - 1) * across + 1, (cols - 1) * along + 1
    count = fine_rows * fine_cols
    for i, j in ti.ndrange(fine_rows, fine_cols):
        point, _, _, n = membrane_sample(points, first, rows, cols, across, along, i, j)
        positions[offset + i * fine_cols + j] = point + half_thickness * n
        normals[offset + i * fine_cols + j] = n
        positions[offset + count + i * fine_cols + j] = point - half_thickness * n
        normals[offset + count + i * fine_cols + j] = -n
    border = 2 * (fine_rows - 1) + 2 * (fine_cols - 1)
    for k in range(border):
        i, j, side = rim_sample(k, fine_rows, fine_cols)
        _, d_row, d_col, n = membrane_sample(points, first, rows, cols, across, along, i, j)
        out = -d_row
        if side == 1:
            out = d_col
        elif side == 2:
            out = d_row
        elif side == 3:
            out = -d_col
        out = (out - out.dot(n) * n).normalized(1e-12)
        rim = offset + 2 * count
        positions[rim + k] = positions[offset + i * fine_cols + j]
        positions[rim + border + k] = positions[offset + count + i * fine_cols + j]
        normals[rim + k] = out
        normals[rim + border + k] = out
