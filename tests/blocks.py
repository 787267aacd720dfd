"""A Kuhn-split tet block as topology arrays, for the tests of the topology validator
and of dissection (no Taichi); and the scene file of a tet block with one tool."""

import numpy as np

from taichi_lap.core.mesh import tet_volumes
from taichi_lap.core.topology import OrganRecord
from taichi_lap.core.mesh import TET_FACES

KUHN_TETS = np.array(
    [[0, 1, 3, 7], [0, 3, 2, 7], [0, 2, 6, 7], [0, 6, 4, 7], [0, 4, 5, 7], [0, 5, 1, 7]]
)
"""The six tets of a unit cube around its diagonal 0-7 (corner k at the bits of k)."""


def block(cells: int = 2) -> dict:
    """The arguments of a valid :class:`Topology`: a cube of ``cells``³ Kuhn-split
    cells of 1 cm, its boundary the surface (a surface vertex on each boundary
    particle), one cluster per cell."""
    corner = np.array([[k & 1, (k >> 1) & 1, (k >> 2) & 1] for k in range(8)])
    side = cells + 1
    points = np.array([[i, j, k] for k in range(side) for j in range(side) for i in range(side)])
    index = {tuple(p): n for n, p in enumerate(points)}
    tets, clusters = [], []
    for origin in points[(points < cells).all(axis=1)]:
        ids = np.array([index[tuple(origin + c)] for c in corner])
        tets.extend(ids[KUHN_TETS])
        clusters.append(ids)
    tets = np.array(tets)
    x = 0.01 * points.astype(np.float64)
    tets[tet_volumes(x, tets) < 0] = tets[tet_volumes(x, tets) < 0][:, [1, 0, 2, 3]]
    faces = tets[:, TET_FACES].reshape(-1, 3)
    keys, count = np.unique(np.sort(faces, axis=1), axis=0, return_counts=True)
    boundary = {tuple(k) for k in keys[count == 1]}
    on_surface, triangles = np.unique(
        [f for f in faces if tuple(sorted(f)) in boundary], return_inverse=True
    )
    triangles = triangles.reshape(-1, 3)
    n, v, f = len(points), len(on_surface), len(triangles)
    return dict(
        rest_positions=x,
        positions=x.copy(),
        tets=tets,
        surface_index=np.stack([on_surface] + [np.zeros(v, dtype=int)] * 3, axis=1),
        surface_weight=np.repeat([[1.0, 0.0, 0.0, 0.0]], v, axis=0),
        triangles=triangles,
        cluster_start=np.arange(0, 8 * len(clusters) + 1, 8),
        cluster_member=np.concatenate(clusters),
        organs=[
            OrganRecord(
                "block",
                "tet_clusters",
                particles=(0, n),
                triangles=(0, f),
                surface_vertices=(0, v),
                tets=(0, len(tets)),
                clusters=(0, len(clusters)),
            )
        ],
    )


def block_model(cells: int = 4, whole_cluster: bool = False):
    """The block of :func:`block` as a ``ModelData`` (1 g particles, no constraints
    besides its clusters, with ``whole_cluster`` also one of every particle) for the
    dissection tests."""
    from taichi_lap.preprocess.model_data import PARTICLE_MATERIAL, ModelData

    arguments = block(cells)
    n = len(arguments["rest_positions"])
    none = np.zeros(0)
    start, member = arguments["cluster_start"], arguments["cluster_member"]
    if whole_cluster:
        start, member = np.append(start, start[-1] + n), np.concatenate([member, np.arange(n)])
        organ = arguments["organs"][0]
        organ.clusters = (0, len(start) - 1)
    return ModelData(
        rest_position=arguments["rest_positions"],
        mass=np.full(n, 1e-3),
        pinned=np.zeros(n, dtype=bool),
        radius=np.full(n, 0.005),
        organ=np.zeros(n, dtype=np.int64),
        material={name: np.zeros(n) for name in PARTICLE_MATERIAL},
        cluster_start=start,
        cluster_member=member,
        cluster_radius=np.full(len(start) - 1, 0.01),
        distance_pair=np.zeros((0, 2), dtype=np.int64),
        distance_rest=none,
        distance_stiffness=none,
        lra_particle=np.zeros(0, dtype=np.int64),
        lra_anchor=np.zeros(0, dtype=np.int64),
        lra_rest=none,
        spring_pair=np.zeros((0, 2), dtype=np.int64),
        spring_rest=none,
        spring_stiffness=none,
        spring_damping=none,
        tets=arguments["tets"],
        surface_index=arguments["surface_index"],
        surface_weight=arguments["surface_weight"],
        surface_triangles=arguments["triangles"],
        organs=arguments["organs"],
    )


def block_scene_file(name: str, tool: str, material: str = "") -> str:
    """A scene file: the 4 x 2.4 x 3 cm tet block (2 mm lattice, ``material``: more
    of its material keys, e.g. ``", mass = 0.03"``), fixed at its base, no gravity,
    and the ``[[tools]]`` table ``tool`` (TOML)."""
    return f"""
[scene]
name = "{name}"
gravity = [0.0, 0.0, 0.0]

{tool}

[[organs]]
name = "block"
model = "tet_clusters"
geometry = {{ generator = "box", half_extents = [0.02, 0.012, 0.015] }}
material = {{ particle_spacing = 0.002{material} }}
attachments = [ {{ kind = "fixed", box_min = [-1, -1, -1], box_max = [1, -0.011, 1] }} ]
"""
