"""Row writes of a topology update (kernels/scatter.py): every group's rows land in
their fields in one launch, adds to the same fields join one group whatever their row
counts (one compiled kernel), 2-D tables take whole rows, gather reads rows back."""

import numpy as np
import pytest
import taichi as ti

from taichi_lap import runtime
from taichi_lap.core.fields import FieldGroup
from taichi_lap.kernels.scatter import RowWrites, gather, scatter
from tests.archrun import assert_backend_matches_cpu

N = 32


def fields():
    group = FieldGroup()
    made = {
        "mass": group.field(ti.f32, N),
        "center": group.field(ti.f32, N, vector=3),
        "member": group.field(ti.i32, N),
        "index": group.field(ti.i32, N, vector=4),
        "table": group.field(ti.i32, N, columns=6),
    }
    group.finalize()
    return made


def write_update(f, removed, changed, vertices):
    """What an update writes: three groups of rows, one added in two parts."""
    writes = RowWrites()
    writes.add(removed, {f["mass"]: np.zeros(len(removed))})
    writes.add(changed[:1], {f["center"]: changed[:1, None] * [1.0, 2.0, 3.0]})
    writes.add(changed[1:], {f["center"]: changed[1:, None] * [1.0, 2.0, 3.0]})
    writes.add(
        vertices,
        {f["member"]: vertices + 100, f["index"]: vertices[:, None] + np.arange(4)},
    )
    writes.flush()


def written_rows() -> dict:
    """Writes through each entry point (run on any backend)."""
    f = fields()
    f["mass"].fill(1.0)
    write_update(f, np.array([3, 5]), np.array([7, 9, 11]), np.array([2, 4]))
    writes = RowWrites()
    writes.add([0], {f["mass"]: [0.5], f["center"]: [[4.0, 5.0, 6.0]]})
    writes.flush()
    scatter(f["table"], [1, 30], [[1, 2, 3, 4, 5, 6], [-1, -1, 7, -1, -1, -1]])
    out = {name: field.to_numpy() for name, field in f.items()}
    out["gathered"] = gather(f["member"], np.array([4, 2, 0]))
    return out


def test_every_group_lands_in_its_rows():
    out = written_rows()
    mass = np.ones(N)
    mass[[3, 5]] = 0.0
    mass[0] = 0.5
    assert np.array_equal(out["mass"], mass)
    center = np.zeros((N, 3))
    center[[7, 9, 11]] = np.array([7, 9, 11])[:, None] * [1.0, 2.0, 3.0]
    center[0] = [4.0, 5.0, 6.0]
    assert np.array_equal(out["center"], center)
    assert out["member"][[2, 4]].tolist() == [102, 104] and out["member"].sum() == 206
    assert out["index"][4].tolist() == [4, 5, 6, 7] and out["index"][[0, 1, 3]].sum() == 0
    assert out["table"][1].tolist() == [1, 2, 3, 4, 5, 6]
    assert out["table"][30].tolist() == [-1, -1, 7, -1, -1, -1]
    assert out["gathered"].tolist() == [104, 102, 0]


def test_one_caller_compiles_once_whatever_its_row_counts():
    f = fields()
    write_update(f, np.array([1]), np.array([2, 3]), np.array([4]))
    compiled = runtime.kernel_compilations()
    write_update(f, np.array([], dtype=int), np.array([6]), np.array([8, 9, 10]))
    write_update(f, np.array([12, 13, 14]), np.array([15, 16, 17, 18]), np.array([], dtype=int))
    assert runtime.kernel_compilations() == compiled
    assert f["mass"].to_numpy()[[12, 13, 14]].sum() == 0.0
    assert f["member"].to_numpy()[[8, 9, 10]].tolist() == [108, 109, 110]


def test_a_row_written_twice_in_one_launch_is_refused_and_two_flushes_keep_the_last():
    """A GPU writes a launch's rows in parallel, so of two values for one row either
    could stay: the flush refuses them, also when the two writes are in different
    groups; written in two flushes, the later one stays."""
    f = fields()
    writes = RowWrites()
    writes.add([3, 5], {f["mass"]: [1.0, 2.0]})
    writes.add([5], {f["mass"]: [3.0]})
    with pytest.raises(RuntimeError, match=r"rows \[5\] of a field are written twice"):
        writes.flush()
    writes.add([6], {f["mass"]: [1.0], f["member"]: [7]})
    writes.add([6], {f["mass"]: [2.0]})
    with pytest.raises(RuntimeError, match=r"rows \[6\]"):
        writes.flush()
    writes.add([6], {f["mass"]: [1.0], f["member"]: [7]})
    writes.flush()
    writes.add([6], {f["mass"]: [2.0]})
    writes.flush()
    assert f["mass"].to_numpy()[6] == 2.0 and f["member"].to_numpy()[6] == 7


@pytest.mark.vulkan
def test_vulkan_writes_the_rows_of_the_cpu():
    assert_backend_matches_cpu("tests.test_scatter:written_rows", 0.0)
