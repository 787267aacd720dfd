"""Polygon baseline of seed 000 §4.4: exact triangle features instead of spheres.

Closest points of Ericson 2004, "Real-Time Collision Detection": segment-segment and
segment-triangle from :mod:`~taichi_lap.kernels.collision.closest_points`, barycentric
coordinates (§3.4) here. Responses are PBD
projections (Müller et al. 2007 §3.4), weighted by the corners' inverse masses:

* vertex-triangle: a vertex whose projection falls inside the other triangle keeps at
  least ``polygon_thickness`` [m] on the side of the triangle's plane it started the
  substep on; constraint C = side (v - a)·n - h, gradients side n for the vertex and
  -side b_k n for the triangle's corners (b its barycentric coordinates);
* edge-edge: interior closest points c1(s), c2(t) keep at least h apart along the
  direction they had at the substep's start; gradients (1-s) n, s n on the first edge;
* tool: each vertex (once, by its owner corner) is projected to the surface of the
  tool's union of shapes; the axis segment of every sphere or capsule shape is
  projected out of the triangle's interior (segment-triangle closest points).

Each triangle computes its own side of a pair (the other triangle computes the
mirror image), adding corrections to local accumulators of its three corners;
:func:`~taichi_lap.kernels.collision.response.detect_and_respond` averages and applies them.
"""

import taichi as ti
from taichi_lap.kernels.collision.closest_points import segment_segment, segment_triangle
from taichi_lap.kernels.collision.tool_shapes import round_shape, tool_distance

from taichi_lap.core.instruments import MAX_TOOL_SHAPES


@ti.func
def barycentric(q, a, b, c):
    """Barycentric coordinates of ``q`` in the plane of a, b, c (Ericson §3.4)."""
    v0, v1, v2 = b - a, c - a, q - a
    d00, d01, d11 = v0.dot(v0), v0.dot(v1), v1.dot(v1)
    d20, d21 = v2.dot(v0), v2.dot(v1)
    denom = ti.max(d00 * d11 - d01 * d01, 1e-30)
    v = (d11 * d20 - d01 * d21) / denom
    w = (d00 * d21 - d01 * d20) / denom
    return ti.Vector([1.0 - v - w, v, w])


@ti.func
def vertex_face(v, v0, w_v, a, b, c, a0, b0, c0, w_f, thickness):
    """Vertex-triangle projection (module docstring): (hit, correction of the vertex,
    barycentric weights b, scalar λ side) with the face corners' corrections
    -λ side w_f[k] b[k] n; ``v0``, ``a0``.. are start positions."""
    n = (b - a).cross(c - a)
    twice_area = n.norm()
    n = n / ti.max(twice_area, 1e-30)
    n0 = (b0 - a0).cross(c0 - a0)
    side = ti.select((v0 - a0).dot(n0) >= 0.0, 1.0, -1.0)
    dist = side * (v - a).dot(n)
    hit, dv, bary, lam = 0, ti.Vector([0.0, 0.0, 0.0]), ti.Vector([0.0, 0.0, 0.0]), 0.0
    if dist < thickness and twice_area > 1e-20:  # degenerate faces: edges handle them
        bary = barycentric(v - (v - a).dot(n) * n, a, b, c)
        denom = w_v + (bary * bary * w_f).sum()
        if bary.min() >= 0.0 and denom > 0.0:
            lam = side * (thickness - dist) / denom
            dv = lam * w_v * n
            hit = 1
    return hit, dv, bary, lam * n


@ti.func
def edge_edge(p1, q1, p10, q10, wp, wq, p2, q2, p20, q20, wp2, wq2, thickness):
    """Edge-edge projection (module docstring): (hit, correction of p1, of q1)."""
    s, t, c1, c2 = segment_segment(p1, q1, p2, q2)
    hit, dp, dq = 0, ti.Vector([0.0, 0.0, 0.0]), ti.Vector([0.0, 0.0, 0.0])
    if 0.0 < s < 1.0 and 0.0 < t < 1.0:
        start = (p10 + s * (q10 - p10)) - (p20 + t * (q20 - p20))
        if start.norm() > 1e-12:
            n = start.normalized()
            gap = (c1 - c2).dot(n)
            denom = wp * (1 - s) ** 2 + wq * s * s + wp2 * (1 - t) ** 2 + wq2 * t * t
            if gap < thickness and denom > 0.0:
                lam = (thickness - gap) / denom
                dp, dq, hit = lam * wp * (1.0 - s) * n, lam * wq * s * n, 1
    return hit, dp, dq


@ti.func
def add_corner(acc, count, corner, delta):
    """Row ``corner`` of the local accumulator ``acc`` (3 x 3) += ``delta``, and
    count[corner] += 1; locals, so no atomics (see :mod:`kernels.collision.spatial_hash`)."""
    for r in ti.static(range(3)):
        if corner == r:
            for c in ti.static(range(3)):
                acc[r, c] += delta[c]
            count[r] += 1
    return acc, count


@ti.func
def polygon_pair(coll: ti.template(), t, u, acc, hits):
    """Triangle t's side of the vertex-triangle and edge-edge tests against u, added to
    t's corner accumulators; returns (corrections, acc, hits). Runtime loops over the
    features keep one inlined copy of each test."""
    vt, vu = coll.tri_vertex[t], coll.tri_vertex[u]
    h = coll.polygon_thickness
    tw = ti.Vector([coll.corner_inv_mass[3 * t + k] for k in ti.static(range(3))])
    uw = ti.Vector([coll.corner_inv_mass[3 * u + k] for k in ti.static(range(3))])
    count = 0
    for test in range(6):  # t's vertices against u's face, then u's against t's
        k = test % 3
        mine = test < 3
        vertex, face = ti.select(mine, vt[k], vu[k]), ti.select(mine, vu, vt)
        w_v, w_f = ti.select(mine, tw[k], uw[k]), ti.select(mine, uw, tw)
        hit, dv, bary, lam_n = vertex_face(
            coll.vertex_p[vertex],
            coll.vertex_x[vertex],
            w_v,
            coll.vertex_p[face[0]],
            coll.vertex_p[face[1]],
            coll.vertex_p[face[2]],
            coll.vertex_x[face[0]],
            coll.vertex_x[face[1]],
            coll.vertex_x[face[2]],
            w_f,
            h,
        )
        if hit:
            count += 1
            if mine:
                acc, hits = add_corner(acc, hits, k, dv)
            else:
                for j in ti.static(range(3)):
                    if bary[j] > 1e-6:
                        acc, hits = add_corner(acc, hits, j, -lam_n * tw[j] * bary[j])
    for test in range(9):  # edge i of t against edge j of u
        i, j = test // 3, test % 3
        i1, j1 = (i + 1) % 3, (j + 1) % 3
        hit, dp, dq = edge_edge(
            coll.vertex_p[vt[i]],
            coll.vertex_p[vt[i1]],
            coll.vertex_x[vt[i]],
            coll.vertex_x[vt[i1]],
            tw[i],
            tw[i1],
            coll.vertex_p[vu[j]],
            coll.vertex_p[vu[j1]],
            coll.vertex_x[vu[j]],
            coll.vertex_x[vu[j1]],
            uw[j],
            uw[j1],
            h,
        )
        if hit:
            acc, hits = add_corner(acc, hits, i, dp)
            acc, hits = add_corner(acc, hits, i1, dq)
            count += 1
    return count, acc, hits


@ti.func
def polygon_tool(coll: ti.template(), control: ti.template(), t, tool, pose, acc, hits):
    """Triangle t against a kinematic tool at ``pose``: vertices projected to the
    surface of the union, triangle interior pushed off the axis of each round shape,
    added to t's corner accumulators. Returns (corrections, acc, hits)."""
    v = coll.tri_vertex[t]
    w = ti.Vector([coll.corner_inv_mass[3 * t + k] for k in ti.static(range(3))])
    count = 0
    for k in range(3):
        if coll.corner_owner[3 * t + k] and w[k] > 0.0:
            dist, grad = tool_distance(control, tool, pose, coll.vertex_p[v[k]])
            if dist < 0.0:
                acc, hits = add_corner(acc, hits, k, -dist * grad)
                count += 1
    p0, p1, p2 = coll.vertex_p[v[0]], coll.vertex_p[v[1]], coll.vertex_p[v[2]]
    for s in range(MAX_TOOL_SHAPES):
        round_, a, b, r = round_shape(control, tool * MAX_TOOL_SHAPES + s, pose)
        if round_:
            _, bary, on_seg, on_tri = segment_triangle(a, b, p0, p1, p2)
            gap = on_tri - on_seg
            dist = gap.norm()
            denom = (bary * bary * w).sum()
            if dist < r and denom > 0.0:
                n = coll.start_normal[t]
                if dist > 1e-9:
                    n = gap / dist
                lam = (r - dist) / denom
                for j in ti.static(range(3)):
                    if bary[j] > 1e-6 and w[j] > 0.0:
                        acc, hits = add_corner(acc, hits, j, lam * w[j] * bary[j] * n)
                count += 1
    return count, acc, hits
