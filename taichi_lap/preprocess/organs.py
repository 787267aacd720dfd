"""One organ from its validated spec: geometry, then the tissue model's particles,
clusters, constraints and surface binding, in the organ's own (local) indices.

| model            | geometry          | particles                | constraints                    |
|------------------|-------------------|--------------------------|--------------------------------|
| `tet_clusters`   | solid/closed mesh | BCC tet vertices         | overlapping clusters (seed 002)|
| `shape_matching` | surface           | surface vertices         | clusters (seed 000 Alg. 1)     |
| `fascia_lra`     | surface (sheet)   | surface vertices         | edges, bending, LRA (Eq. 3)    |
| `truss`          | closed surface    | surface vertices         | edges, struts (Alg. 2)         |
| `mass_spring`    | spring sheet      | rows of masses           | damped springs (seed 001 §3.2) |
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from taichi_lap.core.errors import InputError
from taichi_lap.core.geometry import Geometry, Solid, SpringSheet, TriangleMesh
from taichi_lap.core.instruments import cutting_geometry
from taichi_lap.core.mesh import pair_lengths, unique_edges
from taichi_lap.preprocess import clusters as clustering
from taichi_lap.preprocess.meshfile import load_surface_mesh
from taichi_lap.preprocess.sheets import (
    bending_pairs,
    long_range_attachments,
    sheet_springs,
    sheet_triangles,
)
from taichi_lap.preprocess.tetrahedralize import tetrahedralize
from taichi_lap.preprocess.transform import place
from taichi_lap.preprocess.truss import generate_truss
from taichi_lap.scene import OrganSpec
from taichi_lap.scenes.anatomy import GENERATORS

SURFACE_CLUSTER_EDGES = 4.0
"""Default cluster radius of a surface organ, in mean edge lengths."""
BODY_GAP = 0.6
"""A cluster centre of a tet organ lies in the body: within this many lattice
spacings of a particle (the BCC Voronoi cell reaches 0.56 spacings)."""

Progress = Callable[[float], None]


@dataclass
class OrganParts:
    """Everything the builder concatenates for one organ (local indices)."""

    positions: np.ndarray
    mass: np.ndarray
    radius: np.ndarray
    pinned: np.ndarray
    clusters: clustering.Clusters | None = None
    distance_pairs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    distance_rest: np.ndarray = field(default_factory=lambda: np.zeros(0))
    distance_stiffness: np.ndarray = field(default_factory=lambda: np.zeros(0))
    lra_particle: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    lra_anchor: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    lra_rest: np.ndarray = field(default_factory=lambda: np.zeros(0))
    spring_pairs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    spring_rest: np.ndarray = field(default_factory=lambda: np.zeros(0))
    spring_stiffness: np.ndarray = field(default_factory=lambda: np.zeros(0))
    spring_damping: np.ndarray = field(default_factory=lambda: np.zeros(0))
    tets: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.int64))
    surface_index: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.int64))
    surface_weight: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    surface_triangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))
    struts: int = 0
    row_length: int = 0
    reserve: int = 0


def make_geometry(organ: OrganSpec, source: str) -> Geometry:
    """The organ's geometry in scene coordinates (generator or mesh file, placed)."""
    spec = organ.geometry
    if spec.mesh is not None:
        closed = organ.model in ("tet_clusters", "truss")
        geometry = load_surface_mesh(
            spec.mesh,
            scene_file=source,
            key=f"{organ.key}.geometry.mesh",
            scale=spec.units,
            watertight=closed,
        )
    else:
        geometry = GENERATORS[spec.generator].build(dict(spec.params))
    return place(geometry, spec.rotate, spec.translate)


def _direct_binding(count: int) -> tuple[np.ndarray, np.ndarray]:
    index = np.repeat(np.arange(count)[:, None], 4, axis=1)
    weight = np.zeros((count, 4))
    weight[:, 0] = 1.0
    return index, weight


def _uniform(count: int, total: float) -> np.ndarray:
    return np.full(count, total / max(count, 1))


def _mean_edge(mesh: TriangleMesh) -> float:
    return float(pair_lengths(mesh.vertices, unique_edges(mesh.triangles)).mean())


def _surface_parts(mesh: TriangleMesh, mass: float) -> OrganParts:
    """Particles at the vertices of ``mesh``, surface bound directly."""
    n = len(mesh.vertices)
    index, weight = _direct_binding(n)
    return OrganParts(
        positions=mesh.vertices.copy(),
        mass=_uniform(n, mass),
        radius=np.full(n, 0.5 * _mean_edge(mesh)),
        pinned=np.zeros(n, bool),
        surface_index=index,
        surface_weight=weight,
        surface_triangles=mesh.triangles.copy(),
    )


def _edge_constraints(parts: OrganParts, pairs: np.ndarray, stiffness: float | np.ndarray):
    rest = pair_lengths(parts.positions, pairs)
    parts.distance_pairs = np.concatenate([parts.distance_pairs, pairs])
    parts.distance_rest = np.concatenate([parts.distance_rest, rest])
    parts.distance_stiffness = np.concatenate(
        [parts.distance_stiffness, np.broadcast_to(stiffness, (len(pairs),))]
    )


def _with_organ_cluster(
    local: clustering.Clusters, positions: np.ndarray, material: dict
) -> clustering.Clusters:
    """The local clusters, plus the whole-organ cluster when ``organ_cluster`` is set."""
    if not material["organ_cluster"]:
        return local
    return clustering.concatenate([local, clustering.whole_body_cluster(positions)])


def build_tet_clusters(
    organ: OrganSpec, geometry: Geometry, detail: float, progress: Progress | None
) -> OrganParts:
    """Seed 002 §3.2: BCC tets fill the solid, tet vertices are the particles,
    overlapping lattice clusters; the surface is bound to the tets."""
    material = organ.material
    solid = geometry
    if isinstance(geometry, TriangleMesh):
        solid = Solid(bounds=(geometry.vertices.min(0), geometry.vertices.max(0)), surface=geometry)
    shrink = detail ** (-1.0 / 3.0)
    spacing = material["particle_spacing"] * shrink
    tet = tetrahedralize(solid, spacing, progress=progress)
    n = len(tet.particles)
    radius = material["cluster_radius"]
    radius = clustering.auto_cluster_radius(spacing) if radius is None else radius * shrink
    clusters = clustering.lattice_clusters(tet.particles, radius, max_gap=BODY_GAP * spacing)
    return OrganParts(
        positions=tet.particles,
        mass=_uniform(n, material["mass"]),
        radius=np.full(n, 0.5 * spacing),
        pinned=np.zeros(n, bool),
        clusters=_with_organ_cluster(clusters, tet.particles, material),
        tets=tet.tets,
        surface_index=tet.binding_index,
        surface_weight=tet.binding_weight,
        surface_triangles=tet.surface.triangles,
    )


def build_shape_matching(organ: OrganSpec, mesh: TriangleMesh) -> OrganParts:
    """Seed 000 §3.1: the surface vertices are the particles, grouped in clusters."""
    parts = _surface_parts(mesh, organ.material["mass"])
    radius = organ.material["cluster_radius"] or SURFACE_CLUSTER_EDGES * _mean_edge(mesh)
    parts.clusters = _with_organ_cluster(
        clustering.lattice_clusters(parts.positions, radius), parts.positions, organ.material
    )
    return parts


CUTTABLE_SHEETS = ("fascia_lra",)
"""Tissue models whose sheets instruments cut (seed 000 Alg. 3,
:mod:`taichi_lap.dissection.sheet_cut`): their vertices are their particles."""
CUT_WALLS = ("shape_matching",)
"""Tissue models of surface particles in clusters (seed 000 §3.1: the rectum wall)
whose surface instruments cut where the material makes it ``cuttable``, the clusters
splitting where the cut parts them
(:meth:`~taichi_lap.dissection.removal.MutableTopology.cut_wall`)."""
CUT_SURFACES = CUTTABLE_SHEETS + ("truss",) + CUT_WALLS
"""Tissue models whose surface instruments cut (seed 000 Alg. 3): the sheets, the
truss structures of vessels and glands (§3.3) and the walls, whose surface vertices
are their particles too; a truss or a wall is cut where a scene holds an instrument
that cuts."""
CUT_RESERVE = 1.0
"""Particle rows a cuttable surface keeps for the vertices cuts make, as a fraction of
its vertices (a cut across the rectum's fascia makes about two per edge it crosses;
the vertices a cut removes give their rows back)."""
WALL_CUT_RESERVE = 0.5
"""Particle rows a wall keeps for the vertices cuts make, as a fraction of its
vertices (cutting an 8 mm tube of 12 by 32 vertices a skin through, pushed along by
the jaws, held 145 at once)."""
VOLUME_CUT_RESERVE = 0.5
"""Particle rows a tet organ whose surface is its particles keeps for the vertices
volumetric cuts make (seed 000 §5.3, :mod:`taichi_lap.dissection.volume_cut`), as a
fraction of its particles, in a scene whose instruments include scissors (two per
tet edge a cut crosses: a cut through the polyp's stalk takes about 10 %)."""


def cut_reserve(organ: OrganSpec, parts: OrganParts, tools: list[dict]) -> float:
    """The fraction of reserve rows ``organ`` keeps for cuts: a sheet or a truss where
    scissors or a hook can cut it, or a sheet that tears (:data:`CUT_RESERVE`), a wall
    its material makes ``cuttable`` where they can cut it (:data:`WALL_CUT_RESERVE`),
    or a directly bound tet organ where scissors can cut it (:data:`VOLUME_CUT_RESERVE`); 0
    for others (the solver's loops run over reserve rows too: a 128 x 128 sheet's step
    took 14.0 ms with them, 8.5 ms without)."""
    cutting = any(cutting_geometry(tool) is not None for tool in tools)
    if organ.model in CUTTABLE_SHEETS and (cutting or organ.material.get("tear_strain", 0.0) > 0):
        return CUT_RESERVE
    if organ.model == "truss" and cutting:
        return CUT_RESERVE
    if organ.model in CUT_WALLS and cutting and organ.material.get("cuttable", False):
        return WALL_CUT_RESERVE
    direct = len(parts.tets) and bool(np.all(parts.surface_weight[:, 0] == 1.0))
    if direct and any(tool["kind"] == "scissors" for tool in tools):
        return VOLUME_CUT_RESERVE
    return 0.0


def add_cut_reserve(parts: OrganParts, fraction: float):
    """Append ``fraction`` of the organ's particle count as reserve rows: pinned
    (inverse mass 0), in no constraint, cluster, tet or surface, parked at the first
    vertex, until a cut takes them."""
    count = int(np.ceil(fraction * len(parts.positions)))
    parts.positions = np.concatenate([parts.positions, np.repeat(parts.positions[:1], count, 0)])
    parts.mass = np.concatenate([parts.mass, np.full(count, parts.mass[0])])
    parts.radius = np.concatenate([parts.radius, np.full(count, parts.radius[0])])
    parts.pinned = np.concatenate([parts.pinned, np.ones(count, dtype=bool)])
    parts.reserve = count


def build_fascia(organ: OrganSpec, mesh: TriangleMesh) -> OrganParts:
    """Seed 000 §3.2: edge and bending distance constraints; the LRAs are added once
    the anchors are known (:func:`add_long_range_attachments`)."""
    material = organ.material
    parts = _surface_parts(mesh, material["mass"])
    _edge_constraints(parts, unique_edges(mesh.triangles), material["edge_stiffness"])
    _edge_constraints(parts, bending_pairs(mesh.triangles), material["bending_stiffness"])
    return parts


def add_long_range_attachments(organ: OrganSpec, parts: OrganParts, anchors: np.ndarray):
    """Attach every free vertex to its nearest ``lra_anchors`` anchors (seed 000 Eq. 3)."""
    mesh = TriangleMesh(parts.positions, parts.surface_triangles)
    lra = long_range_attachments(mesh, anchors, organ.material["lra_anchors"])
    parts.lra_particle, parts.lra_anchor, parts.lra_rest = lra.particle, lra.anchor, lra.rest


def build_truss(organ: OrganSpec, mesh: TriangleMesh, progress: Progress | None) -> OrganParts:
    """Seed 000 §3.3: surface edges plus Alg. 2 struts, all distance constraints."""
    material = organ.material
    parts = _surface_parts(mesh, material["mass"])
    _edge_constraints(parts, unique_edges(mesh.triangles), material["edge_stiffness"])
    truss = generate_truss(
        mesh,
        cone_angle=material["cone_angle"],
        bending_threshold=material["bending_threshold"],
        min_stiffness=material["min_stiffness"],
        progress=progress,
    )
    parts.distance_pairs = np.concatenate([parts.distance_pairs, truss.pairs])
    parts.distance_rest = np.concatenate([parts.distance_rest, truss.rest])
    parts.distance_stiffness = np.concatenate([parts.distance_stiffness, truss.stiffness])
    parts.struts = len(truss.pairs)
    return parts


def build_mass_spring(organ: OrganSpec, sheet: SpringSheet) -> OrganParts:
    """Seed 001 §3.2: rows of masses (row 0 the intestine) joined by damped springs."""
    material = organ.material
    rows, cols = sheet.rows.shape[:2]
    mass = np.concatenate(
        [
            _uniform(cols, material["intestine_mass"]),
            _uniform((rows - 1) * cols, material["mesentery_mass"]),
        ]
    )
    radius = np.repeat(sheet.row_radius if len(sheet.row_radius) == rows else np.zeros(rows), cols)
    springs = sheet_springs(
        sheet,
        intestine=material["intestine_stiffness"],
        mesentery=material["mesentery_stiffness"],
        bending=material["bending_stiffness"],
    )
    index, weight = _direct_binding(rows * cols)
    return OrganParts(
        positions=sheet.rows.reshape(-1, 3).copy(),
        mass=mass,
        radius=radius,
        pinned=np.zeros(rows * cols, bool),
        spring_pairs=springs.pairs,
        spring_rest=springs.rest,
        spring_stiffness=springs.stiffness,
        spring_damping=np.full(len(springs.pairs), material["spring_damping"]),
        surface_index=index,
        surface_weight=weight,
        surface_triangles=sheet_triangles(rows, cols),
        row_length=cols,
    )


def build_organ(
    organ: OrganSpec, source: str, detail: float, progress: Progress | None = None
) -> OrganParts:
    """Geometry and tissue model of one organ."""
    geometry = make_geometry(organ, source)
    if organ.model == "tet_clusters":
        return build_tet_clusters(organ, geometry, detail, progress)
    if organ.model == "mass_spring":
        return build_mass_spring(organ, geometry)
    mesh = geometry.surface if isinstance(geometry, Solid) else geometry
    if organ.model == "shape_matching":
        return build_shape_matching(organ, mesh)
    if organ.model == "fascia_lra":
        return build_fascia(organ, mesh)
    return build_truss(organ, mesh, progress)


def select_region(
    parts: OrganParts, region: dict, *, source: str, key: str, organ: str
) -> np.ndarray:
    """Local indices of the particles in a box, sphere or set of rows."""
    x = parts.positions
    if "rows" in region:
        if not parts.row_length:
            raise InputError(
                source, f"{key}.rows", f"rows select spring-sheet rows; organ {organ!r} has none"
            )
        rows = len(x) // parts.row_length
        picked = []
        for r in region["rows"]:
            if not -rows <= r < rows:
                raise InputError(
                    source, f"{key}.rows", f"a row in [{-rows}, {rows - 1}] was expected, found {r}"
                )
            picked.append(np.arange(parts.row_length) + (r % rows) * parts.row_length)
        selected = np.concatenate(picked)
    elif "center" in region:
        selected = np.flatnonzero(
            np.linalg.norm(x - np.asarray(region["center"]), axis=1) <= region["radius"]
        )
    else:
        lo, hi = np.asarray(region["box_min"]), np.asarray(region["box_max"])
        selected = np.flatnonzero(np.all((x >= lo) & (x <= hi), axis=1))
    if len(selected) == 0:
        raise InputError(
            source,
            key,
            f"a region holding particles of organ {organ!r} was expected, it holds none",
        )
    return np.unique(selected)
