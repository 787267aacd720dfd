"""Surface vertices follow the particles: direct binding (a liver capsule vertex is a
tet vertex) or barycentric binding in a tetrahedron (vessels, seed 002 §3.2); a
vertex dissection made has no particle and follows its nearest cluster by linear
blend skinning, v = R (x^0 - x_cm^0) + p_cm (seed 002 §3.3)."""

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
    """surface_position[s] = Σ_k w[s, k] x[idx[s, k]], or for a vertex bound to cluster
    c: R_c (rest[s] - x_cm^0_c) + p_cm_c with the cluster frames of the last step.
    Reads x, cluster frames; writes surface_position."""
    for s in range(model.surface_vertex_count):
        c = model.surface_cluster[s]
        if c >= 0:
            state.surface_position[s] = (
                state.cluster_rotation[c] @ (model.surface_rest[s] - model.cluster_rest_center[c])
                + state.cluster_center[c]
            )
        else:
            state.surface_position[s] = skin(model, state.x, s)
