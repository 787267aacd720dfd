"""Writes of a few rows of fields from host arrays, and reads of a few rows: the
incremental updates of a topology change touch only the rows near the change (seed
002 §3.3), not whole fields. Fields whose rows are written together are written in
one launch (a launch costs about 0.1-0.2 ms on the CPU backend, whatever its size)."""

import numpy as np
import taichi as ti
from taichi.lang import impl


def serial_on_cpu() -> bool:
    """Whether a loop over the few rows a topology update touches runs serially (read
    at compile time, ``ti.loop_config(serialize=ti.static(serial_on_cpu()))``): on
    the CPU backend a parallel loop took 0.13 ms to hand 50 rows to its threads and a
    serial one 0.03 ms; GPUs keep them parallel."""
    return impl.current_cfg().arch == ti.cpu


@ti.data_oriented
class _Plan:
    """The groups (targets, layout) of one flush, as one object: the compile-time
    argument of :func:`_scatter_groups`. Taichi keys a template argument that is a
    tuple by each of its items (a flush of 30 fields spent 0.17 ms on that, more than
    the launch), an object by itself; :func:`_plan` gives one object per distinct
    set of groups."""

    def __init__(self, groups: tuple):
        self.groups = groups


_PLANS: dict[tuple, _Plan] = {}


def _plan(groups: tuple) -> _Plan:
    """The one :class:`_Plan` of ``groups`` (it holds its fields, so their ids in the
    key stay theirs)."""
    key = tuple((tuple(map(id, targets)), layout) for targets, layout in groups)
    plan = _PLANS.get(key)
    if plan is None:
        plan = _PLANS[key] = _Plan(groups)
    return plan


@ti.kernel
def _scatter_groups(
    plan: ti.template(),
    rows: ti.types.ndarray(),
    bounds: ti.types.ndarray(),
    ints: ti.types.ndarray(),
    floats: ti.types.ndarray(),
):
    """For each group g = (targets, layout) of ``plan`` and each k in [bounds[g],
    bounds[g + 1]): row rows[k] of targets[t] = the columns of row k that layout[t] =
    (is_int, first column, width; 0 for a scalar field, is_table: a 2-D table field)
    names, of ``ints`` or ``floats``."""
    ti.loop_config(serialize=ti.static(serial_on_cpu()))
    for k in range(rows.shape[0]):
        for g in ti.static(range(len(plan.groups))):
            if bounds[g] <= k and k < bounds[g + 1]:
                for t in ti.static(range(len(plan.groups[g][0]))):
                    target = ti.static(plan.groups[g][0][t])
                    is_int, first, width, is_table = ti.static(plan.groups[g][1][t])
                    if ti.static(is_table):
                        for a in range(width):  # a loop: a table's row can be wide
                            if ti.static(is_int):
                                target[rows[k], a] = ints[k, first + a]
                            else:
                                target[rows[k], a] = floats[k, first + a]
                    elif ti.static(width == 0):
                        if ti.static(is_int):
                            target[rows[k]] = ints[k, first]
                        else:
                            target[rows[k]] = floats[k, first]
                    else:
                        for a in ti.static(range(width)):
                            if ti.static(is_int):
                                target[rows[k]][a] = ints[k, first + a]
                            else:
                                target[rows[k]][a] = floats[k, first + a]


@ti.kernel
def _gather(source: ti.template(), rows: ti.types.ndarray(), out: ti.types.ndarray()):
    """out[k] = source[rows[k]] for a scalar field."""
    ti.loop_config(serialize=ti.static(serial_on_cpu()))
    for k in range(rows.shape[0]):
        out[k] = source[rows[k]]


class RowWrites:
    """Rows of scalar, vector and 2-D table fields (i32 or f32) to write, collected with
    :meth:`add` and written in one launch by :meth:`flush`: what one topology update
    changes. Adds to the same fields join one group, and a group stays when it has no
    rows, so that the launches of one caller compile once. No row of a field may be
    written twice in one flush (:meth:`flush` raises: a GPU writes the rows in
    parallel, so which of the two values stays would be its choice)."""

    def __init__(self):
        self._groups: dict[tuple, tuple[tuple, list, list]] = {}

    def add(self, rows, columns: dict):
        """Write ``columns`` (each field to its values, (R,) or (R, n), converted to
        its element type) into the rows ``rows`` (R,) of those fields."""
        rows = np.asarray(rows, dtype=np.int32).reshape(-1)
        targets = tuple(columns)
        _, row_parts, value_parts = self._groups.setdefault(
            tuple(id(target) for target in targets), (targets, [], [[] for _ in targets])
        )
        row_parts.append(rows)
        for parts, (target, values) in zip(value_parts, columns.items()):
            values = np.asarray(values, dtype=_host_type(target))
            parts.append(values.reshape(len(rows), _row_width(target)))

    def flush(self):
        """Write what was added, in one launch (none when there are no rows)."""
        groups, rows, blocks = [], [], {np.int32: [], np.float32: []}
        for targets, row_parts, value_parts in self._groups.values():
            rows.append(np.concatenate(row_parts))
            layout, pieces = [], {np.int32: [], np.float32: []}
            for target, parts in zip(targets, value_parts):
                values = np.concatenate(parts)
                dtype = values.dtype.type
                first = sum(piece.shape[1] for piece in pieces[dtype])
                table = len(target.shape) == 2
                width = values.shape[1] if table or hasattr(target, "n") else 0
                layout.append((dtype is np.int32, first, width, table))
                pieces[dtype].append(values)
            for dtype, block in pieces.items():
                blocks[dtype].append(
                    np.concatenate(block, axis=1) if block else np.zeros((len(rows[-1]), 0), dtype)
                )
            groups.append((targets, tuple(layout)))
        self._groups = {}
        _check_written_once(groups, rows)
        rows = np.concatenate(rows) if rows else np.zeros(0, dtype=np.int32)
        if not len(rows):
            return
        bounds = np.cumsum([0] + [len(block) for block in blocks[np.int32]]).astype(np.int32)
        ints, floats = (_stacked(blocks[dtype], dtype) for dtype in (np.int32, np.float32))
        _scatter_groups(_plan(tuple(groups)), rows, bounds, ints, floats)


def _check_written_once(groups: list, rows: list[np.ndarray]):
    """Raise if a row of a field is written twice in one flush (:class:`RowWrites`;
    the CPU backend writes the rows in order, a GPU in parallel)."""
    groups_of: dict[int, list[int]] = {}
    for g, (targets, _) in enumerate(groups):
        for target in targets:
            groups_of.setdefault(id(target), []).append(g)
    for together in {tuple(g) for g in groups_of.values()}:
        written = np.concatenate([rows[g] for g in together])
        unique, counts = np.unique(written, return_counts=True)
        if len(unique) < len(written):
            twice = unique[counts > 1]
            raise RuntimeError(
                f"RowWrites: rows {twice[:8].tolist()} of a field are written twice in "
                "one launch; flush between the writes"
            )


def _host_type(field):
    """The NumPy type of ``field``'s i32 or f32 elements."""
    return np.int32 if field.dtype == ti.i32 else np.float32


def _row_width(target) -> int:
    """Values in a row of a scalar, vector or 2-D table field."""
    if len(target.shape) == 2:
        return target.shape[1]
    return target.n if hasattr(target, "n") else 1


def _stacked(blocks: list[np.ndarray], dtype) -> np.ndarray:
    """The row blocks of the groups one under another, as wide as the widest."""
    width = max(1, max(block.shape[1] for block in blocks))
    out = np.zeros((sum(len(block) for block in blocks), width), dtype=dtype)
    at = 0
    for block in blocks:
        out[at : at + len(block), : block.shape[1]] = block
        at += len(block)
    return out


def scatter(target, rows, values):
    """Write ``values`` (R,) or (R, n) into the rows ``rows`` (R,) of ``target``, a
    scalar, vector or 2-D table field (converted to its element type; nothing is
    launched for no rows)."""
    writes = RowWrites()
    writes.add(rows, {target: values})
    writes.flush()


def gather(source, rows) -> np.ndarray:
    """The values of the rows ``rows`` of the scalar field ``source``."""
    rows = np.ascontiguousarray(rows, dtype=np.int32)
    out = np.zeros(len(rows), dtype=_host_type(source))
    if len(rows):
        _gather(source, rows, out)
    return out
