"""Removing particles from a tet organ (seed 002 §3.3): after any removals the
topology validator passes, the surface updated near each removal is the one marching
tetrahedra makes from scratch, the cluster tables agree, a cut neck splits its
cluster in two, and a small piece cut off is removed as a fragment."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from taichi_lap import scene as scene_mod
from taichi_lap.core.mesh import enclosed_volume, tet_volumes
from taichi_lap.core.topology import check_topology
from taichi_lap.dissection.marching import clipped_triangles, wound_triangles
from taichi_lap.dissection import removal
from taichi_lap.dissection.removal import FRAGMENT_PARTICLES, MutableTopology
from taichi_lap.preprocess.cache import build_model
from tests.blocks import block_model


def canonical(named: np.ndarray) -> set[tuple]:
    """Triangles of vertex names (K, 3, 2) as a set, each from its least corner (so
    the turn, the orientation, is kept)."""
    out = set()
    for triangle in map(tuple, named.reshape(-1, 3, 2).tolist()):
        corners = [tuple(c) for c in triangle]
        k = corners.index(min(corners))
        out.add(tuple(corners[k:] + corners[:k]))
    return out


def live_surface(topology: MutableTopology) -> set[tuple]:
    """The live triangles by the names of their vertices."""
    v, f = topology.vertices, topology.triangles
    wound = v["kept"] >= 0
    names = np.where(
        wound[:, None],
        np.stack([v["kept"], v["cut"]], axis=1),
        np.repeat(v["index"][:, :1], 2, axis=1),
    )
    live = f["vertices"][: f.used][f["alive"][: f.used]]
    return canonical(names[live])


def surface_from_scratch(topology: MutableTopology) -> set[tuple]:
    data, removed = topology.data, ~topology.particle_alive
    wound, _ = wound_triangles(data.tets, removed)
    clipped, _ = clipped_triangles(data.surface_index[data.surface_triangles, 0], removed)
    return canonical(np.concatenate([wound, clipped]))


def assert_consistent(topology: MutableTopology):
    assert check_topology(topology.topology()) == []
    assert live_surface(topology) == surface_from_scratch(topology)
    alive = topology.particle_alive
    by_cluster = {
        (c, i)
        for c, members in enumerate(topology.cluster_members)
        if topology.cluster_alive[c]
        for i in members.tolist()
    }
    start, cluster = topology.membership_start, topology.membership_cluster
    by_particle = {
        (int(cluster[j]), i)
        for i in np.flatnonzero(alive).tolist()
        for j in range(start[i], start[i + 1])
    }
    assert by_cluster == by_particle
    v = topology.vertices
    for vertex in np.flatnonzero(v["alive"][: v.used] & (v["kept"][: v.used] >= 0)).tolist():
        c = v["cluster"][vertex]
        assert topology.cluster_alive[c] and v["kept"][vertex] in topology.cluster_members[c]


REMOVALS = st.lists(st.lists(st.integers(0, 124), min_size=1, max_size=6), min_size=1, max_size=20)


@settings(max_examples=25, deadline=None)
@given(REMOVALS)
def test_random_removals_keep_a_valid_topology_and_the_scratch_surface(removals):
    remove_and_check(MutableTopology(block_model(4)), removals)


@settings(max_examples=25, deadline=None)
@given(REMOVALS)
def test_random_removals_split_an_organ_wide_cluster_checked_near_each_removal(removals):
    """An organ-wide cluster is first checked for a split near the removal: with the
    check on every cluster, the results are the same as with a full search."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(removal, "LOCAL_CHECK_MEMBERS", 0)
        local = MutableTopology(block_model(4, whole_cluster=True))
        remove_and_check(local, removals)
    full = MutableTopology(block_model(4, whole_cluster=True))
    for particles in removals:
        full.remove(particles)
    assert sorted(map(tuple, map(sorted, local.cluster_members))) == sorted(
        map(tuple, map(sorted, full.cluster_members))
    )


def remove_and_check(topology: MutableTopology, removals: list[list[int]]):
    volume = 0.0
    for particles in removals:
        change = topology.remove(particles)
        volume += change.removed_volume
        assert not topology.particle_alive[particles].any()
        assert_consistent(topology)
    assert topology.removed_volume == pytest.approx(volume)


def test_a_small_piece_cut_off_is_removed_as_a_fragment():
    topology = MutableTopology(block_model(4))
    grid = np.round(topology.rest / 0.01).astype(int)
    shell = np.flatnonzero(grid.max(axis=1) == 2)  # around the corner cube max <= 1
    change = topology.remove(shell)

    corner = np.flatnonzero(grid.max(axis=1) <= 1)
    assert change.fragments == [len(corner)] and len(corner) <= FRAGMENT_PARTICLES
    assert not topology.particle_alive[corner].any()
    assert topology.particle_alive[grid.max(axis=1) >= 3].all()
    assert_consistent(topology)


def test_cutting_the_neck_of_a_dumbbell_splits_its_cluster_in_two():
    topology = MutableTopology(block_model(6, whole_cluster=True))
    grid = np.round(topology.rest / 0.01).astype(int)
    slab = grid[:, 0] == 3
    neck = slab & np.isin(grid[:, 1], [2, 3, 4]) & np.isin(grid[:, 2], [2, 3, 4])
    whole = len(topology.cluster_members) - 1
    first = topology.remove(np.flatnonzero(slab & ~neck))
    assert first.fragments == [] and len(topology.cluster_members) == whole + 1

    second = topology.remove(np.flatnonzero(neck))
    assert second.fragments == []
    new = [c for c in second.clusters.tolist() if c > whole]
    assert len(new) == 1
    halves = {frozenset(np.flatnonzero(grid[:, 0] < 3)), frozenset(np.flatnonzero(grid[:, 0] > 3))}
    split = {
        frozenset(topology.cluster_members[whole]),
        frozenset(topology.cluster_members[new[0]]),
    }
    assert split == halves
    assert_consistent(topology)


def test_removal_refuses_what_it_cannot_dissect():
    topology = MutableTopology(block_model(2))
    with pytest.raises(ValueError, match=r"\[0, 27\)"):
        topology.remove([27])
    assert topology.remove([]).empty
    topology.data.organs[0].tets = (0, 0)  # no tets: not dissectable
    with pytest.raises(ValueError, match="organ.*block"):
        MutableTopology(topology.data).remove([0])


def test_a_ball_removed_from_the_built_liver_leaves_a_valid_closed_wound():
    data = build_model(scene_mod.load("liver", {"scene.detail": 0.03}), progress=False)
    topology = MutableTopology(data)
    liver = data.organs[0]
    liver_volume = enclosed_volume(
        data.rest_position[data.surface_index[:, 0]],
        data.surface_triangles[slice(*liver.triangles)],
    )
    assert topology.dissectable[0]
    surface = data.surface_index[slice(*liver.surface_vertices), 0]
    top = surface[np.argmax(data.rest_position[surface, 1])]
    distance = np.linalg.norm(data.rest_position - data.rest_position[top], axis=1)
    ball = np.flatnonzero((distance < 0.012) & (data.organ == 0))
    change = topology.remove(ball)

    view = topology.topology()
    assert check_topology(view) == []
    assert len(change.new_vertices) > 0
    # the liver's closed surface lost between the volume of the tets removed whole
    # and that of every dead tet (the wound passes halfway through the cut ones)
    live = view.triangle_alive & (view.triangle_organ == 0)
    lost = liver_volume - enclosed_volume(view.surface_position, view.triangles[live])
    dead = topology.tets[change.dead_tets]
    whole = tet_volumes(data.rest_position, dead[(~topology.particle_alive[dead]).all(axis=1)])
    assert whole.sum() < lost < change.removed_volume


def liver_with_vessels():
    data = build_model(scene_mod.load("liver", {"scene.detail": 0.03}), progress=False)
    vessels = [k for k, organ in enumerate(data.organs) if organ.name == "portal_vein"]
    return data, vessels[0]


def vessel_volume(view, organ: int) -> float:
    live = view.triangle_alive & (view.triangle_organ == organ)
    return enclosed_volume(view.surface_position, view.triangles[live])


def test_a_cut_across_a_vessel_caps_its_ends_and_keeps_a_valid_topology():
    """A slab 3 mm thick across the portal vein's trunk removed: the vessel's tube
    loses the vertices bound to the removed particles, every hole is capped across
    its boundary loop (a sealed stump on each side), the surface stays closed,
    manifold and outward, and the vessel's enclosed volume shrinks."""
    data, vessel = liver_with_vessels()
    topology = MutableTopology(data)
    assert topology.embedded[vessel] and not topology.dissectable[vessel]
    view = topology.topology()
    before = vessel_volume(view, vessel)
    particles = np.arange(*data.organs[vessel].particles)
    rest = data.rest_position[particles]
    axis = np.linalg.svd(rest - rest.mean(axis=0))[2][0]  # the trunk's main direction
    along = (rest - rest.mean(axis=0)) @ axis
    slab = particles[np.abs(along) < 0.0015]
    triangles_before = topology.triangles["alive"].sum()
    change = topology.remove(slab)

    view = topology.topology()
    assert check_topology(view) == []
    assert len(change.new_triangles) > 0 and len(change.dead_triangles) > 0
    caps = topology.triangles["organ"][change.new_triangles]
    assert (caps == vessel).all()  # the liver around it was not touched
    assert topology.triangles["alive"].sum() < triangles_before
    assert 0.0 < vessel_volume(view, vessel) < before

    # the particle a cap's new vertex follows removed: that cap goes and a new one
    # closes the stump again
    kept = int(topology.vertices["kept"][change.new_vertices[0]])
    again = topology.remove([kept])
    assert change.new_vertices[0] in again.dead_vertices
    assert check_topology(topology.topology()) == []


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 10**6), st.floats(0.001, 0.005)), min_size=1, max_size=6))
def test_random_cuts_of_a_vessel_keep_a_valid_topology(cuts):
    """Balls of random places and radii removed from the portal vein one after the
    other (later ones may cut caps earlier ones made): the validator passes."""
    data, vessel = cached_liver()
    topology = MutableTopology(data)
    particles = np.arange(*data.organs[vessel].particles)
    for pick, radius in cuts:
        centre = data.rest_position[particles[pick % len(particles)]]
        near = np.linalg.norm(data.rest_position[particles] - centre, axis=1) < radius
        topology.remove(particles[near])
        assert check_topology(topology.topology()) == []


_LIVER = []


def cached_liver():
    """:func:`liver_with_vessels`, built once for the examples of a property test."""
    if not _LIVER:
        _LIVER.append(liver_with_vessels())
    return _LIVER[0]
