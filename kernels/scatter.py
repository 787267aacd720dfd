"""Writes of a few rows of a field from host arrays: the incremental updates of a
topology change touch only the rows near the change (seed 002 §3.3), not whole
fields."""

import numpy as np
import taichi as ti


@ti.kernel
def scatter_scalars(target: ti.template(), rows: ti.types.ndarray(), values: ti.types.ndarray()):
    """target[rows[k]] = values[k] for a scalar field."""
    for k in range(rows.shape[0]):
        target[rows[k]] = values[k]


@ti.kernel
def scatter_vectors(target: ti.template(), rows: ti.types.ndarray(), values: ti.types.ndarray()):
    """target[rows[k]] = values[k, :] for a vector field."""
    for k in range(rows.shape[0]):
        for a in ti.static(range(target.n)):
            target[rows[k]][a] = values[k, a]


@ti.kernel
def scatter_table_rows(target: ti.template(), rows: ti.types.ndarray(), values: ti.types.ndarray()):
    """target[rows[k], a] = values[k, a] for a 2-D table field."""
    for k, a in ti.ndrange(rows.shape[0], values.shape[1]):
        target[rows[k], a] = values[k, a]


def scatter(target, rows, values):
    """Write ``values`` (R,) or (R, n) into the rows ``rows`` (R,) of ``target``
    (converted to its element type; nothing is launched for no rows)."""
    rows = np.ascontiguousarray(rows, dtype=np.int32)
    if not len(rows):
        return
    dtype = np.int32 if target.dtype == ti.i32 else np.float32
    values = np.ascontiguousarray(values, dtype=dtype)
    if values.ndim == 1:
        scatter_scalars(target, rows, values)
    elif len(target.shape) == 2:
        scatter_table_rows(target, rows, values)
    else:
        scatter_vectors(target, rows, values)
