"""Copies between flat host buffers and many fields in one launch.

Taichi's own ``from_numpy``, ``to_numpy``, ``fill`` and ``copy_from`` compile one
kernel per field they are given (its template argument). A session that uploads fifty
fields compiled fifty small kernels, each paying the backend compiler's fixed cost;
:func:`copy_fields` takes the whole tuple of fields at once and compiles once per tuple
and direction.

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
def copy_fields(
    fields: ti.template(),
    layout: ti.template(),
    floats: ti.types.ndarray(dtype=ti.f32, ndim=1),
    ints: ti.types.ndarray(dtype=ti.i32, ndim=1),
    into_fields: ti.template(),
):
    """Fill every field of ``fields`` from its place in ``floats`` or ``ints``
    (``into_fields``), or write it there."""
    for k in ti.static(range(len(fields))):
        integer, offset, entry = ti.static(layout[k])
        width = ti.static(_entry_width(entry))
        for index in ti.grouped(fields[k]):
            base = offset + _flat_index(index, ti.static(fields[k].shape)) * width
            if ti.static(integer):
                _copy_entry(fields[k], index, entry, ints, base, into_fields)
            else:
                _copy_entry(fields[k], index, entry, floats, base, into_fields)


def _entry_width(entry: tuple) -> int:
    """Components of one entry of shape ``entry``."""
    width = 1
    for n in entry:
        width *= n
    return width


def _component(entry: tuple, c: int) -> tuple:
    """Index of component ``c`` (row-major) in an entry of shape ``entry``."""
    return (c,) if len(entry) == 1 else divmod(c, entry[1])


@ti.func
def _copy_entry(
    field: ti.template(),
    index,
    entry: ti.template(),
    buffer: ti.template(),
    base,
    into_field: ti.template(),
):
    """Entry ``index`` of ``field`` from the buffer's components from ``base`` on
    (``into_field``), or to them."""
    if ti.static(len(entry) == 0):
        if ti.static(into_field):
            field[index] = buffer[base]
        else:
            buffer[base] = field[index]
    else:
        for c in ti.static(range(_entry_width(entry))):
            part = ti.static(_component(entry, c))
            if ti.static(into_field):
                field[index][part] = buffer[base + c]
            else:
                buffer[base + c] = field[index][part]
