"""The model on the device: rest shape, masses, materials, clusters, constraints,
surfaces and environment colliders (the Warp/Newton ``Model``).

Built from :class:`taichi_lap.preprocess.model_data.ModelData`; kernels receive it as
a ``ti.template()`` argument and only read it. Dissection changes it between steps
(:mod:`taichi_lap.dissection.device`): the cluster tables have spare rows (members,
chunks and clusters are appended, counts live in fields), a cluster drops a member by
the member's weight in it (``cluster_member_mass``), a removed particle gets inverse
mass 0. Spare rows that run out are reallocated larger (:meth:`Model.grow`);
:meth:`Model.reset_topology` puts back the model as built.
"""

from __future__ import annotations

import numpy as np
import taichi as ti

from taichi_lap.core.csr import both_ends, incidence, rows_of_extents
from taichi_lap.core import fields
from taichi_lap.core.fields import FieldGroup, FieldOwner, padded_rows, placed_rows
from taichi_lap.core.mesh import incident_table
from taichi_lap import runtime
from taichi_lap.core.topology import MAX_ORGANS
from taichi_lap.kernels.scatter import RowWrites
from taichi_lap.preprocess.model_data import ModelData
from taichi_lap.preprocess.organs import CUT_WALLS
from taichi_lap.preprocess.sheets import torn_cells

CHUNK = 128
"""Cluster members summed by one thread in the cluster-matching reduction."""
SURFACE_SPARE = 1.5
"""Spare surface rows of a model with tets, as a fraction of its surface."""


ROW_KINDS = (
    "vertices",
    "triangles",
    "members",
    "memberships",
    "clusters",
    "chunks",
    "distances",
    "distance_ends",
    "attachments",
)
"""The kinds of rows dissection appends to (:attr:`Model.capacity`, :meth:`Model.grow`)."""
TABLES = ("surface_incident",)
"""Fields whose rows are as wide as the mesh needs (a vertex's triangles): 2-D tables,
read in a loop, not vectors unrolled into every kernel that reads them."""


CHUNK_SPARE = 2.0
"""Spare chunk rows, as a fraction of those built (a chunk row is three integers; a
volumetric cut lists the chunks of each cluster it adds members to again)."""


def spare_rows(count: int, dissectable: bool, spare: float = 0.5) -> int:
    """Rows to allocate for ``count`` rows that dissection may append to: ``spare``
    times as many again (at least 64) for a model with tets, none otherwise."""
    return count + (int(spare * count) + 64 if dissectable else 0)


JACOBI_ROWS = {
    "distance_begin": None,
    "distance_end": None,
    "distance_other": "distance_ends",
    "distance_rest": "distance_ends",
    "distance_stiffness": "distance_ends",
    "lra_begin": None,
    "lra_end": None,
    "lra_anchor": "attachments",
    "lra_rest": "attachments",
}
"""The Jacobi tables of the distance constraints and long-range attachments: field ->
the kind of its spare rows (None: one row per particle). Particle i's entries are the
rows ``begin[i]..end[i]`` of its table; as built, one particle's follow the last's,
and a cut appends a particle's new list after the rows in use
(:meth:`Model.replace_constraints`)."""
LISTS = {
    "distance": ("distance_ends", ("distance_other", "distance_rest", "distance_stiffness")),
    "lra": ("attachments", ("lra_anchor", "lra_rest")),
}
"""The two kinds of per-particle lists in :data:`JACOBI_ROWS`: their rows' kind and
the fields of their entries."""
CONSTRAINT_SPARE = {"distances": 3.0, "distance_ends": 3.0, "attachments": 20.0}
"""Spare rows of the constraint tables of a model with cuttable sheets, as a fraction
of those built: a cut appends the lists it changed there, and a table is written
whole again (compacted) when it is full. A cut changes the distance lists near it,
but the attachments of every particle whose geodesics to its anchors it lengthened
(half the fascia's, late in the rectum scene's cut: the table filled every fourth
frame with 3.0)."""


def constraint_arrays(pairs, rest, stiffness, lra_particle, lra_anchor, lra_rest) -> dict:
    """Distance constraints and long-range attachments as arrays of one shape and type
    each: ``pairs`` (D, 2), ``rest`` [m] and ``stiffness`` (D,), ``lra_particle``,
    ``lra_anchor`` and ``lra_rest`` [m] (A,)."""
    return {
        "pairs": np.asarray(pairs, dtype=np.int64).reshape(-1, 2),
        "rest": np.asarray(rest, dtype=np.float64),
        "stiffness": np.asarray(stiffness, dtype=np.float64),
        "lra_particle": np.asarray(lra_particle, dtype=np.int64),
        "lra_anchor": np.asarray(lra_anchor, dtype=np.int64),
        "lra_rest": np.asarray(lra_rest, dtype=np.float64),
    }


def iteration_stiffness(stiffness: np.ndarray, iterations: int) -> np.ndarray:
    """Per-iteration stiffness k' = 1 - (1 - k)^(1/n) so that n iterations give the
    effect of stiffness k whatever n is (Müller et al. 2007, §3.3)."""
    k = np.clip(np.asarray(stiffness, dtype=np.float64), 0.0, 1.0)
    return 1.0 - (1.0 - k) ** (1.0 / max(iterations, 1))


def greedy_colors(pairs: np.ndarray, count: int) -> np.ndarray:
    """Colour the constraints ``pairs`` (D, 2) so that no two of one colour share a
    particle (greedy, in order); for graph-coloured Gauss-Seidel."""
    used = [0] * count
    colors = np.empty(len(pairs), dtype=np.int64)
    for e, (i, j) in enumerate(pairs.tolist()):
        taken = used[i] | used[j]
        c = (~taken & (taken + 1)).bit_length() - 1
        colors[e] = c
        used[i] |= 1 << c
        used[j] |= 1 << c
    return colors


def cluster_tables(
    rest: np.ndarray, mass: np.ndarray, start: np.ndarray, member: np.ndarray
) -> dict:
    """Seed 000 Alg. 1 rest data of clusters ``start``/``member`` (compressed rows):
    per member its ``mass`` (its weight in the fits,
    :func:`~taichi_lap.preprocess.model_data.fit_weights`) and rest offset
    q = x0 - x0_cm, per cluster its mass and rest mass centre x0_cm [m], and the
    particle-major memberships."""
    c = len(start) - 1
    owner = np.repeat(np.arange(c), np.diff(start))
    m = mass[member]
    cmass = np.bincount(owner, weights=m, minlength=c)
    center = (
        np.stack(
            [np.bincount(owner, weights=m * rest[member, a], minlength=c) for a in range(3)], axis=1
        )
        / np.maximum(cmass, 1e-12)[:, None]
    )
    offset = rest[member] - center[owner]
    mstart, mrows = incidence(member, len(rest))
    return {
        "member_mass": m,
        "offset": offset,
        "center": center,
        "mass": cmass,
        "membership_start": mstart,
        "membership_cluster": owner[mrows],
        "membership_offset": offset[mrows],
    }


def particle_organs(data: ModelData) -> np.ndarray:
    """Each particle's organ (an index of ``data.organs``): the organs' particle ranges
    cover the particle array, the rows a cut takes for new particles included."""
    if len(data.organs) > MAX_ORGANS:
        raise ValueError(f"at most {MAX_ORGANS} organs were expected, found {len(data.organs)}")
    organ = np.full(data.particle_count, -1, dtype=np.int32)
    for k, record in enumerate(data.organs):
        organ[record.particles[0] : record.particles[1]] = k
    if (organ < 0).any():
        raise ValueError(f"particles outside every organ's range: {np.flatnonzero(organ < 0)[:5]}")
    return organ


def volume_cut_rows(data) -> dict[str, int]:
    """Member and chunk rows to add for the cuts of ``data``'s organs whose clusters a
    cut parts (a cut reserve and tets, :mod:`taichi_lap.dissection.volume_cut`, or a
    wall, :data:`~taichi_lap.preprocess.organs.CUT_WALLS`): a cut appends the pieces
    of each cluster it parts and lists again the chunks of each cluster it gives
    members, so twice the members and chunks of the clusters holding a particle of
    such an organ. Without them the rectum script's polyp excision outgrew the spare
    rows (members 33,973 to 50,959, chunks 820 to 1,230) and stalled about 2 s while
    every kernel compiled again."""
    start = np.asarray(data.cluster_start, dtype=np.int64)
    member = np.asarray(data.cluster_member, dtype=np.int64)
    owner = np.repeat(np.arange(len(start) - 1), np.diff(start))
    touched = np.zeros(len(start) - 1, dtype=bool)
    for organ in data.organs:
        if organ.volume_cuttable or organ.reserve and organ.model in CUT_WALLS:
            first, end = organ.particles
            touched[owner[(member >= first) & (member < end)]] = True
    sizes = np.diff(start)[touched]
    return {"members": 2 * int(sizes.sum()), "chunks": 2 * int((-(-sizes // CHUNK)).sum())}


def member_chunks(start: np.ndarray, first_row: int = 0) -> dict:
    """Chunks of at most :data:`CHUNK` members of each cluster ``start`` (compressed
    rows): ``first`` (C + 1,) each cluster's first chunk (from ``first_row``), and
    per chunk its cluster, ``begin`` and ``end`` member rows."""
    sizes = np.diff(start)
    per_cluster = np.maximum(-(-sizes // CHUNK), 1)
    first = np.concatenate([[0], np.cumsum(per_cluster)])
    owner = np.repeat(np.arange(len(sizes)), per_cluster)
    rank = np.arange(first[-1]) - first[owner]
    begin = start[owner] + rank * CHUNK
    return {
        "first": first + first_row,
        "cluster": owner,
        "begin": begin,
        "end": np.minimum(begin + CHUNK, start[owner + 1]),
    }


@ti.data_oriented
class Model(FieldOwner):
    """Device copy of a :class:`ModelData` plus the environment planes.

    ``planes`` is a list of ``(point, normal, friction)``, ``tubes`` (the environment's
    fixed tubes) of ``(centre line (n, 3), radius, friction)``; ``iterations`` is the
    number of constraint iterations per substep (sets the per-iteration stiffness).
    Per-particle material channels are fields named as in ``PARTICLE_MATERIAL``.
    """

    def __init__(
        self,
        data: ModelData,
        *,
        planes=(),
        tubes=(),
        iterations: int = 10,
        constraint_solver: str = "jacobi",
    ):
        self.data = data
        self._group = FieldGroup()
        n = data.particle_count
        self.particle_count = n
        self.serial = runtime.serial_loops(n)  # the kernels' loop_config (compile time)
        self.cluster_total = data.cluster_count
        self.constraint_solver = constraint_solver

        self.iterations = iterations
        self.cuttable = any(organ.reserve for organ in data.organs)
        self.dissectable = len(data.tets) > 0 or self.cuttable
        self.radius = self._floats(data.radius)
        self.contact_radius = self._floats(data.contact_radius())
        self.particle_organ = self._ints(particle_organs(data))
        for name, values in data.material.items():
            setattr(self, name, self._floats(values))

        self._init_clusters(data)
        self._init_springs(data, n)
        self._init_tubes(data)
        self._init_planes(planes)
        self._init_environment_tubes(tubes)
        self._group.finalize()
        self.finalize_counts()

    def _ints(self, values, vector: int = 0, rows: int = 0, columns: int = 0):
        """An i32 field holding ``values`` (one entry per row; ``rows`` at least)."""
        values = np.asarray(values, dtype=np.int32)
        return self._group.field(
            ti.i32,
            max(len(values), rows),
            vector=vector,
            columns=columns,
            values=padded_rows(values, rows),
        )

    def _floats(self, values, vector: int = 0, rows: int = 0):
        """An f32 field holding ``values`` (one entry per row; ``rows`` at least)."""
        values = np.asarray(values, dtype=np.float32)
        return self._group.field(
            ti.f32, max(len(values), rows), vector=vector, values=padded_rows(values, rows)
        )

    def _init_clusters(self, data: ModelData):
        """Cluster tables of seed 000 Alg. 1 (:func:`cluster_tables`), chunked
        (:func:`member_chunks`), and the inverse masses: the fields dissection
        changes. Those with spare rows (:data:`ROW_KINDS`) are the ``rows`` that
        :meth:`grow` reallocates."""
        self.cluster_count = self._group.field(ti.i32, None)
        self.chunk_count = self._group.field(ti.i32, None)
        self._rows = self._group  # a tree of their own once grown
        self._row_fill = {}
        for name, (values, kind, fill) in self._as_built(data).items():
            make = self._ints if values.dtype.kind in "iu" else self._floats
            values = padded_rows(values, self.capacity.get(kind, 0), fill)
            width = values.shape[1] if values.ndim > 1 else 0
            if name in TABLES:
                setattr(self, name, make(values, columns=width))
            else:
                setattr(self, name, make(values, vector=width))
            if kind is not None:
                self._row_fill[name] = (kind, fill)
        self._set_capacities()
        self.topology_version = 0  # counts the changes written to the model
        self.as_built = True  # no dissection changed the model since it was built or reset
        self.layout_version = 0  # counts the reallocations of the row fields (grow)

    def _set_capacities(self):
        """The attributes kernels and dissection read for the rows allocated."""
        self.cluster_capacity = self.capacity["clusters"]
        self.member_capacity = self.capacity["members"]
        self.chunk_capacity = self.capacity["chunks"]
        self.surface_vertex_count = self.capacity["vertices"]  # spare rows included
        self.surface_triangle_count = self.capacity["triangles"]

    def grow(self, **rows: int):
        """Reallocate the row fields with at least ``rows`` of each kind named
        (:data:`ROW_KINDS`), values kept, in a tree of their own (the first growth
        leaves the rows as built unused in the model's tree: one tree more only for a
        model that grew, as a process holds a limited number): the first dissection
        that outgrows the spare rows pays it (every kernel compiles again) and the
        rows' consumers (the state, the drawn mesh) follow :attr:`layout_version`."""
        unknown = set(rows) - set(ROW_KINDS)
        if unknown:
            raise ValueError(f"grow: unknown row kinds {sorted(unknown)}; {ROW_KINDS} expected")
        for kind, count in rows.items():
            self.capacity[kind] = max(self.capacity[kind], int(count))
        self._rows = self._rows.regrown(
            self,
            {name: self.capacity[kind] for name, (kind, _) in self._row_fill.items()},
            {name: fill for name, (_, fill) in self._row_fill.items()},
        )
        self._set_capacities()
        self.layout_version += 1

    def close(self):
        """Free the model's fields (:meth:`FieldGroup.close`; the rows' own tree too
        once grown)."""
        self._rows.close()
        super().close()

    def _as_built(self, data: ModelData) -> dict[str, tuple[np.ndarray, str | None, int]]:
        """Field name -> (values as built, the kind of its spare rows or None for
        none, value of the spare rows) of what dissection changes
        (``cluster_rest_shift``: :mod:`taichi_lap.dissection.device`): the surface
        (each vertex follows four particles, a wound vertex with a ``surface_cluster``
        >= 0 its kept particle plus its rest offset ``surface_offset`` turned by that
        cluster's rotation; the triangles, (0, 0, 0) when dead,
        their organ, and each vertex's triangles in ``surface_incident``, -1 padded),
        and members with their mass in the cluster, rest offsets q = x0 - x0_cm,
        cluster masses and rest centres, every particle's clusters and offsets in
        them (the memberships it gathers goals from, particle-major so the gather
        reads contiguous memory), and chunks of at most :data:`CHUNK` members summed
        in parallel then per cluster in order (balanced work for clusters of any
        size, a whole-organ cluster has ~10^5 members, still deterministic). Sets
        the counts as built and, at the first call, :attr:`capacity`."""
        tables = cluster_tables(
            data.rest_position, data.fit_mass(), data.cluster_start, data.cluster_member
        )
        chunks = member_chunks(data.cluster_start)
        self.cluster_total = data.cluster_count
        self.chunk_total = len(chunks["cluster"])
        if not hasattr(self, "capacity"):
            # a wound across a whole organ adds about as much surface as it had
            surface = {
                "vertices": len(data.surface_index),
                "triangles": len(data.surface_triangles),
            }
            constraints = {
                "distances": len(data.distance_pair),
                "distance_ends": 2 * len(data.distance_pair),
                "attachments": len(data.lra_particle),
            }
            volume = volume_cut_rows(data)
            self.capacity = {
                **{k: spare_rows(n, self.dissectable, SURFACE_SPARE) for k, n in surface.items()},
                "members": spare_rows(len(data.cluster_member), self.dissectable)
                + volume["members"],
                "memberships": spare_rows(len(data.cluster_member), self.dissectable),
                "clusters": spare_rows(self.cluster_total, self.dissectable),
                # a cut lists a cluster's chunks again to give it members
                "chunks": spare_rows(self.chunk_total, self.dissectable, CHUNK_SPARE)
                + volume["chunks"],
                **{
                    k: max(spare_rows(n, self.cuttable, CONSTRAINT_SPARE[k]), 1)
                    for k, n in constraints.items()
                },
            }
        organ = np.zeros(len(data.surface_triangles), dtype=np.int64)
        for k, record in enumerate(data.organs):
            organ[record.triangles[0] : record.triangles[1]] = k
        return {
            "surface_index": (data.surface_index, "vertices", 0),
            "surface_weight": (data.surface_weight, "vertices", 0),
            "surface_cluster": (np.full(len(data.surface_index), -1), "vertices", -1),
            "surface_offset": (np.zeros((len(data.surface_index), 3)), "vertices", 0),
            "surface_triangles": (data.surface_triangles.reshape(-1, 3), "triangles", 0),
            "surface_triangle_organ": (organ, "triangles", 0),
            "surface_incident": (
                incident_table(data.surface_triangles, len(data.surface_index)),
                "vertices",
                -1,
            ),
            "inv_mass": (data.inverse_mass(), None, 0),
            "rest_position": (data.rest_position, None, 0),
            "mass": (data.mass, None, 0),
            "cluster_member": (data.cluster_member, "members", 0),
            "cluster_member_mass": (tables["member_mass"], "members", 0),
            "cluster_rest_offset": (tables["offset"], "members", 0),
            "cluster_rest_center": (tables["center"], "clusters", 0),
            "cluster_mass": (tables["mass"], "clusters", 0),
            "cluster_rest_shift": (np.zeros((data.cluster_count, 3)), "clusters", 0),
            "membership_start": (tables["membership_start"], None, 0),
            "membership_cluster": (tables["membership_cluster"], "memberships", 0),
            "membership_offset": (tables["membership_offset"], "memberships", 0),
            "cluster_chunk_begin": (chunks["first"][:-1], "clusters", 0),
            "cluster_chunk_end": (chunks["first"][1:], "clusters", 0),
            "chunk_cluster": (chunks["cluster"], "chunks", 0),
            "chunk_begin": (chunks["begin"], "chunks", 0),
            "chunk_end": (chunks["end"], "chunks", 0),
            **self._constraint_tables(
                data.distance_pair.reshape(-1, 2),
                data.distance_rest,
                data.distance_stiffness,
                data.lra_particle,
                data.lra_anchor,
                data.lra_rest,
            ),
        }

    @property
    def serial_sweeps(self) -> bool:
        """Whether the Jacobi sweeps run serially (the kernel's loop_config, fixed
        when it compiles for this model): a :attr:`serial` model whose lists hold
        fewer than :data:`~taichi_lap.runtime.SWEEP_SERIAL_BELOW` entries."""
        entries = 2 * self.distance_count + self.lra_count
        return self.serial and entries < runtime.SWEEP_SERIAL_BELOW

    def _constraint_tables(
        self, pairs, rest, stiffness, lra_particle, lra_anchor, lra_rest
    ) -> dict[str, tuple[np.ndarray, str | None, int]]:
        """The distance constraints (struts, sheet edges; ``stiffness`` per
        constraint, made per iteration) as per-particle lists for the Jacobi gather
        and, for the Gauss-Seidel solver, sorted by colour, and the long-range
        attachments per constrained particle (seed 000 §3.2), as :meth:`_as_built`
        entries. Sets the counts and :attr:`color_ranges`."""
        n = self.particle_count
        # as given (replace_constraints relists particle ranges of them)
        host = self._constraint_host = constraint_arrays(
            pairs, rest, stiffness, lra_particle, lra_anchor, lra_rest
        )
        self._relisted: dict[tuple[int, int], dict[str, np.ndarray]] = {}
        pairs, rest = host["pairs"], host["rest"]
        stiff = iteration_stiffness(host["stiffness"], self.iterations)
        gauss_seidel = self.constraint_solver == "gauss_seidel"
        colors = greedy_colors(pairs, n) if gauss_seidel else np.zeros(len(pairs), dtype=np.int64)
        order = np.argsort(colors, kind="stable")
        bounds = np.searchsorted(colors[order], np.arange(colors.max() + 2)) if len(pairs) else [0]
        self.color_ranges = [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
        self.distance_count = len(pairs)
        self.lra_count = len(host["lra_particle"])
        # the Jacobi tables as written (replace_constraints appends)
        self._jacobi = self.jacobi_lists(host)
        tables = {name: (values, JACOBI_ROWS[name], 0) for name, values in self._jacobi.items()}
        self._list_rows = {kind: len(self._jacobi[names[0]]) for kind, (_, names) in LISTS.items()}
        if gauss_seidel:  # the same constraints sorted by colour (Jacobi does not read them)
            tables["colored_pair"] = (pairs[order], "distances", 0)
            tables["colored_rest"] = (rest[order], "distances", 0)
            tables["colored_stiffness"] = (stiff[order], "distances", 0)
        return tables

    def jacobi_lists(
        self,
        constraints: dict[str, np.ndarray],
        kinds=tuple(LISTS),
        first: int = 0,
        count: int | None = None,
    ) -> dict[str, np.ndarray]:
        """The :data:`JACOBI_ROWS` tables of the ``kinds`` of lists (:data:`LISTS`) of
        ``constraints`` (:func:`constraint_arrays`) written whole: each particle's
        entries follow the last's. Those of the ``count`` particles from ``first``
        (all by default; ``constraints`` then hold theirs alone), the extents
        counted from their first entry."""
        n, out = self.particle_count - first if count is None else count, {}
        if "distance" in kinds:
            stiff = iteration_stiffness(constraints["stiffness"], self.iterations)
            start, edge, other = both_ends(constraints["pairs"] - first, n)
            out |= {
                "distance_begin": start[:-1].copy(),
                "distance_end": start[1:].copy(),
                "distance_other": other + first,
                "distance_rest": constraints["rest"][edge],
                "distance_stiffness": stiff[edge],
            }
        if "lra" in kinds:
            start, rows = incidence(constraints["lra_particle"] - first, n)
            out |= {
                "lra_begin": start[:-1].copy(),
                "lra_end": start[1:].copy(),
                "lra_anchor": constraints["lra_anchor"][rows],
                "lra_rest": constraints["lra_rest"][rows],
            }
        return out

    def replace_constraints(
        self, first: int, end: int, pairs, rest, stiffness, lra_particle, lra_anchor, lra_rest
    ):
        """Make ``pairs`` (with their ``rest`` lengths [m] and ``stiffness``) the
        distance constraints, and ``lra_particle``/``lra_anchor``/``lra_rest`` the
        long-range attachments, of the particles ``first..end`` (a cut sheet's,
        :mod:`taichi_lap.dissection.sheet_cut`; constraints stay within an organ).
        Only the particles whose lists changed are written: their new lists are
        appended after the rows in use and their extents point there, in one launch.
        A table that is full is written whole, compacted (grown, :meth:`grow`, when
        that is not enough). The Gauss-Seidel solver's tables are written whole,
        their colours found again over all constraints."""
        new = constraint_arrays(pairs, rest, stiffness, lra_particle, lra_anchor, lra_rest)
        self._relisted[(first, end)] = new
        if self.constraint_solver == "gauss_seidel":
            merged = self.constraints()
            self._fit_constraints(
                distances=len(merged["pairs"]),
                distance_ends=2 * len(merged["pairs"]),
                attachments=len(merged["lra_particle"]),
            )
            self._write_whole(self._constraint_tables(*merged.values()))
            return
        lists = self.jacobi_lists(new, first=first, count=end - first)
        writes = RowWrites()
        for kind, (rows_kind, names) in LISTS.items():
            begin = lists[f"{kind}_begin"]
            size = lists[f"{kind}_end"] - begin
            columns = {name: lists[name] for name in names}
            changed = self._changed_lists(kind, first, begin, size, columns)
            if self._list_rows[kind] + int(size[changed].sum()) > self.capacity[rows_kind]:
                self._compact_lists(writes, kind)
            else:
                self._append_lists(writes, kind, first, changed, begin, size, columns)
        writes.flush()
        self._count_lists()

    def _fit_constraints(self, **need: int):
        """Grow the constraint rows of the kinds whose capacity is below ``need``."""
        short = {k: n for k, n in need.items() if n > self.capacity[k]}
        if short:
            self.grow(**{k: max(n, int(1.5 * self.capacity[k])) for k, n in short.items()})

    def _compact_lists(self, writes: RowWrites, kind: str):
        """Write the ``kind`` lists (:data:`LISTS`) whole (host tables and ``writes``,
        flushed first if the rows must grow): each particle's entries after the
        last's, no rows between them."""
        whole = self.jacobi_lists(self.constraints(), (kind,))
        rows_kind, columns = LISTS[kind]
        if len(whole[columns[0]]) > self.capacity[rows_kind]:
            writes.flush()  # into the fields before they are reallocated
            self._fit_constraints(**{rows_kind: len(whole[columns[0]])})
        self._jacobi.update(whole)
        self._list_rows[kind] = len(whole[columns[0]])
        extents = (f"{kind}_begin", f"{kind}_end")
        writes.add(
            np.arange(self.particle_count), {getattr(self, name): whole[name] for name in extents}
        )
        writes.add(
            np.arange(len(whole[columns[0]])),
            {getattr(self, name): whole[name] for name in columns},
        )

    def _count_lists(self):
        """The distance constraints and long-range attachments the lists hold."""
        live = {k: self._jacobi[f"{k}_end"] - self._jacobi[f"{k}_begin"] for k in LISTS}
        self.distance_count = int(live["distance"].sum()) // 2
        self.lra_count = int(live["lra"].sum())

    def constraints(self) -> dict[str, np.ndarray]:
        """The model's distance constraints and long-range attachments now
        (:func:`constraint_arrays`): as built, with the lists of the particle ranges
        :meth:`replace_constraints` replaced."""
        host = self._constraint_host
        if not self._relisted:
            return host
        mine = np.zeros(len(host["pairs"]), dtype=bool)
        attached = np.zeros(len(host["lra_particle"]), dtype=bool)
        for first, end in self._relisted:
            mine |= (host["pairs"][:, 0] >= first) & (host["pairs"][:, 0] < end)
            attached |= (host["lra_particle"] >= first) & (host["lra_particle"] < end)
        return {
            name: np.concatenate(
                [values[~(attached if name.startswith("lra") else mine)]]
                + [new[name] for new in self._relisted.values()]
            )
            for name, values in host.items()
        }

    def _changed_lists(
        self,
        kind: str,
        first: int,
        begin: np.ndarray,
        size: np.ndarray,
        columns: dict[str, np.ndarray],
    ) -> np.ndarray:
        """The particles (from ``first``) whose ``kind`` list (:data:`LISTS`) as
        given (the ``size[i]`` entries of ``columns`` from ``begin[i]``) differs from
        the one written."""
        count = len(begin)
        written = self._jacobi[f"{kind}_begin"][first : first + count]
        alike = np.flatnonzero(
            (self._jacobi[f"{kind}_end"][first : first + count] - written) == size
        )
        old = rows_of_extents(written[alike], size[alike])
        now = rows_of_extents(begin[alike], size[alike])
        owner = np.repeat(np.arange(len(alike)), size[alike])
        differs = np.zeros(len(alike), dtype=bool)
        for name, values in columns.items():
            differs[owner[self._jacobi[name][old] != values[now]]] = True
        changed = np.ones(count, dtype=bool)
        changed[alike[~differs]] = False
        return np.flatnonzero(changed)

    def _append_lists(
        self,
        writes: RowWrites,
        kind: str,
        first: int,
        changed: np.ndarray,
        begin: np.ndarray,
        size: np.ndarray,
        columns: dict[str, np.ndarray],
    ):
        """Append the ``kind`` lists of the particles ``first + changed`` (the
        ``size[i]`` entries of ``columns`` from ``begin[i]``) after the rows in use
        and point their extents there (host tables and ``writes``)."""
        rows = rows_of_extents(begin[changed], size[changed])
        used = self._list_rows[kind]
        sizes = size[changed]
        starts = used + np.cumsum(sizes) - sizes
        particles = first + changed
        self._jacobi[f"{kind}_begin"][particles] = starts
        self._jacobi[f"{kind}_end"][particles] = starts + sizes
        writes.add(
            particles,
            {getattr(self, f"{kind}_begin"): starts, getattr(self, f"{kind}_end"): starts + sizes},
        )
        for name, values in columns.items():
            self._jacobi[name] = placed_rows(self._jacobi[name], used, values[rows])
        self._list_rows[kind] = used + len(rows)
        writes.add(
            np.arange(used, used + len(rows)),
            {getattr(self, name): values[rows] for name, values in columns.items()},
        )

    def _write_whole(self, tables: dict[str, tuple[np.ndarray, str | None, int]]):
        """Write each field of ``tables`` (:meth:`_as_built` entries) whole, its spare
        rows filled (an empty table has one row)."""
        fields.write(
            (getattr(self, name), padded_rows(values, getattr(self, name).shape[0], fill))
            for name, (values, _, fill) in tables.items()
        )

    def reset_topology(self):
        """Put back every field dissection changes as it was built (off the frame's
        path: whole fields are written; rows a :meth:`grow` added stay, spare)."""
        self._write_whole(self._as_built(self.data))
        self._mend_springs()
        self.finalize_counts()
        self.topology_version += 1
        self.as_built = True

    def finalize_counts(self):
        """Write the Python-side counts of clusters and chunks to their fields."""
        self.cluster_count[None] = self.cluster_total
        self.chunk_count[None] = self.chunk_total

    def _init_springs(self, data: ModelData, n: int):
        """Damped springs gathered per particle (seed 001 §3.2); ``broken_springs``
        (host, per row of ``data.spring_pair``) marks those a tear broke."""
        start, edge, other = both_ends(data.spring_pair, n)
        self.spring_count = len(data.spring_pair)
        self._spring_edge = edge  # the spring of each gathered entry
        self.broken_springs = np.zeros(len(data.spring_pair), dtype=bool)
        self.spring_start = self._ints(start)
        self.spring_other = self._ints(other)
        self.spring_rest = self._floats(data.spring_rest[edge])
        self.spring_stiffness = self._floats(data.spring_stiffness[edge])
        self.spring_damping = self._floats(data.spring_damping[edge])

    def break_springs(self, springs: np.ndarray):
        """Springs ``springs`` (rows of ``data.spring_pair``) break (a torn or cut mesentery,
        :mod:`taichi_lap.dissection.spring_sheets`): their stiffness and damping become 0
        at both ends, so they pull no more."""
        springs = np.asarray(springs, dtype=np.int64)
        for entry in np.flatnonzero(np.isin(self._spring_edge, springs)).tolist():
            self.spring_stiffness[entry] = 0.0
            self.spring_damping[entry] = 0.0
        self.broken_springs[springs] = True
        self.topology_version += 1
        self.as_built = False

    def torn_cells(self, organ: int) -> np.ndarray:
        """(rows - 1, cols - 1) bool: the cells of spring-sheet ``organ``'s grid of
        masses that its broken springs lay in or bordered
        (:func:`~taichi_lap.preprocess.sheets.torn_cells`)."""
        record = self.data.organs[organ]
        first, end = record.particles
        pairs = np.asarray(self.data.spring_pair, np.int64).reshape(-1, 2)[self.broken_springs]
        inside = pairs[((pairs >= first) & (pairs < end)).all(axis=1)] - first
        return torn_cells(inside, (end - first) // record.row_length, record.row_length)

    def _mend_springs(self):
        """Every spring as built (:meth:`reset_topology`)."""
        if self.broken_springs.any():
            edge, data = self._spring_edge, self.data
            for field, values in (
                (self.spring_stiffness, data.spring_stiffness),
                (self.spring_damping, data.spring_damping),
            ):
                field.from_numpy(padded_rows(values[edge].astype(np.float32), field.shape[0]))
            self.broken_springs[:] = False

    def _init_tubes(self, data: ModelData):
        """Tubes drawn around a row of masses (row 0 of a spring sheet, seed 001): the
        particles in order with their neighbours along the tube (-1 at its ends)."""
        rows = [np.arange(o.particles[0], o.particles[0] + o.row_length) for o in data.organs]
        particle = np.concatenate([r for r in rows if len(r)] or [np.zeros(0, np.int64)])
        prev = np.concatenate([np.r_[-1, r[:-1]] for r in rows if len(r)] or [particle])
        after = np.concatenate([np.r_[r[1:], -1] for r in rows if len(r)] or [particle])
        self.tube_particle_count = len(particle)
        self.tube_particle = self._ints(particle)
        self.tube_prev = self._ints(prev)
        self.tube_next = self._ints(after)

    def _init_environment_tubes(self, tubes):
        """The segments of the environment's fixed tubes (a colon beneath the loops):
        capsules ``environment_a``-``environment_b`` of ``environment_radius`` [m]."""
        segments = [
            (a, b, radius, friction)
            for line, radius, friction in tubes
            for a, b in zip(line[:-1], line[1:])
        ]
        self.environment_count = len(segments)
        self.environment_a = self._floats(np.reshape([s[0] for s in segments], (-1, 3)), vector=3)
        self.environment_b = self._floats(np.reshape([s[1] for s in segments], (-1, 3)), vector=3)
        self.environment_radius = self._floats([s[2] for s in segments])
        self.environment_friction = self._floats([s[3] for s in segments])

    def _init_planes(self, planes):
        """Environment half-spaces (abdominal wall, table) the tissue rests on."""
        planes = list(planes)
        normal = np.array([p[1] for p in planes], dtype=np.float64).reshape(-1, 3)
        self.plane_count = len(planes)
        self.plane_point = self._floats(np.reshape([p[0] for p in planes], (-1, 3)), vector=3)
        self.plane_normal = self._floats(
            normal / np.linalg.norm(normal, axis=1, keepdims=True), vector=3
        )
        self.plane_friction = self._floats([p[2] for p in planes])
