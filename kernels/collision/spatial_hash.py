"""Spatial hash broad phase, rebuilt every step by a counting sort (seed 000 §4.1).

Seed 000 §4.1 localises potentially colliding pairs with a spatial hash before its
bounding-sphere and circumsphere narrow phases. Points [m] are binned into cubic
cells of edge ``cell_size`` [m]; cell (i, j, k) = floor(x / cell_size) goes to
bucket ``(i*73856093 ^ j*19349663 ^ k*83492791) mod table_size`` (Teschner et al.
2003, "Optimized Spatial Hashing for Collision Detection of Deformable Objects"),
evaluated in u32 so CPU and Vulkan agree bit for bit.

``build(points, count)`` reads ``points[0:count]`` and writes, in one kernel launch:
``point_bucket[p]`` (bucket of point p), ``bucket_start[b]`` (exclusive prefix sum of
bucket sizes, ``table_size + 1`` entries) and ``sorted_index`` (point indices grouped
by bucket, ascending inside each bucket, so the result does not depend on the order
the atomics ran in). Buckets hold several cells (hash collisions): callers check
candidates by distance. Fields are allocated once; only f32/i32/u32, no float atomics.

Query from another kernel, a ball of any radius: visit the cells it may touch (or
every bucket, when they would be more), and in each cell's bucket only the points of
that cell (two cells of the span may share a bucket)::

    grid = SpatialHash(capacity=n, table_size=1 << 16, cell_size=0.004)

    @ti.kernel
    def touch(x: ti.template(), n: ti.i32, r: ti.f32):
        for i in range(n):
            lo, extent, visits = grid.ball_span(x[i], r)
            for k in range(visits):
                cell, start, end = grid.span_visit(lo, extent, k)
                for s in range(start, end):
                    j = grid.sorted_index[s]
                    if j != i and grid.in_visit(cell, extent, x[j]):
                        if (x[i] - x[j]).norm_sqr() <= r * r:
                            ...  # neighbour pair (i, j)

On Vulkan (seen with Mesa lavapipe 22.3) an atomic inside such candidate loops, even
one never executed, corrupts results: count first, then reserve slots per point.
"""

import math

import numpy as np
import taichi as ti

from taichi_lap.core.fields import FieldGroup, FieldOwner

_PRIMES = (73856093, 19349663, 83492791)


@ti.func
def store_pair(
    pairs: ti.template(),
    count: ti.template(),
    capacity: ti.template(),
    write: ti.template(),
    base,
    found,
    i,
    j,
):
    """Pair (i, j), the ``found``-th of its point: ``write`` 1 into slot base + found
    (reserved beforehand), 2 into a slot taken by one atomic on ``count[None]``;
    dropped past ``capacity`` (the count still says how many there were)."""
    slot = base + found
    if ti.static(write == 2):
        slot = ti.atomic_add(count[None], 1)
    if slot < capacity:
        pairs[slot] = ti.Vector([i, j])


@ti.func
def exclusive_scan(
    count: ti.template(), start: ti.template(), n, block_start: ti.template(), block: ti.template()
):
    """start[i] = count[0] + ... + count[i - 1] for i = 0..n (start[n] the total): block
    totals in parallel, a short serial scan over them, offsets inside the blocks in
    parallel. ``block_start`` holds ceil(n / block) entries. Call it at a kernel's top
    level: its loops are then the kernel's parallel loops."""
    n_blocks = (n + block - 1) // block
    for blk in range(n_blocks):
        total = 0
        for b in range(blk * block, ti.min(blk * block + block, n)):
            total += count[b]
        block_start[blk] = total
    ti.loop_config(serialize=True)  # one thread, without the CPU's thread-pool launch
    for _ in range(1):
        running = 0
        for blk in range(n_blocks):
            total = block_start[blk]
            block_start[blk] = running
            running += total
        start[n] = running
    for blk in range(n_blocks):
        running = block_start[blk]
        for b in range(blk * block, ti.min(blk * block + block, n)):
            start[b] = running
            running += count[b]


@ti.data_oriented
class SpatialHash(FieldOwner):
    """Counting-sort spatial hash over at most ``capacity`` points.

    ``table_size`` buckets, cells of ``cell_size`` [m]; kernels query it with
    :meth:`ball_span`, :meth:`span_visit` and :meth:`in_visit` (module docstring). The
    fields go in ``group`` when given (:meth:`FieldOwner._declare_in`).
    """

    def __init__(
        self, capacity: int, table_size: int, cell_size: float, group: FieldGroup | None = None
    ):
        if capacity < 1 or table_size < 1 or not cell_size > 0:
            raise ValueError("capacity and table_size must be >= 1, cell_size > 0")
        self.capacity, self.table_size, self.cell_size = capacity, table_size, float(cell_size)
        self.inv_cell = float(np.float32(1.0 / cell_size))  # x * inv_cell: exact on every backend
        self.block = max(64, math.isqrt(table_size - 1) + 1)  # prefix-sum block of buckets
        self.n_blocks = (table_size + self.block - 1) // self.block
        group = self._declare_in(group)
        self.point_bucket = group.field(ti.i32, capacity)
        self.sorted_index = group.field(ti.i32, capacity)
        self.bucket_count = group.field(ti.i32, table_size)  # counts, then scatter cursors
        self.bucket_start = group.field(ti.i32, table_size + 1)
        self.block_start = group.field(ti.i32, self.n_blocks)
        self._finalize()
        self.count = 0  # points in the last build
        # Vulkan: no atomic inside the candidate loops (see the module docstring).
        self.reserve_per_point = ti.lang.impl.current_cfg().arch == ti.vulkan

    # ---- ti.func query helpers -------------------------------------------------
    @ti.func
    def cell_of(self, x):
        """Integer cell (ivec3) of position ``x`` [m]: floor(x * f32(1 / cell_size))."""
        return ti.cast(ti.floor(x * self.inv_cell), ti.i32)

    @ti.func
    def bucket_of_cell(self, cell):
        """Teschner 2003 hash of an integer cell, in [0, table_size)."""
        c = ti.cast(cell, ti.u32)
        h = (c[0] * ti.u32(_PRIMES[0])) ^ (c[1] * ti.u32(_PRIMES[1])) ^ (c[2] * ti.u32(_PRIMES[2]))
        return ti.cast(h % ti.u32(self.table_size), ti.i32)

    @ti.func
    def bucket_range(self, bucket):
        """(start, end) of ``bucket``'s slice of ``sorted_index``."""
        return self.bucket_start[bucket], self.bucket_start[bucket + 1]

    @ti.func
    def ball_span(self, x, radius):
        """What to visit for the points within ``radius`` [m] of ``x``, any radius:
        (lo, extent, n), visits 0 to n - 1 of :meth:`span_visit`. The box of cells the
        ball may touch (lowest cell ``lo`` and ``extent``, ivec3s), or every bucket
        (extent 0) when that box would have more cells than the table has buckets or
        the radius is not finite."""
        y = x * self.inv_cell
        reach = radius * self.inv_cell + 1e-3  # margin covers f32 rounding up to ~1e4 cells
        side = 2.0 * reach + 2.0  # at least the box's cells along each axis
        lo, extent, n = ti.Vector([0, 0, 0]), ti.Vector([0, 0, 0]), self.table_size
        if side * side * side <= self.table_size:  # false for NaN
            lo = ti.cast(ti.floor(y - reach), ti.i32)
            extent = ti.cast(ti.floor(y + reach), ti.i32) - lo + 1
            n = extent[0] * extent[1] * extent[2]
        return lo, extent, n

    @ti.func
    def span_visit(self, lo, extent, k):
        """Visit ``k`` of :meth:`ball_span`: (cell, start, end), the cell (ivec3, x
        fastest) and the slice of ``sorted_index`` to read; only its points that
        :meth:`in_visit` accepts belong to the visit (other cells may share the bucket)."""
        cell, bucket = lo, k
        if extent[0] > 0:
            cell = lo + ti.Vector(
                [k % extent[0], k // extent[0] % extent[1], k // (extent[0] * extent[1])]
            )
            bucket = self.bucket_of_cell(cell)
        start, end = self.bucket_range(bucket)
        return cell, start, end

    @ti.func
    def in_visit(self, cell, extent, x):
        """A point at ``x`` [m] read in the visit of ``cell`` belongs to it (each point
        is visited once)."""
        return extent[0] == 0 or (self.cell_of(x) == cell).all()

    # ---- build -----------------------------------------------------------------
    def build(self, points, count: int | None = None):
        """Rebuild from ``points[0:count]`` (a 3-vector f32 field [m], or a 4-vector one
        whose first three components are the point); one kernel launch."""
        count = self.capacity if count is None else int(count)
        if not 0 <= count <= self.capacity or count > points.shape[0]:
            raise ValueError(f"count {count} exceeds capacity {self.capacity} or points")
        self.count = count
        self._build(points, count)

    @ti.kernel
    def _build(self, points: ti.template(), count: ti.i32):
        T, B = ti.static(self.table_size, self.block)
        for b in range(T):
            self.bucket_count[b] = 0
        for p in range(count):  # bucket of each point, counted with i32 atomics
            b = self.bucket_of_cell(self.cell_of(points[p]))
            self.point_bucket[p] = b
            ti.atomic_add(self.bucket_count[b], 1)
        exclusive_scan(self.bucket_count, self.bucket_start, T, self.block_start, B)
        for b in range(T):  # counts -> cursors
            self.bucket_count[b] = 0
        for p in range(count):  # scatter
            b = self.point_bucket[p]
            self.sorted_index[self.bucket_start[b] + ti.atomic_add(self.bucket_count[b], 1)] = p
        for b in range(T):  # shell sort each bucket by point index (deterministic)
            lo, hi = self.bucket_start[b], self.bucket_start[b + 1]
            gap = 1
            while gap < (hi - lo) // 3:
                gap = 3 * gap + 1
            while gap >= 1:
                for a in range(lo + gap, hi):
                    v, c = self.sorted_index[a], a
                    while c - gap >= lo:
                        if self.sorted_index[c - gap] <= v:
                            break
                        self.sorted_index[c] = self.sorted_index[c - gap]
                        c -= gap
                    self.sorted_index[c] = v
                gap //= 3
