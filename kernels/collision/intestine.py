"""Stochastic self-collision detection and displacement-velocity response for the
intestine and mesentery (seed 001 §4, Raghupathi et al., IEEE TVCG 2004).

Elements: intestine *segments* (capsules of radius r [m] around the row-0 axis),
elements 0..S-1, then mesentery *triangles* (radius: half the thickness). Pairs
are (segment, segment) with a < b or (segment, triangle); mesentery-mesentery
pairs are ignored (§4.1). Elements of one organ are *neighbours*, never paired,
when the rest arc length of the intestine between them is under π (r1 + r2) / 2,
the arc of the tightest U-turn that brings them into contact. The gap of a pair
is d - r1 - r2 [m], d the distance of the skeletons (segment-triangle: edge-edge,
point-triangle and segment-through-triangle cases, the fix §7 gives for Fig. 13d).

Detection (§4.1, Fig. 7-8): active pairs track local minima of the gap under a
threshold (:func:`climb`); each detection draws n pairs from a PCG hash of (seed,
step, draw), even draws uniform as in the paper, odd draws near an active pair;
pairs that reach the same minimum merge. The contact areas ("a recursive
algorithm searches the neighbors to find all the colliding pairs in the area")
are kept over time like the pairs, a flood fill growing one ring per detection
(:func:`grow_contacts`). *In contact* is gap < skin, a margin that keeps a
resting contact, held at gap ~ 0 by the response, in one piece.

Lists stay in one canonical order, (a, b) ascending, rebuilt by a counting sort
(:func:`compact`) whose result does not depend on the order atomics ran in.
Integer atomics only, each at the top level of its parallel loop (Mesa's lavapipe
loses atomics in nested loops).

Response (§4.2, Eq. 2-9), on predicted positions p with v = (p - x) / h. For a
contact with closest points at parameter s on S1 and barycentric weights w on
element 2, unit direction u from element 2 to S1 and K = Σ β_k² / m_k over the
end-points (β = s̄, s, w0, w1, w2):
    f = -(v_c1 - v_c2)·u / K                                  (Eq. 7)
    g = (r1 + r2 - (x_c1 - x_c2)·u) / K                       (Eq. 9)
end-point k moves by ±β_k g u / m_k (Eq. 8) and its velocity changes by
±β_k f u / m_k (Eq. 4): p += Δx and x += Δx - h Δv, so that v = (p - x)/h carries
the velocity correction and the displacement adds no velocity (no bounce).
Contacts are answered one after the other in (a, b) order, ``passes`` sweeps in
one serial loop (Gauss-Seidel; the paper: "a fixed number of iterations"):
deterministic, each pair's impulses equal and opposite (momentum is conserved).
f and g accumulate over the sweeps, clamped at zero (projected Gauss-Seidel): a
contact pushes, never pulls, and an impulse a later sweep finds too large is
taken back, so contacts pushed by their neighbours do not bounce.
"""

import taichi as ti
from taichi_lap.kernels.collision.closest_points import segment_segment, segment_triangle

HUGE = 1e30


@ti.func
def pcg_hash(v):
    """PCG output permutation of a u32 (O'Neill 2014), the random source."""
    state = v * ti.u32(747796405) + ti.u32(2891336453)
    word = ((state >> ((state >> ti.u32(28)) + ti.u32(4))) ^ state) * ti.u32(277803737)
    return (word >> ti.u32(22)) ^ word


@ti.func
def closest(cd: ti.template(), x: ti.template(), a, b):
    """Closest points of segment ``a`` (pq) and element ``b`` at positions ``x`` [m]:
    (distance d [m], s on pq, weights w on b's vertices, point on a, point on b), by
    the segment-segment or segment-triangle routine of
    :mod:`~taichi_lap.kernels.collision.closest_points`."""
    va, vb = cd.element_vertex[a], cd.element_vertex[b]
    p, q = x[cd.particle_global[va[0]]], x[cd.particle_global[va[1]]]
    b0, b1 = x[cd.particle_global[vb[0]]], x[cd.particle_global[vb[1]]]
    s, w, xa, xb = 0.0, ti.Vector([1.0, 0.0, 0.0]), p, b0
    if vb[2] >= 0:
        s, w, xa, xb = segment_triangle(p, q, b0, b1, x[cd.particle_global[vb[2]]])
    else:
        s, t, on_pq, on_b = segment_segment(p, q, b0, b1)
        s, w, xa, xb = s, ti.Vector([1.0 - t, t, 0.0]), on_pq, on_b
    return (xa - xb).norm(), s, w, xa, xb


@ti.func
def gap(cd: ti.template(), x: ti.template(), a, b):
    """d - r1 - r2 [m]: negative when the pair collides."""
    d = closest(cd, x, a, b)[0]
    return d - cd.element_radius[a] - cd.element_radius[b]


@ti.func
def is_pair(cd: ti.template(), a, b):
    """True when segment ``a`` and element ``b > a`` exist, are not neighbours and
    ``b`` is live (not in a torn cell of the mesentery)."""
    ok = False
    if 0 <= a < cd.segment_count and a < b < cd.element_count:
        ok = cd.element_live[b] != 0
        if ok and cd.element_organ[a] == cd.element_organ[b]:
            arc_a, arc_b = cd.element_arc[a], cd.element_arc[b]
            arc_gap = ti.max(arc_b[0] - arc_a[1], arc_a[0] - arc_b[1])
            ok = arc_gap >= 0.5 * ti.math.pi * (cd.element_radius[a] + cd.element_radius[b])
    return ok


@ti.func
def around(cd: ti.template(), e, k):
    """Element ``e`` itself (k = 0), its k-th adjacent element (k = 1..3) or its
    far neighbour a stride back (k = 4) or ahead (k = 5); -1 if none."""
    r = e
    if k > 0:
        r = cd.element_neighbour[e][k - 1]
    return r


SEGMENT_STENCIL = [(i, j) for i in (0, 1, 2) for j in (0, 1, 2) if i or j] + [
    (i, j) for i in (0, 4, 5) for j in (0, 4, 5) if i or j
]
"""(k on a, k on b) of the pairs a segment-segment update tests (see :func:`around`)."""
GROWTH = 6
"""Candidates per listed contact when the areas grow: itself, then the pairs with a
replaced by its 2 neighbours or b by its (up to) 3 adjacent elements."""
TRIANGLE_STENCIL = [(1, 0), (2, 0), (4, 0), (5, 0), (0, 1), (0, 2), (0, 3), (0, 4), (0, 5)] + [
    (0, 0)
] * 7
"""The same for segment-triangle: the first four move a, the others b around a'."""


@ti.func
def climb(cd: ti.template(), x: ti.template(), a, b, g):
    """One local-minimum update of pair (a, b) with gap ``g`` [m] (§4.1, Fig. 8). Two
    segments: the closest of the 9 pairs (a or a neighbour) x (b or a neighbour),
    and of the same with far neighbours. A segment and a triangle, the two-step
    convergence: a' of {a, its neighbours} closest to b, then the closest of b and
    its adjacent triangles to a'. Where the sampling is finer than the paper's
    (stride = radius / segment length > 1), far neighbours a stride away are tested
    too, so the update steps over wrinkles shorter than the tube: at most 16
    distance tests for two segments (paper: 9), 9 for a segment and a triangle
    (paper: 13)."""
    best_a, best_b, best = a, b, g
    segment_stencil, triangle_stencil = ti.Matrix(SEGMENT_STENCIL), ti.Matrix(TRIANGLE_STENCIL)
    for n in range(16):
        ka, kb, base = segment_stencil[n, 0], segment_stencil[n, 1], a
        if b >= cd.segment_count:
            ka, kb = triangle_stencil[n, 0], triangle_stencil[n, 1]
            if n >= 4:
                base = best_a
        a2, b2 = around(cd, base, ka), around(cd, b, kb)
        lo, hi = ti.min(a2, b2), ti.max(a2, b2)
        if ka + kb > 0 and a2 >= 0 and b2 >= 0 and is_pair(cd, lo, hi):
            g2 = gap(cd, x, lo, hi)
            if g2 < best:
                best_a, best_b, best = lo, hi, g2
    return best_a, best_b, best


@ti.func
def random_pair(cd: ti.template(), seed, step, draw, active):
    """Draw ``draw`` of step ``step``, from a hash of (seed, step, draw): even draws a
    segment and any element, uniform (§4.1); odd draws, while there are ``active``
    pairs, a random active pair moved by up to ``explore`` elements on each side."""
    h = pcg_hash(seed ^ pcg_hash(step ^ pcg_hash(ti.u32(draw))))
    a = ti.i32(h % ti.u32(cd.segment_count))
    h = pcg_hash(h)
    b = ti.i32(h % ti.u32(cd.element_count))
    if draw % 2 == 1 and active > 0:
        k = ti.i32(h % ti.u32(active))
        span = ti.u32(2 * cd.explore + 1)
        h = pcg_hash(h)
        a = ti.math.clamp(cd.pair_a[k] + ti.i32(h % span) - cd.explore, 0, cd.segment_count - 1)
        h = pcg_hash(h)
        b = cd.pair_b[k] + ti.i32(h % span) - cd.explore
        if cd.pair_b[k] < cd.segment_count:
            b = ti.math.clamp(b, 0, cd.segment_count - 1)
        else:
            b = ti.math.clamp(b, cd.segment_count, cd.element_count - 1)
    return ti.min(a, b), ti.max(a, b)


@ti.kernel
def track_pairs(
    cd: ti.template(),
    x: ti.template(),
    seed: ti.u32,
    step: ti.u32,
    draws: ti.i32,
    threshold: ti.f32,
    climb_steps: ti.i32,
):
    """Update every active pair (at most ``climb_steps`` local-minimum updates) and
    draw ``draws`` new ones (§4.1); write the candidates (a = -1 when over
    ``threshold`` [m]) with their gaps [m]. Reads pair_*."""
    old = cd.pair_count[None]
    cd.candidate_count[None] = old + draws
    ti.loop_config(serialize=ti.static(cd.serial))
    for k in range(old + draws):
        a, b = -1, -1
        if k < old:
            a, b = cd.pair_a[k], cd.pair_b[k]
        else:
            a, b = random_pair(cd, seed, step, k - old, old)
        out_a, out_b, g = -1, -1, HUGE
        if is_pair(cd, a, b):
            g = gap(cd, x, a, b)
            for _ in range(climb_steps):  # until a local minimum
                a2, b2, g2 = climb(cd, x, a, b, g)
                if a2 == a and b2 == b:
                    break
                a, b, g = a2, b2, g2
            if g <= threshold:
                out_a, out_b = a, b
        cd.candidate_a[k], cd.candidate_b[k], cd.candidate_gap[k] = out_a, out_b, g


@ti.kernel
def compact(
    cd: ti.template(),
    src_a: ti.template(),
    src_b: ti.template(),
    src_gap: ti.template(),
    src_count: ti.template(),
    dst_a: ti.template(),
    dst_b: ti.template(),
    dst_gap: ti.template(),
    dst_count: ti.template(),
    dst_start: ti.template(),
    dst_dropped: ti.template(),
    capacity: ti.i32,
):
    """Valid source pairs (a >= 0) without duplicates into dst, sorted by (a, b): a
    counting sort over segments, then each segment's pairs sorted by (b, source
    index); dst_start[a] is where segment a's pairs begin. Pairs past ``capacity``
    are dropped and counted in ``dst_dropped``."""
    n = src_count[None]
    ti.loop_config(serialize=ti.static(cd.serial))
    for c in range(n):
        valid = ti.i32(src_a[c] >= 0)
        ti.atomic_add(cd.bucket_count[ti.max(src_a[c], 0)], valid)
    ti.loop_config(serialize=True)  # one thread, without the CPU's thread-pool launch
    for _ in range(1):
        total = 0
        for a in range(cd.segment_count):
            cd.bucket_start[a] = total
            total += cd.bucket_count[a]
            cd.bucket_fill[a] = 0
        cd.bucket_start[cd.segment_count] = total
    ti.loop_config(serialize=ti.static(cd.serial))
    for c in range(n):
        a = ti.max(src_a[c], 0)
        slot = cd.bucket_start[a] + ti.atomic_add(cd.bucket_fill[a], ti.i32(src_a[c] >= 0))
        if src_a[c] >= 0:
            cd.sorted_source[slot] = c
    ti.loop_config(serialize=ti.static(cd.serial))
    for a in range(cd.segment_count):
        lo, hi = cd.bucket_start[a], cd.bucket_start[a + 1]
        for i in range(lo + 1, hi):  # insertion sort by (b, source index)
            c = cd.sorted_source[i]
            j = i - 1
            while j >= lo:
                o = cd.sorted_source[j]
                if src_b[o] < src_b[c] or (src_b[o] == src_b[c] and o < c):
                    break
                cd.sorted_source[j + 1] = o
                j -= 1
            cd.sorted_source[j + 1] = c
        unique, last = 0, -1
        for i in range(lo, hi):
            if src_b[cd.sorted_source[i]] != last:
                unique += 1
                last = src_b[cd.sorted_source[i]]
        cd.bucket_unique[a] = unique
    ti.loop_config(serialize=True)  # one thread, without the CPU's thread-pool launch
    for _ in range(1):
        total = 0
        for a in range(cd.segment_count):
            cd.bucket_fill[a] = total
            dst_start[a] = ti.min(total, capacity)
            total += cd.bucket_unique[a]
            cd.bucket_count[a] = 0
        dst_start[cd.segment_count] = ti.min(total, capacity)
        dst_count[None] = ti.min(total, capacity)
        dst_dropped[None] = ti.max(total - capacity, 0)
    ti.loop_config(serialize=ti.static(cd.serial))
    for a in range(cd.segment_count):
        out, last = cd.bucket_fill[a], -1
        for i in range(cd.bucket_start[a], cd.bucket_start[a + 1]):
            c = cd.sorted_source[i]
            if src_b[c] != last and out < capacity:
                dst_a[out], dst_b[out], dst_gap[out] = a, src_b[c], src_gap[c]
                out += 1
            last = src_b[c]


@ti.func
def has_contact(cd: ti.template(), a, b):
    """Whether (a, b) is in the contact list (binary search in segment a's run)."""
    lo, hi = cd.contact_start[a], cd.contact_start[a + 1]
    while lo < hi:
        mid = (lo + hi) // 2
        if cd.contact_b[mid] < b:
            lo = mid + 1
        else:
            hi = mid
    found = False
    if lo < cd.contact_start[a + 1]:
        found = cd.contact_b[lo] == b
    return found


@ti.kernel
def grow_contacts(cd: ti.template(), x: ti.template(), retest: ti.i32, skin: ti.f32):
    """§4.1, the contact areas: candidates (area_*) for the next contact list, each
    a pair in contact (gap < ``skin`` [m]): every contact still in contact (re-tested
    at x when ``retest``), the pairs not yet listed that replace one of its elements
    by an adjacent one, and the active pairs in contact, the local minima. One ring
    of growth; region_count = colliding active pairs."""
    n, m = cd.contact_count[None], cd.pair_count[None]
    cd.area_count[None] = n * GROWTH + m
    cd.region_count[None] = 0
    ti.loop_config(serialize=ti.static(cd.serial))
    for k in range(m):
        ti.atomic_add(cd.region_count[None], ti.i32(cd.pair_gap[k] < 0.0))
    ti.loop_config(serialize=ti.static(cd.serial))
    for k in range(n * GROWTH + m):
        out_a, out_b, g = -1, -1, HUGE
        if k >= n * GROWTH:
            g = cd.pair_gap[k - n * GROWTH]
            if g < skin:
                out_a, out_b = cd.pair_a[k - n * GROWTH], cd.pair_b[k - n * GROWTH]
        else:
            c, j = k // GROWTH, k % GROWTH  # j: the contact, then (a's, b) and (a, b's)
            a, b = cd.contact_a[c], cd.contact_b[c]
            if j == 0:
                g = cd.contact_gap[c]
                if retest:
                    g = gap(cd, x, a, b)
                if g < skin and cd.element_live[b] != 0:  # its triangle may have torn
                    out_a, out_b = a, b
            else:
                a2 = around(cd, a, ti.select(j < 3, j, 0))
                b2 = around(cd, b, ti.select(j < 3, 0, j - 2))
                lo, hi = ti.min(a2, b2), ti.max(a2, b2)
                if a2 >= 0 and b2 >= 0 and is_pair(cd, lo, hi):
                    if not has_contact(cd, lo, hi):
                        g = gap(cd, x, lo, hi)
                        if g < skin:
                            out_a, out_b = lo, hi
        cd.area_a[k], cd.area_b[k], cd.area_gap[k] = out_a, out_b, g


@ti.func
def contact_vertex(cd: ti.template(), c, j):
    """Local particle of entry j in 0..4 of contact c (S1's two, element 2's up to
    three), -1 for the missing third vertex of a segment."""
    v = cd.element_vertex[cd.contact_a[c]][ti.min(j, 1)]
    if j >= 2:
        v = cd.element_vertex[cd.contact_b[c]][j - 2]
    return v


@ti.func
def contact_direction(cd: ti.template(), x: ti.template(), c, xa, xb):
    """Unit u from element 2 to segment 1; when the skeletons touch (d ~ 0), the
    common normal (segments) or the triangle normal, oriented from element 2's
    centroid towards segment 1's midpoint."""
    u = xa - xb
    if u.norm() < 1e-7:
        va, vb = cd.element_vertex[cd.contact_a[c]], cd.element_vertex[cd.contact_b[c]]
        p, q = x[cd.particle_global[va[0]]], x[cd.particle_global[va[1]]]
        b0, b1 = x[cd.particle_global[vb[0]]], x[cd.particle_global[vb[1]]]
        centroid, n = 0.5 * (b0 + b1), (q - p).cross(b1 - b0)
        if vb[2] >= 0:
            b2 = x[cd.particle_global[vb[2]]]
            centroid, n = (b0 + b1 + b2) / 3.0, (b1 - b0).cross(b2 - b0)
        if n.norm() < 1e-12:
            n = (q - p).cross(ti.Vector([0.0, 0.0, 1.0]))
            if n.norm() < 1e-12:
                n = ti.Vector([0.0, 1.0, 0.0])
        u = n
        if n.dot(0.5 * (p + q) - centroid) < 0.0:
            u = -n
    return u.normalized()


@ti.kernel
def respond(
    cd: ti.template(), model: ti.template(), state: ti.template(), h: ti.f32, passes: ti.i32
):
    """``passes`` projected Gauss-Seidel sweeps of Eq. 2-9 over the contacts (see
    the module docstring); ``h`` [s] the substep. Reads and writes state.p (Eq. 8
    displacement) and state.x (x = p - h v carries the Eq. 4 velocity change);
    writes contact_impulse (accumulated f [kg m/s], g [kg m])."""
    ti.loop_config(serialize=True)
    for sweep in range(passes):
        for c in range(cd.contact_count[None]):
            a, b = cd.contact_a[c], cd.contact_b[c]
            d, s, w, xa, xb = closest(cd, state.p, a, b)
            u = contact_direction(cd, state.p, c, xa, xb)
            beta = ti.Vector([1.0 - s, s, -w[0], -w[1], -w[2]])  # signed: element 2 < 0
            k_sum, v_sep = 0.0, 0.0
            for j in range(5):
                v = contact_vertex(cd, c, j)
                if v >= 0:
                    i = cd.particle_global[v]
                    k_sum += beta[j] * beta[j] * model.inv_mass[i]
                    v_sep += beta[j] * (state.p[i] - state.x[i]).dot(u) / h  # (v_c1 - v_c2)·u
            total = ti.Vector([0.0, 0.0])
            if sweep > 0:
                total = cd.contact_impulse[c]
            if k_sum > 0.0:
                f = ti.max(total[0] - v_sep / k_sum, 0.0)  # Eq. 7
                g = ti.max(
                    total[1] + (cd.element_radius[a] + cd.element_radius[b] - d) / k_sum, 0.0
                )  # Eq. 9
                df, dg = f - total[0], g - total[1]
                total = ti.Vector([f, g])
                for j in range(5):
                    v = contact_vertex(cd, c, j)
                    if v >= 0:
                        i = cd.particle_global[v]
                        scale = beta[j] * model.inv_mass[i] * u
                        state.p[i] += dg * scale  # Eq. 8
                        state.x[i] += dg * scale - h * df * scale  # Eq. 4
            cd.contact_impulse[c] = total


@ti.kernel
def exact_collisions(cd: ti.template(), exact: ti.template(), x: ti.template()):
    """Ground truth, O(n²): every non-neighbouring (segment, element) pair with
    gap < exact.skin [m], after a bounding-sphere test; order unspecified."""
    for e in range(cd.element_count):
        v = cd.element_vertex[e]
        p0, p1 = x[cd.particle_global[v[0]]], x[cd.particle_global[v[1]]]
        centre, bound = 0.5 * (p0 + p1), 0.5 * (p1 - p0).norm()
        if v[2] >= 0:
            p2 = x[cd.particle_global[v[2]]]
            centre = (p0 + p1 + p2) / 3.0
            bound = ti.max(ti.max((p0 - centre).norm(), (p1 - centre).norm()), (p2 - centre).norm())
        exact.centre[e], exact.bound[e] = centre, bound + cd.element_radius[e] + 0.5 * exact.skin
    exact.count[None] = 0
    for k in range(cd.segment_count * cd.element_count):
        a, b = k // cd.element_count, k % cd.element_count
        hit, g = 0, HUGE
        if (exact.centre[a] - exact.centre[b]).norm() < exact.bound[a] + exact.bound[b]:
            if is_pair(cd, a, b):
                g = gap(cd, x, a, b)
                hit = ti.i32(g < exact.skin)
        slot = ti.atomic_add(exact.count[None], hit)
        if hit and slot < exact.capacity:
            exact.pair_a[slot], exact.pair_b[slot], exact.pair_gap[slot] = a, b, g
