"""Distance constraints: averaged Jacobi with over-relaxation and coloured Gauss-Seidel."""

import numpy as np
import pytest

from tests.archrun import assert_backend_matches_cpu
from tests.helpers import simulation


def sheet():
    return {
        "name": "sheet",
        "model": "fascia_lra",
        "geometry": {
            "generator": "sheet",
            "width": 0.1,
            "depth": 0.1,
            "resolution_x": 20,
            "resolution_z": 20,
            "sag": 0.0,
        },
        "material": {"edge_stiffness": 1.0, "bending_stiffness": 0.0},
    }


def strain(data, p) -> float:
    d = np.linalg.norm(p[data.distance_pair[:, 0]] - p[data.distance_pair[:, 1]], axis=1)
    return float(np.abs(d / data.distance_rest - 1.0).max())


@pytest.mark.parametrize("solver_name", ["jacobi", "gauss_seidel"])
def test_constraint_sweeps_remove_stretch(solver_name):
    _, data, model, state, control, solver = simulation(
        [sheet()], gravity=[0, 0, 0], iterations=30, constraint_solver=solver_name
    )
    rng = np.random.default_rng(0)
    noisy = data.rest_position + rng.normal(0, 0.0005, data.rest_position.shape)
    state.p.from_numpy(noisy.astype(np.float32))
    before = strain(data, noisy)
    solver._solve_constraints(state, control)
    after = strain(data, state.p.to_numpy())
    assert before > 0.2
    assert after < 0.1 * before


def test_gauss_seidel_colours_share_no_particle():
    _, data, model, *_ = simulation([sheet()], constraint_solver="gauss_seidel")
    pairs = model.colored_pair.to_numpy()
    for begin, end in model.color_ranges:
        ends = pairs[begin:end].reshape(-1)
        assert len(np.unique(ends)) == len(ends)
    assert sum(e - b for b, e in model.color_ranges) == len(data.distance_pair)


def compute_sweeps(solver_name: str) -> dict:
    """Constraint sweeps from a fixed noisy sheet (run on any backend)."""
    _, data, _, state, control, solver = simulation(
        [sheet()], gravity=[0, 0, 0], iterations=30, constraint_solver=solver_name
    )
    noisy = data.rest_position + np.random.default_rng(0).normal(
        0, 0.0005, data.rest_position.shape
    )
    state.p.from_numpy(noisy.astype(np.float32))
    solver._solve_constraints(state, control)
    return {"p": state.p.to_numpy()}


@pytest.mark.vulkan
@pytest.mark.parametrize("solver_name", ["jacobi", "gauss_seidel"])
def test_vulkan_agrees_with_cpu(solver_name):
    assert_backend_matches_cpu("tests.test_distance:compute_sweeps", 1e-5, solver_name=solver_name)
