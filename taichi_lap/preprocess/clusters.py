"""Overlapping shape-matching clusters (seed 002 §3.2 and §4.1, Table 1).

Cluster centres sit on a coarse cubic lattice whose spacing equals the cluster
radius, so neighbouring clusters overlap by one radius ("the overlap region
between two clusters was equal to the cluster radius", seed 002 §4.1). Every
particle within the radius of a centre belongs to that cluster; a particle no
centre reaches joins its nearest cluster, so every particle is shape matched.

Seed 002 reports "approximately 50 particles" per cluster together with 146 090
liver particles in 2 994 clusters of radius 0.84 cm (Table 1): 146 090 / 2 994
≈ 49 is particles *per cluster count*; with centres one radius apart each
cluster reaches ≈ 4.2 × that many particles. :func:`auto_cluster_radius` keeps
that ratio.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

MIN_MEMBERS = 4
"""Fewer members than this cannot define a rotation (seed 000 Eq. 1)."""


@dataclass
class Clusters:
    """Clusters in compressed-row form: cluster ``c`` holds particles
    ``members[start[c]:start[c+1]]`` (sorted). ``center`` ``(C, 3)`` is the lattice
    centre [m]; ``radius`` ``(C,)`` the membership radius [m]."""

    start: np.ndarray
    members: np.ndarray
    center: np.ndarray
    radius: np.ndarray

    @property
    def count(self) -> int:
        return len(self.start) - 1

    def sizes(self) -> np.ndarray:
        return np.diff(self.start)


def auto_cluster_radius(particle_spacing: float, particles_per_cluster: float = 50.0) -> float:
    """Radius [m] giving ``particles_per_cluster`` particles per cluster *count* on a
    BCC lattice of cube edge ``particle_spacing`` (2 particles per cube) with centres
    one radius apart: N/C = r³ / (a³/2)."""
    return particle_spacing * (particles_per_cluster / 2.0) ** (1.0 / 3.0)


def _from_lists(lists: list[np.ndarray], centers: np.ndarray, radius: float) -> Clusters:
    """Compressed-row clusters from one member array per cluster."""
    sizes = np.array([len(m) for m in lists], dtype=np.int64)
    start = np.concatenate([[0], np.cumsum(sizes)])
    members = np.concatenate(lists).astype(np.int64) if lists else np.zeros(0, np.int64)
    return Clusters(
        start=start,
        members=members,
        center=np.asarray(centers, float).reshape(-1, 3),
        radius=np.full(len(lists), float(radius)),
    )


def lattice_clusters(
    positions: np.ndarray, radius: float, max_gap: float | None = None
) -> Clusters:
    """Clusters of ``positions`` (N, 3) [m] with centres on a cubic lattice of
    spacing ``radius`` (seed 002 §3.2). Centres farther than ``max_gap`` [m] from
    every particle (outside a filled body) and centres reaching fewer than
    :data:`MIN_MEMBERS` particles are dropped; uncovered particles join their
    nearest remaining centre."""
    positions = np.asarray(positions, dtype=np.float64)
    if len(positions) < MIN_MEMBERS:
        raise ValueError(f"{len(positions)} particles cannot form a cluster of {MIN_MEMBERS}")
    lo = positions.min(axis=0)
    cells = np.unique(np.floor((positions - lo) / radius).astype(np.int64), axis=0)
    # candidate centres: the corners of every occupied cell
    corners = (
        cells[:, None, :]
        + np.array(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij")).reshape(3, -1).T[None]
    ).reshape(-1, 3)
    corners = np.unique(corners, axis=0)
    centers = lo + corners * radius
    tree = cKDTree(positions)
    if max_gap is not None:
        gap, _ = tree.query(centers)
        centers = centers[gap <= max_gap]
    lists = [
        np.sort(np.asarray(m, dtype=np.int64))
        for m in tree.query_ball_point(centers, radius * (1 + 1e-9))
    ]
    keep = [i for i, m in enumerate(lists) if len(m) >= MIN_MEMBERS]
    if not keep:
        centroid = positions.mean(axis=0, keepdims=True)
        return _from_lists([np.arange(len(positions))], centroid, radius)
    centers = centers[keep]
    lists = [lists[i] for i in keep]
    covered = np.zeros(len(positions), dtype=bool)
    for m in lists:
        covered[m] = True
    if not covered.all():
        lonely = np.flatnonzero(~covered)
        _, nearest = cKDTree(centers).query(positions[lonely])
        for c in np.unique(nearest):
            lists[c] = np.union1d(lists[c], lonely[nearest == c])
    return _from_lists(lists, centers, radius)


def whole_body_cluster(positions: np.ndarray) -> Clusters:
    """One cluster holding every particle: the global shape matching of Müller et
    al. (2005), which seed 000 §3.1 names as the way to preserve an organ's overall
    shape. Added to the local clusters, it carries the organ's weight in one pass,
    which overlapping local clusters alone pass on only one cluster per iteration."""
    positions = np.asarray(positions, dtype=np.float64)
    center = positions.mean(axis=0)
    radius = float(np.linalg.norm(positions - center, axis=1).max())
    return _from_lists([np.arange(len(positions))], center[None], radius)


def joining_clusters(
    positions: np.ndarray, own: np.ndarray, other: np.ndarray, radius: float
) -> Clusters:
    """Clusters tying two organs together (seed 002 §3.2: "additional clusters to
    physically connect the liver parenchyma and intrahepatic vessels").

    The contact zone is the particles of ``own`` within ``radius`` of a particle of
    ``other`` (global indices). One cluster per occupied cell of a 2·radius lattice
    over the zone, centred at the mean of the zone particles in the cell, holds the
    particles of both organs within ``radius``; kept where each organ gives at least
    two. An empty result means the organs do not touch."""
    positions = np.asarray(positions, dtype=np.float64)
    own_tree, other_tree = cKDTree(positions[own]), cKDTree(positions[other])
    gap, _ = other_tree.query(positions[own], distance_upper_bound=radius)
    zone = positions[own][np.isfinite(gap)]
    if len(zone) == 0:
        return _from_lists([], np.zeros((0, 3)), radius)
    cell = np.floor(zone / (2.0 * radius)).astype(np.int64)
    _, which = np.unique(cell, axis=0, return_inverse=True)
    which = which.reshape(-1)
    centers = (
        np.stack([np.bincount(which, weights=zone[:, a]) for a in range(3)], axis=1)
        / np.bincount(which)[:, None]
    )
    lists, kept = [], []
    for center, a, b in zip(
        centers,
        own_tree.query_ball_point(centers, radius),
        other_tree.query_ball_point(centers, radius),
    ):
        if len(a) >= 2 and len(b) >= 2:
            lists.append(np.sort(np.concatenate([own[a], other[b]])))
            kept.append(center)
    return _from_lists(lists, np.array(kept).reshape(-1, 3), radius)


def concatenate(parts: list[Clusters]) -> Clusters:
    """All clusters of ``parts`` in one compressed-row table (members are global)."""
    lists = [p.members[p.start[c] : p.start[c + 1]] for p in parts for c in range(p.count)]
    merged = _from_lists(
        lists, np.concatenate([p.center for p in parts] or [np.zeros((0, 3))]), 0.0
    )
    merged.radius = np.concatenate([p.radius for p in parts] or [np.zeros(0)])
    return merged
