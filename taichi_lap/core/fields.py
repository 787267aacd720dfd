"""Fields allocated together in one SNode tree and filled once it is built.

Taichi gives every separately created field its own SNode tree, and a process can
hold only a limited number of trees (beyond ~512 the CPU backend crashes). A
session allocates dozens of fields, so each Model, State, Control or viewer places
its fields in one :class:`FieldGroup`, and :meth:`FieldGroup.close` frees the tree
when its owner is closed (Taichi frees trees only on request).
"""

from __future__ import annotations

import numpy as np
import taichi as ti
from taichi.lang import impl
from taichi.lang.struct import StructType
from taichi.lang.matrix import MatrixField
from taichi.lang.util import to_numpy_type

from taichi_lap import runtime
from taichi_lap.kernels import transfer

_BATCHED = {ti.f32: False, ti.i32: True}
"""The element types :func:`write` and :func:`read` move in one launch: f32, i32
(whether integer)."""
_BUFFER_TYPES = {False: np.float32, True: np.int32}
"""The host buffer's type for the f32 fields (False) and the i32 ones (True)."""
LAUNCH_FIELDS = 32
"""Fields per launch of the transfer kernels, whose loop over them is unrolled (Taichi
warns beyond 32 unrolled iterations)."""


def _entry_shape(field) -> tuple[int, ...]:
    if isinstance(field, MatrixField):
        return (field.n,) if field.ndim == 1 else (field.n, field.m)
    return ()


def _batched(field) -> bool:
    return field.dtype in _BATCHED and len(field.shape) > 0


def _launches(fields):
    """The batched ``fields`` in launches of :data:`LAUNCH_FIELDS`: each launch's fields,
    its static layout for :func:`~taichi_lap.kernels.transfer.copy_fields` (integer,
    offset, entry shape per field), each field's place in its buffer (buffer, slice)
    and the two zeroed buffers (a buffer of no field still has an entry)."""
    for begin in range(0, len(fields), LAUNCH_FIELDS):
        launch = tuple(fields[begin : begin + LAUNCH_FIELDS])
        layout, places, sizes = [], [], {False: 0, True: 0}
        for f in launch:
            integer, entry = _BATCHED[f.dtype], _entry_shape(f)
            count = int(np.prod(f.shape + entry))
            layout.append((integer, sizes[integer], entry))
            places.append((integer, slice(sizes[integer], sizes[integer] + count)))
            sizes[integer] += count
        buffers = {k: np.zeros(max(sizes[k], 1), _BUFFER_TYPES[k]) for k in sizes}
        yield launch, tuple(layout), places, buffers


def write(pairs):
    """Set fields to host values: ``pairs`` of (field, array of exactly the field's
    shape, entry shape included). The f32 and i32 fields of one or more dimensions
    are written :data:`LAUNCH_FIELDS` at a time in one launch
    (:func:`~taichi_lap.kernels.transfer.copy_fields`, compiled once per tuple of
    fields), the rest by ``from_numpy``."""
    pairs = [(f, np.asarray(values)) for f, values in pairs]
    for f, values in pairs:
        expected = f.shape + _entry_shape(f)
        if values.shape != expected:
            raise ValueError(f"{values.shape} values for a field of shape {expected}")
    for f, values in pairs:
        if not _batched(f):
            f.from_numpy(values.astype(to_numpy_type(f.dtype)))
    batch = [(f, values) for f, values in pairs if _batched(f)]
    values_of = {id(f): values for f, values in batch}
    for launch, layout, places, buffers in _launches([f for f, _ in batch]):
        for f, (integer, rows) in zip(launch, places):
            buffers[integer][rows] = values_of[id(f)].ravel()
        transfer.copy_fields(launch, layout, buffers[False], buffers[True], True)


def fill(pairs):
    """Set every entry of each field of ``pairs`` (field, value) to its value, as
    :func:`write` does (one launch for the f32 and i32 fields)."""
    write((f, np.full(f.shape + _entry_shape(f), value)) for f, value in pairs)


def read(fields) -> list[np.ndarray]:
    """The values of ``fields`` as NumPy copies (``to_numpy``), the f32 and i32 fields
    of one or more dimensions read :data:`LAUNCH_FIELDS` at a time in one launch
    (:func:`~taichi_lap.kernels.transfer.copy_fields`)."""
    fields = list(fields)
    out = {}
    for launch, layout, places, buffers in _launches([f for f in fields if _batched(f)]):
        transfer.copy_fields(launch, layout, buffers[False], buffers[True], False)
        for f, (integer, rows) in zip(launch, places):
            out[id(f)] = buffers[integer][rows].reshape(f.shape + _entry_shape(f))
    return [out[id(f)] if id(f) in out else f.to_numpy() for f in fields]


def padded_rows(values: np.ndarray, rows: int, fill=0) -> np.ndarray:
    """``values`` with rows of ``fill`` appended up to ``rows``."""
    if len(values) >= rows:
        return values
    extra = np.full((rows - len(values),) + values.shape[1:], fill, values.dtype)
    return np.concatenate([values, extra])


def placed_rows(table: np.ndarray, at: int, values: np.ndarray) -> np.ndarray:
    """``table`` with ``values`` written into its rows from ``at``: the same array,
    or where it is too short a copy half as long again (at least long enough), so
    that appending to a table a little at a time does not copy it each time."""
    end = at + len(values)
    if end > len(table):
        table = padded_rows(table, max(end, int(1.5 * len(table))))
    table[at:end] = values
    return table


class FieldGroup:
    """Declare fields with :meth:`field`, then :meth:`finalize` builds the tree and
    uploads the values given at declaration. A group is refused (an error) where
    Taichi has handed out as many tree ids as it can hold trees
    (:data:`~taichi_lap.runtime.SNODE_TREE_LIMIT`: building one more corrupts its
    runtime and crashes the process), even if some were freed since."""

    def __init__(self):
        if runtime.snode_trees() >= runtime.SNODE_TREE_LIMIT:
            raise RuntimeError(
                f"this process made {runtime.SNODE_TREE_LIMIT} Taichi SNode trees, as many "
                "as Taichi can hold: close the sessions, renderers or collisions no longer "
                "used before more are made"
            )
        self._builder = ti.FieldsBuilder()
        self._uploads: list = []
        self._specs: dict[int, tuple] = {}  # id(field) -> (dtype, vector, matrix, columns)
        self.tree = None

    def field(
        self,
        dtype,
        n: int | None,
        *,
        vector: int = 0,
        matrix: tuple[int, int] | None = None,
        columns: int = 0,
        values=None,
    ):
        """A field of ``n`` entries (at least one; ``n=None`` for a 0-D field) of
        scalars, ``vector``-vectors, ``matrix`` matrices or structs (``dtype`` a
        ``ti.types.struct``), or a table of ``n`` rows of ``columns`` scalars (a 2-D
        field, read ``f[row, column]``: a row as wide as the data needs compiles as a
        loop, where a vector's components are unrolled), filled with ``values`` (padded
        with zeros) when the group is finalized."""
        if isinstance(dtype, StructType):
            f = dtype.field()
        elif matrix:
            f = ti.Matrix.field(matrix[0], matrix[1], dtype)
        elif vector:
            f = ti.Vector.field(vector, dtype)
        else:
            f = ti.field(dtype)  # scalars, or a table's
        self._specs[id(f)] = (dtype, vector, matrix, columns)
        if n is None:
            self._builder.place(f)
        elif columns:
            self._builder.dense(ti.ij, (max(int(n), 1), int(columns))).place(f)
        else:
            self._builder.dense(ti.i, max(int(n), 1)).place(f)
        if values is not None:
            self.fill(f, values)
        return f

    def fill(self, field, values):
        """Upload ``values`` into ``field`` when the group is finalized."""
        self._uploads.append((field, np.asarray(values)))

    def regrown(self, owner, rows: dict[str, int], fill: dict | None = None) -> FieldGroup:
        """Reallocate fields of this group, attributes ``rows`` of ``owner``, with
        ``rows[name]`` entries each (at least as many as it has): a new group holds
        them, their values kept and the new rows ``fill[name]`` (0 when not named);
        ``owner``'s attributes are the new fields, and every kernel compiles again.
        When they were every field of this group it is closed (:meth:`close`), else
        it stays, the old fields unused in it. Returns the new group."""
        fields = {name: getattr(owner, name) for name in rows}
        if not {id(f) for f in fields.values()} <= set(self._specs):
            raise ValueError("regrown: rows must name fields of the group")
        whole = len(fields) == len(self._specs)
        fill = fill or {}
        arrays = dict(zip(fields, read(fields.values())))  # before declaring
        group = FieldGroup()
        for name, f in fields.items():
            values = arrays[name]
            if rows[name] < len(values):
                raise ValueError(f"regrown: {name} has {len(values)} rows, more than {rows[name]}")
            values = padded_rows(values, rows[name], fill.get(name, 0))
            dtype, vector, matrix, columns = self._specs[id(f)]
            setattr(
                owner,
                name,
                group.field(
                    dtype, rows[name], vector=vector, matrix=matrix, columns=columns, values=values
                ),
            )
        group.finalize()
        if whole:
            self.close()
        else:  # as destroying a tree does: a compiled kernel holds the fields it read
            impl.get_runtime().clear_compiled_functions()
        return group

    def close(self):
        """Free the fields' memory (destroy the SNode tree). The fields must not be used
        afterwards; closing twice, or a group never finalized, does nothing. Taichi
        then compiles every kernel of the process again at its next launch (it cannot
        tell which kernels read the tree), so groups are closed when a whole session
        ends, not on a frame's path."""
        if self.tree is not None:
            ti.sync()
            self.tree.destroy()
            self.tree = None

    def finalize(self):
        self.tree = self._builder.finalize()
        writes = []
        for f, values in self._uploads:
            if len(values):
                shape = f.shape[:1] + values.shape[1:]
                padded = np.zeros(shape, dtype=to_numpy_type(f.dtype))
                padded[: len(values)] = values
                writes.append((f, padded))
        write(writes)
        self._uploads = []


class FieldOwner:
    """Base of objects whose fields live in one :class:`FieldGroup`, ``self._group``:
    their own, or that of an owner that holds them (one SNode tree for both)."""

    _group: FieldGroup

    def _declare_in(self, group: FieldGroup | None) -> FieldGroup:
        """The group to declare the fields in: ``group``, which its owner finalizes
        and closes, or (None) a group of this object's own (:meth:`_finalize`)."""
        self._group = FieldGroup() if group is None else group
        self._owns_group = group is None
        return self._group

    def _finalize(self):
        """Build the tree once the fields are declared, when the group is this
        object's own."""
        if self._owns_group:
            self._group.finalize()

    def close(self):
        """Free the object's fields (:meth:`FieldGroup.close`: all of its group)."""
        self._group.close()
