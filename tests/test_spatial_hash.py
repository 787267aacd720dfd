"""Spatial hash broad phase (kernels/spatial_hash.py): pairs equal brute force, layout is
the Teschner 2003 counting sort, results are deterministic and identical on Vulkan."""

import numpy as np
import pytest
import taichi as ti
from taichi_lap.kernels.collision.spatial_hash import SpatialHash

from tests.archrun import run_on_arch

CELL = 0.01  # [m]


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
    total = grid.find_pairs(points, radius)
    grid.count_neighbours(points, radius)
    return dict(
        points=x,
        pairs=grid.pairs_numpy(),
        total=np.int32(total),
        sorted_index=grid.sorted_index.to_numpy(),
        bucket_start=grid.bucket_start.to_numpy(),
        neighbour_count=grid.neighbour_count.to_numpy(),
    )


@pytest.mark.parametrize("table_size", [1, 7, 1021, 1 << 16])
def test_pairs_match_brute_force(table_size):
    x = random_points(1500, seed=table_size)
    grid, points = SpatialHash(len(x), table_size, CELL), make_points(x)
    grid.build(points, len(x))
    for radius in (0.2 * CELL, 0.6 * CELL, CELL):
        total = grid.find_pairs(points, radius)
        found = pair_set(grid.pairs_numpy())
        assert total == len(found) and not grid.overflowed()
        assert_pairs(found, x, radius)
        grid.count_neighbours(points, radius)
        counts = np.bincount(np.array(sorted(found)).ravel(), minlength=len(x))
        assert np.array_equal(grid.neighbour_count.to_numpy(), counts)


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
    assert grid.find_pairs(points, CELL) == 0
    grid.count_neighbours(points, CELL)
    assert not grid.neighbour_count.to_numpy().any()


def test_crowded_cell_gives_all_pairs():
    n = 300
    x = random_points(n, seed=2, lo=0.002, hi=0.007)  # one cell, diameter < CELL
    grid, points = SpatialHash(n, 1 << 12, CELL, pair_capacity=n * n), make_points(x)
    grid.build(points, n)
    assert grid.find_pairs(points, CELL) == n * (n - 1) // 2
    assert pair_set(grid.pairs_numpy()) == set(zip(*np.triu_indices(n, 1)))
    assert np.diff(grid.bucket_start.to_numpy()).max() == n


def test_negative_coordinates():
    x = random_points(1500, seed=3, lo=-10.05, hi=-9.95)
    grid, points = SpatialHash(len(x), 1021, CELL), make_points(x)
    grid.build(points, len(x))
    grid.find_pairs(points, 0.7 * CELL)
    assert_pairs(pair_set(grid.pairs_numpy()), x, 0.7 * CELL)

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
    grid.build(points, len(x0))
    grid.find_pairs(points, CELL)
    points.from_numpy(x1)
    grid.build(points, len(x1))
    grid.find_pairs(points, CELL)
    assert fields == (grid.sorted_index, grid.bucket_start, grid.point_bucket)
    fresh = compute_pairs(n=2000, seed=6, radius=CELL)
    assert np.array_equal(grid.sorted_index.to_numpy(), fresh["sorted_index"])
    assert np.array_equal(grid.pairs_numpy(), fresh["pairs"])


def test_pair_buffer_overflow_is_reported():
    n = 100
    x = random_points(n, seed=7, lo=0.002, hi=0.007)
    grid, points = SpatialHash(n, 61, CELL, pair_capacity=50), make_points(x)
    grid.build(points, n)
    assert grid.find_pairs(points, CELL) == n * (n - 1) // 2
    assert grid.overflowed()
    kept = grid.pairs_numpy()
    assert len(kept) == 50 and all(i < j for i, j in kept.tolist())


def test_bad_arguments_are_refused():
    grid, points = SpatialHash(10, 7, CELL), make_points(random_points(20))
    with pytest.raises(ValueError):
        grid.build(points, 20)
    grid.build(points, 10)
    with pytest.raises(ValueError):
        grid.find_pairs(points, 1.5 * CELL)


@pytest.mark.vulkan
def test_vulkan_matches_cpu():
    kwargs = dict(n=3001, seed=8, table_size=2039, radius=0.9 * CELL)
    gpu, cpu = (
        run_on_arch("vulkan", "tests.test_spatial_hash:compute_pairs", **kwargs),
        compute_pairs(**kwargs),
    )
    for key in ("points", "sorted_index", "bucket_start", "neighbour_count", "pairs", "total"):
        assert np.array_equal(gpu[key], cpu[key]), key
    assert int(cpu["total"]) > 1000
