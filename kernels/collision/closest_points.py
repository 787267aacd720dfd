"""Closest points of Ericson 2004, "Real-Time Collision Detection", written once for
every collision kernel: the tools' capsules, the polygon baseline of seed 000 §4.4 and
the intestine self-collision of seed 001 §4."""

import taichi as ti


@ti.func
def point_segment(a, b, q):
    """The point of segment ``a``-``b`` closest to ``q`` (§5.1.2; a degenerate segment
    gives ``a``)."""
    ab = b - a
    t = 0.0
    denom = ab.dot(ab)
    if denom > 1e-12:
        t = ti.math.clamp((q - a).dot(ab) / denom, 0.0, 1.0)
    return a + t * ab


@ti.func
def segment_segment(p1, q1, p2, q2):
    """Parameters s, t in [0, 1] and closest points c1 = p1 + s (q1 - p1), c2 = p2 +
    t (q2 - p2) of segments p1q1 and p2q2 (§5.1.9; degenerate segments allowed, nearly
    parallel ones take s = 0)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = d1.dot(d1), d2.dot(d2), d2.dot(r)
    s, t = 0.0, 0.0
    if a > 1e-20 and e > 1e-20:
        c, b = d1.dot(r), d1.dot(d2)
        denom = a * e - b * b
        if denom > 1e-6 * a * e:
            s = ti.math.clamp((b * f - c * e) / denom, 0.0, 1.0)
        t = (b * s + f) / e
        if t < 0.0:
            t, s = 0.0, ti.math.clamp(-c / a, 0.0, 1.0)
        elif t > 1.0:
            t, s = 1.0, ti.math.clamp((b - c) / a, 0.0, 1.0)
    elif a > 1e-20:
        s = ti.math.clamp(-d1.dot(r) / a, 0.0, 1.0)
    elif e > 1e-20:
        t = ti.math.clamp(f / e, 0.0, 1.0)
    return s, t, p1 + s * d1, p2 + t * d2


@ti.func
def point_triangle(p, a, b, c):
    """Barycentric weights of the point of triangle abc closest to p (§5.1.5, Voronoi
    regions of vertices, edges, face)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = ab.dot(ap), ac.dot(ap)
    w = ti.Vector([1.0, 0.0, 0.0])
    bp = p - b
    d3, d4 = ab.dot(bp), ac.dot(bp)
    cp = p - c
    d5, d6 = ab.dot(cp), ac.dot(cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    if d1 <= 0.0 and d2 <= 0.0:
        w = ti.Vector([1.0, 0.0, 0.0])
    elif d3 >= 0.0 and d4 <= d3:
        w = ti.Vector([0.0, 1.0, 0.0])
    elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        k = d1 / ti.max(d1 - d3, 1e-30)
        w = ti.Vector([1.0 - k, k, 0.0])
    elif d6 >= 0.0 and d5 <= d6:
        w = ti.Vector([0.0, 0.0, 1.0])
    elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        k = d2 / ti.max(d2 - d6, 1e-30)
        w = ti.Vector([1.0 - k, 0.0, k])
    elif va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0:
        k = (d4 - d3) / ti.max((d4 - d3) + (d5 - d6), 1e-30)
        w = ti.Vector([0.0, 1.0 - k, k])
    else:
        inv = 1.0 / ti.max(va + vb + vc, 1e-30)
        w = ti.Vector([1.0 - (vb + vc) * inv, vb * inv, vc * inv])
    return w


@ti.func
def segment_triangle(p, q, a, b, c):
    """Closest points of segment pq and triangle abc: the nearest of pq against each
    edge (§5.1.9), then each end of pq and the point where pq crosses the triangle's
    plane against the triangle (§5.1.5; that point lies on the triangle when pq pierces
    it). Returns (s, w, on_segment, on_triangle): the parameter on pq and the
    barycentric weights on abc of the two points."""
    corners = [a, b, c]
    best, best_s, best_w = 1e30, 0.0, ti.Vector([1.0, 0.0, 0.0])
    for k in ti.static(range(3)):
        s, t, on_pq, on_edge = segment_segment(p, q, corners[k], corners[(k + 1) % 3])
        d2 = (on_pq - on_edge).norm_sqr()
        if d2 < best:
            best, best_s, best_w = d2, s, ti.Vector([0.0, 0.0, 0.0])
            best_w[k], best_w[(k + 1) % 3] = 1.0 - t, t
    n = (b - a).cross(c - a)
    denom = n.dot(q - p)
    crossing = -1.0  # parameter on pq where it meets the triangle's plane
    if ti.abs(denom) > 1e-30:
        crossing = n.dot(a - p) / denom
    for k in range(3):  # end p, end q, crossing point
        s = ti.select(k == 2, crossing, ti.f32(k))
        if 0.0 <= s <= 1.0:
            y = p + s * (q - p)
            w = point_triangle(y, a, b, c)
            d2 = (y - w[0] * a - w[1] * b - w[2] * c).norm_sqr()
            if d2 < best:
                best, best_s, best_w = d2, s, w
    return best_s, best_w, p + best_s * (q - p), best_w[0] * a + best_w[1] * b + best_w[2] * c
