"""Field groups and the bulk copies between host arrays and fields (core.fields)."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import taichi as ti

from taichi_lap import runtime
from taichi_lap.core import fields
from taichi_lap.core.fields import FieldGroup
from taichi_lap.runtime import kernel_compilations
from tests.archrun import assert_backend_matches_cpu


def group_of_every_kind():
    """One field of each kind a group declares, filled with distinct values."""
    rng = np.random.default_rng(3)
    values = {
        "scalar": rng.random(6),
        "vector": rng.random((4, 3)),  # padded to 5 rows
        "matrix": rng.random((3, 3, 3)),
        "integers": rng.integers(-50, 50, 7),
        "table": rng.integers(0, 9, (4, 5)),
        "wide": rng.integers(0, 2**40, 3),  # i64: not batched
    }
    group = FieldGroup()
    made = {
        "scalar": group.field(ti.f32, 6, values=values["scalar"]),
        "vector": group.field(ti.f32, 5, vector=3, values=values["vector"]),
        "matrix": group.field(ti.f32, 3, matrix=(3, 3), values=values["matrix"]),
        "integers": group.field(ti.i32, 7, values=values["integers"]),
        "table": group.field(ti.i32, 4, columns=5, values=values["table"]),
        "wide": group.field(ti.i64, 3, values=values["wide"]),
        "single": group.field(ti.f32, None),
    }
    group.finalize()
    return group, made, values


def test_a_group_uploads_every_kind_of_field_and_read_returns_what_to_numpy_does():
    group, made, values = group_of_every_kind()
    try:
        np.testing.assert_array_equal(made["vector"].to_numpy()[:4], values["vector"].astype("f4"))
        assert not made["vector"].to_numpy()[4].any()  # the padding row
        for name in ("scalar", "matrix", "integers", "table", "wide"):
            np.testing.assert_array_equal(
                made[name].to_numpy(), values[name].astype(made[name].to_numpy().dtype)
            )
        read = fields.read(made.values())
        for (name, f), array in zip(made.items(), read):
            expected = f.to_numpy()
            assert array.dtype == expected.dtype and array.shape == expected.shape, name
            np.testing.assert_array_equal(array, expected)
    finally:
        group.close()


def test_write_sets_many_fields_in_one_compiled_kernel_and_checks_shapes():
    group, made, _ = group_of_every_kind()
    try:
        batched = [made[name] for name in ("scalar", "vector", "matrix", "integers", "table")]
        shapes = [f.to_numpy().shape for f in batched]
        new = [-np.arange(np.prod(shape)).reshape(shape) for shape in shapes]
        fields.write(zip(batched, new))  # compiles the transfer for this tuple
        compiled = kernel_compilations()
        fields.write(zip(batched, [2 * v for v in new]))
        assert kernel_compilations() == compiled  # one kernel for the five fields, reused
        for f, v in zip(batched, new):
            np.testing.assert_array_equal(f.to_numpy(), 2 * v)
        fields.fill([(made["vector"], 0.5), (made["wide"], 7), (made["single"], 2.0)])
        assert (made["vector"].to_numpy() == 0.5).all()
        assert (made["wide"].to_numpy() == 7).all() and made["single"][None] == 2.0
        with pytest.raises(ValueError, match=r"\(4, 3\) values for a field of shape \(5, 3\)"):
            fields.write([(made["vector"], np.zeros((4, 3)))])
    finally:
        group.close()


def test_more_fields_than_one_launch_takes_are_written_and_read_in_several():
    count = fields.LAUNCH_FIELDS + 5
    group = FieldGroup()
    made = [group.field(ti.i32 if k % 2 else ti.f32, 3 + k) for k in range(count)]
    group.finalize()
    try:
        values = [np.arange(3 + k) * (k + 1) for k in range(count)]
        fields.write(zip(made, values))
        for f, v, back in zip(made, values, fields.read(made)):
            np.testing.assert_array_equal(f.to_numpy(), v)
            np.testing.assert_array_equal(back, v)
    finally:
        group.close()


def round_trip() -> dict:
    """Every kind of field the transfer kernel moves, uploaded by its group, doubled
    by write, read back (not the i64 field: in this group Mesa's lavapipe gives it
    other values through Taichi's own from_numpy and to_numpy)."""
    group, made, _ = group_of_every_kind()
    del made["wide"]
    try:
        first = fields.read(made.values())
        fields.write((f, 2 * v) for f, v in zip(made.values(), first))
        return dict(zip(made, fields.read(made.values())))
    finally:
        group.close()


@pytest.mark.vulkan
def test_vulkan_round_trip_matches_cpu():
    cpu = assert_backend_matches_cpu("tests.test_fields:round_trip", 0.0)
    assert cpu["integers"].any() and cpu["matrix"].any()


TREES_TO_THE_LIMIT = """
import taichi as ti
from taichi_lap import runtime
from taichi_lap.core import fields
from taichi_lap.core.fields import FieldGroup

runtime.init("cpu")
groups = []
try:
    while True:
        group = FieldGroup()
        groups.append(group.field(ti.f32, 4))
        group.finalize()
except RuntimeError as error:
    print("refused", len(groups), runtime.snode_trees(), error)
# written and read 32 fields a launch (a field's own to_numpy compiles for each field)
fields.write((f, [1.0, 2.0, 3.0, 4.0]) for f in groups)
print("sum", sum(float(values.sum()) for values in fields.read(groups)))
"""


def test_a_tree_past_taichis_limit_is_refused_with_an_error_instead_of_crashing(tmp_path):
    """In a fresh process: groups are built until Taichi's limit on SNode trees; the
    next one raises an error that says so (building a tree past the limit corrupts
    Taichi's runtime and crashes the process) and every group built is still read
    right."""
    done = subprocess.run(
        [sys.executable, "-c", TREES_TO_THE_LIMIT],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=Path(__file__).parents[1],
        env={**os.environ, "TAICHI_LAP_CACHE": str(tmp_path)},
    )
    assert done.returncode == 0, done.stderr[-2000:]
    lines = dict(line.split(" ", 1) for line in done.stdout.splitlines() if " " in line)
    built, handed_out, message = lines["refused"].split(" ", 2)
    # the runtime's own tree (Taichi's root of fields made outside groups) comes first
    assert int(handed_out) == runtime.SNODE_TREE_LIMIT
    assert int(built) == runtime.SNODE_TREE_LIMIT - 1
    assert "as many as Taichi can hold" in message
    assert float(lines["sum"]) == 10.0 * int(built)


def test_placed_rows_append_into_spare_rows_and_grow_by_half():
    """Rows written past a table's end grow it half again (or to fit), and writes
    that fit land in place, in the same array."""
    from taichi_lap.core.fields import placed_rows

    table = np.arange(4.0)
    table = placed_rows(table, 4, [4.0, 5.0])  # past its end: 6 rows
    assert table.tolist() == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
    same = placed_rows(table, 2, [9.0])
    assert same is table and table.tolist() == [0.0, 1.0, 9.0, 3.0, 4.0, 5.0]
    grown = placed_rows(table, 6, [6.0])
    assert len(grown) == 9 and grown[:7].tolist() == [0.0, 1.0, 9.0, 3.0, 4.0, 5.0, 6.0]
