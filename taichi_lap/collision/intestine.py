"""Self-collisions of the intestine and mesentery (seed 001 §4): element tables
built from a :class:`Model`, the stochastic detector and displacement-velocity
response of :mod:`taichi_lap.kernels.collision.intestine` (the exact O(n²) detector
they are validated against is :mod:`.intestine_reference`).

Call once per substep, after the constraints and before the velocity update
(``update_goals``), on the predicted positions ``state.p``::

    collision = IntestineCollision(model, threshold=0.02, passes=8, seed=scene_seed)
    collision.step(state, h)          # = collision.detect(state); collision.respond(state, h)

and :meth:`IntestineCollision.reset` when the state is reset.
"""

from __future__ import annotations

import numpy as np
import taichi as ti

from taichi_lap.core.fields import FieldGroup, FieldOwner
from taichi_lap.core.geometry import arc_length
from taichi_lap.core.mesh import edge_neighbours
from taichi_lap.kernels.collision import intestine as kernels


def _strided(keys: np.ndarray, stride: int) -> np.ndarray:
    """Index of the element whose key (group, column) is (group, column -/+ stride),
    or -1: the far neighbours (E, 2)."""
    lookup = {tuple(k): i for i, k in enumerate(keys.tolist())}
    out = np.full((len(keys), 2), -1, dtype=np.int64)
    if stride > 1:
        for i, (group, column) in enumerate(keys.tolist()):
            out[i] = [
                lookup.get((group, column - stride), -1),
                lookup.get((group, column + stride), -1),
            ]
    return out


def _organ_elements(data, local: np.ndarray, organ: int, record) -> dict:
    """Segments and triangles of one organ with spring rows, indices local to it."""
    first, length = record.particles[0], record.row_length
    row = np.arange(first, first + length)
    s = arc_length(data.rest_position[row])
    radius = 0.5 * (data.radius[row[:-1]] + data.radius[row[1:]])
    stride = max(1, int(round(float(radius.mean()) / (s[-1] / (length - 1)))))
    k = np.arange(length - 1)
    adjacent = np.stack(
        [np.where(k > 0, k - 1, -1), np.where(k < length - 2, k + 1, -1), np.full(length - 1, -1)],
        1,
    )
    far = _strided(np.stack([0 * k, k], 1), stride)
    segments = dict(
        vertex=np.stack([local[row[:-1]], local[row[1:]], np.full(length - 1, -1)], 1),
        neighbour=np.concatenate([adjacent, far], 1),
        radius=radius,
        arc=np.stack([s[:-1], s[1:]], 1),
        organ=np.full(length - 1, organ),
    )
    corners = data.surface_index[data.surface_triangles[slice(*record.triangles)], 0]
    row_of, column = (corners - first) // length, (corners - first) % length
    apex_below = (row_of == row_of.min(axis=1, keepdims=True)).sum(axis=1) == 2
    group = np.stack([row_of.min(axis=1) * 2 + apex_below, column.min(axis=1)], 1)
    far = _strided(group, stride)
    triangles = dict(
        vertex=local[corners],
        neighbour=np.concatenate([edge_neighbours(corners), far], 1),
        radius=data.radius[corners].min(axis=1),
        arc=np.stack([s[column.min(axis=1)], s[column.max(axis=1)]], 1),
        organ=np.full(len(corners), organ),
    )
    cell = row_of.min(axis=1) * (length - 1) + column.min(axis=1)  # the grid cell it lies in
    return dict(stride=stride, segments=segments, triangles=triangles, cell=cell)


def collision_elements(model) -> dict[str, np.ndarray]:
    """Segments then triangles of every organ with spring rows (``row_length > 0``),
    in local particle numbering: vertex (E, 3) (-1 third vertex for segments);
    neighbour (E, 5): the adjacent elements (a segment's two, a triangle's three
    across its edges, -1 padded) then the far neighbours ``stride`` columns along
    the intestine either way (stride = intestine radius / segment length, rounded;
    none when it is 1); radius (E,) [m]; arc (E, 2) [m] (rest arc-length interval
    along the organ's intestine); organ (E,); ``particles`` (local -> global); ``cells``:
    per organ, the grid cell (row-major) each of its triangles lies in."""
    data = model.data
    records = [r for r in data.organs if r.row_length > 0]
    particles = (
        np.concatenate([np.arange(*r.particles) for r in records])
        if records
        else np.zeros(0, dtype=np.int64)
    )
    local = np.full(data.particle_count, -1, dtype=np.int64)
    local[particles] = np.arange(len(particles))
    tables = [_organ_elements(data, local, organ, r) for organ, r in enumerate(records)]
    parts: dict[str, list] = {k: [] for k in ("vertex", "neighbour", "radius", "arc", "organ")}
    base = 0
    for kind in ("segments", "triangles"):  # all segments first, then all triangles
        for table in tables:
            t = table[kind]
            parts["neighbour"].append(np.where(t["neighbour"] >= 0, t["neighbour"] + base, -1))
            for key in ("vertex", "radius", "arc", "organ"):
                parts[key].append(t[key])
            base += len(t["radius"])
    out = {k: np.concatenate(v) for k, v in parts.items()} if tables else {}
    out["cells"] = [table["cell"] for table in tables]
    out["particles"] = particles
    out["segment_count"] = sum(len(t["segments"]["radius"]) for t in tables)
    out["stride"] = max((t["stride"] for t in tables), default=1)
    return out


@ti.data_oriented
class IntestineCollision(FieldOwner):
    """Stochastic self-collision detection (seed 001 §4.1) and response (§4.2) of
    every organ with spring rows in ``model``.

    ``threshold`` [m]: active pairs are kept while their gap d - r1 - r2 is below it;
    ``random_pairs`` (default half the number of segments, at least 64): new pairs
    drawn per :meth:`detect` (even: uniform, odd: near an active pair; may be
    lowered later, not raised); ``passes``: response sweeps per
    :meth:`respond`; ``seed``: the
    scene seed (draws are a hash of seed, detection counter and draw number);
    ``capacity`` (default 8 per segment, at least 1024): active pairs kept,
    ``contact_capacity`` (default 4 x capacity):
    contacts kept (the rest, last in (a, b) order, are dropped and counted in
    :attr:`dropped`); ``contact_rings``: rings the contact areas grow per detection;
    ``climb_steps``: local-minimum updates per detection at most (the paper makes
    one per time step; the update stops early at a minimum); ``skin`` [m]: gap
    under which a pair counts as in contact (listed and answered). ``threshold``,
    ``random_pairs``, ``passes``, ``climb_steps``, ``skin`` and ``seed`` are read at
    every call and may be changed between steps.

    After :meth:`detect`: :attr:`active_pair_count`, :attr:`colliding_pair_count`
    (active pairs that collide: local minima with gap < 0), :attr:`contact_total`
    (pairs of the contact areas), :meth:`active_pairs`, :meth:`contacts`,
    :meth:`colliding_pairs` (NumPy copies).
    """

    def __init__(
        self,
        model,
        *,
        threshold: float = 0.02,
        random_pairs: int | None = None,
        passes: int = 8,
        seed: int = 0,
        capacity: int | None = None,
        contact_capacity: int | None = None,
        contact_rings: int = 1,
        climb_steps: int = 8,
        skin: float = 0.001,
    ):
        elements = collision_elements(model)
        if elements["segment_count"] < 1:
            raise ValueError("the model has no organ with spring rows (row_length > 0)")
        self.model = model
        self.segment_count = int(elements["segment_count"])
        self.element_count = len(elements["radius"])
        self.particle_count = len(elements["particles"])
        self.threshold, self.skin = float(threshold), float(skin)
        self.random_pairs = self.draw_capacity = int(
            random_pairs if random_pairs is not None else max(64, self.segment_count // 2)
        )
        self.passes, self.seed = int(passes), int(seed)
        self.capacity = int(capacity or max(1024, 8 * self.segment_count))
        self.contact_capacity = int(contact_capacity or 4 * self.capacity)
        self.contact_rings, self.climb_steps = int(contact_rings), int(climb_steps)
        self.explore = 2 * int(elements["stride"]) + 1  # reach of the draws near active pairs
        self.step_count = 0

        group = FieldGroup()
        i32, f32 = ti.i32, ti.f32
        self.element_vertex = group.field(
            i32, self.element_count, vector=3, values=elements["vertex"]
        )
        self.element_neighbour = group.field(
            i32, self.element_count, vector=5, values=elements["neighbour"]
        )
        self.element_radius = group.field(f32, self.element_count, values=elements["radius"])
        self.element_arc = group.field(f32, self.element_count, vector=2, values=elements["arc"])
        self.element_organ = group.field(i32, self.element_count, values=elements["organ"])
        self.element_live = group.field(i32, self.element_count)  # 0: in a torn cell
        self._cells = elements["cells"]
        self.particle_global = group.field(i32, self.particle_count, values=elements["particles"])
        # pair lists (a, b, gap, count): active pairs, their candidates, contact
        # candidates, contacts
        candidates = self.capacity + self.draw_capacity
        areas = kernels.GROWTH * self.contact_capacity + self.capacity
        for name, n in (
            ("pair", self.capacity),
            ("candidate", candidates),
            ("area", areas),
            ("contact", self.contact_capacity),
        ):
            setattr(self, f"{name}_a", group.field(i32, n))
            setattr(self, f"{name}_b", group.field(i32, n))
            setattr(self, f"{name}_gap", group.field(f32, n))
            setattr(self, f"{name}_count", group.field(i32, None))
        self.pair_start = group.field(i32, self.segment_count + 1)
        self.contact_start = group.field(i32, self.segment_count + 1)
        self.contact_impulse = group.field(f32, self.contact_capacity, vector=2)  # f, g
        self.pair_dropped = group.field(i32, None)
        self.contact_dropped = group.field(i32, None)
        self.region_count = group.field(i32, None)
        for name in ("bucket_count", "bucket_fill", "bucket_unique"):  # the counting sort
            setattr(self, name, group.field(i32, self.segment_count))
        self.bucket_start = group.field(i32, self.segment_count + 1)
        self.sorted_source = group.field(i32, max(candidates, areas))
        group.finalize()
        self._group = group
        self.follow_tears()

    def follow_tears(self):
        """The mesentery's triangles in the cells its broken springs lay in or bordered
        (:meth:`~taichi_lap.sim.model.Model.torn_cells`, a torn or cut mesentery:
        :mod:`~taichi_lap.dissection.spring_sheets`) collide no more; all do again once
        the model's springs are mended."""
        live = [np.ones(self.segment_count, np.int32)]
        organs = [k for k, r in enumerate(self.model.data.organs) if r.row_length > 0]
        for organ, cells in zip(organs, self._cells):
            live.append(~self.model.torn_cells(organ).ravel()[cells])
        self.element_live.from_numpy(np.concatenate(live).astype(np.int32))

    @property
    def serial(self) -> bool:
        """Whether its kernels loop serially (their loop_config): as its model's
        (:attr:`~taichi_lap.sim.model.Model.serial`)."""
        return self.model.serial

    def reset(self):
        """Forget the active pairs and contacts; restart the random sequence; the torn
        cells as the model's springs are now (:meth:`follow_tears`)."""
        self.pair_count[None] = 0
        self.contact_count[None] = 0
        self.step_count = 0
        self.follow_tears()

    def detect(self, state):
        """§4.1 at the predicted positions ``state.p`` [m]: update and merge the
        active pairs, add random ones, update the contact areas."""
        if not 0 <= self.random_pairs <= self.draw_capacity:
            raise ValueError(f"random_pairs must be in [0, {self.draw_capacity}]")
        kernels.track_pairs(
            self,
            state.p,
            self.seed & 0xFFFFFFFF,
            self.step_count & 0xFFFFFFFF,
            self.random_pairs,
            self.threshold,
            self.climb_steps,
        )
        self.step_count += 1
        kernels.compact(
            self,
            self.candidate_a,
            self.candidate_b,
            self.candidate_gap,
            self.candidate_count,
            self.pair_a,
            self.pair_b,
            self.pair_gap,
            self.pair_count,
            self.pair_start,
            self.pair_dropped,
            self.capacity,
        )
        for ring in range(self.contact_rings):
            kernels.grow_contacts(self, state.p, int(ring == 0), self.skin)
            kernels.compact(
                self,
                self.area_a,
                self.area_b,
                self.area_gap,
                self.area_count,
                self.contact_a,
                self.contact_b,
                self.contact_gap,
                self.contact_count,
                self.contact_start,
                self.contact_dropped,
                self.contact_capacity,
            )

    def respond(self, state, h: float):
        """§4.2, Eq. 2-9: ``passes`` passes over the contacts of the last
        :meth:`detect`; writes ``state.p`` and ``state.x`` (``h`` [s] the substep)."""
        kernels.respond(self, self.model, state, h, self.passes)

    def step(self, state, h: float):
        """Detect, then respond."""
        self.detect(state)
        self.respond(state, h)

    @property
    def active_pair_count(self) -> int:
        return int(self.pair_count[None])

    @property
    def colliding_pair_count(self) -> int:
        return int(self.region_count[None])

    @property
    def contact_total(self) -> int:
        return int(self.contact_count[None])

    @property
    def dropped(self) -> int:
        """Pairs and contacts dropped for capacity at the last detection."""
        return int(self.pair_dropped[None]) + int(self.contact_dropped[None])

    def active_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """Active pairs (n, 2) in (a, b) order and their gaps [m]."""
        n = self.active_pair_count
        pairs = np.stack([self.pair_a.to_numpy()[:n], self.pair_b.to_numpy()[:n]], axis=1)
        return pairs, self.pair_gap.to_numpy()[:n]

    def contacts(self) -> tuple[np.ndarray, np.ndarray]:
        """Element pairs (n, 2) of the contact areas (gap < skin), in (a, b) order,
        and their gaps [m] at the last detection."""
        n = self.contact_total
        pairs = np.stack([self.contact_a.to_numpy()[:n], self.contact_b.to_numpy()[:n]], axis=1)
        return pairs, self.contact_gap.to_numpy()[:n]

    def colliding_pairs(self) -> np.ndarray:
        """Colliding element pairs (gap < 0) of the contact areas, in (a, b) order."""
        pairs, gaps = self.contacts()
        return pairs[gaps < 0.0]
