"""Electrocautery heat conduction (seed 002 §3.3): P1 edge conductances, the explicit
step bound, the source, cooling and removal, against exact and analytic solutions."""

import numpy as np
import pytest
from scipy.special import erfc

from taichi_lap.core.mesh import tet_volumes
from taichi_lap.dissection.heat import (
    HeatField,
    HeatSource,
    edge_conductance,
    heat_capacity,
    stable_time_step,
)
from tests.archrun import assert_backend_matches_cpu
from tests.blocks import KUHN_TETS, block

KAPPA, DENSITY, SPECIFIC_HEAT = 0.52, 1060.0, 3600.0  # liver: W/(m K), kg/m^3, J/(kg K)
ALPHA = KAPPA / (DENSITY * SPECIFIC_HEAT)  # diffusivity [m^2/s]
BODY = 37.0  # [°C]
SPACING = 0.001  # [m]


def bar(cells: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A bar of ``cells`` Kuhn-split cubes of :data:`SPACING` along x: positions [m]
    (slab i holds particles 4i..4i+3 at x = i·SPACING), tets, lumped masses ρV/4 [kg]."""
    corner = np.array([[k & 1, (k >> 1) & 1, (k >> 2) & 1] for k in range(8)])
    offset = corner @ np.array([4, 1, 2])
    tets = np.concatenate([(4 * c + offset)[KUHN_TETS] for c in range(cells)])
    slabs = [[i, j, k] for i in range(cells + 1) for k in range(2) for j in range(2)]
    x = SPACING * np.array(slabs, dtype=np.float64)
    volume = np.abs(tet_volumes(x, tets))
    mass = np.bincount(tets.reshape(-1), weights=np.repeat(DENSITY * volume / 4, 4))
    return x, tets, mass


def bar_heat(
    cells: int, cooling_rate: float = 0.0, **thresholds
) -> tuple[HeatField, np.ndarray, np.ndarray]:
    """A :class:`HeatField` on :func:`bar` (``thresholds``: its ablation and damage
    temperatures), with its positions and capacities [J/K]."""
    x, tets, mass = bar(cells)
    heat = HeatField(
        x,
        tets,
        mass,
        conductivity=KAPPA,
        specific_heat=SPECIFIC_HEAT,
        body_temperature=BODY,
        cooling_rate=cooling_rate,
        **thresholds,
    )
    return heat, x, heat_capacity(mass, SPECIFIC_HEAT)


def no_source(heat: HeatField, dt: float):
    heat.step(dt)


def end_source(power: float, x: float = 0.0) -> list[HeatSource]:
    """A point source of ``power`` [W] on the 4 particles of the slab at ``x`` [m]."""
    center = (x, SPACING / 2, SPACING / 2)
    return [HeatSource(center, center, 0.8 * SPACING, power)]


def test_conductance_is_the_cotangent_formula_and_clipped():
    """One tet: g_ij = κ/6 l_kl cot θ_kl (θ_kl the dihedral angle at the opposite edge);
    a flattened tet's obtuse angle gives a negative share, clipped to 0."""
    x = np.array([[0.0, 0.0, 0.0], [1.0, 0.1, 0.0], [0.2, 0.9, 0.1], [0.1, 0.2, 1.1]])
    edges, g = edge_conductance(x, np.array([[0, 1, 2, 3]]), 2.0)
    for (i, j), gij in zip(edges, g):
        k, l = (c for c in range(4) if c not in (i, j))
        axis = (x[l] - x[k]) / np.linalg.norm(x[l] - x[k])
        a, b = (v - (v @ axis) * axis for v in (x[i] - x[k], x[j] - x[k]))
        cot = (a @ b) / np.linalg.norm(np.cross(a, b))
        assert gij == pytest.approx(2.0 / 6.0 * np.linalg.norm(x[l] - x[k]) * cot, rel=1e-12)
    flat = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, 1.0, 0.0], [0.5, 0.4, 0.05]])
    _, g = edge_conductance(flat, np.array([[0, 1, 2, 3]]), 1.0)
    assert (g == 0.0).sum() == 3 and (g > 0.0).sum() == 3


def test_block_conducts_like_the_continuum():
    """A linear field is the exact steady state of the P1 conductances on a Kuhn block
    (nothing clipped): no net flow at any particle off the two end faces, and through
    the block exactly κ A ΔT / L (float64 rounding only)."""
    arguments = block(4)
    x, tets = arguments["rest_positions"], arguments["tets"]
    edges, g = edge_conductance(x, tets, KAPPA)
    temperature = 90.0 - 1000.0 * x[:, 0]  # 40 K over L = 4 cm
    flow = g * (temperature[edges[:, 1]] - temperature[edges[:, 0]])
    net = np.bincount(edges[:, 0], flow, len(x)) - np.bincount(edges[:, 1], flow, len(x))
    hot = np.isclose(x[:, 0], 0.0)
    ends = hot | np.isclose(x[:, 0], 0.04)
    assert np.abs(net[~ends]).max() < 1e-12
    assert -net[hot].sum() == pytest.approx(KAPPA * 0.04**2 * 40.0 / 0.04, rel=1e-12)


def test_energy_is_conserved_and_the_maximum_principle_holds():
    """No source, no cooling: Σ C_i T_i stays within 1e-5 (relative; f32 rounding of
    each update) over 2000 steps at exactly the stable step, and no temperature leaves
    the initial [min, max] (the weights are a convex combination; 1e-4 K of f32 slack)."""
    heat, _, capacity = bar_heat(40)
    start = np.random.default_rng(1).uniform(BODY, 90.0, heat.particle_count)
    heat.temperature.from_numpy(start.astype(np.float32))
    energy = capacity @ heat.temperatures()
    for _ in range(200):
        no_source(heat, heat.max_step)
        t = heat.temperatures()
        assert t.min() >= start.min() - 1e-4 and t.max() <= start.max() + 1e-4
    no_source(heat, 1800 * heat.max_step)
    assert abs(capacity @ heat.temperatures() / energy - 1.0) < 1e-5
    assert np.ptp(heat.temperatures()) < 0.1 * np.ptp(start)  # it did diffuse


def test_constant_power_at_the_end_of_a_long_bar():
    """Power P into the end face of an 8 cm bar for 300 s against the semi-infinite rod
    with constant flux q = P/A: T - T0 = 2q/κ [√(αt/π) e^(-x²/4αt) - x/2 erfc(x/2√(αt))].
    The heat penetrates ~4√(αt) = 2.6 cm, so the far end stays cold. Bound: 3 % of the
    end's rise everywhere (measured 1.2 %; the lumped P1 error falls as O(h/√(αt)),
    0.64 % at half the spacing; f32 adds ~1e-6); the heat put in is P t within 1e-5."""
    heat, x, capacity = bar_heat(80)
    power, time = 0.002, 300.0  # [W], [s]
    heat.step(time, end_source(power))  # into the 4 end particles
    q = power / SPACING**2
    r = x[:, 0] / (2.0 * np.sqrt(ALPHA * time))
    exact = 2 * q / KAPPA * np.sqrt(ALPHA * time) * (np.exp(-(r**2)) / np.sqrt(np.pi) - r * erfc(r))
    rise = heat.temperatures() - BODY
    assert np.abs(rise - exact).max() < 0.03 * exact[0]
    assert capacity @ rise == pytest.approx(power * time, rel=1e-5)
    assert rise[-4:].max() < 1e-3


def test_cooling_decays_exponentially():
    """A uniform bar 20 K above body temperature cools as e^(-rt) (explicit Euler: (1 -
    rh)^n, within r²ht of it; the discrete value itself within 1e-5, f32) and stays
    uniform."""
    rate, time = 0.01, 100.0  # [1/s], [s]
    heat, _, _ = bar_heat(10, cooling_rate=rate)
    heat.temperature.fill(BODY + 20.0)
    no_source(heat, time)
    excess = heat.temperatures() - BODY
    n = int(np.ceil(time / heat.max_step))
    h = time / n
    assert np.ptp(excess) == 0.0
    assert excess[0] / 20.0 == pytest.approx((1.0 - rate * h) ** n, rel=1e-5)
    assert excess[0] / 20.0 == pytest.approx(np.exp(-rate * time), rel=rate**2 * h * time)


@pytest.mark.parametrize("factor", [1.0, 3.0])
def test_the_stable_step_is_a_real_bound(factor):
    """A checkerboard of hot and cold slabs (the fastest mode) on a fine chain: at the
    stable step the temperatures stay in their range; at 3 times it they overshoot at
    once and then grow without bound."""
    heat, x, capacity = bar_heat(30)
    edges, g = edge_conductance(x, bar(30)[1], KAPPA)
    assert heat.max_step == pytest.approx(stable_time_step(g, edges, capacity, 0.0))
    start = np.where(np.round(x[:, 0] / SPACING) % 2 == 0, 90.0, BODY)
    heat.temperature.from_numpy(start.astype(np.float32))
    heat.max_step *= factor
    no_source(heat, heat.max_step)
    first = heat.temperatures()
    no_source(heat, 20 * heat.max_step)
    later = heat.temperatures()
    if factor == 1.0:
        assert BODY - 1e-4 <= first.min() and later.max() <= 90.0 + 1e-4
        assert BODY - 1e-4 <= later.min() and first.max() <= 90.0 + 1e-4
    else:
        assert first.min() < BODY - 10.0 or first.max() > 90.0 + 10.0
        assert np.ptp(later) > 100.0 * np.ptp(start)


def test_removed_particles_neither_gain_nor_pass_heat():
    """Slab 10 of a 20-cell bar removed, hot: the left part keeps its heat (and mixes),
    the right part stays at body temperature, the dead keep theirs, a source over only
    dead particles adds nothing, and only alive particles are ablated."""
    heat, x, capacity = bar_heat(20, ablation_temperature=60.0)
    slab = np.round(x[:, 0] / SPACING)
    dead, left = np.flatnonzero(slab == 10), slab < 10
    start = np.select([slab < 5, slab < 10, slab == 10], [80.0, 50.0, 80.0], BODY)
    heat.temperature.from_numpy(start.astype(np.float32))
    heat.remove(dead)
    heat.step(200.0, end_source(1.0, 10 * SPACING))
    t = heat.temperatures()
    assert np.array_equal(t[dead], start[dead])
    assert np.array_equal(t[slab > 10], start[slab > 10])
    assert capacity[left] @ t[left] == pytest.approx(capacity[left] @ start[left], rel=1e-5)
    assert np.ptp(t[left]) < 0.5 * 30.0
    hot = heat.ablated()
    assert len(hot) and np.array_equal(hot, np.flatnonzero(left & (heat.peaks() >= 60.0)))
    assert heat.peaks()[dead].min() == 80.0
    assert heat.hottest[None] == pytest.approx(t[~np.isin(np.arange(len(t)), dead)].max())


def test_sources_share_their_power_along_a_segment():
    """A segment source along the axis of slabs 5 to 8 (16 particles within its radius)
    and a point source on slab 15: each particle near a source gets an equal share of
    its power, none elsewhere, and the heat put in is (P1 + P2) dt."""
    heat, x, capacity = bar_heat(20)
    axis = (SPACING / 2, SPACING / 2)
    segment = HeatSource((5 * SPACING, *axis), (8 * SPACING, *axis), 0.8 * SPACING, 0.4)
    sources = [segment, *end_source(0.1, 15 * SPACING)]
    heat.step(2.0, sources)
    slab = np.round(x[:, 0] / SPACING)
    expected = np.select([(slab >= 5) & (slab <= 8), slab == 15], [0.4 / 16, 0.1 / 4], 0.0)
    assert np.allclose(heat.power.to_numpy(), expected, rtol=1e-6, atol=0.0)
    assert capacity @ (heat.temperatures() - BODY) == pytest.approx(0.5 * 2.0, rel=1e-5)


def test_damage_is_reported_once_per_particle():
    """Particles are listed by ``newly_damaged`` the first time their peak reaches the
    damage temperature, never again; those further away join as the heat spreads."""
    heat, x, _ = bar_heat(20, damage_temperature=45.0)
    heat.step(20.0, end_source(0.05))
    first = heat.newly_damaged()
    assert len(first) and np.array_equal(first, np.flatnonzero(heat.peaks() >= 45.0))
    assert len(heat.newly_damaged()) == 0
    heat.step(40.0, end_source(0.05))
    later = heat.newly_damaged()
    assert len(later) and not np.isin(later, first).any()
    assert np.array_equal(np.union1d(first, later), np.flatnonzero(heat.peaks() >= 45.0))


def compute_diffusion(steps: int = 20) -> dict:
    """A 12-cell bar with cooling, a source at one end and a removed slab (any backend)."""
    heat, _, _ = bar_heat(12, cooling_rate=0.01)
    heat.remove(np.arange(24, 28))
    for _ in range(steps):
        heat.step(1.0, end_source(0.01))
    return {"temperature": heat.temperatures(), "peak": heat.peaks()}


@pytest.mark.vulkan
def test_vulkan_agrees_with_cpu():
    cpu = assert_backend_matches_cpu("tests.test_heat:compute_diffusion", 1e-4)
    assert cpu["peak"].max() > BODY + 10.0
