"""Electrocautery heat conduction in the tet organs (seed 002 §3.3).

Seed 002 heats the particles near the electrocautery hook and carries the heat along
the tet edges with a heat transfer function (its ref. [9], Pan et al. 2019); particles
whose temperature reaches a threshold are removed. Here that function is the linear
(P1) finite-element heat equation with lumped capacity, plus the source and Newton
cooling towards body temperature (perfusion):

    C_i dT_i/dt = Σ_j g_ij (T_j - T_i) + P_i - C_i r (T_i - T_body)

with temperatures T [°C], capacities C_i = m_i c [J/K], edge conductances g_ij = -K_ij
[W/K] of the P1 stiffness matrix, source power P_i [W] and cooling rate r [1/s]
(:mod:`taichi_lap.dissection.heat` builds them). Explicit Euler advances it by steps h
[s] no longer than :func:`taichi_lap.dissection.heat.stable_time_step`, so each new
temperature is a convex combination of old ones and T_body (maximum principle). Each
particle gathers over its compressed-row edges into ``temperature_next``: no float
atomics. Dead particles (``alive`` 0) neither gain nor pass heat.
"""

import taichi as ti


@ti.kernel
def mark_source(
    heat: ti.template(), positions: ti.template(), center: ti.math.vec3, radius: ti.f32
):
    """Flag in ``heat.heated`` the alive particles closer than ``radius`` [m] to
    ``center`` [m] at ``positions`` [m] and count them in ``heat.source_count`` (seed 002
    §3.3: the particles near the hook are heated; an integer atomic, so deterministic)."""
    heat.source_count[None] = 0
    for i in range(heat.particle_count):
        inside = 0
        if heat.alive[i] and (positions[i] - center).norm_sqr() < radius * radius:
            inside = 1
            ti.atomic_add(heat.source_count[None], 1)
        heat.heated[i] = inside


@ti.func
def conduction(heat: ti.template(), i, t):
    """Heat flow [W] into particle ``i`` at temperature ``t`` [°C] from its alive
    neighbours: Σ_j g_ij (T_j - T_i), the P1 Laplacian row (gathered)."""
    flow = 0.0
    for e in range(heat.edge_start[i], heat.edge_start[i + 1]):
        j = heat.edge_other[e]
        if heat.alive[j]:
            flow += heat.edge_conductance[e] * (heat.temperature[j] - t)
    return flow


@ti.func
def source_power(heat: ti.template(), i, power):
    """Share [W] of the source ``power`` [W] of particle ``i``: equal among the
    particles :func:`mark_source` flagged."""
    share = 0.0
    if heat.heated[i]:
        share = power / heat.source_count[None]
    return share


@ti.kernel
def diffuse(heat: ti.template(), h: ti.f32, power: ti.f32):
    """One explicit Euler step of ``h`` [s] of the module's equation (P1 Laplacian,
    lumped capacity, the source sharing ``power`` [W], Newton cooling), reading
    ``temperature`` and writing ``temperature_next`` [°C]; dead particles keep theirs."""
    for i in range(heat.particle_count):
        t = heat.temperature[i]
        if heat.alive[i]:
            gain = conduction(heat, i, t) + source_power(heat, i, power)
            t += h * heat.inv_capacity[i] * gain - h * heat.cooling_rate * (
                t - heat.body_temperature
            )
        heat.temperature_next[i] = t


@ti.kernel
def commit(heat: ti.template()):
    """Take ``temperature_next`` as the temperature [°C] and raise the peaks to it."""
    for i in range(heat.particle_count):
        t = heat.temperature_next[i]
        heat.temperature[i] = t
        heat.peak[i] = ti.max(heat.peak[i], t)


@ti.kernel
def collect_above(heat: ti.template(), threshold: ti.f32):
    """List in ``heat.hit`` (``heat.hit_count`` of them, in no fixed order) the alive
    particles whose peak temperature reached ``threshold`` [°C] (seed 002 §3.3: they
    are removed)."""
    heat.hit_count[None] = 0
    for i in range(heat.particle_count):
        if heat.alive[i] and heat.peak[i] >= threshold:
            heat.hit[ti.atomic_add(heat.hit_count[None], 1)] = i


@ti.kernel
def kill(heat: ti.template(), indices: ti.types.ndarray(dtype=ti.i32, ndim=1)):
    """Mark the particles ``indices`` dead: they stop exchanging heat."""
    for k in range(indices.shape[0]):
        heat.alive[indices[k]] = 0
