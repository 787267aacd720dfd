"""Damped springs for the intestine and mesentery (seed 001 §3.2).

Seed 001 models the small intestine and its mesentery as rows of masses linked by
damped springs; the intestine is the first row with its own mass and stiffness,
the last row is attached to the main vessel. The force on particle i is gathered
over its springs (no scatter):

    f_i = Σ_j [ k_ij (|x_j - x_i| - L_ij) + c_ij (v_j - v_i)·n_ij ] n_ij,
    n_ij = (x_j - x_i) / |x_j - x_i|

with stiffness k [N/m], damping c [N s/m] and rest length L [m].

The forces are integrated by linearised backward Euler (Baraff and Witkin 1998, Eq.
15) with the stiffness matrix taken by its diagonal, the particle's own springs:

    v' = (v + h f / m) / (1 + (h² Σ_j k_ij + h Σ_j c_ij) / m)

The explicit step (the denominator 1) diverges once h √(Σ k / m) passes about 2: the
mesentery's springs did at one 60 Hz substep. The rest state is unchanged (f = 0
there), only motion is damped where springs are stiff for the step.
"""

import taichi as ti


@ti.func
def spring_velocity(model: ti.template(), state: ti.template(), i, v, h):
    """Velocity ``v`` [m/s] of particle ``i`` after its springs act for ``h`` [s]
    (module docstring: backward Euler with the diagonal of the stiffness matrix)."""
    stiffness, damping = 0.0, 0.0
    for s in range(model.spring_start[i], model.spring_start[i + 1]):
        stiffness += model.spring_stiffness[s]
        damping += model.spring_damping[s]
    w = model.inv_mass[i]
    return (v + h * spring_force(model, state, i) * w) / (
        1.0 + (h * h * stiffness + h * damping) * w
    )


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
