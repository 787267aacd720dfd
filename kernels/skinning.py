"""Surface vertices follow the particles: direct binding (a liver capsule vertex is a
tet vertex) or barycentric binding in a tetrahedron (vessels, seed 002 §3.2)."""

import taichi as ti


@ti.func
def skin(model: ti.template(), positions: ti.template(), s):
    """Surface vertex s placed by its binding from the particle ``positions`` [m]."""
    idx, w = model.surface_index[s], model.surface_weight[s]
    pos = ti.Vector([0.0, 0.0, 0.0])
    for k in ti.static(range(4)):
        pos += w[k] * positions[idx[k]]
    return pos


@ti.kernel
def skin_surface(model: ti.template(), state: ti.template()):
    """surface_position[s] = Σ_k w[s, k] x[idx[s, k]]. Reads x; writes surface_position."""
    for s in range(model.surface_vertex_count):
        state.surface_position[s] = skin(model, state.x, s)
