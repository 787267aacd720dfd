"""Copies between flat host buffers and many fields in one launch.

Taichi's own ``from_numpy``, ``to_numpy``, ``fill`` and ``copy_from`` compile one
kernel per field they are given (its template argument). A session that uploads fifty
fields compiled fifty small kernels, each paying the backend compiler's fixed cost;
these kernels take the whole tuple of fields at once and compile once per tuple.

``layout`` holds one static entry per field: ``(integer, offset, entry_shape)``:
whether the field is i32 (else f32), where its values start in the buffer of its
type, and the shape of one entry (``()`` scalar, ``(n,)`` vector, ``(n, m)``
matrix). A field's values are its entries in row-major order of its index, each
entry's components in row-major order.
"""

import taichi as ti


@ti.func
def _flat_index(index, shape: ti.template()):
    """Row-major position of ``index`` in a field of ``shape``."""
    flat = index[0]
    for d in ti.static(range(1, len(shape))):
        flat = flat * shape[d] + index[d]
    return flat


@ti.kernel
def write_fields(
    fields: ti.template(),
    layout: ti.template(),
    floats: ti.types.ndarray(dtype=ti.f32, ndim=1),
    ints: ti.types.ndarray(dtype=ti.i32, ndim=1),
):
    """Fill every field of ``fields`` from its place in ``floats`` or ``ints``."""
    for k in ti.static(range(len(fields))):
        integer, offset, entry = ti.static(layout[k])
        width = ti.static(_entry_width(entry))
        for index in ti.grouped(fields[k]):
            base = offset + _flat_index(index, ti.static(fields[k].shape)) * width
            if ti.static(integer):
                _store(fields[k], index, entry, ints, base)
            else:
                _store(fields[k], index, entry, floats, base)


@ti.kernel
def read_fields(
    fields: ti.template(),
    layout: ti.template(),
    floats: ti.types.ndarray(dtype=ti.f32, ndim=1),
    ints: ti.types.ndarray(dtype=ti.i32, ndim=1),
):
    """Write every field of ``fields`` to its place in ``floats`` or ``ints``."""
    for k in ti.static(range(len(fields))):
        integer, offset, entry = ti.static(layout[k])
        width = ti.static(_entry_width(entry))
        for index in ti.grouped(fields[k]):
            base = offset + _flat_index(index, ti.static(fields[k].shape)) * width
            if ti.static(integer):
                _load(fields[k], index, entry, ints, base)
            else:
                _load(fields[k], index, entry, floats, base)


def _entry_width(entry: tuple) -> int:
    """Components of one entry of shape ``entry``."""
    width = 1
    for n in entry:
        width *= n
    return width


@ti.func
def _store(field: ti.template(), index, entry: ti.template(), buffer: ti.template(), base):
    if ti.static(len(entry) == 0):
        field[index] = buffer[base]
    elif ti.static(len(entry) == 1):
        for c in ti.static(range(entry[0])):
            field[index][c] = buffer[base + c]
    else:
        for r, c in ti.static(ti.ndrange(entry[0], entry[1])):
            field[index][r, c] = buffer[base + r * entry[1] + c]


@ti.func
def _load(field: ti.template(), index, entry: ti.template(), buffer: ti.template(), base):
    if ti.static(len(entry) == 0):
        buffer[base] = field[index]
    elif ti.static(len(entry) == 1):
        for c in ti.static(range(entry[0])):
            buffer[base + c] = field[index][c]
    else:
        for r, c in ti.static(ti.ndrange(entry[0], entry[1])):
            buffer[base + r * entry[1] + c] = field[index][r, c]
