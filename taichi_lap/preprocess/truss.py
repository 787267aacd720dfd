"""Truss structure pre-processing for tubular and glandular tissue: seed 000 §3.3, Alg. 2.

For each surface vertex x_i with normal n_i: cast -n_i into the body and take the
nearest face it hits (among faces whose normal opposes n_i, lines 3-9); the cone
κ_i has apex x_i, axis d = f_center - x_i and half-angle θ (lines 10-11). Every
vertex j inside the cone whose normal differs from n_i by more than θ_threshold
(n_i·n_j < cos θ_threshold, lines 15-17) is joined to x_i by a strut. Stiffness
(lines 19-29): with D_min, D_max the shortest and longest strut of x_i,

    k_ij = (|x_i - x_j| - D_max) / (D_min - D_max) + k_min

so x_i's shortest strut is the stiffest. PBD stiffness lies in [0, 1]: k_ij is
clipped to 1, which only touches struts within k_min of the shortest. A strut found
from both of its ends keeps the larger stiffness.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from taichi_lap.core.geometry import TriangleMesh


@dataclass
class Truss:
    """Struts ``pairs`` (E, 2), rest lengths [m] and Alg. 2 stiffness in [k_min, 1]."""

    pairs: np.ndarray
    rest: np.ndarray
    stiffness: np.ndarray


def vertex_normals(mesh: TriangleMesh) -> tuple[np.ndarray, np.ndarray]:
    """Area-weighted unit vertex normals and unit face normals."""
    v, f = mesh.vertices, mesh.triangles
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    normals = np.zeros_like(v)
    for corner in range(3):
        np.add.at(normals, f[:, corner], cross)
    face = cross / np.maximum(np.linalg.norm(cross, axis=1, keepdims=True), 1e-30)
    return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30), face


def _nearest_opposite_hit(origins, directions, v, f, face_normals) -> np.ndarray:
    """Index of the nearest face hit by each ray among faces opposing its direction's
    source normal (Möller-Trumbore), or -1. Rays are ``origins + t directions``."""
    a, e1, e2 = v[f[:, 0]], v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]
    hits = np.full(len(origins), -1)
    for start in range(0, len(origins), 64):
        o, d = origins[start : start + 64, None, :], directions[start : start + 64, None, :]
        pvec = np.cross(d, e2[None])
        det = np.einsum("rfk,fk->rf", pvec, e1)
        inv = 1.0 / np.where(np.abs(det) < 1e-18, np.inf, det)
        tvec = o - a[None]
        u = np.einsum("rfk,rfk->rf", tvec, pvec) * inv
        qvec = np.cross(tvec, e1[None])
        w = np.einsum("rfk,rfk->rf", d, qvec) * inv
        t = np.einsum("fk,rfk->rf", e2, qvec) * inv
        facing = np.einsum("rk,fk->rf", -d[:, 0, :], face_normals) < 0  # n_i · nf_k < 0
        ok = (u >= 0) & (w >= 0) & (u + w <= 1) & (t > 1e-9) & facing & np.isfinite(inv)
        t = np.where(ok, t, np.inf)
        best = np.argmin(t, axis=1)
        found = np.isfinite(t[np.arange(len(t)), best])
        hits[start : start + 64] = np.where(found, best, -1)
    return hits


def generate_truss(
    mesh: TriangleMesh,
    *,
    cone_angle: float,
    bending_threshold: float,
    min_stiffness: float,
    progress: Callable[[float], None] | None = None,
) -> Truss:
    """Alg. 2 on a closed, outward-oriented surface ``mesh``; angles in radians."""
    v, f = mesh.vertices, mesh.triangles
    normals, face_normals = vertex_normals(mesh)
    hit = _nearest_opposite_hit(v, -normals, v, f, face_normals)
    centers = v[f].mean(axis=1)
    cos_cone, cos_bend = np.cos(cone_angle), np.cos(bending_threshold)
    found: dict[tuple[int, int], float] = {}
    for i in np.flatnonzero(hit >= 0):
        axis = centers[hit[i]] - v[i]
        axis /= np.linalg.norm(axis)
        rel = v - v[i]
        dist = np.linalg.norm(rel, axis=1)
        inside = (rel @ axis) >= cos_cone * dist
        inside[i] = False
        struts = np.flatnonzero(inside & (normals @ normals[i] < cos_bend))
        if len(struts) == 0:
            continue
        lengths = dist[struts]
        d_min, d_max = lengths.min(), lengths.max()
        if d_max > d_min:
            k = (lengths - d_max) / (d_min - d_max) + min_stiffness
        else:
            k = np.ones_like(lengths)
        for j, kij in zip(struts.tolist(), np.minimum(k, 1.0).tolist()):
            key = (min(i, j), max(i, j))
            found[key] = max(found.get(key, 0.0), kij)
        if progress is not None and i % 256 == 0:
            progress(i / len(v))
    pairs = np.array(sorted(found), dtype=np.int64).reshape(-1, 2)
    stiffness = np.array([found[tuple(p)] for p in pairs.tolist()], dtype=np.float64)
    rest = np.linalg.norm(v[pairs[:, 0]] - v[pairs[:, 1]], axis=1) if len(pairs) else np.zeros(0)
    return Truss(pairs=pairs, rest=rest, stiffness=stiffness)


def through_links(mesh: TriangleMesh) -> np.ndarray:
    """Pairs (L, 2), i < j, joining each vertex of a closed, outward-oriented surface
    ``mesh`` to the corner nearest to it of the face its inward normal hits first
    (Alg. 2 lines 3-9): across a wall's thickness, the links a cut must cross to part
    what the surface alone would not join (the inner and outer skins of a tube)."""
    v, f = mesh.vertices, mesh.triangles
    normals, face_normals = vertex_normals(mesh)
    hit = _nearest_opposite_hit(v, -normals, v, f, face_normals)
    source = np.flatnonzero(hit >= 0)
    corners = f[hit[source]]
    nearest = np.linalg.norm(v[corners] - v[source, None], axis=2).argmin(axis=1)
    pairs = np.sort(np.stack([source, corners[np.arange(len(source)), nearest]], 1), axis=1)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    return np.unique(pairs, axis=0).reshape(-1, 2)
