"""Electrocautery heat conduction in the tet organs (seed 002 §3.3).

Seed 002 heats the particles near the electrocautery hook and carries the heat along
the tet edges with a heat transfer function (its ref. [9], Pan et al. 2019); particles
whose temperature reaches a threshold are removed. Here that function is the linear
(P1) finite-element heat equation with lumped capacity, plus the source and Newton
cooling towards body temperature (perfusion):

    C_i dT_i/dt = Σ_j g_ij (T_j - T_i) + P_i - C_i r_i (T_i - T_body)

with temperatures T [°C], capacities C_i = m_i c [J/K], edge conductances g_ij = -K_ij
[W/K] of the P1 stiffness matrix, source power P_i [W] and cooling rate r_i [1/s]
(:mod:`taichi_lap.dissection.heat` builds them). Explicit Euler advances it by steps h
[s] no longer than :func:`taichi_lap.dissection.heat.stable_time_step`, so each new
temperature is a convex combination of old ones and T_body (maximum principle). Each
particle gathers over its compressed-row edges into ``temperature_next``: no float
atomics. Dead particles (``alive`` 0) neither gain nor pass heat.
"""

import taichi as ti


@ti.kernel
def clear_power(heat: ti.template()):
    """No source power [W] into any particle (before :func:`deposit`)."""
    for i in range(heat.particle_count):
        heat.power[i] = 0.0


@ti.kernel
def deposit(
    heat: ti.template(),
    positions: ti.template(),
    a: ti.math.vec3,
    b: ti.math.vec3,
    radius: ti.f32,
    power: ti.f32,
):
    """Share ``power`` [W] equally among the alive particles that reach within
    ``radius`` [m] of the segment ``a``-``b`` [m] (their distance at ``positions`` [m]
    less their ``heat.particle_radius``; seed 002 §3.3: the particles near the hook
    are heated), adding each share to ``heat.power``. Counted with an integer atomic
    first, so the shares are deterministic."""
    heat.source_count[None] = 0
    ab = b - a
    for i in range(heat.particle_count):
        inside = 0
        if heat.alive[i]:
            t = ti.math.clamp((positions[i] - a).dot(ab) / ti.max(ab.norm_sqr(), 1e-30), 0.0, 1.0)
            reach = radius + heat.particle_radius[i]
            if (positions[i] - a - t * ab).norm_sqr() < reach * reach:
                inside = 1
                ti.atomic_add(heat.source_count[None], 1)
        heat.heated[i] = inside
    for i in range(heat.particle_count):
        if heat.heated[i]:
            heat.power[i] += power / heat.source_count[None]


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


@ti.kernel
def diffuse(heat: ti.template(), h: ti.f32):
    """One explicit Euler step of ``h`` [s] of the module's equation (P1 Laplacian,
    lumped capacity, the sources' ``power`` [W] per particle, Newton cooling), reading
    ``temperature`` and writing ``temperature_next`` [°C]; dead particles keep theirs."""
    for i in range(heat.particle_count):
        t = heat.temperature[i]
        if heat.alive[i]:
            gain = conduction(heat, i, t) + heat.power[i]
            t += h * heat.inv_capacity[i] * gain - h * heat.cooling_rate[i] * (
                t - heat.body_temperature
            )
        heat.temperature_next[i] = t


@ti.kernel
def commit(heat: ti.template()):
    """Take ``temperature_next`` as the temperature [°C], raise the peaks to it and
    keep the highest temperature of an alive particle in ``heat.hottest``."""
    heat.hottest[None] = heat.body_temperature
    for i in range(heat.particle_count):
        t = heat.temperature_next[i]
        heat.temperature[i] = t
        heat.peak[i] = ti.max(heat.peak[i], t)
        if heat.alive[i]:
            ti.atomic_max(heat.hottest[None], t)


@ti.kernel
def collect_ablated(heat: ti.template()):
    """List in ``heat.hit`` (``heat.hit_count`` of them, in no fixed order) the alive
    particles whose peak temperature reached their ablation temperature (seed 002
    §3.3: they are removed)."""
    heat.hit_count[None] = 0
    for i in range(heat.particle_count):
        if heat.alive[i] and heat.peak[i] >= heat.ablation_temperature[i]:
            heat.hit[ti.atomic_add(heat.hit_count[None], 1)] = i


@ti.kernel
def collect_damaged(heat: ti.template()):
    """List in ``heat.hit`` the particles whose peak temperature reached their damage
    temperature since the last call, and flag them ``damaged``."""
    heat.hit_count[None] = 0
    for i in range(heat.particle_count):
        if not heat.damaged[i] and heat.peak[i] >= heat.damage_temperature[i]:
            heat.damaged[i] = 1
            heat.hit[ti.atomic_add(heat.hit_count[None], 1)] = i


@ti.kernel
def kill(heat: ti.template(), indices: ti.types.ndarray(dtype=ti.i32, ndim=1)):
    """Mark the particles ``indices`` dead: they stop exchanging heat."""
    for k in range(indices.shape[0]):
        heat.alive[indices[k]] = 0
