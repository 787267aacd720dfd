"""Electrocautery heating of tet organs (seed 002 §3.3): the heat equation's
coefficients on the tet mesh (NumPy, once) and :class:`HeatField`, which advances the
particle temperatures on the device (:mod:`taichi_lap.kernels.heat`).

Seed 002 carries the heat of the electrocautery hook along the tet edges and removes
the particles that reach a threshold. The edge conductances here are those of the
linear finite-element (P1) heat equation with lumped capacity, so a lattice conducts
like the continuum; the explicit step is bounded so the maximum principle holds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import taichi as ti

from taichi_lap.core.csr import both_ends
from taichi_lap.core import fields
from taichi_lap.core.fields import FieldGroup, FieldOwner
from taichi_lap.core.mesh import TET_EDGES, unique_edges
from taichi_lap.kernels import heat as kernels

FAR_HOT = 1e30
"""A threshold no temperature reaches [°C] (an infinite one, stored in f32)."""


def edge_conductance(
    rest_positions: np.ndarray, tets: np.ndarray, conductivity
) -> tuple[np.ndarray, np.ndarray]:
    """The edges ``(E, 2)`` of ``tets`` (:func:`taichi_lap.core.mesh.unique_edges`) and
    their conductances ``(E,)`` [W/K] for a thermal ``conductivity`` [W/(m K)] (scalar
    or one per tet) at ``rest_positions`` [m].

    g_ij = -K_ij of the P1 stiffness matrix, K_ij = Σ_t κ V_t ∇φ_i·∇φ_j over the tets
    sharing edge ij (φ the barycentric functions), which is the cotangent formula
    Σ_t κ/6 l_kl cot θ_kl (k, l the opposite edge, l_kl its length, θ_kl the dihedral
    angle there). An obtuse dihedral angle makes a tet's share negative; a negative sum
    is clipped to 0 (an edge may not carry heat from cold to hot), so the scheme keeps
    the maximum principle at the cost of reproducing linear fields exactly only where
    nothing was clipped. Regular BCC and Kuhn lattices have no obtuse angles (some of
    their edges get 0: on a Kuhn lattice all but the axis edges); the tetrahedralizer's
    snapped skin has some (a 4 mm BCC ellipsoid: 6 % of its edges, 2 % of the
    conductance clipped)."""
    x = np.asarray(rest_positions, dtype=np.float64)
    tets = np.asarray(tets, dtype=np.int64)
    edges, inverse = unique_edges(tets, return_inverse=True)
    d = x[tets[:, 1:]] - x[tets[:, :1]]  # rows: the edges from corner 0 [m]
    gradient = np.linalg.inv(d).transpose(0, 2, 1)  # rows: ∇φ_1..3 [1/m]
    gradient = np.concatenate([-gradient.sum(axis=1, keepdims=True), gradient], axis=1)
    volume = np.abs(np.linalg.det(d)) / 6.0
    kappa = np.broadcast_to(np.asarray(conductivity, dtype=np.float64), volume.shape)
    dot = np.einsum("tek,tek->te", gradient[:, TET_EDGES[:, 0]], gradient[:, TET_EDGES[:, 1]])
    share = -(kappa * volume)[:, None] * dot
    conductance = np.bincount(inverse, weights=share.reshape(-1), minlength=len(edges))
    return edges, np.maximum(conductance, 0.0)


def heat_capacity(mass: np.ndarray, specific_heat) -> np.ndarray:
    """Lumped heat capacities C_i = m_i c_i [J/K] of particles of ``mass`` [kg] and
    ``specific_heat`` [J/(kg K)] (scalar or per particle)."""
    return np.asarray(mass, dtype=np.float64) * np.asarray(specific_heat, dtype=np.float64)


def stable_time_step(
    conductance: np.ndarray, edges: np.ndarray, capacity: np.ndarray, cooling_rate
) -> float:
    """The longest explicit Euler step [s] of :mod:`taichi_lap.kernels.heat` that keeps
    the maximum principle: min_i C_i / (Σ_j g_ij + C_i r_i) for conductances ``g``
    [W/K] on ``edges``, capacities ``C`` [J/K] and cooling rates ``r`` [1/s] (scalar or
    per particle; inf when nothing conducts or cools).

    The step is T_i' = (1 - h (Σ_j g_ij / C_i + r_i)) T_i + h Σ_j g_ij / C_i T_j +
    h r_i T_body + h P_i / C_i. With g_ij >= 0 and h at most this bound every weight is
    non-negative and they sum to 1: without the source each new temperature is a convex
    combination of old ones and T_body, so none leaves their range (maximum principle)
    and the scheme is stable in the max norm; removing particles only lowers Σ_j g_ij.
    Gershgorin's discs put the spectrum of C⁻¹K in [0, 2 max_i Σ_j g_ij / C_i], so at
    this step (cooling aside) no mode grows either; the margin beyond it is small: the
    Kuhn bar of the tests has h λ_max = 1.64 here, so it diverges past 1.22 times it."""
    capacity = np.asarray(capacity, dtype=np.float64)
    if (capacity <= 0.0).any():
        raise ValueError("heat capacities must be positive")
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    total = np.bincount(
        edges.reshape(-1), weights=np.repeat(conductance, 2), minlength=len(capacity)
    )
    rate = float((total / capacity + cooling_rate).max(initial=0.0))
    return 1.0 / rate if rate > 0.0 else math.inf


@dataclass(frozen=True)
class HeatSource:
    """Heat put into the tissue: ``power`` [W] shared equally by the alive particles
    that reach within ``radius`` [m] of the segment ``a``-``b`` [m] (a hook's
    electrode) with their own radius."""

    a: tuple[float, float, float]
    b: tuple[float, float, float]
    radius: float
    power: float


@ti.data_oriented
class HeatField(FieldOwner):
    """Particle temperatures of tet organs heated by an electrocautery source (seed 002
    §3.3, the equation of :mod:`taichi_lap.kernels.heat`).

    ``rest_positions`` (N, 3) [m], ``tets`` (T, 4), ``masses`` (N,) [kg]; material
    ``conductivity`` [W/(m K)] (scalar or per tet), ``specific_heat`` [J/(kg K)],
    ``cooling_rate`` [1/s], ``ablation_temperature`` and ``damage_temperature`` [°C]
    (scalars or per particle; inf: never), ``body_temperature`` [°C] (the start and
    the cooling target), ``particle_radius`` [m] (scalar or per particle: how far a
    particle reaches towards a source). Fields: ``temperature`` and ``peak`` (the
    highest so far) [°C], ``alive`` (particles in no tet are dead from the start:
    other organs take no heat), the edges of each particle in compressed rows with
    their conductances, the thresholds, ``hottest`` (the highest alive temperature
    after the last step) and scratch of a step. ``max_step`` [s] is
    :func:`stable_time_step`, computed once."""

    def __init__(
        self,
        rest_positions: np.ndarray,
        tets: np.ndarray,
        masses: np.ndarray,
        *,
        conductivity,
        specific_heat,
        body_temperature: float,
        cooling_rate,
        ablation_temperature=math.inf,
        damage_temperature=math.inf,
        particle_radius=0.0,
    ):
        n = len(rest_positions)
        edges, conductance = edge_conductance(rest_positions, tets, conductivity)
        capacity = heat_capacity(masses, specific_heat)
        self.max_step = stable_time_step(conductance, edges, capacity, cooling_rate)
        self.particle_count = n
        self.body_temperature = float(body_temperature)
        start, edge, other = both_ends(edges, n)
        alive = np.zeros(n, dtype=np.int32)
        alive[np.unique(tets)] = 1
        self._alive_at_start = alive
        warm = np.full(n, self.body_temperature)

        group = FieldGroup()
        self.rest_position = group.field(ti.f32, n, vector=3, values=rest_positions)
        self.inv_capacity = group.field(ti.f32, n, values=1.0 / capacity)
        self.edge_start = group.field(ti.i32, n + 1, values=start)
        self.edge_other = group.field(ti.i32, len(other), values=other)
        self.edge_conductance = group.field(ti.f32, len(other), values=conductance[edge])
        self.alive = group.field(ti.i32, n, values=alive)
        per_particle = {
            "cooling_rate": cooling_rate,
            "ablation_temperature": ablation_temperature,
            "damage_temperature": damage_temperature,
            "particle_radius": particle_radius,
        }
        for name, value in per_particle.items():
            values = np.broadcast_to(np.asarray(value, dtype=np.float64), (n,))
            setattr(self, name, group.field(ti.f32, n, values=np.minimum(values, FAR_HOT)))
        self.damaged = group.field(ti.i32, n)
        self.power = group.field(ti.f32, n)
        self.hottest = group.field(ti.f32, None)
        self.temperature = group.field(ti.f32, n, values=warm)
        self.temperature_next = group.field(ti.f32, n, values=warm)
        self.peak = group.field(ti.f32, n, values=warm)
        self.heated = group.field(ti.i32, n)
        self.source_count = group.field(ti.i32, None)
        self.hit = group.field(ti.i32, n)
        self.hit_count = group.field(ti.i32, None)
        group.finalize()
        self.hottest[None] = self.body_temperature
        self._group = group

    def step(self, dt: float, sources=(), positions=None):
        """Advance ``dt`` [s] in the fewest equal substeps of at most ``max_step``, with
        the :class:`HeatSource` s ``sources`` found at ``positions`` (a field of the N
        particle positions [m], e.g. ``State.x``, so a source meets the deformed
        tissue; the rest positions by default) at the start."""
        substeps = max(1, math.ceil(dt / self.max_step))
        kernels.clear_power(self)
        for source in sources:
            kernels.deposit(
                self,
                self.rest_position if positions is None else positions,
                ti.math.vec3(*source.a),
                ti.math.vec3(*source.b),
                source.radius,
                source.power,
            )
        for _ in range(substeps):
            kernels.diffuse(self, dt / substeps)
            kernels.commit(self)

    def reset(self):
        """Back to the start: body temperature (and peak) everywhere, the particles of
        the tets alive, nothing damaged."""
        warm = (self.temperature, self.temperature_next, self.peak, self.hottest)
        fields.write(
            [(f, np.full(f.shape, self.body_temperature)) for f in warm]
            + [(self.damaged, np.zeros(self.damaged.shape)), (self.alive, self._alive_at_start)]
        )

    def remove(self, indices: np.ndarray):
        """The particles ``indices`` die: they neither gain nor pass heat from now on
        (their temperature and peak stay as they were)."""
        indices = np.asarray(indices, dtype=np.int32).reshape(-1)
        if len(indices):
            kernels.kill(self, indices)

    def temperatures(self) -> np.ndarray:
        """(N,) temperatures [°C], a NumPy copy."""
        return self.temperature.to_numpy()

    def peaks(self) -> np.ndarray:
        """(N,) highest temperatures so far [°C], a NumPy copy."""
        return self.peak.to_numpy()

    def ablated(self) -> np.ndarray:
        """Sorted indices (int64) of the alive particles whose peak temperature reached
        their ablation temperature (to remove)."""
        return self._collected(kernels.collect_ablated)

    def newly_damaged(self) -> np.ndarray:
        """Sorted indices (int64) of the particles whose peak temperature reached their
        damage temperature since the last call."""
        return self._collected(kernels.collect_damaged)

    def _collected(self, collect) -> np.ndarray:
        """The particles ``collect`` lists, compacted on the device with an atomic
        counter; the host reads the count (one scalar, a sync) and only when it is not
        zero the list."""
        collect(self)
        count = int(self.hit_count[None])
        if count == 0:
            return np.zeros(0, dtype=np.int64)
        return np.sort(self.hit.to_numpy()[:count]).astype(np.int64)
