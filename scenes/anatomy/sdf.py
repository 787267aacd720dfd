"""Vectorised signed-distance primitives [m] (negative inside) and their combinations.

Every primitive maps points ``p`` ``(K, 3)`` to ``(K,)``. The exact ones (sphere,
box, capsule, round cone, plane) follow Quilez's formulas; the ellipsoid is his
first-order bound, exact on the surface with ``|grad| = 1`` there, which is all
the builder's Newton projection needs.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

Sdf = Callable[[np.ndarray], np.ndarray]


def _pts(p) -> np.ndarray:
    return np.asarray(p, dtype=np.float64).reshape(-1, 3)


def sphere(p, center, radius: float) -> np.ndarray:
    """Exact distance to a sphere."""
    return np.linalg.norm(_pts(p) - np.asarray(center, float), axis=1) - radius


def box(p, center, half_extents) -> np.ndarray:
    """Exact distance to an axis-aligned box."""
    q = np.abs(_pts(p) - np.asarray(center, float)) - np.asarray(half_extents, float)
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    return outside + np.minimum(q.max(axis=1), 0.0)


def ellipsoid(p, center, radii) -> np.ndarray:
    """Ellipsoid distance bound ``k0 (k0 - 1) / k1`` (exact zero set, |grad| = 1 on it)."""
    r = np.asarray(radii, float)
    q = _pts(p) - np.asarray(center, float)
    k0 = np.linalg.norm(q / r, axis=1)
    k1 = np.linalg.norm(q / (r * r), axis=1)
    # at the centre k1 -> 0: the bound tends to -k0/k1 -> -min(r); use that limit
    return np.where(k1 > 1e-12, k0 * (k0 - 1.0) / np.maximum(k1, 1e-12), -r.min())


def plane(p, point, normal) -> np.ndarray:
    """Signed distance to a plane; negative on the side opposite ``normal``."""
    n = np.asarray(normal, float)
    n = n / np.linalg.norm(n)
    return (_pts(p) - np.asarray(point, float)) @ n


def capped_cylinder(p, y0: float, y1: float, radius: float) -> np.ndarray:
    """Exact distance to a cylinder along y (axis through x = z = 0), y in [y0, y1]."""
    q = _pts(p)
    dr = np.hypot(q[:, 0], q[:, 2]) - radius
    half = 0.5 * (y1 - y0)
    dy = np.abs(q[:, 1] - 0.5 * (y0 + y1)) - half
    return np.minimum(np.maximum(dr, dy), 0.0) + np.hypot(np.maximum(dr, 0.0), np.maximum(dy, 0.0))


def round_cones(p, a, b, ra, rb) -> np.ndarray:
    """Exact distance from points ``(K, 3)`` to ``S`` round cones (capsules with
    end radii ``ra``, ``rb``) from ``a`` to ``b``; returns ``(K, S)``. The cones are
    shared, ``a`` ``(S, 3)`` and ``ra`` ``(S,)``, or per point, ``(K, S, 3)`` and
    ``(K, S)``. Where one end sphere swallows the other the cone is that sphere."""
    p = _pts(p)[:, None, :]
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.ndim == 2:
        a, b = a[None], b[None]
    ra, rb = np.asarray(ra, float), np.asarray(rb, float)
    if ra.ndim == 1:
        ra, rb = ra[None], rb[None]
    ba = b - a
    l2 = np.maximum(np.einsum("...i,...i->...", ba, ba), 1e-30)
    rr = ra - rb
    a2 = l2 - rr * rr
    pa = p - a
    pa2 = np.einsum("...i,...i->...", pa, pa)
    y = np.einsum("...i,...i->...", pa, ba)
    z = y - l2
    x2 = np.maximum(l2 * (l2 * pa2 - y * y), 0.0)  # |pa * l2 - ba * y|^2
    k = np.sign(rr) * rr * rr * x2
    d_a = np.sqrt(pa2) - ra  # Quilez: sqrt(x2 + y2) / l2 - ra
    d_b = np.sqrt(np.maximum(pa2 - 2.0 * y + l2, 0.0)) - rb  # |p - b| - rb
    d_side = (np.sqrt(x2 * np.maximum(a2, 0.0) / l2) + y * rr) / l2 - ra
    d = np.where(
        np.sign(z) * a2 * z * z * l2 > k,
        d_b,
        np.where(np.sign(y) * a2 * y * y * l2 < k, d_a, d_side),
    )
    # degenerate cone (one sphere contains the other): the bigger sphere
    return np.where(a2 > 0.0, d, np.minimum(d_a, d_b))


def union(*ds) -> np.ndarray:
    return np.minimum.reduce(ds)


def smooth_union(d1, d2, k: float) -> np.ndarray:
    """Polynomial smooth minimum with blend width ``k`` [m] (Quilez)."""
    if k <= 0.0:
        return np.minimum(d1, d2)
    h = np.clip(0.5 + 0.5 * (d2 - d1) / k, 0.0, 1.0)
    return d2 + (d1 - d2) * h - k * h * (1.0 - h)


def smooth_intersection(d1, d2, k: float) -> np.ndarray:
    """Smooth maximum: ``-smooth_union(-d1, -d2, k)``."""
    return -smooth_union(-np.asarray(d1), -np.asarray(d2), k)


def gradient(f: Sdf, p, h: float = 1e-5) -> np.ndarray:
    """Central-difference gradient of ``f`` at points ``(K, 3)``; returns ``(K, 3)``."""
    p = _pts(p)
    g = np.empty_like(p)
    for i in range(3):
        e = np.zeros(3)
        e[i] = h
        g[:, i] = (f(p + e) - f(p - e)) / (2.0 * h)
    return g


def scaled(f: Sdf, s: float) -> Sdf:
    """The shape of ``f`` scaled uniformly by ``s`` about the origin (still a distance)."""
    return lambda p: s * f(_pts(p) / s)
