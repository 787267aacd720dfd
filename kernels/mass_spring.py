"""Damped springs for the intestine and mesentery (seed 001 §3.2).

Seed 001 models the small intestine and its mesentery as rows of masses linked by
damped springs; the intestine is the first row with its own mass and stiffness,
the last row is attached to the main vessel. The force on particle i is gathered
over its springs (no scatter):

    f_i = Σ_j [ k_ij (|x_j - x_i| - L_ij) + c_ij (v_j - v_i)·n_ij ] n_ij,
    n_ij = (x_j - x_i) / |x_j - x_i|

with stiffness k [N/m], damping c [N s/m] and rest length L [m].
"""

import taichi as ti


@ti.func
def spring_force(model: ti.template(), state: ti.template(), i):
    """Sum of the damped spring forces on particle ``i`` [N] (reads x and v)."""
    f = ti.Vector([0.0, 0.0, 0.0])
    xi, vi = state.x[i], state.v[i]
    for s in range(model.spring_start[i], model.spring_start[i + 1]):
        j = model.spring_other[s]
        d = state.x[j] - xi
        length = d.norm()
        if length > 1e-9:
            n = d / length
            stretch = length - model.spring_rest[s]
            f += (
                model.spring_stiffness[s] * stretch
                + model.spring_damping[s] * (state.v[j] - vi).dot(n)
            ) * n
    return f
