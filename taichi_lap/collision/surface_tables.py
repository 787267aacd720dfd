"""Tables of a model's surface triangles that tissue collision (seed 000 §4) reads,
built once with NumPy from the model data: edge neighbours (for the dual-mesh
curvature of §4.2.1), the bodies organs form, the rest broad spheres, and the binding
of triangle corners to particles (gather lists for the response); and the same for
the rows a dissection rewrote (:class:`SurfaceRows`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from taichi_lap.core.csr import incidence


def broad_spheres(corners: np.ndarray) -> np.ndarray:
    """(F, 4) broad spheres of triangles ``corners`` (F, 3, 3) [m]: the centroid and the
    largest corner distance from it (:func:`taichi_lap.kernels.collision.broad_phase.update_bounds`)."""
    center = corners.mean(axis=1)
    radius = np.linalg.norm(corners - center[:, None, :], axis=2).max(axis=1)
    return np.concatenate([center, radius[:, None]], axis=1)


def rest_tables(rest: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rest broad spheres (F, 4) and unit rest normals (F, 3) of ``triangles`` (F, 3)
    with vertices at ``rest`` (V, 3) [m] (rest exclusion of the broad phase)."""
    corners = rest[triangles]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-30)
    return broad_spheres(corners), normal


def organ_bodies(data) -> np.ndarray:
    """Body index of each organ: organs that share a shape-matching cluster (joined, as
    seed 002's vessels are into the liver) are one body."""
    body = np.arange(len(data.organs))
    member_cluster = np.repeat(np.arange(data.cluster_count), np.diff(data.cluster_start))
    pairs = np.unique(np.stack([member_cluster, data.organ[data.cluster_member]], axis=1), axis=0)
    for c in np.flatnonzero(np.bincount(pairs[:, 0], minlength=data.cluster_count) > 1):
        joined = body[pairs[pairs[:, 0] == c, 1]]
        body[np.isin(body, joined)] = joined.min()
    return body


def corner_binding(
    triangles: np.ndarray,
    vertex_index: np.ndarray,
    vertex_weight: np.ndarray,
    inverse_mass: np.ndarray,
    contact_radius: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The corners (3 t + k) of ``triangles`` (F, 3): their inverse masses (Σ w m⁻¹ of
    the particles their vertex is bound to) and their thickness against tools (Σ w
    times the particles' contact radius), each (3 F,)."""
    corner_vertex = np.asarray(triangles, dtype=np.int64).reshape(-1)
    index, weight = vertex_index[corner_vertex], vertex_weight[corner_vertex]
    return (weight * inverse_mass[index]).sum(axis=1), (weight * contact_radius[index]).sum(axis=1)


def first_corners(corner_vertex: np.ndarray, corner: np.ndarray) -> np.ndarray:
    """(K,) bool: whether each ``corner`` (3 t + k) is the lowest of those given at its
    vertex ``corner_vertex`` (K,): the owner of that vertex."""
    distinct, which = np.unique(corner_vertex, return_inverse=True)
    first = np.full(len(distinct), np.iinfo(np.int64).max)
    np.minimum.at(first, which, corner)
    return first[which] == corner


def corner_owners(triangles: np.ndarray, live: np.ndarray) -> np.ndarray:
    """(3 F,) 1 where a corner is the first corner of a live triangle at its vertex:
    one owner per vertex (the polygon method tests each vertex once)."""
    corner_vertex = np.asarray(triangles, dtype=np.int64).reshape(-1)
    corner = np.flatnonzero(np.repeat(live, 3))
    owner = np.zeros(len(corner_vertex), dtype=np.int32)
    owner[corner] = first_corners(corner_vertex[corner], corner)
    return owner


def triangle_corner_tables(data) -> dict[str, np.ndarray]:
    """Host tables binding triangle corners (3 t + k) to particles as built: the
    gather lists per particle (weights > 0 of the surface binding), and the corners'
    inverse masses, thickness (:func:`corner_binding`) and owners (:func:`corner_owners`)."""
    corner_vertex = data.surface_triangles.reshape(-1)
    index = data.surface_index[corner_vertex]
    weight = data.surface_weight[corner_vertex]
    particle, corner = index.reshape(-1), np.repeat(np.arange(len(corner_vertex)), 4)
    keep = weight.reshape(-1) > 0.0
    bound = np.unique(particle[keep])
    rank = np.searchsorted(bound, particle[keep])
    start, rows = incidence(rank, len(bound))
    inv_mass, thickness = corner_binding(
        data.surface_triangles,
        data.surface_index,
        data.surface_weight,
        data.inverse_mass(),
        data.contact_radius(),
    )
    triangles = data.surface_triangles.reshape(-1, 3)
    return {
        "bound_particle": bound,
        "particle_start": start,
        "particle_corner": corner[keep][rows],
        "particle_weight": weight.reshape(-1)[keep][rows],
        "corner_inv_mass": inv_mass,
        "corner_owner": corner_owners(triangles, np.ones(len(triangles), dtype=bool)),
        "corner_thickness": thickness,
    }


def live_neighbours(
    triangles: np.ndarray, live: np.ndarray, incident: np.ndarray, rows: np.ndarray
) -> np.ndarray:
    """(R, 3) the live triangle across edge k = (v_k, v_k+1) of each of ``rows`` (its
    vertices' ``incident`` rows, -1 padded, give the candidates); -1 where there is
    none, or more than one (a non-manifold edge), or the row is dead (as
    :func:`taichi_lap.core.mesh.edge_neighbours` for the whole surface)."""
    rows = np.asarray(rows, dtype=np.int64)
    out = np.full((len(rows), 3), -1, dtype=np.int64)
    for k in range(3):
        a = incident[triangles[rows, k]]
        b = incident[triangles[rows, (k + 1) % 3]]
        shared = (a[:, :, None] == b[:, None, :]).any(axis=2) & (a >= 0)
        shared &= (a != rows[:, None]) & live[np.maximum(a, 0)]
        single = shared.sum(axis=1) == 1
        out[single, k] = a[single][shared[single]]
    out[~live[rows]] = -1
    return out


@dataclass
class SurfaceRows:
    """The model's surface rows as a dissection left them, on the host (what
    :meth:`taichi_lap.collision.tissue.TissueCollision.rewrite` reads): triangle rows
    (F, 3) ((0, 0, 0) where dead), ``live`` (F,), ``organ`` (F,), each vertex's
    triangles ``incident`` (V, W) -1 padded, vertex binding ``index``/``weight`` (V, 4)
    and rest place ``rest`` (V, 3) [m], the vertex rows in use, and the particles'
    inverse masses (removed ones 0) and contact radii [m]."""

    triangles: np.ndarray
    live: np.ndarray
    organ: np.ndarray
    incident: np.ndarray
    index: np.ndarray
    weight: np.ndarray
    rest: np.ndarray
    vertex_rows: int
    inverse_mass: np.ndarray
    contact_radius: np.ndarray

    def triangles_at(self, particles: np.ndarray) -> np.ndarray:
        """The live triangles with a corner bound to one of ``particles``."""
        index, weight = self.index[: self.vertex_rows], self.weight[: self.vertex_rows]
        marked = np.zeros(len(self.inverse_mass), dtype=bool)
        marked[particles] = True
        return self.triangles_of(np.flatnonzero((marked[index] & (weight > 0.0)).any(axis=1)))

    def triangles_of(self, vertices: np.ndarray) -> np.ndarray:
        """The live triangles at ``vertices`` (surface vertex rows), from their
        incident rows, sorted."""
        incident = self.incident[vertices]
        triangles = np.unique(incident[incident >= 0])
        return triangles[self.live[triangles]]
