"""The topology validator (seed 002 §3.3): built models pass it, and each of its
checks finds the defect it is for in an otherwise valid tet block."""

import numpy as np
import pytest

from taichi_lap import scene as scene_mod
from taichi_lap.core.mesh import tet_volumes
from taichi_lap.core.topology import (
    Topology,
    TopologyError,
    assert_valid,
    check_topology,
)
from taichi_lap.preprocess.cache import build_model
from tests.blocks import block


def checks(**arguments) -> set[str]:
    return {problem.check for problem in check_topology(Topology(**arguments))}


def test_the_block_is_valid_and_its_surface_its_boundary():
    arguments = block()
    assert check_topology(Topology(**arguments)) == []
    assert len(arguments["triangles"]) == 6 * 2 * 2 * 2  # 2 per boundary cell face


@pytest.mark.parametrize(
    "name,overrides", [("liver", {"scene.detail": 0.1}), ("rectum", {}), ("intestine", {})]
)
def test_built_models_are_valid(name, overrides):
    data = build_model(scene_mod.load(name, {"scene.detail": 0.03, **overrides}), progress=False)
    assert_valid(Topology.of_model(data))


def test_an_index_out_of_range_is_found_before_anything_indexes_with_it():
    arguments = block()
    arguments["tets"][3, 2] = len(arguments["rest_positions"])
    assert checks(**arguments) == {"index range"}


def test_a_live_tet_of_a_removed_particle_is_a_dead_reference():
    arguments = block()
    alive = np.ones(len(arguments["rest_positions"]), dtype=bool)
    alive[13] = False  # the centre: in no surface triangle
    assert checks(**arguments, particle_alive=alive) == {"dead reference"}


def test_a_flipped_triangle_breaks_the_orientation_and_all_flipped_point_inwards():
    arguments = block()
    arguments["triangles"][5] = arguments["triangles"][5, ::-1]
    assert checks(**arguments) == {"orientation"}
    arguments = block()
    arguments["triangles"] = arguments["triangles"][:, ::-1].copy()
    inward = check_topology(Topology(**arguments))
    assert [p.check for p in inward] == ["orientation"]
    assert "inwards" in inward[0].detail  # every one: consistent, but inwards


def test_a_removed_triangle_opens_the_surface():
    arguments = block()
    alive = np.ones(len(arguments["triangles"]), dtype=bool)
    alive[7] = False
    assert checks(**arguments, triangle_alive=alive) == {"open surface"}


def test_an_inverted_and_a_duplicate_tet_are_found():
    arguments = block()
    arguments["tets"][0] = arguments["tets"][0, [1, 0, 2, 3]]
    assert checks(**arguments) == {"inverted tet"}
    arguments = block()
    arguments["tets"] = np.concatenate([arguments["tets"], arguments["tets"][4:5, ::-1]])
    arguments["organs"][0].tets = (0, len(arguments["tets"]))
    assert checks(**arguments) == {"duplicate"}


def test_a_collapsed_surface_triangle_is_degenerate():
    arguments = block()
    corner = arguments["triangles"][0]
    arguments["positions"][corner[1]] = arguments["positions"][corner[0]]
    assert "degenerate triangle" in checks(**arguments)


def test_a_particle_in_no_tet_or_cluster_is_an_orphan():
    arguments = block()
    arguments["rest_positions"] = np.concatenate([arguments["rest_positions"], [[0.5, 0.5, 0.5]]])
    arguments["positions"] = arguments["rest_positions"].copy()
    organ = arguments["organs"][0]
    organ.particles = (0, len(arguments["rest_positions"]))
    assert checks(**arguments) == {"orphan", "not in a cluster"}


def test_cluster_members_must_live_and_clusters_must_not_be_empty():
    arguments = block()
    particle_alive = np.ones(len(arguments["rest_positions"]), dtype=bool)
    particle_alive[13] = False
    tet_alive = ~np.isin(arguments["tets"], [13]).any(axis=1)
    removed = float(tet_volumes(arguments["rest_positions"], arguments["tets"])[~tet_alive].sum())
    problems = check_topology(
        Topology(
            **arguments, particle_alive=particle_alive, tet_alive=tet_alive, removed_volume=removed
        )
    )
    # the eight clusters hold the centre; the two cells whose diagonal ends at it lose
    # every tet, and their far corners with them
    assert {(p.check, p.where) for p in problems} == {
        ("dead reference", "cluster members"),
        ("orphan", "organ block"),
    }
    cluster_alive = np.zeros(8, dtype=bool)  # every cluster gone: live particles left out
    found = checks(**arguments, cluster_alive=cluster_alive)
    assert found == {"not in a cluster"}
    arguments["cluster_start"] = np.concatenate([arguments["cluster_start"], [64]])
    assert checks(**arguments) == {"empty cluster"}


def test_removed_tets_must_balance_the_reported_volume():
    arguments = block()
    tet_alive = np.ones(len(arguments["tets"]), dtype=bool)
    tet_alive[0] = False  # its corners stay in the cell's other tets
    assert checks(**arguments, tet_alive=tet_alive) == {"volume"}
    sixth_of_a_cell = 1e-6 / 6.0  # [m^3]
    assert checks(**arguments, tet_alive=tet_alive, removed_volume=sixth_of_a_cell) == set()


def test_assert_valid_names_every_problem():
    arguments = block()
    arguments["tets"][0] = arguments["tets"][0, [1, 0, 2, 3]]
    arguments["triangles"][2] = arguments["triangles"][2, ::-1]
    with pytest.raises(TopologyError) as error:
        assert_valid(Topology(**arguments))
    assert {p.check for p in error.value.problems} == {"inverted tet", "orientation"}
    assert "inverted tet (tets): 1 live tets (first: 0)" in str(error.value)
