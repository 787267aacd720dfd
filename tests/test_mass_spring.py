"""Damped mass-spring intestine and mesentery (seed 001 §3)."""

import numpy as np
import pytest

from tests.archrun import assert_backend_matches_cpu
from tests.helpers import simulation, state_after

INTESTINE = {
    "name": "intestine",
    "model": "mass_spring",
    "geometry": {"generator": "intestine"},
    "attachments": [{"kind": "fixed", "rows": [-1]}],
}


def energy(data, x, v) -> float:
    """Kinetic plus spring potential energy [J]."""
    kinetic = 0.5 * np.sum(data.mass[:, None] * v * v)
    d = np.linalg.norm(x[data.spring_pair[:, 0]] - x[data.spring_pair[:, 1]], axis=1)
    return float(kinetic + 0.5 * np.sum(data.spring_stiffness * (d - data.spring_rest) ** 2))


def test_intestine_is_four_metres_long_in_four_rows_of_one_hundred():
    _, data, _, _, _, _ = simulation([INTESTINE])
    record = data.organs[0]
    assert record.row_length == 100
    assert record.particles[1] - record.particles[0] == 400
    row = data.rest_position[:100]
    assert abs(np.linalg.norm(np.diff(row, axis=0), axis=1).sum() - 4.0) < 0.04
    assert data.pinned[300:].all() and not data.pinned[:300].any()


def energy_history(organ: dict, frames: int, seed: int, **settings) -> tuple[float, list]:
    """The energy [J] at the start, the free rows thrown at random speeds, and after
    each 60 Hz frame, gravity off."""
    _, data, _, state, control, solver = simulation([organ], gravity=[0, 0, 0], **settings)
    rng = np.random.default_rng(seed)
    v0 = rng.normal(0.0, 0.3, size=(400, 3)).astype(np.float32)
    v0[300:] = 0
    state.v.from_numpy(v0)
    e0 = energy(data, state.x.to_numpy(), v0)
    history = []
    for _ in range(frames):
        solver.step(state, control, 1 / 60)
        history.append(energy(data, state.x.to_numpy(), state.v.to_numpy()))
    return e0, history


def test_damped_energy_decays():
    e0, history = energy_history(INTESTINE, 180, 3, substeps=8)
    assert max(history) <= 1.05 * e0
    assert history[-1] < 0.2 * e0
    assert np.mean(history[-30:]) < np.mean(history[:30])


def test_one_undamped_substep_at_60_hz_never_gains_energy():
    """The mesentery's springs are too stiff for an explicit step of 1/60 s (h sqrt(Σk/m)
    above 2: it faulted within 12 frames); backward Euler on the diagonal keeps the
    energy bounded with no damping at all."""
    organ = dict(INTESTINE, material={"damping": 0.0, "spring_damping": 0.0})
    e0, history = energy_history(organ, 120, 5, substeps=1, self_collision=False)
    assert np.all(np.isfinite(history))
    assert max(history) <= e0


def compute_intestine_case() -> dict:
    """The intestine hanging from its root for 30 frames (run on any backend); the
    springs alone: self-collision decisions are discrete, and its own tests compare
    backends (tests/test_intestine_collision.py)."""
    return state_after([INTESTINE], 30, substeps=8, self_collision=False)


@pytest.mark.vulkan
def test_vulkan_agrees_with_cpu():
    assert_backend_matches_cpu("tests.test_mass_spring:compute_intestine_case", 1e-4)
