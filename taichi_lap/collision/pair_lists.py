"""Storage of the broad phase's margin pair lists (seed 000 §4.1 kept between steps,
:mod:`taichi_lap.kernels.collision.broad_phase`)."""

import taichi as ti

from taichi_lap.core.fields import FieldGroup, FieldOwner
from taichi_lap.kernels.collision.broad_phase import ROW_BLOCK


@ti.data_oriented
class PairRows(FieldOwner):
    """Partner lists of ``triangles`` triangles in one array of ``capacity`` entries:
    row t is ``partner[start[t]:start[t + 1]]``, sorted (CSR); ``size``, ``cursor`` and
    ``block_start`` are scratch of the rebuild (:func:`kernels.collision.broad_phase.count_rows`).
    The fields go in ``group`` when given (:meth:`FieldOwner._declare_in`)."""

    def __init__(self, triangles: int, capacity: int, group: FieldGroup | None = None):
        group = self._declare_in(group)
        self.capacity = int(capacity)
        self.start = group.field(ti.i32, triangles + 1)
        self.size = group.field(ti.i32, triangles)
        self.cursor = group.field(ti.i32, triangles)
        self.block_start = group.field(ti.i32, -(-triangles // ROW_BLOCK))
        self.partner = group.field(ti.i32, self.capacity)
        self._finalize()


@ti.data_oriented
class FoundPairs(FieldOwner):
    """Pairs found by one rescan (at most ``capacity``; ``count`` may say more); the
    fields in ``group`` when given (:meth:`FieldOwner._declare_in`)."""

    def __init__(self, capacity: int, group: FieldGroup | None = None):
        group = self._declare_in(group)
        self.capacity = int(capacity)
        self.pair = group.field(ti.i32, self.capacity, vector=2)
        self.count = group.field(ti.i32, None)
        self._finalize()
