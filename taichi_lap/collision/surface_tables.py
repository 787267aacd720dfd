"""Tables of a model's surface triangles that tissue collision (seed 000 §4) reads,
built once with NumPy from the model data: edge neighbours (for the dual-mesh
curvature of §4.2.1), the bodies organs form, the rest broad spheres, and the binding
of triangle corners to particles (gather lists for the response)."""

from __future__ import annotations

import numpy as np

from taichi_lap.core.csr import incidence


def broad_spheres(corners: np.ndarray) -> np.ndarray:
    """(F, 4) broad spheres of triangles ``corners`` (F, 3, 3) [m]: the centroid and the
    largest corner distance from it (:func:`taichi_lap.kernels.collision.broad_phase.update_bounds`)."""
    center = corners.mean(axis=1)
    radius = np.linalg.norm(corners - center[:, None, :], axis=2).max(axis=1)
    return np.concatenate([center, radius[:, None]], axis=1)


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


def triangle_corner_tables(data) -> dict[str, np.ndarray]:
    """Host tables binding triangle corners (3 t + k) to particles: the gather lists
    per particle (weights > 0 of the surface binding), the corners' inverse masses
    (Σ w m⁻¹ of the bound particles), their thickness against tools (Σ w times the
    particles' contact radius) and one owner corner per surface vertex."""
    corner_vertex = data.surface_triangles.reshape(-1)
    index = data.surface_index[corner_vertex]
    weight = data.surface_weight[corner_vertex]
    corner_inv_mass = (weight * data.inverse_mass()[index]).sum(axis=1)
    particle, corner = index.reshape(-1), np.repeat(np.arange(len(corner_vertex)), 4)
    keep = weight.reshape(-1) > 0.0
    bound = np.unique(particle[keep])
    rank = np.searchsorted(bound, particle[keep])
    start, rows = incidence(rank, len(bound))
    first = np.full(len(data.surface_index), len(corner_vertex))
    np.minimum.at(first, corner_vertex, np.arange(len(corner_vertex)))
    owner = first[corner_vertex] == np.arange(len(corner_vertex))
    return {
        "bound_particle": bound,
        "particle_start": start,
        "particle_corner": corner[keep][rows],
        "particle_weight": weight.reshape(-1)[keep][rows],
        "corner_inv_mass": corner_inv_mass,
        "corner_owner": owner.astype(np.int32),
        "corner_thickness": (weight * data.contact_radius()[index]).sum(axis=1),
    }
