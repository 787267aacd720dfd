"""The constraint-based proxy of seed 002 §3.4: contacts, QP, forces, ω filter, grasp."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from taichi_lap.core.instruments import ToolGeometry, ToolShape
from taichi_lap.haptics import (
    HapticProxy,
    HapticScene,
    ProxySettings,
    ProxyStatus,
    SceneSnapshot,
    SurfaceClusters,
    grasp_edges,
    pull_force,
)
from taichi_lap.preprocess.cache import build_model
from taichi_lap.scene import from_tables
from tests.helpers import BOX

TOOL = ToolGeometry((ToolShape("shaft"),), length=0.05, radius=0.003)
PARTICLE_RADIUS = 0.001
R = TOOL.radius + PARTICLE_RADIUS  # closest allowed tool-axis to particle-centre distance [m]
GAIN = 300.0  # [N/m]
UP, ALONG_X = np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0])


def scene_of(positions: np.ndarray, block: float = 0.008) -> HapticScene:
    """Particles grouped into cubes of ``block`` [m], with bounding cluster spheres."""
    cell = np.floor(positions / block).astype(np.int64)
    _, label = np.unique(cell, axis=0, return_inverse=True)
    order = np.argsort(label.ravel(), kind="stable")
    positions = positions[order]
    counts = np.bincount(label.ravel())
    start = np.concatenate([[0], np.cumsum(counts)])
    center = np.add.reduceat(positions, start[:-1], axis=0) / counts[:, None]
    reach = np.linalg.norm(positions - np.repeat(center, counts, axis=0), axis=1)
    radius = np.maximum.reduceat(reach, start[:-1]) + PARTICLE_RADIUS
    empty = np.zeros((0, 3))
    return HapticScene(
        1,
        0.0,
        center,
        radius,
        start,
        positions.astype(np.float32),
        np.full(len(positions), PARTICLE_RADIUS, np.float32),
        empty,
        empty,
        np.zeros(0),
    )


def plane(y: float = 0.0, spacing: float = 0.002, half: int = 20) -> np.ndarray:
    """Particles on a square grid in the plane at height ``y`` [m]."""
    g = np.arange(-half, half + 1) * spacing
    x, z = np.meshgrid(g, g, indexing="ij")
    return np.stack([x.ravel(), np.full(x.size, y), z.ravel()], axis=1)


def pose(tip, axis=UP) -> np.ndarray:
    """A tool pose whose local +z (tip towards handle) is ``axis``."""
    z = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    x = np.cross([0.0, 0.0, 1.0] if abs(z[2]) < 0.9 else [1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    out = np.eye(4)
    out[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    out[:3, 3] = tip
    return out


def descend(proxy, scene, x, z, y_from, y_to, axis=UP, steps=200):
    """Move the haptic tool from ``y_from`` to ``y_to`` [m] one tick per step."""
    for y in np.linspace(y_from, y_to, steps):
        result = proxy.step(pose([x, y, z], axis), scene)
    return result


def axis_distances(points, q, axis, length: float = TOOL.length) -> np.ndarray:
    """Distances [m] of ``points`` from the segment from ``q`` ``length`` along ``axis``
    (the test's own reference of the shaft's axis)."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    w = np.asarray(points, np.float64) - q
    s = np.clip(w @ axis, 0.0, length)
    return np.linalg.norm(w - s[:, None] * axis, axis=1)


def min_distance(points, q, axis) -> float:
    return float(axis_distances(points, q, axis).min())


@pytest.mark.parametrize("axis", [UP, ALONG_X, (1.0, 1.0, 0.0)], ids=["tip", "side", "tilted"])
def test_graphic_tool_ends_at_least_R_from_every_particle_it_collided_with(axis):
    positions = plane()
    scene = scene_of(positions)
    proxy = HapticProxy(ProxySettings(TOOL, gain=GAIN))
    axis = np.asarray(axis) / np.linalg.norm(axis)
    for depth in (0.0, 0.002, 0.006):
        result = descend(proxy, scene, 0.0011, 0.0007, 0.01, R - depth, axis=axis)
        assert result.status == ProxyStatus.CONTACT and result.contacts > 0
        assert min_distance(positions, result.graphic_position, axis) >= R - 1e-6
        proxy.reset()


def test_contact_force_opposes_penetration_and_grows_with_depth():
    scene = scene_of(plane())
    forces = []
    for depth in (0.001, 0.002, 0.004):
        proxy = HapticProxy(ProxySettings(TOOL, gain=GAIN))
        result = descend(proxy, scene, 0.0, 0.0, 0.01, R - depth)  # the tip above a particle
        q_h = np.array([0.0, R - depth, 0.0])
        assert np.dot(result.contact_force, result.graphic_position - q_h) > 0.0
        np.testing.assert_allclose(result.contact_force, [0.0, GAIN * depth, 0.0], atol=1e-6)
        forces.append(np.linalg.norm(result.contact_force))
    assert forces[0] < forces[1] < forces[2]


def test_qp_recovers_when_particles_move_into_the_previous_proxy_from_one_side():
    proxy = HapticProxy(ProxySettings(TOOL, gain=GAIN))
    result = descend(proxy, scene_of(plane()), 0.0011, 0.0007, 0.01, 0.0)
    raised = plane(y=0.002)  # the tissue moved 2 mm into the proxy since the last snapshot
    assert min_distance(raised, result.graphic_position, UP) < R - 0.0015
    result = proxy.step(pose([0.0011, 0.0, 0.0007]), scene_of(raised))
    assert result.status == ProxyStatus.CONTACT
    assert min_distance(raised, result.graphic_position, UP) >= R - 1e-6


def test_qp_stays_feasible_when_squeezed_particles_penetrate_the_previous_proxy():
    proxy = HapticProxy(ProxySettings(TOOL, gain=GAIN))
    lower, upper = plane(y=0.0), plane(y=2 * R + 0.002)
    result = descend(
        proxy,
        scene_of(np.concatenate([lower, upper])),
        0.0,
        0.0,
        R + 0.001,
        R,
        axis=ALONG_X,
        steps=20,
    )
    assert result.status in (ProxyStatus.FREE, ProxyStatus.CONTACT)
    previous = result.graphic_position
    squeezed = np.concatenate([plane(y=0.0015), plane(y=2 * R - 0.0015)])  # gap < 2 R
    before = [min_distance(squeezed[i : i + 1], previous, ALONG_X) for i in range(len(squeezed))]
    result = proxy.step(pose([0.0, R - 0.003, 0.0], ALONG_X), scene_of(squeezed))
    assert result.status == ProxyStatus.RELAXED and result.contacts > 0
    assert np.all(np.isfinite(result.graphic_position))
    after = [
        min_distance(squeezed[i : i + 1], result.graphic_position, ALONG_X)
        for i in range(len(squeezed))
    ]
    hit = np.array(before) < R  # no particle it touched is penetrated deeper than before
    assert np.all(np.array(after)[hit] >= np.array(before)[hit] - 1e-6)


def test_a_coupled_proxy_is_the_simulated_tool_and_pulls_the_stylus_to_it():
    """While tissue pushes the simulation's tool, the graphical tool is that tool and
    the device force is the coupling spring g (s - q_h), whatever particles lie near."""
    tip = np.array([0.0, 0.001, 0.0])
    scene = dataclasses.replace(scene_of(plane()), coupling_tip=tip)
    proxy = HapticProxy(ProxySettings(TOOL, gain=GAIN))
    stylus = np.array([0.0005, -0.002, 0.0])
    result = proxy.step(pose(stylus), scene)
    assert result.status == ProxyStatus.COUPLED
    np.testing.assert_array_equal(result.graphic_position, tip)
    np.testing.assert_allclose(result.contact_force, GAIN * (tip - stylus))
    uncoupled = dataclasses.replace(scene, coupling_tip=None)  # the proxy takes over
    for _ in range(100):
        free = proxy.step(pose(tip + UP * 0.01), uncoupled)
    assert free.status == ProxyStatus.FREE and not np.any(free.contact_force)


def test_physical_tool_blends_previous_graphic_and_haptic_by_omega():
    scene = scene_of(plane())
    for omega in (0.95, 0.5):
        proxy = HapticProxy(ProxySettings(TOOL, gain=GAIN, omega=omega))
        previous = descend(proxy, scene, 0.0, 0.0, 0.01, R - 0.002).graphic_position
        q_h = np.array([0.001, -0.01, 0.002])
        result = proxy.step(pose(q_h), scene)
        np.testing.assert_allclose(
            result.physical_position, omega * previous + (1.0 - omega) * q_h, atol=1e-12
        )
    free = HapticProxy(ProxySettings(TOOL, gain=GAIN)).step(pose([0.0, 0.02, 0.0]), scene)
    assert free.status == ProxyStatus.FREE and np.all(free.contact_force == 0.0)
    np.testing.assert_allclose(free.physical_position, [0.0, 0.02, 0.0])


def test_proxy_pulls_towards_grasped_edges_carried_in_the_tool_frame():
    proxy = HapticProxy(ProxySettings(TOOL, gain=GAIN, grasp_stiffness=2.0))
    tool_pose = pose([0.0, 0.05, 0.0], ALONG_X)  # tool +z along scene +x, far from the plane
    scene = dataclasses.replace(
        scene_of(plane()),
        grasp_local=np.array([[0.0, 0.0, 0.002]]),  # 2 mm up the shaft
        grasp_neighbor=np.array([[0.002, 0.04, 0.0]]),
        grasp_rest=np.array([0.006]),
    )
    result = proxy.step(tool_pose, scene)  # grasped end at (0.002, 0.05, 0): edge 10 mm long
    assert result.status == ProxyStatus.FREE
    np.testing.assert_allclose(result.pull_force, [0.0, -2.0 * 0.004, 0.0], atol=1e-12)


@pytest.fixture(scope="module")
def box_data():
    return build_model(from_tables([BOX]), use_cache=False, progress=False)


def test_grasp_pull_force_grows_with_stretch_and_is_zero_at_rest(box_data):
    rest = box_data.rest_position
    top = rest[:, 1].max()
    grasped = np.flatnonzero(
        (rest[:, 1] > top - 1e-6) & (np.linalg.norm(rest[:, [0, 2]], axis=1) < 0.006)
    )
    edges = grasp_edges(box_data.tets, grasped)
    assert len(edges) and np.all(np.isin(edges[:, 0], grasped))
    assert not np.any(np.isin(edges[:, 1], grasped))
    rest_length = np.linalg.norm(rest[edges[:, 1]] - rest[edges[:, 0]], axis=1)
    neighbor = rest[edges[:, 1]]
    np.testing.assert_array_equal(pull_force(rest[edges[:, 0]], neighbor, rest_length), 0.0)
    magnitudes = []
    for lift in (0.001, 0.002, 0.004):
        force = pull_force(rest[edges[:, 0]] + [0.0, lift, 0.0], neighbor, rest_length)
        assert force[1] < 0.0  # pulls the tool back towards the tissue
        magnitudes.append(np.linalg.norm(force))
    assert magnitudes[0] < magnitudes[1] < magnitudes[2]
    lifted = rest[edges[:, 0]] + [0.0, 0.002, 0.0]
    np.testing.assert_allclose(
        pull_force(lifted, neighbor, rest_length, stiffness=0.004),
        4.0 * pull_force(lifted, neighbor, rest_length, stiffness=0.001),
    )


def test_surface_clusters_bound_their_particles_and_the_proxy_touches_them(box_data):
    surface = SurfaceClusters(box_data)
    bound = np.unique(box_data.surface_index[box_data.surface_weight > 0])
    np.testing.assert_array_equal(np.sort(surface.particles), bound)  # each one once
    rng = np.random.default_rng(1)
    x = box_data.rest_position + rng.normal(0.0, 0.001, box_data.rest_position.shape)
    center, radius, positions = surface.spheres(x.astype(np.float32))
    counts = np.diff(surface.start)
    reach = np.linalg.norm(positions - np.repeat(center, counts, axis=0), axis=1) + surface.radius
    assert np.all(reach <= np.repeat(radius, counts) + 1e-6)

    snapshot = SceneSnapshot.create(
        clusters=surface.cluster_count, particles=surface.particle_count
    )
    try:
        surface.publish(snapshot, box_data.rest_position)
        reader = snapshot.reader()
        assert reader.poll()
        proxy = HapticProxy(ProxySettings(TOOL, gain=GAIN))
        top = box_data.rest_position[:, 1].max()
        result = descend(proxy, reader.scene, 0.001, 0.001, top + 0.01, top, steps=100)
        assert result.status == ProxyStatus.CONTACT and result.contact_force[1] > 0.0
        r = 0.003 + surface.radius  # the contact radius: 0 on a tet surface
        distance = axis_distances(
            box_data.rest_position[surface.particles], result.graphic_position, UP
        )
        assert np.all(distance >= r - 1e-6)
    finally:
        snapshot.close()


def test_jaws_keep_the_graphical_tool_off_particles_ahead_of_the_tip():
    """A grasper's jaws reach ahead of its tip: pushed down onto the plane, the proxy
    stops where the jaws' capsule touches, not where the shaft's tip would."""
    jaws = ToolGeometry((ToolShape("jaws"), ToolShape("shaft")), 0.05, 0.003, 0.012, 0.002)
    proxy = HapticProxy(ProxySettings(jaws, gain=GAIN))
    result = descend(proxy, scene_of(plane()), 0.0, 0.0, 0.03, 0.005)  # the shaft's tip
    jaw_end = result.graphic_position[1] - jaws.jaw_length  # stays 5 mm up
    assert jaw_end - jaws.jaw_radius > PARTICLE_RADIUS - 1e-5
    assert result.graphic_position[1] > 0.005 + 0.008
    assert result.status == ProxyStatus.CONTACT
    assert result.contact_force[1] > 0.0  # pushes the stylus back up
