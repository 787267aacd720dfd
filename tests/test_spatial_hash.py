"""Spatial hash broad phase (kernels/collision/spatial_hash.py): pairs equal brute force, layout is
the Teschner 2003 counting sort, results are deterministic and identical on Vulkan."""

import numpy as np
import pytest
import taichi as ti
from taichi_lap.core.fields import FieldGroup
from taichi_lap.kernels.collision.spatial_hash import SpatialHash, store_pair

from tests.archrun import COMPARE_ARCH, run_on_arch

CELL = 0.01  # [m]


@ti.data_oriented
class PairQuery:
    """The pairs within a radius of a built :class:`SpatialHash`, found through its
    query API as the broad phase scans it (cell spans, bucket ranges, the
    sorted index): the tests' window on the hash."""

    def __init__(self, grid: SpatialHash, capacity: int | None = None):
        self.grid = grid
        self.capacity = capacity or 40 * grid.capacity
        group = FieldGroup()
        self.pairs = group.field(ti.i32, self.capacity, vector=2)
        self.count = group.field(ti.i32, None)
        self.neighbour_count = group.field(ti.i32, grid.capacity)
        group.finalize()

    def find_pairs(self, points, radius: float) -> int:
        """All pairs i < j of the last build with |x_i - x_j| <= radius [m] into ``pairs``;
        returns how many there were (more than ``capacity``: only the first written)."""
        self._find_pairs(points, self.grid.count, radius)
        return int(self.count[None])

    def overflowed(self) -> bool:
        """True when the last ``find_pairs`` found more pairs than ``pair_capacity``."""
        return int(self.count[None]) > self.capacity

    def pairs_numpy(self) -> np.ndarray:
        """Found pairs as an (m, 2) i32 array sorted lexicographically."""
        n = min(int(self.count[None]), self.capacity)
        p = self.pairs.to_numpy()[:n]
        return p[np.lexsort((p[:, 1], p[:, 0]))]

    def count_neighbours(self, points, radius: float) -> None:
        """``neighbour_count[i]`` = number of j != i with |x_i - x_j| <= radius [m]."""
        self._count_neighbours(points, self.grid.count, radius)

    @ti.func
    def _visit(
        self, points: ti.template(), i, radius, upper: ti.template(), write: ti.template(), base
    ):
        """Count neighbours j of point i (only j > i if ``upper``); ``write`` pairs (i, j):
        0 no, 1 from slot ``base`` on, 2 to slots taken by one atomic per pair."""
        x = points[i]
        lo, extent, visits = self.grid.ball_span(x, radius)
        r2, found = radius * radius, 0
        for k in range(visits):
            cell, start, end = self.grid.span_visit(lo, extent, k)
            for s in range(start, end):
                j = self.grid.sorted_index[s]
                near = (points[j] - x).norm_sqr() <= r2 and self.grid.in_visit(
                    cell, extent, points[j]
                )
                if (j > i if ti.static(upper) else j != i) and near:
                    if ti.static(write):
                        store_pair(
                            self.pairs,
                            self.count,
                            self.capacity,
                            write,
                            base,
                            found,
                            i,
                            j,
                        )
                    found += 1
        return found

    @ti.kernel
    def _find_pairs(self, points: ti.template(), count: ti.i32, radius: ti.f32):
        self.count[None] = 0
        for i in range(count):
            if ti.static(self.grid.reserve_per_point):  # count, reserve the slots, write
                found = self._visit(points, i, radius, True, 0, 0)
                self._visit(points, i, radius, True, 1, ti.atomic_add(self.count[None], found))
            else:
                self._visit(points, i, radius, True, 2, 0)

    @ti.kernel
    def _count_neighbours(self, points: ti.template(), count: ti.i32, radius: ti.f32):
        for i in range(count):
            self.neighbour_count[i] = self._visit(points, i, radius, False, 0, 0)


def make_points(x: np.ndarray):
    field = ti.Vector.field(3, ti.f32, len(x))
    field.from_numpy(x.astype(np.float32))
    return field


def random_points(n, seed=0, lo=-0.05, hi=0.05):
    return np.random.default_rng(seed).uniform(lo, hi, (n, 3)).astype(np.float32)


def brute_pairs(x, radius, tie=1e-6):
    """(sure, maybe): pairs i < j with |d| <= r, and those within ``tie`` of r (either way)."""
    d = x[:, None, :] - x[None, :, :]
    d2 = d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + d[..., 2] * d[..., 2]
    r2 = np.float32(radius) * np.float32(radius)
    upper = np.triu(np.ones(d2.shape, bool), 1)
    sure = set(zip(*np.nonzero(upper & (d2 <= r2 * (1 - tie)))))
    maybe = set(zip(*np.nonzero(upper & (d2 <= r2 * (1 + tie)))))
    return sure, maybe


def pair_set(pairs):
    return set(map(tuple, np.asarray(pairs).tolist()))


def assert_pairs(found, x, radius):
    sure, maybe = brute_pairs(x, radius)
    assert sure <= found <= maybe, (len(sure), len(found), len(maybe))


def teschner_bucket(x, cell, table_size):
    c = np.floor(x * np.float32(1.0 / cell)).astype(np.int32).astype(np.uint32)
    h = (
        (c[:, 0] * np.uint32(73856093))
        ^ (c[:, 1] * np.uint32(19349663))
        ^ (c[:, 2] * np.uint32(83492791))
    )
    return (h % np.uint32(table_size)).astype(np.int32)


def compute_pairs(n=2000, seed=0, table_size=1021, cell=CELL, radius=0.008, lo=-0.05, hi=0.05):
    """Build + pairs + neighbour counts on the current backend (also run on Vulkan)."""
    x = random_points(n, seed, lo, hi)
    grid = SpatialHash(n, table_size, cell)
    points = make_points(x)
    grid.build(points, n)
    query = PairQuery(grid)
    total = query.find_pairs(points, radius)
    query.count_neighbours(points, radius)
    return dict(
        points=x,
        pairs=query.pairs_numpy(),
        total=np.int32(total),
        sorted_index=grid.sorted_index.to_numpy(),
        bucket_start=grid.bucket_start.to_numpy(),
        neighbour_count=query.neighbour_count.to_numpy(),
    )


@pytest.mark.parametrize("table_size", [1, 7, 1021, 1 << 16])
def test_pairs_match_brute_force(table_size):
    x = random_points(1500, seed=table_size)
    grid, points = SpatialHash(len(x), table_size, CELL), make_points(x)
    grid.build(points, len(x))
    query = PairQuery(grid)
    for radius in (0.2 * CELL, 0.6 * CELL, CELL, 2.5 * CELL):  # 2.5: 6 cells across, or all
        total = query.find_pairs(points, radius)
        found = pair_set(query.pairs_numpy())
        assert total == len(found) and not query.overflowed()
        assert_pairs(found, x, radius)
        query.count_neighbours(points, radius)
        counts = np.bincount(np.array(sorted(found)).ravel(), minlength=len(x))
        assert np.array_equal(query.neighbour_count.to_numpy(), counts)


def test_layout_is_teschner_counting_sort():
    x, table_size = random_points(3000, seed=1), 509
    grid = SpatialHash(len(x), table_size, CELL)
    grid.build(make_points(x), len(x))
    bucket = teschner_bucket(x, CELL, table_size)
    assert np.array_equal(grid.point_bucket.to_numpy(), bucket)
    start = grid.bucket_start.to_numpy()
    assert np.array_equal(
        start, np.concatenate([[0], np.cumsum(np.bincount(bucket, minlength=table_size))])
    )
    order = grid.sorted_index.to_numpy()
    assert np.array_equal(order, np.argsort(bucket, kind="stable"))  # ascending inside buckets


def test_empty_space_has_no_pairs():
    g = np.arange(6, dtype=np.float32) * 10 * CELL
    x = np.stack(np.meshgrid(g, g, g), -1).reshape(-1, 3)
    grid, points = SpatialHash(len(x), 97, CELL), make_points(x)
    grid.build(points, len(x))
    query = PairQuery(grid)
    assert query.find_pairs(points, CELL) == 0
    query.count_neighbours(points, CELL)
    assert not query.neighbour_count.to_numpy().any()


def test_crowded_cell_gives_all_pairs():
    n = 300
    x = random_points(n, seed=2, lo=0.002, hi=0.007)  # one cell, diameter < CELL
    grid, points = SpatialHash(n, 1 << 12, CELL), make_points(x)
    grid.build(points, n)
    query = PairQuery(grid, capacity=n * n)
    assert query.find_pairs(points, CELL) == n * (n - 1) // 2
    assert pair_set(query.pairs_numpy()) == set(zip(*np.triu_indices(n, 1)))
    assert np.diff(grid.bucket_start.to_numpy()).max() == n


def test_negative_coordinates():
    x = random_points(1500, seed=3, lo=-10.05, hi=-9.95)
    grid, points = SpatialHash(len(x), 1021, CELL), make_points(x)
    grid.build(points, len(x))
    query = PairQuery(grid)
    query.find_pairs(points, 0.7 * CELL)
    assert_pairs(pair_set(query.pairs_numpy()), x, 0.7 * CELL)

    probe = make_points(np.array([[-0.001, 0.0, 0.0099], [-0.0101, -1e-7, 0.0101]]))
    cells = ti.Vector.field(3, ti.i32, 2)

    @ti.kernel
    def cell_of_probe():
        for i in range(2):
            cells[i] = grid.cell_of(probe[i])

    cell_of_probe()
    assert cells.to_numpy().tolist() == [[-1, 0, 0], [-2, -1, 1]]  # floor, not truncation


def test_two_builds_are_identical():
    a, b = compute_pairs(seed=4, table_size=13), compute_pairs(seed=4, table_size=13)
    for key in ("sorted_index", "bucket_start", "pairs", "neighbour_count"):
        assert np.array_equal(a[key], b[key]), key


def test_rebuild_after_moving_points_equals_fresh_build():
    x0, x1 = random_points(2000, seed=5), random_points(2000, seed=6)
    grid, points = SpatialHash(len(x0), 1021, CELL), make_points(x0)
    fields = (grid.sorted_index, grid.bucket_start, grid.point_bucket)
    query = PairQuery(grid)
    grid.build(points, len(x0))
    query.find_pairs(points, CELL)
    points.from_numpy(x1)
    grid.build(points, len(x1))
    query.find_pairs(points, CELL)
    assert fields == (grid.sorted_index, grid.bucket_start, grid.point_bucket)
    fresh = compute_pairs(n=2000, seed=6, radius=CELL)
    assert np.array_equal(grid.sorted_index.to_numpy(), fresh["sorted_index"])
    assert np.array_equal(query.pairs_numpy(), fresh["pairs"])


def test_pair_buffer_overflow_keeps_the_count_and_the_first_pairs():
    """store_pair, as the broad phase uses it: past the capacity pairs are counted, not
    written."""
    n = 100
    x = random_points(n, seed=7, lo=0.002, hi=0.007)
    grid, points = SpatialHash(n, 61, CELL), make_points(x)
    grid.build(points, n)
    query = PairQuery(grid, capacity=50)
    assert query.find_pairs(points, CELL) == n * (n - 1) // 2
    assert query.overflowed()
    kept = query.pairs_numpy()
    assert len(kept) == 50 and all(i < j for i, j in kept.tolist())


def test_a_build_of_more_points_than_the_capacity_is_refused():
    grid, points = SpatialHash(10, 7, CELL), make_points(random_points(20))
    with pytest.raises(ValueError):
        grid.build(points, 20)


@pytest.mark.vulkan
def test_vulkan_matches_cpu():
    kwargs = dict(n=3001, seed=8, table_size=2039, radius=0.9 * CELL)
    gpu, cpu = (
        run_on_arch(COMPARE_ARCH, "tests.test_spatial_hash:compute_pairs", **kwargs),
        compute_pairs(**kwargs),
    )
    for key in ("points", "sorted_index", "bucket_start", "neighbour_count", "pairs", "total"):
        assert np.array_equal(gpu[key], cpu[key]), key
    assert int(cpu["total"]) > 1000
