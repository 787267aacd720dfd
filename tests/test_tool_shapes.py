"""One definition of an instrument's shape (core.instruments): the kernels' union of
shapes and its NumPy evaluation (haptic proxy) agree, particles are pushed out of
every shape, and the drawn mesh is the collision shape."""

import numpy as np
import pytest
import taichi as ti
from taichi_lap.kernels.collision.tool_shapes import control_pose, push_out_of_tools
from taichi_lap.kernels.collision.tool_shapes import tool_distance as kernel_tool_distance

from taichi_lap.core.instruments import (
    JAW_RADIUS,
    MAX_TOOL_SHAPES,
    ToolGeometry,
    ToolShape,
    tool_distance,
    tool_geometry,
)
from taichi_lap.render.instruments import instrument_mesh
from taichi_lap.sim import Control
from taichi_lap.core.frames import frame_towards, turned_about_axis, twist

RADIUS, LENGTH, JAW = 0.003, 0.05, 0.012
SHAPES = (
    ToolShape("jaws"),
    ToolShape("shaft"),
    ToolShape.sphere([0.004, 0.0, 0.01], 0.003),
    ToolShape.box([-0.004, 0.002, 0.02], [0.002, 0.003, 0.004]),
)
GEOMETRY = ToolGeometry(SHAPES, LENGTH, RADIUS, JAW, JAW_RADIUS * RADIUS)
TIP = np.array([0.01, 0.02, -0.005])


def tilted_control() -> tuple[Control, np.ndarray]:
    """Tool 1 of a Control as :data:`GEOMETRY`, tilted; returns it and its frame."""
    control = Control()
    direction = np.array([0.3, 1.0, -0.2]) / np.linalg.norm([0.3, 1.0, -0.2])
    control.set_tool(1, TIP, TIP + LENGTH * direction, RADIUS, jaw_length=JAW)
    control.set_tool_shapes(1, SHAPES)
    return control, control.tool_frame.to_numpy()[1].astype(np.float64)


@ti.kernel
def kernel_distances(
    control: ti.template(),
    points: ti.types.ndarray(dtype=ti.math.vec3),
    out: ti.types.ndarray(),
    grad: ti.types.ndarray(dtype=ti.math.vec3),
):
    for i in range(points.shape[0]):
        out[i], grad[i] = kernel_tool_distance(control, 1, control_pose(control, 1), points[i])


@ti.kernel
def pushed(control: ti.template(), points: ti.types.ndarray(dtype=ti.math.vec3), r: ti.f32):
    for i in range(points.shape[0]):
        points[i], _ = push_out_of_tools(control, points[i], points[i], r)  # tool still


def sample_points(count: int) -> np.ndarray:
    rng = np.random.default_rng(4)
    return TIP + rng.uniform([-0.015, -0.02, -0.015], [0.015, 0.07, 0.015], (count, 3))


def test_kernels_and_numpy_give_the_same_distance_of_a_union():
    control, frame = tilted_control()
    points = sample_points(4000).astype(np.float32)
    dist, grad = np.zeros(len(points), np.float32), np.zeros_like(points)
    kernel_distances(control, points, dist, grad)
    local = (points.astype(np.float64) - TIP) @ frame
    expected, expected_grad, on_axis = tool_distance(GEOMETRY, local)
    assert np.abs(dist - expected).max() < 2e-6
    clear = ~on_axis & (np.abs(dist) > 1e-4)
    np.testing.assert_allclose(grad[clear], (expected_grad @ frame.T)[clear], atol=2e-3)
    assert (expected < 0).sum() > 50 and (expected > 0).sum() > 1000  # inside and out


def test_particles_are_pushed_out_of_every_shape_of_the_union():
    control, frame = tilted_control()
    r = 0.0005
    points = sample_points(4000).astype(np.float32)
    before, _, _ = tool_distance(GEOMETRY, (points.astype(np.float64) - TIP) @ frame)
    pushed(control, points, r)
    after, _, _ = tool_distance(GEOMETRY, (points.astype(np.float64) - TIP) @ frame)
    assert (before < 0.0).sum() > 50  # inside some shape
    assert after.min() > 0.9 * r  # every particle out of every shape
    assert np.quantile(after, 0.01) > r - 2e-5  # and nearly all onto the surface


def test_the_drawn_instrument_is_its_collision_shape():
    for kind in ("probe", "grasper"):
        tool = {"kind": kind, "radius": RADIUS, "length": LENGTH}
        geometry, mesh = tool_geometry(tool), instrument_mesh(tool)
        distance, _, _ = tool_distance(geometry, mesh.vertices)
        assert distance.max() < 1e-9  # nothing is drawn outside the collision shape
        assert len(geometry.shapes) <= MAX_TOOL_SHAPES
        reach = geometry.jaw_length + geometry.jaw_radius if kind == "grasper" else RADIUS
        np.testing.assert_allclose(mesh.bounds[:, 2], [-reach, LENGTH + RADIUS], atol=1e-9)
    grasper = tool_geometry({"kind": "grasper", "radius": RADIUS, "length": LENGTH})
    jaw_end = np.array([[0.0, 0.0, -grasper.jaw_length - grasper.jaw_radius]])
    assert abs(tool_distance(grasper, jaw_end)[0][0]) < 1e-12  # the jaws reach ahead


def test_a_tool_turned_every_frame_keeps_an_orthonormal_frame_and_its_roll():
    """frame_towards, called once per frame with a direction that sweeps back and
    forth for 2000 frames (as a script's keyframes turn a tool), keeps a right-handed
    orthonormal frame whose third column is the direction (before, its rounding
    errors grew with each turn: a scripted tool's frame went NaN in 60 frames)."""
    frame = np.eye(3)
    for k in range(2000):
        angle = 1.2 * np.sin(k * 0.01)
        direction = [np.sin(angle) * 0.3, np.cos(angle), -0.4 * np.sin(2 * angle)]
        frame = frame_towards(frame, direction)
        np.testing.assert_allclose(frame.T @ frame, np.eye(3), atol=1e-12)
        assert np.linalg.det(frame) == pytest.approx(1.0)
        np.testing.assert_allclose(frame[:, 2], direction / np.linalg.norm(direction), atol=1e-12)


def test_twist_is_the_turn_about_the_new_shaft_after_the_smallest_swing():
    """For random frames and random turns up to 2 rad between them:
    turned_about_axis(frame_towards(a, b's shaft), twist(a, b)) is b, and a pure
    turn about the shaft is its own twist."""
    rng = np.random.default_rng(7)
    for _ in range(500):
        a = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        a[:, 0] *= np.sign(np.linalg.det(a))  # right-handed
        axis = rng.normal(size=3)
        angle = rng.uniform(0.0, 2.0)
        k = axis / np.linalg.norm(axis)
        cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        b = (np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross) @ a
        turned = turned_about_axis(frame_towards(a, b[:, 2]), twist(a, b))
        np.testing.assert_allclose(turned, b, atol=1e-10)
        roll = rng.uniform(-3.0, 3.0)
        assert twist(a, turned_about_axis(a, roll)) == pytest.approx(roll, abs=1e-12)


def test_a_rolled_tool_frame_is_the_unrolled_one_turned_by_the_roll():
    """Control.set_tool along a path of shaft directions, once with a roll that
    grows past 2π and once without: each frame is the other turned about the shaft
    by the roll (the roll adds to the frame the path gives, it never drifts), and
    the tool's shapes follow the rolled frame."""
    plain, rolled = Control(), Control()
    tip = np.zeros(3)
    for k in range(120):
        angle = 0.8 * np.sin(k * 0.05)
        direction = np.array([np.sin(angle), np.cos(angle), 0.3 * np.sin(2 * angle)])
        roll = 0.07 * k
        plain.set_tool(0, tip, tip + 0.3 * direction, 0.005)
        rolled.set_tool(0, tip, tip + 0.3 * direction, 0.005, roll=roll)
        np.testing.assert_allclose(
            rolled.frames[0], turned_about_axis(plain.frames[0], roll), atol=1e-9
        )
    np.testing.assert_allclose(rolled.tool_frame.to_numpy()[0], rolled.frames[0], atol=1e-6)
    assert rolled.rolls[0] == pytest.approx(0.07 * 119)
