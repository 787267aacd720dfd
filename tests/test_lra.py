"""Relaxed long-range attachments (seed 000 §3.2, Eq. 3)."""

import numpy as np
import pytest
from taichi_lap.kernels import distance

from tests.archrun import assert_backend_matches_cpu
from tests.helpers import simulation, state_after

DT = 1.0 / 60.0


def fascia(beta: float, anchors: int, **material) -> dict:
    return {
        "name": "fascia",
        "model": "fascia_lra",
        "geometry": {
            "generator": "sheet",
            "width": 0.1,
            "depth": 0.06,
            "resolution_x": 16,
            "resolution_z": 10,
            "sag": 0.0,
        },
        "material": {
            "lra_relaxation": beta,
            "lra_anchors": anchors,
            "edge_stiffness": 0.0,
            "bending_stiffness": 0.0,
            "damping": 0.0,
            **material,
        },
        "attachments": [{"kind": "lra_anchor", "box_min": [-1, -1, -1], "box_max": [-0.049, 1, 1]}],
    }


def lra_distances(data, x):
    return np.linalg.norm(x[data.lra_particle] - x[data.lra_anchor], axis=1)


@pytest.mark.parametrize("beta", [0.0, 0.25, 0.4])
def test_one_projection_lands_on_the_relaxed_bound(beta):
    """Eq. 3 with one anchor per vertex: a stretched vertex ends exactly at
    d_LRA = d' + β (|x^a - x| - d')."""
    _, data, model, state, control, _ = simulation(
        [fascia(beta, 1)], gravity=[0, 0, 0], iterations=1
    )
    rest = data.rest_position
    stretched = rest.copy()
    stretched[:, 0] = rest[:, 0] + 0.5 * (
        rest[:, 0] - rest[:, 0].min()
    )  # pull away from the anchors
    state.p.from_numpy(stretched.astype(np.float32))
    before = lra_distances(data, stretched)
    distance.jacobi_sweep(model, state, control, state.p, state.p_next, 1.0)
    after = lra_distances(data, state.p_next.to_numpy())
    bound = data.lra_rest + beta * np.maximum(before - data.lra_rest, 0.0)
    violated = before > data.lra_rest
    assert violated.sum() > 10
    assert np.allclose(after[violated], bound[violated], rtol=1e-5, atol=1e-7)
    assert np.allclose(after[~violated], before[~violated], atol=1e-7)


def test_hard_lra_keeps_every_vertex_within_rest_distance():
    """β = 0 with four anchors per vertex: after each frame under gravity every
    vertex is within d' of all its anchors (1 mm slack over a 10 cm sheet)."""
    _, data, _, state, control, solver = simulation([fascia(0.0, 4)], iterations=20)
    for _ in range(30):
        solver.step(state, control, DT)
        excess = lra_distances(data, state.x.to_numpy()) - data.lra_rest
        assert excess.max() < 1e-3
    assert np.abs(state.x.to_numpy() - data.rest_position).max() > 0.01  # it did fall


def test_relaxed_lra_stretches_more_than_hard():
    sag = []
    for beta in (0.0, 0.4):
        _, data, _, state, control, solver = simulation([fascia(beta, 4)], iterations=4)
        for _ in range(40):
            solver.step(state, control, DT)
        sag.append((lra_distances(data, state.x.to_numpy()) / data.lra_rest).max())
    assert sag[1] > sag[0]


def compute_fascia_case() -> dict:
    """Hard LRA fascia falling for 20 frames (run on any backend)."""
    return state_after([fascia(0.0, 4)], 20, iterations=20)


@pytest.mark.vulkan
def test_vulkan_agrees_with_cpu():
    assert_backend_matches_cpu("tests.test_lra:compute_fascia_case", 1e-4)
