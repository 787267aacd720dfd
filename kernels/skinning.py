"""Surface vertices follow the particles: direct binding (a liver capsule vertex is a
tet vertex) or barycentric binding in a tetrahedron (vessels, seed 002 §3.2); a
vertex dissection made follows its nearest cluster by linear blend skinning (seed
002 §3.3) anchored at the kept particle of its cut edge: v = x_kept + R (x^0 -
x^0_kept), so it moves with the particle a tool pushes and stays joined to the
tissue around it, and turns with the cluster."""

import taichi as ti

from taichi_lap.kernels.scatter import serial_on_cpu


@ti.func
def skin(model: ti.template(), state: ti.template(), positions: ti.template(), s):
    """Surface vertex s placed by its binding from the particle ``positions`` [m]
    (``state.p`` or ``state.x``) and, for a wound vertex (``surface_cluster`` >= 0),
    its rest offset from its kept particle turned by its cluster's rotation (the
    state's last cluster frames)."""
    idx, w = model.surface_index[s], model.surface_weight[s]
    pos = ti.Vector([0.0, 0.0, 0.0])
    for k in ti.static(range(4)):
        pos += w[k] * positions[idx[k]]
    c = model.surface_cluster[s]
    if c >= 0:
        pos += state.cluster_rotation[c] @ model.surface_offset[s]
    return pos


@ti.kernel
def skin_surface(model: ti.template(), state: ti.template()):
    """surface_position[s] from x (:func:`skin`). Reads x, cluster rotations; writes
    surface_position."""
    ti.loop_config(serialize=ti.static(model.serial))
    for s in range(model.surface_vertex_count):
        state.surface_position[s] = skin(model, state, state.x, s)


@ti.kernel
def skin_surface_rows(model: ti.template(), state: ti.template(), rows: ti.types.ndarray()):
    """surface_position of the surface vertices ``rows`` alone (those a topology
    change bound anew) from x (:func:`skin`)."""
    ti.loop_config(serialize=ti.static(serial_on_cpu()))
    for k in range(rows.shape[0]):
        s = rows[k]
        state.surface_position[s] = skin(model, state, state.x, s)
