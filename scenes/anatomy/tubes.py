"""Tubes along centrelines: spline sampling, rotation-minimising frames, closed
tube meshes (solid or thick-walled) and the signed distance of a tree of tubes.

The generalized-cylinder construction follows seed 001 §5 (cardinal spline
skeleton, rotation-minimising frames, Eq. 12); frames are computed with the
double-reflection method (Wang et al. 2008). Units are metres.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from taichi_lap.core.geometry import TriangleMesh, arc_length

from . import sdf as _sdf

_BLOCK = 1 << 12
"""Points a :class:`TubeTree` evaluates at once: their (points x cones) temporaries
stay in the CPU's caches (a million at once spent most of the full liver's build
waiting on memory); each point's value does not depend on the others'."""


def catmull_rom(points, samples_per_segment: int = 16, alpha: float = 0.5) -> np.ndarray:
    """Sample the Catmull-Rom spline through ``points`` ``(n, 3)`` (centripetal for
    ``alpha = 0.5``, so no cusps); ends use reflected phantom points. Returns
    ``((n - 1) * samples_per_segment + 1, 3)`` including both end points."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) < 2:
        raise ValueError("a spline needs at least two points")
    q = np.vstack([2 * p[0] - p[1], p, 2 * p[-1] - p[-2]])
    m = int(samples_per_segment)
    u = np.arange(m) / m
    out = []
    for i in range(1, len(q) - 2):
        p0, p1, p2, p3 = q[i - 1], q[i], q[i + 1], q[i + 2]
        t0 = 0.0
        t1 = t0 + max(np.linalg.norm(p1 - p0), 1e-12) ** alpha
        t2 = t1 + max(np.linalg.norm(p2 - p1), 1e-12) ** alpha
        t3 = t2 + max(np.linalg.norm(p3 - p2), 1e-12) ** alpha
        t = (t1 + (t2 - t1) * u)[:, None]
        a1 = ((t1 - t) * p0 + (t - t0) * p1) / (t1 - t0)
        a2 = ((t2 - t) * p1 + (t - t1) * p2) / (t2 - t1)
        a3 = ((t3 - t) * p2 + (t - t2) * p3) / (t3 - t2)
        b1 = ((t2 - t) * a1 + (t - t0) * a2) / (t2 - t0)
        b2 = ((t3 - t) * a2 + (t - t1) * a3) / (t3 - t1)
        out.append(((t2 - t) * b1 + (t - t1) * b2) / (t2 - t1))
    out.append(p[-1:])
    return np.vstack(out)


ENVIRONMENT_TUBE_SAMPLES = 6
"""Segments per span of an environment tube's spline: what collides and what is drawn."""


def environment_centreline(points) -> np.ndarray:
    """The centre line of a scene's environment tube (``[[environment.tubes]]``): the
    Catmull-Rom spline through its ``points``, sampled :data:`ENVIRONMENT_TUBE_SAMPLES`
    times per span; particles collide with the capsules of its segments and the
    renderer draws the tube around it."""
    return catmull_rom(points, ENVIRONMENT_TUBE_SAMPLES)


def resample(points, radii, spacing_factor: float = 1.0, min_spacing: float = 1e-4):
    """Resample a dense polyline so consecutive points are about
    ``spacing_factor`` x the local radius apart (at least ``min_spacing``) [m].
    ``radii`` is a scalar or ``(n,)``; returns ``(points (m, 3), radii (m,))``."""
    p = np.asarray(points, float).reshape(-1, 3)
    r = np.broadcast_to(np.asarray(radii, float), (len(p),)).astype(float)
    s = arc_length(p)
    # u(s) = integral of ds / spacing(s); stations at equal steps of u
    density = 1.0 / np.maximum(spacing_factor * r, min_spacing)
    u = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(s))])
    n = max(1, int(round(u[-1])))
    t = np.interp(np.linspace(0.0, u[-1], n + 1), u, s)
    q = np.stack([np.interp(t, s, p[:, k]) for k in range(3)], axis=1)
    return q, np.interp(t, s, r)


def rmf_frames(points, normal0=None):
    """Rotation-minimising frames along a polyline by double reflection.

    Returns tangents ``T``, normals ``N`` and binormals ``B = T x N``, each
    ``(n, 3)``. ``normal0`` sets the first normal (projected onto the normal plane)."""
    p = np.asarray(points, float).reshape(-1, 3)
    n = len(p)
    d = np.diff(p, axis=0)
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    T = np.empty((n, 3))
    T[0], T[-1] = d[0], d[-1]
    if n > 2:
        mid = d[:-1] + d[1:]
        bad = np.linalg.norm(mid, axis=1) < 1e-9
        mid[bad] = d[1:][bad]
        T[1:-1] = mid / np.linalg.norm(mid, axis=1, keepdims=True)
    if normal0 is None:
        helper = np.eye(3)[np.argmin(np.abs(T[0]))]
    else:
        helper = np.asarray(normal0, float)
    N0 = helper - (helper @ T[0]) * T[0]
    if np.linalg.norm(N0) < 1e-9:
        helper = np.eye(3)[np.argmin(np.abs(T[0]))]
        N0 = helper - (helper @ T[0]) * T[0]
    N = np.empty((n, 3))
    N[0] = N0 / np.linalg.norm(N0)
    for i in range(n - 1):
        v1 = p[i + 1] - p[i]
        c1 = v1 @ v1
        if c1 < 1e-300:
            N[i + 1] = N[i]
            continue
        rL = N[i] - (2.0 / c1) * (v1 @ N[i]) * v1
        tL = T[i] - (2.0 / c1) * (v1 @ T[i]) * v1
        v2 = T[i + 1] - tL
        c2 = v2 @ v2
        N[i + 1] = rL if c2 < 1e-300 else rL - (2.0 / c2) * (v2 @ rL) * v2
        N[i + 1] -= (N[i + 1] @ T[i + 1]) * T[i + 1]
        N[i + 1] /= np.linalg.norm(N[i + 1])
    return T, N, np.cross(T, N)


def _rings(centers, radii, N, B, m: int) -> np.ndarray:
    """Circles ``(n, m, 3)`` of ``m`` vertices around each centre."""
    phi = 2.0 * np.pi * np.arange(m) / m
    ring = np.cos(phi)[None, :, None] * N[:, None, :] + np.sin(phi)[None, :, None] * B[:, None, :]
    return centers[:, None, :] + np.asarray(radii, float).reshape(-1, 1, 1) * ring


def _strip(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Triangles joining vertex rings ``a`` -> ``b`` (index arrays of length m, the
    vertices at increasing angle about the frame's T). Their normal is
    ``e_phi x (b - a)``: outward for a ring stepping along +T, +T for a ring
    stepping inward. A scalar index is a pole (a fan)."""
    m = max(np.size(a), np.size(b))
    a = np.broadcast_to(a, (m,))
    b = np.broadcast_to(b, (m,))
    a1, b1 = np.roll(a, -1), np.roll(b, -1)
    t1 = np.stack([a, a1, b1], axis=1)
    t2 = np.stack([a, b1, b], axis=1)
    tris = np.vstack([t1, t2])
    ok = (tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 0] != tris[:, 2])
    return tris[ok]


def tube_mesh(
    points,
    radii,
    segments_around: int = 12,
    caps: str = "round",
    cap_rings: int | None = None,
    normal0=None,
) -> TriangleMesh:
    """Closed tube through the centreline ``points`` ``(n, 3)`` with radius
    ``radii`` (scalar or ``(n,)``) [m]; ``caps`` is ``"round"`` (hemispheres) or
    ``"flat"`` (discs). Rings are placed at the given points (see :func:`resample`)."""
    p = np.asarray(points, float).reshape(-1, 3)
    r = np.broadcast_to(np.asarray(radii, float), (len(p),)).astype(float)
    m = int(segments_around)
    T, N, B = rmf_frames(p, normal0)
    centers, rads, NN, BB = [p], [r], [N], [B]
    poles = []
    if caps == "round":
        k = cap_rings or max(2, m // 4)
        ang = 0.5 * np.pi * np.arange(1, k) / k
        # start cap rings (pole side first), then body, then end cap rings
        cs = p[0] - r[0] * np.sin(ang[::-1])[:, None] * T[0]
        ce = p[-1] + r[-1] * np.sin(ang)[:, None] * T[-1]
        centers = [cs, p, ce]
        rads = [r[0] * np.cos(ang[::-1]), r, r[-1] * np.cos(ang)]
        NN = [np.repeat(N[:1], k - 1, 0), N, np.repeat(N[-1:], k - 1, 0)]
        BB = [np.repeat(B[:1], k - 1, 0), B, np.repeat(B[-1:], k - 1, 0)]
        poles = [p[0] - r[0] * T[0], p[-1] + r[-1] * T[-1]]
    elif caps == "flat":
        poles = [p[0], p[-1]]
    else:
        raise ValueError(f"unknown caps {caps!r}")
    c = np.vstack(centers)
    verts = _rings(c, np.concatenate(rads), np.vstack(NN), np.vstack(BB), m).reshape(-1, 3)
    nr = len(c)
    idx = np.arange(nr * m).reshape(nr, m)
    s_pole, e_pole = nr * m, nr * m + 1
    tris = [_strip(np.int64(s_pole), idx[0])]
    tris += [_strip(idx[i], idx[i + 1]) for i in range(nr - 1)]
    tris.append(_strip(idx[-1], np.int64(e_pole)))
    return TriangleMesh(np.vstack([verts, poles]), np.vstack(tris))


def hollow_tube_mesh(
    points, outer_radius: float, inner_radius: float, segments_around: int = 24
) -> TriangleMesh:
    """Closed thick-walled tube: outer wall, inner wall (normals into the lumen),
    annular end caps. ``points`` ``(n, 3)`` are the ring centres [m]."""
    if not 0.0 < inner_radius < outer_radius:
        raise ValueError("need 0 < inner_radius < outer_radius")
    p = np.asarray(points, float).reshape(-1, 3)
    m = int(segments_around)
    _, N, B = rmf_frames(p)
    n = len(p)
    outer = _rings(p, np.full(n, outer_radius), N, B, m).reshape(-1, 3)
    inner = _rings(p, np.full(n, inner_radius), N, B, m).reshape(-1, 3)
    o = np.arange(n * m).reshape(n, m)
    i = o + n * m
    tris = [_strip(o[k], o[k + 1]) for k in range(n - 1)]
    tris += [_strip(i[k + 1], i[k]) for k in range(n - 1)]  # reversed: faces the lumen
    tris += [_strip(i[0], o[0]), _strip(o[-1], i[-1])]  # annular end caps
    return TriangleMesh(np.vstack([outer, inner]), np.vstack(tris))


def concatenate(meshes) -> TriangleMesh:
    """One mesh holding all components (indices offset)."""
    verts, tris, off = [], [], 0
    for mesh in meshes:
        verts.append(mesh.vertices)
        tris.append(mesh.triangles + off)
        off += len(mesh.vertices)
    return TriangleMesh(np.vstack(verts), np.vstack(tris))


class TubeTree:
    """Signed distance to a union of tubes, each a polyline with per-point radius:
    the minimum over the round cones between consecutive points. Call with points
    ``(K, 3)`` [m]. Each point is tested against the ``candidates`` cones with the
    nearest midpoints (k-d tree); the others are at least ``lb`` = (k-th midpoint
    distance - largest cone half-extent ``e``) away. Points with ``lb < e`` that
    the candidates do not settle are tested against every cone, so the value is
    exact within ``e`` of the surface (and the sign everywhere); farther out it is
    ``min(exact over candidates, lb)``, a positive lower bound."""

    def __init__(self, branches, candidates: int = 8):
        a, b, ra, rb = [], [], [], []
        for pts, rad in branches:
            pts = np.asarray(pts, float).reshape(-1, 3)
            rad = np.broadcast_to(np.asarray(rad, float), (len(pts),))
            if len(pts) == 1:
                pts, rad = np.vstack([pts, pts]), np.concatenate([rad, rad])
            a.append(pts[:-1]), b.append(pts[1:]), ra.append(rad[:-1]), rb.append(rad[1:])
        self.a, self.b = np.vstack(a), np.vstack(b)
        self.ra, self.rb = np.concatenate(ra), np.concatenate(rb)
        mid = 0.5 * (self.a + self.b)
        self.extent = (
            0.5 * np.linalg.norm(self.b - self.a, axis=1) + np.maximum(self.ra, self.rb)
        ).max()
        self.k = min(int(candidates), len(mid))
        self.kd = cKDTree(mid)
        lo = np.minimum(self.a - self.ra[:, None], self.b - self.rb[:, None]).min(0)
        hi = np.maximum(self.a + self.ra[:, None], self.b + self.rb[:, None]).max(0)
        self.bounds = (lo, hi)

    def _all(self, p):
        out = np.empty(len(p))
        step = max(1, 2**18 // len(self.a))
        for s in range(0, len(p), step):
            out[s : s + step] = _sdf.round_cones(
                p[s : s + step], self.a, self.b, self.ra, self.rb
            ).min(1)
        return out

    def _nearest(self, p, k):
        dist, idx = self.kd.query(p, k)
        best = _sdf.round_cones(p, self.a[idx], self.b[idx], self.ra[idx], self.rb[idx]).min(1)
        return best, dist[:, -1] - self.extent

    def __call__(self, p) -> np.ndarray:
        p = np.asarray(p, float).reshape(-1, 3)
        out = np.empty(len(p))
        for start in range(0, len(p), _BLOCK):
            out[start : start + _BLOCK] = self._distances(p[start : start + _BLOCK])
        return out

    def _distances(self, p) -> np.ndarray:
        out = np.empty(len(p))
        todo = np.arange(len(p))
        k = self.k
        while k < len(self.a) and len(todo):
            best, lb = self._nearest(p[todo], k)
            out[todo] = np.minimum(best, lb)
            todo = todo[(lb < best) & (lb < self.extent)]  # not settled by the k nearest
            k *= 4
        if len(todo):
            out[todo] = self._all(p[todo])
        return out
