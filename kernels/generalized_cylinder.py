"""Generalized-cylinder tubes (intestine, vessels, bile duct): a cylinder skinned along a
cardinal spline through the mechanical points (seed 001 §5, Raghupathi et al. 2004).

A tube is a range [start, end) of ``points`` [m] with a ``radius`` [m] per point.

1. §5.1 step 1. Cardinal spline through the points, tangent m_i = τ (P_{i+1} - P_{i-1}),
   τ = (1 - tension) / 2 (Catmull-Rom for tension 0). Ghost points beyond the ends by
   the Bessel technique: P_{-1} = 3 P_0 - 3 P_1 + P_2, the parabola through P_0, P_1, P_2
   at u = -1 (2 P_0 - P_1 for a two-point tube). Curvature indicator per point, Eq. 10:
   c_i = ½ (P_{i,i-1}·P_{i,i+1} / (|P_{i,i-1}| |P_{i,i+1}|) + 1), P_{i,j} = P_j - P_i:
   0 on a straight line, 1 at a full reversal. (The extracted text reads P_{i-1,i}, which
   gives 1 on a straight line, against the paper's "higher curvature ... higher c_i".)
2. §5.1 step 2. Segment [u_i, u_{i+1}] with c_i >= ε or c_{i+1} >= ε gets the samples
   m - δ and m + δ', δ = (m - u_i) / 3, δ' = (u_{i+1} - m) / 3 (Eq. 11), around m, the
   parameter of maximal curvature κ = |p' × p''| / |p'|³. The paper's closed form for m
   ("a linear equation") is not in the extracted text; m is found by a 17-point scan and
   16 golden-section steps (to ~6e-5 of the segment). A sample closer than KNOT_GAP to a
   knot is dropped (m at a knot: the knot is already a sample). So a segment holds 1 to
   3 samples: capacity is fixed.
3. §5.2 Eq. 12. Frames (t, k, b) at the samples, t = p'/|p'|: at the first sample the
   last call's first normal turned onto the new tangent (rotation-minimising in time,
   so the tube's detail does not spin about it as its first bend turns; the Frenet
   frame on the first call), then rotation-minimising frames by double reflection
   (Wang et al. 2008, ACM TOG 27(1)). Eq. 12 (b_j = t_j × k_{j-1}, k_j = b_j × t_j) is
   the projection method: it is singular when t_j is parallel to k_{j-1}, a turn of 90°
   between two samples, which the Eq. 11 samples at sharp bends produce. Serial along a
   tube, parallel across tubes.
4. §5.2 Eq. 1, 13, 14. Each interval between samples j, j+1 is the cylinder x² + y² = 1,
   z in [0, 1] (Eq. 13), at level n cut by 2^(n+1) rings (§5.2: "2^(n+1) sections";
   the end rings are shared with the neighbouring intervals), skinned by
   X = ω(z) M_1 X_0 + (1 - ω(z)) M_2 X_0 (Eq. 1) with
   M_1 X_0 = p_j + r_j (x k_j + y b_j) + z L t_j,
   M_2 X_0 = p_{j+1} + r_{j+1} (x k_{j+1} + y b_{j+1}) + (z - 1) L t_{j+1},
   L = |p_{j+1} - p_j|. The second branch of Eq. 14 is unreadable; ω(z) = 1 - 2 z² for
   z < ½ and 2 (1 - z)² above continues its first branch: C¹, from 1 to 0, ω' = 0 at both
   ends (the skinned axis leaves each sample along t, so intervals join with G¹).
   Normals: ∂X/∂φ × (c' + (r'/r) q) with c the skinned axis and q the vertex offset,
   the normal of the skinned cylinder without the frame-rotation term ω' (k_1 - k_2) of
   ∂X/∂z, which flips where the unclamped surface would fold (step 5).
5. Plane clearance (not in the paper). Blending alone still lets consecutive rings cross
   on the inner side of a bend tighter than the radius (with the Eq. 11 samples, a 120°
   bend of segments h folds from r ~ 0.2 h). Every skinned ring is a planar ellipse;
   a vertex offset is scaled towards the ring centre (the ring stays star-shaped) so
   it stays behind the next ring's plane and ahead of the previous one by at least
   PLANE_MARGIN of the ring centres' clearance: the inner side of a kink pinches
   instead of folding. Normals keep the unpinched value.

Output (see taichi_lap.render.tubes.TubeMesh): ``sides`` vertices per ring, rings of all tubes
packed in order; two triangles per side and band between consecutive rings of a tube,
counter-clockwise seen from outside. No float atomics: results are deterministic.
"""

import math

import taichi as ti

KNOT_GAP = 0.05  # an Eq. 11 sample closer than this (segment parameter) to a knot is dropped
SCAN_POINTS = 16  # curvature scan intervals before the golden-section search
GOLDEN_STEPS = 16
GOLDEN = 0.5 * (math.sqrt(5.0) - 1.0)  # golden-section ratio
PLANE_MARGIN = 0.25  # fraction of the ring-centre clearance a vertex keeps to neighbour planes
START_NORMAL_KEPT = 0.5
"""The last call's first normal is kept (turned onto the new first tangent) while at
least this much of it lies across that tangent; less (no last call, or the tube's
start turned onto it) starts from the Frenet frame."""
REFERENCE_KEPT = 0.1
"""A sample's normal follows the tube's material direction (``sample_tubes``' reference)
where at least this much of it lies across the tangent; elsewhere (the direction
along the tube) it keeps the rotation-minimizing frame."""
FIRST_RING, LAST_RING = 1, 2  # ring_flags bits


@ti.func
def tube_of_point(tube_range, tube_count, i):
    """Tube t with tube_range[t] = [start, end) holding point i (ranges ascending), or -1."""
    lo, hi = 0, tube_count
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if tube_range[mid][0] <= i:
            lo = mid
        else:
            hi = mid
    t = lo
    if i < tube_range[t][0] or i >= tube_range[t][1]:
        t = -1
    return t


@ti.func
def owner(base, count, value):
    """Largest t < count with base[t] <= value (``base`` ascending, base[0] = 0)."""
    lo, hi = 0, count
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if base[mid] <= value:
            lo = mid
        else:
            hi = mid
    return lo


@ti.func
def control_point(points, start, end, k):
    """P_k for k in [start - 1, end]: the Bessel ghost points beyond the ends (Eq. 10)."""
    p = ti.Vector([0.0, 0.0, 0.0])
    if k < start:
        if end - start >= 3:
            p = 3.0 * points[start] - 3.0 * points[start + 1] + points[start + 2]
        else:
            p = 2.0 * points[start] - points[start + 1]
    elif k >= end:
        if end - start >= 3:
            p = 3.0 * points[end - 1] - 3.0 * points[end - 2] + points[end - 3]
        else:
            p = 2.0 * points[end - 1] - points[end - 2]
    else:
        p = points[k]
    return p


@ti.func
def spline_segment(points, start, end, i, tau):
    """Columns (a0, a1, a2, a3) of segment i, p(t) = a0 + a1 t + a2 t² + a3 t³, t in [0, 1],
    the cardinal Hermite cubic from P_i to P_{i+1} [m]."""
    q1, q2 = points[i], points[i + 1]
    m1 = tau * (q2 - control_point(points, start, end, i - 1))
    m2 = tau * (control_point(points, start, end, i + 2) - q1)
    return ti.Matrix.cols([q1, m1, 3.0 * (q2 - q1) - 2.0 * m1 - m2, 2.0 * (q1 - q2) + m1 + m2])


@ti.func
def spline_point(C, t):
    return C @ ti.Vector([1.0, t, t * t, t * t * t])


@ti.func
def spline_velocity(C, t):
    return C @ ti.Vector([0.0, 1.0, 2.0 * t, 3.0 * t * t])


@ti.func
def spline_acceleration(C, t):
    return C @ ti.Vector([0.0, 0.0, 2.0, 6.0 * t])


@ti.func
def curvature(C, t):
    """κ = |p' × p''| / |p'|³ of the spline C at t (in 1 / the unit of C)."""
    d1, d2 = spline_velocity(C, t), spline_acceleration(C, t)
    speed2 = d1.norm_sqr()
    kappa = 0.0
    if speed2 > 0.0:
        kappa = d1.cross(d2).norm() / (speed2 * ti.sqrt(speed2))
    return kappa


@ti.func
def peak_parameter(C):
    """m in [0, 1] maximising κ on segment C (Eq. 11): scan, then golden-section search."""
    best, best_kappa = 0, -1.0
    for k in range(SCAN_POINTS + 1):
        kappa = curvature(C, k / SCAN_POINTS)
        if kappa > best_kappa:
            best, best_kappa = k, kappa
    lo = ti.max(best - 1, 0) / SCAN_POINTS
    hi = ti.min(best + 1, SCAN_POINTS) / SCAN_POINTS
    x1, x2 = hi - GOLDEN * (hi - lo), lo + GOLDEN * (hi - lo)
    f1, f2 = curvature(C, x1), curvature(C, x2)
    for _ in range(GOLDEN_STEPS):
        if f1 < f2:
            lo, x1, f1 = x1, x2, f2
            x2 = lo + GOLDEN * (hi - lo)
            f2 = curvature(C, x2)
        else:
            hi, x2, f2 = x2, x1, f1
            x1 = hi - GOLDEN * (hi - lo)
            f1 = curvature(C, x1)
    return 0.5 * (lo + hi)


@ti.func
def peak_samples(m):
    """Eq. 11 samples of a segment with peak m: (first, second, count), parameters in (0, 1)."""
    first, second, count = 2.0 * m / 3.0, (1.0 + 2.0 * m) / 3.0, 2
    if first < KNOT_GAP:
        first, count = second, 1
    if second > 1.0 - KNOT_GAP:
        count -= 1
    return first, second, count


@ti.func
def curvature_indicator(points, start, end, i):
    """c_i of Eq. 10 at point i (ghost points at the ends)."""
    a = control_point(points, start, end, i - 1) - points[i]
    b = control_point(points, start, end, i + 1) - points[i]
    den = a.norm() * b.norm()
    c = 0.0
    if den > 0.0:
        c = 0.5 * (a.dot(b) / den + 1.0)
    return c


@ti.kernel
def sample_tubes(
    tubes: ti.template(),
    points: ti.template(),
    radius: ti.template(),
    tube_range: ti.template(),
    tube_count: ti.i32,
    epsilon: ti.f32,
    level: ti.i32,
    reference: ti.template(),
    referenced: ti.template(),
):
    """§5.1 and Eq. 12: indicators, Eq. 11 samples, frames; then the output layout.

    Reads points [m], radius [m], tube_range (ivec2 [start, end), ascending, disjoint).
    Writes tubes.segment_* (per point), tubes.sample_* (packed per tube, starting at
    tubes.tube_sample_start), tubes.tube_ring_base / tube_band_base (tube_count + 1
    entries), the live counts and the padding ends of the next skin_tubes call.
    With ``referenced`` (compile time), each sample's normal is instead ``reference``
    (a direction per point fixed in the tube's material) interpolated to it and made
    normal to its tangent, where that is not too short: the frames, and the texcoords
    round the tube, then move with the material and do not drift in twist as the
    rotation-minimizing frames of a bending tube do (their holonomy).
    """
    tau = 0.5 * (1.0 - tubes.tension)
    point_end = 0
    if tube_count > 0:
        point_end = tube_range[tube_count - 1][1]
    for i in range(point_end):  # Eq. 10 and Eq. 11, one segment per point
        t = tube_of_point(tube_range, tube_count, i)
        if t >= 0:
            start, end = tube_range[t][0], tube_range[t][1]
            c = curvature_indicator(points, start, end, i)
            tubes.segment_indicator[i] = c
            tubes.segment_peak[i] = -1.0
            tubes.segment_sample_count[i] = 0
            if i + 1 < end:
                tubes.segment_sample_count[i] = 1
                if c >= epsilon or curvature_indicator(points, start, end, i + 1) >= epsilon:
                    C = spline_segment(points, start, end, i, tau)
                    m = peak_parameter(C / ti.max((points[i + 1] - points[i]).norm(), 1e-12))
                    tubes.segment_peak[i] = m
                    extra = peak_samples(m)[2]
                    tubes.segment_sample_count[i] = 1 + extra
    ti.loop_config(serialize=True)  # one thread, without the CPU's thread-pool launch
    for _ in range(1):  # serial prefix sums: sample slots, rings and bands per tube
        bands_per_interval = (1 << (level + 1)) - 1
        cursor, ring, band = 0, 0, 0
        for t in range(tube_count):
            start, end = tube_range[t][0], tube_range[t][1]
            tubes.tube_sample_start[t] = cursor
            tubes.tube_ring_base[t] = ring
            tubes.tube_band_base[t] = band
            if end - start >= 2:
                for i in range(start, end - 1):
                    tubes.segment_sample_start[i] = cursor
                    cursor += tubes.segment_sample_count[i]
                cursor += 1  # the end point
                bands = (cursor - tubes.tube_sample_start[t] - 1) * bands_per_interval
                ring += bands + 1
                band += bands
            tubes.tube_sample_count[t] = cursor - tubes.tube_sample_start[t]
        tubes.tube_ring_base[tube_count] = ring
        tubes.tube_band_base[tube_count] = band
        tubes.live_vertex_count[None] = ring * tubes.sides
        tubes.live_triangle_count[None] = 2 * band * tubes.sides
        tubes.vertex_write_end[None] = ti.max(ring * tubes.sides, tubes.padded_vertex_end[None])
        tubes.band_write_end[None] = ti.max(band, tubes.padded_band_end[None])
        tubes.padded_vertex_end[None] = ring * tubes.sides
        tubes.padded_band_end[None] = band
    for i in range(point_end):  # samples of segment i: its start knot, then the Eq. 11 samples
        t = tube_of_point(tube_range, tube_count, i)
        if t >= 0 and i + 1 < tube_range[t][1]:
            start, end = tube_range[t][0], tube_range[t][1]
            C = spline_segment(points, start, end, i, tau)
            s = tubes.segment_sample_start[i]
            count = tubes.segment_sample_count[i]
            first, second, _ = peak_samples(tubes.segment_peak[i])
            for k in range(count + (1 if i + 2 == end else 0)):
                u = 0.0
                if k == count:
                    u = 1.0
                elif k == 1:
                    u = first
                elif k == 2:
                    u = second
                tubes.sample_segment[s + k] = i
                tubes.sample_parameter[s + k] = u
                tubes.sample_position[s + k] = spline_point(C, u)
                tubes.sample_tangent[s + k] = spline_velocity(C, u).normalized(1e-20)
                tubes.sample_radius[s + k] = (1.0 - u) * radius[i] + u * radius[i + 1]
    for t in range(tube_count):  # Eq. 12: the first frame, then double reflection (serial)
        s0, count = tubes.tube_sample_start[t], tubes.tube_sample_count[t]
        if count >= 2:
            start, end = tube_range[t][0], tube_range[t][1]
            t0 = tubes.sample_tangent[s0]
            k = tubes.tube_start_normal[t]  # the last call's, turned onto t0
            k -= k.dot(t0) * t0
            if k.norm() < START_NORMAL_KEPT:  # Frenet
                C = spline_segment(points, start, end, start, tau)
                k = spline_acceleration(C, 0.0)
                k -= k.dot(t0) * t0
                if k.norm() <= 1e-3 * spline_velocity(C, 0.0).norm():  # straight: any normal
                    axis = ti.Vector([1.0, 0.0, 0.0])
                    if ti.abs(t0[0]) > 0.5:
                        axis = ti.Vector([0.0, 1.0, 0.0])
                    k = axis - axis.dot(t0) * t0
            k = k.normalized()
            tubes.tube_start_normal[t] = k
            tubes.sample_normal[s0] = k
            for j in range(s0, s0 + count - 1):
                v1 = tubes.sample_position[j + 1] - tubes.sample_position[j]
                c1 = v1.norm_sqr()
                r_l, t_l = k, tubes.sample_tangent[j]
                if c1 > 1e-24:
                    r_l -= (2.0 / c1) * v1.dot(k) * v1
                    t_l -= (2.0 / c1) * v1.dot(t_l) * v1
                t1 = tubes.sample_tangent[j + 1]
                v2 = t1 - t_l
                c2 = v2.norm_sqr()
                if c2 > 1e-24:
                    r_l -= (2.0 / c2) * v2.dot(r_l) * v2
                k = (r_l - r_l.dot(t1) * t1).normalized()
                tubes.sample_normal[j + 1] = k
            if ti.static(referenced):
                for j in range(s0, s0 + count):
                    i, u = tubes.sample_segment[j], tubes.sample_parameter[j]
                    r = (1.0 - u) * reference[i] + u * reference[ti.min(i + 1, end - 1)]
                    t1 = tubes.sample_tangent[j]
                    across = r - r.dot(t1) * t1
                    if across.norm() > REFERENCE_KEPT * r.norm():
                        tubes.sample_normal[j] = across.normalized()


@ti.func
def blend_weight(z):
    """ω(z) of Eq. 14 and its derivative: 1 - 2 z² (z < ½), 2 (1 - z)² (z >= ½)."""
    w, dw = 1.0 - 2.0 * z * z, -4.0 * z
    if z >= 0.5:
        w, dw = 2.0 * (1.0 - z) * (1.0 - z), -4.0 * (1.0 - z)
    return w, dw


@ti.func
def clear_plane(q, own, other, clearance):
    """q (offset in the plane of normal ``own``) scaled towards the ring centre so that
    q·other <= clearance; scaling keeps the ring star-shaped around its centre."""
    g = other - other.dot(own) * own
    reach = q.dot(g)
    if reach > clearance:
        q *= ti.max(clearance, 0.0) / reach
    return q


CAP_RINGS = 3
"""Rings of a tube's rounded end cap, the pole included: at 30°, 60° and 90° of the
quarter circle from the end ring to the pole."""


def cap_size(sides: int) -> tuple[int, int]:
    """The vertices and triangles of one rounded end cap of a tube of ``sides``: its
    rings but the pole, the pole, and two triangles per side of each band but the
    last, which is a fan of one per side."""
    return (CAP_RINGS - 1) * sides + 1, (2 * CAP_RINGS - 1) * sides


@ti.func
def _capped(tubes: ti.template(), t, tube_count):
    """Whether tube t is live and has rings (its two caps are drawn)."""
    return t < tube_count and tubes.tube_ring_base[t + 1] > tubes.tube_ring_base[t]


@ti.func
def _end_ring(tubes: ti.template(), t, end):
    """The ring index of tube t's first (``end`` 0) or last (1) ring."""
    return tubes.tube_ring_base[t] if end == 0 else tubes.tube_ring_base[t + 1] - 1


@ti.func
def cap_vertex(tubes: ti.template(), t, end, k, spacing):
    """Vertex k of the cap at ``end`` (0: first ring, 1: last) of live tube t: (position,
    normal, texcoord). Ring i = k // sides + 1 of the quarter circle (the pole at i =
    CAP_RINGS) lies at angle θ = i · 90° / CAP_RINGS: centre + cos θ q(φ) + sin θ r
    (outward axis), q the end ring's own radius vector, the normal the sphere's; the
    texcoord continues the tube's (the distance along the axis, then the ring's)."""
    g = _end_ring(tubes, t, end)
    outward = tubes.ring_center_rate[g].normalized(1e-30) * (2.0 * end - 1.0)
    ring = ti.min(k // tubes.sides + 1, CAP_RINGS)
    theta = (0.5 * math.pi / CAP_RINGS) * ring
    phi = (2.0 * math.pi / tubes.sides) * (k - (ring - 1) * tubes.sides)
    radius = tubes.ring_radius[g]
    q = ti.cos(phi) * tubes.ring_a[g] + ti.sin(phi) * tubes.ring_b[g]
    across = ti.cos(theta) * q + ti.sin(theta) * radius * outward
    texcoord = ti.Vector(
        [
            spacing * tubes.ring_param[g] + (2.0 * end - 1.0) * radius * ti.sin(theta),
            radius * ti.cos(theta) * ti.cos(phi),
            radius * ti.cos(theta) * ti.sin(phi),
        ]
    )
    return tubes.ring_center[g] + across, across.normalized(1e-30), texcoord


@ti.kernel
def skin_tubes(
    tubes: ti.template(),
    tube_count: ti.i32,
    level: ti.i32,
    vertices: ti.template(),
    normals: ti.template(),
    indices: ti.template(),
    texcoords: ti.template(),
    vertex_offset: ti.i32,
    index_offset: ti.i32,
    cap_vertex_offset: ti.i32,
    cap_index_offset: ti.i32,
    spacing: ti.f32,
):
    """Eq. 1, 13, 14 and the plane clearance, after sample_tubes with the same level;
    then both ends of every live tube (at least one ring) closed with a rounded cap
    (:func:`cap_vertex`): per tube and end, (CAP_RINGS - 1) sides + 1 vertices from
    ``cap_vertex_offset`` and (2 CAP_RINGS - 1) sides triangles from
    ``cap_index_offset`` (absolute offsets), the first band stitched to the end ring's
    vertices; the caps of tubes beyond ``tube_count`` or without rings are zero
    vertices and degenerate triangles.

    Writes vertices [m], normals and texcoords (where the surface detail is evaluated:
    (spacing × the point parameter along the tube, the ring's radius × (cos φ, sin φ))
    [m], fixed to the tube's material however it bends) at vertex_offset + ring * sides
    + side, and
    indices[index_offset + 3 * triangle] (absolute vertex indices); slots between the
    live counts and the previous call's are padded: zero vertices, degenerate triangles
    (three times vertex_offset).
    """
    bands_per_interval = (1 << (level + 1)) - 1
    for g in range(tubes.tube_ring_base[tube_count]):  # ring planes: centre, axes, rates
        t = owner(tubes.tube_ring_base, tube_count, g)
        r = g - tubes.tube_ring_base[t]
        last = tubes.tube_ring_base[t + 1] - tubes.tube_ring_base[t] - 1
        j = r // bands_per_interval
        z = (r - j * bands_per_interval) / bands_per_interval
        if r == last:
            j, z = j - 1, 1.0
        s = tubes.tube_sample_start[t] + j
        p1, p2 = tubes.sample_position[s], tubes.sample_position[s + 1]
        t1, t2 = tubes.sample_tangent[s], tubes.sample_tangent[s + 1]
        k1, k2 = tubes.sample_normal[s], tubes.sample_normal[s + 1]
        r1, r2 = tubes.sample_radius[s], tubes.sample_radius[s + 1]
        length = (p2 - p1).norm()
        w, dw = blend_weight(z)
        x1, x2 = p1 + z * length * t1, p2 + (z - 1.0) * length * t2
        a1, a2 = r1 * k1, r2 * k2
        b1, b2 = r1 * t1.cross(k1), r2 * t2.cross(k2)
        tubes.ring_center[g] = w * x1 + (1.0 - w) * x2
        tubes.ring_center_rate[g] = dw * (x1 - x2) + length * (w * t1 + (1.0 - w) * t2)
        tubes.ring_a[g] = w * a1 + (1.0 - w) * a2
        tubes.ring_b[g] = w * b1 + (1.0 - w) * b2
        tubes.ring_taper[g] = dw * (r1 - r2) / ti.max(w * r1 + (1.0 - w) * r2, 1e-30)
        tubes.ring_plane[g] = tubes.ring_a[g].cross(tubes.ring_b[g]).normalized(1e-30)
        tubes.ring_flags[g] = (FIRST_RING if r == 0 else 0) | (LAST_RING if r == last else 0)
        u1 = tubes.sample_segment[s] + tubes.sample_parameter[s]
        u2 = tubes.sample_segment[s + 1] + tubes.sample_parameter[s + 1]
        tubes.ring_param[g] = (1.0 - z) * u1 + z * u2
        tubes.ring_radius[g] = w * r1 + (1.0 - w) * r2
    live_rings = tubes.tube_ring_base[tube_count]
    for v in range(tubes.vertex_write_end[None]):
        g = v // tubes.sides
        position, normal = ti.Vector([0.0, 0.0, 0.0]), ti.Vector([0.0, 0.0, 0.0])
        texcoord = ti.Vector([0.0, 0.0, 0.0])
        if g < live_rings:
            phi = (2.0 * math.pi / tubes.sides) * (v - g * tubes.sides)
            cs, sn = ti.cos(phi), ti.sin(phi)
            a, b, own = tubes.ring_a[g], tubes.ring_b[g], tubes.ring_plane[g]
            q = cs * a + sn * b
            x_phi = -sn * a + cs * b
            x_z = tubes.ring_center_rate[g] + tubes.ring_taper[g] * q
            normal = x_phi.cross(x_z)
            if normal.norm_sqr() <= 1e-8 * x_phi.norm_sqr() * x_z.norm_sqr():
                normal = q
            normal = normal.normalized(1e-30)
            flags, c = tubes.ring_flags[g], tubes.ring_center[g]
            if flags & LAST_RING == 0:
                ahead = tubes.ring_plane[g + 1]
                reach = (1.0 - PLANE_MARGIN) * (tubes.ring_center[g + 1] - c).dot(ahead)
                q = clear_plane(q, own, ahead, reach)
            if flags & FIRST_RING == 0:
                behind = tubes.ring_plane[g - 1]
                reach = (1.0 - PLANE_MARGIN) * (c - tubes.ring_center[g - 1]).dot(behind)
                q = clear_plane(q, own, -behind, reach)
            position = c + q
            rim = tubes.ring_radius[g]
            texcoord = ti.Vector([spacing * tubes.ring_param[g], rim * cs, rim * sn])
        vertices[vertex_offset + v] = position
        normals[vertex_offset + v] = normal
        texcoords[vertex_offset + v] = texcoord
    live_bands = tubes.tube_band_base[tube_count]
    for slot in range(tubes.band_write_end[None] * tubes.sides):  # 2 triangles per band and side
        band = slot // tubes.sides
        corners = ti.Vector([vertex_offset] * 6)
        if band < live_bands:
            t = owner(tubes.tube_band_base, tube_count, band)
            g = tubes.tube_ring_base[t] + band - tubes.tube_band_base[t]
            side = slot - band * tubes.sides
            a = vertex_offset + g * tubes.sides + side
            a_next = vertex_offset + g * tubes.sides + (side + 1) % tubes.sides
            b, b_next = a + tubes.sides, a_next + tubes.sides  # the same sides on the next ring
            corners = ti.Vector([a, a_next, b, a_next, b_next, b])
        for k in ti.static(range(6)):
            indices[index_offset + 6 * slot + k] = corners[k]
    sides = tubes.sides  # the rounded end caps (cap_vertex)
    per_cap, triangles_per_cap = ti.static(cap_size(tubes.sides))
    for slot in range(2 * tubes.tube_capacity * per_cap):
        cap = slot // per_cap
        t, end, k = cap // 2, cap % 2, slot - cap * per_cap
        position, normal, texcoord = (
            ti.Vector.zero(ti.f32, 3),
            ti.Vector.zero(ti.f32, 3),
            ti.Vector.zero(ti.f32, 3),
        )
        if _capped(tubes, t, tube_count):
            position, normal, texcoord = cap_vertex(tubes, t, end, k, spacing)
        vertices[cap_vertex_offset + slot] = position
        normals[cap_vertex_offset + slot] = normal
        texcoords[cap_vertex_offset + slot] = texcoord
    for slot in range(2 * tubes.tube_capacity * triangles_per_cap):
        cap = slot // triangles_per_cap
        t, end, k = cap // 2, cap % 2, slot - cap * triangles_per_cap
        corners = ti.Vector([vertex_offset] * 3)
        if _capped(tubes, t, tube_count):
            g = _end_ring(tubes, t, end)
            first = cap_vertex_offset + cap * per_cap
            band, side = k // (2 * sides), (k % (2 * sides)) // 2
            after = (side + 1) % sides
            if band < CAP_RINGS - 1:  # a band of two triangles per side
                inner_row = vertex_offset + g * sides if band == 0 else first + (band - 1) * sides
                outer_row = first + band * sides
                if k % 2 == 0:
                    corners = ti.Vector([inner_row + side, inner_row + after, outer_row + side])
                else:
                    corners = ti.Vector([inner_row + after, outer_row + after, outer_row + side])
            else:  # the fan to the pole, one triangle per side
                side = k - (CAP_RINGS - 1) * 2 * sides
                row = first + (CAP_RINGS - 2) * sides
                corners = ti.Vector([row + side, row + (side + 1) % sides, first + per_cap - 1])
            if end == 0:  # the first end's outward axis runs against the tube: turned round
                corners = corners.yxz
        for c in ti.static(range(3)):
            indices[cap_index_offset + 3 * slot + c] = corners[c]
