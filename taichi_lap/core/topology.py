"""The topology validator: one checker of a model's particles, tets, surfaces and
clusters for tests, benchmarks and the debug option of a run (seed 002 §3.3: after
removals and cuts the wound surface must stay a closed, outward surface of live
tissue; docs/architecture.md, "Topology change").

A :class:`Topology` holds the arrays as NumPy, each element with an alive flag (a
built model has every one alive); :func:`check_topology` lists every
:class:`TopologyProblem` it finds, :func:`assert_valid` raises them. The checks:

* indices in range (tets and cluster members into particles, triangles into surface
  vertices, the particles each surface vertex follows);
* live elements use live particles (tets, clusters, and the particles a live
  triangle's vertices follow) and live triangles live vertices;
* no degenerate, duplicate or inverted elements: tets of positive rest volume,
  triangles of non-zero area, no element listed twice;
* each tet organ's live surface is closed and edge-manifold (every edge in exactly
  two triangles), its triangles agree in orientation and point outwards at rest (the
  volume they enclose there is positive: a surface the simulation turns inside out,
  as a crushed stalk, is the physics' fault, not the mesh's);
* no orphans: every live particle of a tet organ is in a live tet, every surface
  vertex of a live triangle's organ is used by one;
* cluster membership: every live particle of an organ with clusters is in a live
  cluster, and no live cluster is empty;
* volume: the rest volume of the tets as built less that of the live tets (a cut's
  sub-tets fill the tets they replace) equals what the dissection reports it
  removed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from taichi_lap.core.mesh import (
    degenerate_triangles,
    edge_defects,
    enclosed_volume,
    inconsistent_edges,
    tet_volumes,
)

VOLUME_TOLERANCE = 1e-9
MAX_ORGANS = 32  # organs of a scene (the tools' contacts are counted per organ)
"""Relative tolerance of the removed-volume balance (of the organs' rest volume)."""


class TopologyError(ValueError):
    """A topology failed :func:`check_topology`; ``problems`` lists why."""

    def __init__(self, problems: list[TopologyProblem]):
        self.problems = problems
        listed = "\n".join(f"  {problem}" for problem in problems)
        super().__init__(f"invalid topology, {len(problems)} problem(s):\n{listed}")


@dataclass(frozen=True)
class TopologyProblem:
    """One failed check: ``check`` names it, ``where`` the organ or the array,
    ``detail`` what was found (counts and the first offending indices)."""

    check: str
    where: str
    detail: str

    def __str__(self) -> str:
        return f"{self.check} ({self.where}): {self.detail}"


@dataclass
class OrganRecord:
    """Where one organ lives in the global arrays (half-open index ranges), and its
    tissue model."""

    name: str
    model: str
    particles: tuple[int, int]
    triangles: tuple[int, int]
    surface_vertices: tuple[int, int]
    tets: tuple[int, int]
    clusters: tuple[int, int]
    struts: int = 0
    springs: int = 0
    row_length: int = 0  # spring sheets: masses per row (row 0 is the intestine)
    reserve: int = 0  # rows at the end of ``particles`` a cut takes for new vertices

    @property
    def volume_cuttable(self) -> bool:
        """Whether scissors cut through it (seed 000 §5.3): it has tets and a reserve."""
        return bool(self.reserve) and self.tets[1] > self.tets[0]


@dataclass
class Topology:
    """A model's topology as NumPy arrays (shapes as in
    :class:`~taichi_lap.preprocess.model_data.ModelData`), with alive flags.

    ``positions`` (N, 3) [m] are where the particles are now (the surface is checked
    there, or at ``surface_position`` (V, 3) [m] when given: a vertex a dissection
    made sits at its kept particle plus a rest offset its cluster rotates, not at
    the weighted particles alone),
    ``rest_positions`` (N, 3) [m] where they were built (tet volumes), and
    ``rest_surface_position`` (V, 3) [m] where the surface vertices sit at rest
    (default: where the particles' rest positions put them; the surface's outward
    orientation is checked there);
    ``removed_volume`` [m^3] is the tet volume the dissection reports it removed;
    the first ``built_tets`` tets are those the model was built with (default: all),
    the others a cut's.
    ``triangle_organ`` and ``vertex_organ`` give each element's organ where a
    dissection added elements outside the organs' index ranges (default: the
    ranges)."""

    rest_positions: np.ndarray
    positions: np.ndarray
    tets: np.ndarray
    surface_index: np.ndarray
    surface_weight: np.ndarray
    triangles: np.ndarray
    cluster_start: np.ndarray
    cluster_member: np.ndarray
    organs: list[OrganRecord]
    particle_alive: np.ndarray | None = None
    tet_alive: np.ndarray | None = None
    triangle_alive: np.ndarray | None = None
    cluster_alive: np.ndarray | None = None
    vertex_alive: np.ndarray | None = None
    triangle_organ: np.ndarray | None = None
    vertex_organ: np.ndarray | None = None
    surface_position: np.ndarray | None = None
    rest_surface_position: np.ndarray | None = None
    removed_volume: float = 0.0
    built_tets: int | None = None

    def __post_init__(self):
        self.tets = np.asarray(self.tets, dtype=np.int64).reshape(-1, 4)
        self.triangles = np.asarray(self.triangles, dtype=np.int64).reshape(-1, 3)
        self.surface_index = np.asarray(self.surface_index, dtype=np.int64).reshape(-1, 4)
        self.surface_weight = np.asarray(self.surface_weight, dtype=np.float64).reshape(-1, 4)
        for name, count in (
            ("particle_alive", len(self.rest_positions)),
            ("tet_alive", len(self.tets)),
            ("triangle_alive", len(self.triangles)),
            ("cluster_alive", len(self.cluster_start) - 1),
            ("vertex_alive", len(self.surface_index)),
        ):
            flags = getattr(self, name)
            if flags is None:
                flags = np.ones(count, dtype=bool)
            flags = np.asarray(flags, dtype=bool)
            if flags.shape != (count,):
                raise ValueError(f"Topology.{name}: shape ({count},) expected, got {flags.shape}")
            setattr(self, name, flags)
        for name, count, ranges in (
            ("triangle_organ", len(self.triangles), [o.triangles for o in self.organs]),
            ("vertex_organ", len(self.surface_index), [o.surface_vertices for o in self.organs]),
        ):
            if getattr(self, name) is None:
                organ = np.full(count, -1, dtype=np.int64)
                for k, (begin, end) in enumerate(ranges):
                    organ[begin:end] = k
                setattr(self, name, organ)

    @classmethod
    def of_model(cls, data, positions: np.ndarray | None = None, **alive) -> Topology:
        """The topology of a built model ``data`` (a ``ModelData``) with its particles
        at ``positions`` (default: at rest); ``alive``: flags and ``removed_volume``
        (by default every particle lives but the reserve rows no cut took yet)."""
        if "particle_alive" not in alive:
            live = np.ones(len(data.rest_position), dtype=bool)
            for organ in data.organs:
                live[organ.particles[1] - organ.reserve : organ.particles[1]] = False
            alive["particle_alive"] = live
        return cls(
            rest_positions=data.rest_position,
            positions=data.rest_position if positions is None else positions,
            tets=data.tets,
            surface_index=data.surface_index,
            surface_weight=data.surface_weight,
            triangles=data.surface_triangles,
            cluster_start=data.cluster_start,
            cluster_member=data.cluster_member,
            organs=data.organs,
            **alive,
        )

    def surface_positions(self) -> np.ndarray:
        """(V, 3) [m]: each surface vertex where its particles put it (or as given)."""
        if self.surface_position is not None:
            return np.asarray(self.surface_position, dtype=np.float64)
        return self._bound(self.positions)

    def rest_surface(self) -> np.ndarray:
        """(V, 3) [m]: each surface vertex where it sits at rest."""
        if self.rest_surface_position is not None:
            return np.asarray(self.rest_surface_position, dtype=np.float64)
        return self._bound(self.rest_positions)

    def _bound(self, positions: np.ndarray) -> np.ndarray:
        """(V, 3) [m]: each surface vertex where the particle ``positions`` put it."""
        index = np.clip(self.surface_index, 0, len(positions) - 1)
        return (self.surface_weight[..., None] * positions[index]).sum(axis=1)


def check_topology(topology: Topology) -> list[TopologyProblem]:
    """Every problem the module docstring's checks find (empty: valid)."""
    problems: list[TopologyProblem] = []

    def report(check: str, where: str, bad: np.ndarray, what: str):
        problems.extend(_listed(check, where, bad, what))

    t = topology
    n = len(t.rest_positions)
    v = len(t.surface_index)
    members = np.asarray(t.cluster_member, dtype=np.int64)
    ranges = [
        ("tets", t.tets, n),
        ("triangles", t.triangles, v),
        ("cluster members", members[:, None], n),  # one per row
        ("surface vertices", np.where(t.surface_weight != 0.0, t.surface_index, 0), n),
    ]
    for name, indices, count in ranges:
        report("index range", name, ((indices < 0) | (indices >= count)).any(axis=1), name)
    if problems:
        return problems  # the checks below index with them

    dead = ~t.particle_alive
    member_cluster = np.repeat(np.arange(len(t.cluster_start) - 1), np.diff(t.cluster_start))
    follows_dead = (dead[t.surface_index] & (t.surface_weight != 0.0)).any(axis=1)
    report("dead reference", "tets", t.tet_alive & dead[t.tets].any(axis=1), "live tets")
    report(
        "dead reference",
        "cluster members",
        t.cluster_alive[member_cluster] & dead[members],
        "members of live clusters",
    )
    report(
        "dead reference",
        "triangles",
        t.triangle_alive & follows_dead[t.triangles].any(axis=1),
        "live triangles with a vertex following a removed particle",
    )
    report(
        "dead reference",
        "triangles",
        t.triangle_alive & (~t.vertex_alive[t.triangles]).any(axis=1),
        "live triangles with a removed vertex",
    )
    report("empty cluster", "clusters", t.cluster_alive & (np.diff(t.cluster_start) == 0), "")

    rest_volume = tet_volumes(t.rest_positions, t.tets)
    report("inverted tet", "tets", t.tet_alive & (rest_volume <= 0.0), "live tets")
    report("duplicate", "tets", _duplicates(t.tets, t.tet_alive), "live tets")
    report("duplicate", "triangles", _duplicates(t.triangles, t.triangle_alive), "live triangles")

    surface, rest_surface = t.surface_positions(), t.rest_surface()
    degenerate = np.zeros(len(t.triangles), dtype=bool)
    degenerate[t.triangle_alive] = degenerate_triangles(surface, t.triangles[t.triangle_alive])
    report("degenerate triangle", "triangles", degenerate, "live triangles")
    in_cluster = np.zeros(n, dtype=bool)
    in_cluster[members[t.cluster_alive[member_cluster]]] = True
    in_tet = np.zeros(n, dtype=bool)
    in_tet[t.tets[t.tet_alive].ravel()] = True
    for k, organ in enumerate(t.organs):
        particles = slice(*organ.particles)
        live = np.flatnonzero(t.triangle_alive & (t.triangle_organ == k))
        if organ.clusters[1] > organ.clusters[0]:
            report(
                "not in a cluster",
                f"organ {organ.name}",
                t.particle_alive[particles] & ~in_cluster[particles],
                "live particles",
            )
        if organ.tets[1] == organ.tets[0] or not (t.particle_alive[particles].any() or len(live)):
            continue  # not a tet organ, or one removed whole
        report(
            "orphan",
            f"organ {organ.name}",
            t.particle_alive[particles] & ~in_tet[particles],
            "live particles in no live tet",
        )
        problems.extend(_surface_problems(organ, rest_surface, t.triangles[live]))
        used = np.zeros(v, dtype=bool)
        used[t.triangles[live].ravel()] = True
        report(
            "orphan",
            f"organ {organ.name}",
            t.vertex_alive & (t.vertex_organ == k) & ~used,
            "surface vertices in no live triangle",
        )

    _volume_balance(t, rest_volume, problems)
    return problems


def assert_valid(topology: Topology):
    """Raise :class:`TopologyError` listing every problem of ``topology``."""
    problems = check_topology(topology)
    if problems:
        raise TopologyError(problems)


def _duplicates(elements: np.ndarray, alive: np.ndarray) -> np.ndarray:
    """(E,) bool: live elements whose vertex set an earlier live element has."""
    keys = np.sort(np.asarray(elements, dtype=np.int64), axis=1)
    live = np.flatnonzero(alive)
    _, first = np.unique(keys[live], axis=0, return_index=True)
    out = alive.copy()
    out[live[first]] = False
    return out


def _listed(check: str, where: str, bad: np.ndarray, what: str) -> list[TopologyProblem]:
    """One problem counting the ``bad`` entries (a mask) with the first few named,
    or none."""
    bad = np.flatnonzero(bad)
    if not len(bad):
        return []
    first = ", ".join(str(i) for i in bad[:5])
    return [TopologyProblem(check, where, f"{len(bad)} {what} (first: {first})")]


def _surface_problems(
    organ: OrganRecord, rest_surface: np.ndarray, triangles: np.ndarray
) -> list[TopologyProblem]:
    """Closed, edge-manifold, consistently and (at rest) outward oriented (one tet
    organ's live triangles)."""
    where = f"organ {organ.name}"
    out = []
    if not len(triangles):
        return [TopologyProblem("open surface", where, "no live surface triangle")]
    open_edges, fins = edge_defects(triangles)
    if open_edges or fins:
        out.append(
            TopologyProblem(
                "open surface", where, f"{open_edges} open edges, {fins} non-manifold edges"
            )
        )
    flipped = inconsistent_edges(triangles)
    if flipped:
        out.append(
            TopologyProblem(
                "orientation", where, f"{flipped} edges whose two triangles run them alike"
            )
        )
    elif not open_edges and not fins and enclosed_volume(rest_surface, triangles) <= 0.0:
        out.append(TopologyProblem("orientation", where, "the surface's normals point inwards"))
    return out


def _volume_balance(t: Topology, rest_volume: np.ndarray, problems: list[TopologyProblem]):
    """The rest volume of the tets as built less that of the live tets against
    ``removed_volume``."""
    built = len(t.tets) if t.built_tets is None else t.built_tets
    removed = float(rest_volume[:built].sum() - rest_volume[t.tet_alive].sum())
    total = float(np.abs(rest_volume[:built]).sum())
    if abs(removed - t.removed_volume) > VOLUME_TOLERANCE * max(total, 1e-30):
        problems.append(
            TopologyProblem(
                "volume",
                "tets",
                f"the tets as built less the live ones hold {removed:.6g} m^3, the dissection "
                f"reports {t.removed_volume:.6g} m^3",
            )
        )
