"""Inputs to a step (the Warp/Newton ``Control``): kinematic tools and grasp
commands.

Each tool is a union of implicit shapes (:mod:`taichi_lap.core.instruments`) placed by
a device (mouse, script, haptic) before every frame: the shaft from its tip ``a`` to
``b`` with radius [m], an orthonormal frame whose third column points from the tip
towards the handle, and the jaws ahead of the tip. Particle contacts, tissue
collision and the grasp all read the tools from here. A particle the tool pushes is
flagged as collided, which holds its goal (seed 000 Alg. 1, lines 13-14). A grasper
whose jaws are closed holds the particles between them in its frame (seed 002
§3.4; :mod:`taichi_lap.kernels.grasp`).
"""

from __future__ import annotations

import numpy as np
import taichi as ti

from taichi_lap.core import fields
from taichi_lap.core.fields import FieldGroup, FieldOwner
from taichi_lap.core.frames import frame_towards, turned_about_axis
from taichi_lap.core.instruments import (
    JAW_RADIUS,
    MAX_TOOL_SHAPES,
    MAX_TOOLS,
    SHAPE_KINDS,
    ToolGeometry,
    ToolShape,
)
from taichi_lap.core.topology import MAX_ORGANS
from taichi_lap.kernels.collision.tool_shapes import ToolPose, interpolate_tools, place_tool


def shape_rows(shapes) -> tuple[np.ndarray, ...]:
    """One tool's rows of the shape table: kinds (S,) and a, b, size (S, 3), the
    slots after ``shapes`` empty."""
    kind = np.zeros(MAX_TOOL_SHAPES, dtype=np.int32)
    a, b, size = (np.zeros((MAX_TOOL_SHAPES, 3), dtype=np.float32) for _ in range(3))
    for slot, shape in enumerate(shapes):
        kind[slot] = SHAPE_KINDS[shape.kind]
        a[slot], b[slot], size[slot] = shape.a, shape.b, shape.size
    return kind, a, b, size


@ti.data_oriented
class Control(FieldOwner):
    """Tools: the shaft from ``tool_a`` (tip) to ``tool_b`` [m] of ``tool_radius``
    [m], the jaws from ``tool_jaw`` [m] (ahead of the tip) to the tip of
    ``tool_jaw_radius`` [m] (0: no jaws), ``tool_active``, ``tool_frame`` (columns x, y,
    tip-to-handle); the shape table (``shape_kind``, ``shape_a``, ``shape_b``,
    ``shape_size``, :data:`MAX_TOOL_SHAPES` rows per tool, in the tool frame) and
    ``tool_reach`` [m], how far from the tip the shapes placed in the frame reach; per
    tool on the Python side ``tips`` [m], ``frames`` and ``rolls`` [rad] (as last
    placed), ``grasp``
    (jaws closed) and ``jaw_length`` [m]. Every tool
    starts as jaws and shaft (the jaws are nothing while ``tool_jaw_radius`` is 0).

    A tool moves within a step: :meth:`set_tool` keeps the pose it leaves
    (``tool_start``) and the one it goes to (``tool_goal``); the solver places it in
    between for every substep (:meth:`advance`), ``tool_last`` holding its pose at
    the substep's start. Between steps the Control entry is the goal.
    ``tool_reaction`` [N]: the force the tissue pushes a tool with, and
    ``tool_contacts`` (a row per tool, a column per organ): the particles of each organ
    touching it, where :meth:`Solver.tool_contact` measured them."""

    def __init__(self):
        group = FieldGroup()
        self.tool_a = group.field(ti.f32, MAX_TOOLS, vector=3)
        self.tool_b = group.field(ti.f32, MAX_TOOLS, vector=3)
        self.tool_radius = group.field(ti.f32, MAX_TOOLS)
        self.tool_active = group.field(ti.i32, MAX_TOOLS)
        self.tool_frame = group.field(ti.f32, MAX_TOOLS, matrix=(3, 3))
        self.tool_jaw = group.field(ti.f32, MAX_TOOLS, vector=3)
        self.tool_jaw_radius = group.field(ti.f32, MAX_TOOLS)
        default = shape_rows((ToolShape("jaws"), ToolShape("shaft")))
        for name, rows in zip(("kind", "a", "b", "size"), default):
            table = np.tile(rows, (MAX_TOOLS,) + (1,) * (rows.ndim - 1))
            dtype, vector = (ti.i32, 0) if rows.ndim == 1 else (ti.f32, 3)
            setattr(
                self, f"shape_{name}", group.field(dtype, len(table), vector=vector, values=table)
            )
        self.tool_reach = group.field(ti.f32, MAX_TOOLS)
        self.tool_start = group.field(ToolPose, MAX_TOOLS)
        self.tool_goal = group.field(ToolPose, MAX_TOOLS)
        self.tool_last = group.field(ToolPose, MAX_TOOLS)
        self.tool_reaction = group.field(ti.f32, MAX_TOOLS, vector=3)
        self.tool_contacts = group.field(ti.i32, MAX_TOOLS, columns=MAX_ORGANS)
        group.finalize()
        self._group = group
        self.frames = [np.eye(3) for _ in range(MAX_TOOLS)]
        self.rolls = [0.0] * MAX_TOOLS
        self.tips = [np.zeros(3) for _ in range(MAX_TOOLS)]
        self.grasp = [False] * MAX_TOOLS
        self.jaw_length = [0.0] * MAX_TOOLS
        self._jump = [True] * MAX_TOOLS

    def set_tool(
        self,
        index: int,
        tip,
        tail,
        radius: float,
        active: bool = True,
        *,
        grasp: bool = False,
        jaw_length: float = 0.0,
        roll: float = 0.0,
    ):
        """Place tool ``index`` as a capsule from ``tip`` to ``tail`` [m]; its frame is
        the previous one turned onto the new axis, then about it by how much ``roll``
        [rad] changed since the last placement (the frame follows from the path of the
        axis and the roll alone, so a replayed run rebuilds it). Jaws of
        ``jaw_length`` [m] (0: none) collide as a capsule ahead of the tip; ``grasp``
        closes them."""
        if not 0 <= index < MAX_TOOLS:
            raise IndexError(f"tool index {index} outside 0..{MAX_TOOLS - 1}")
        tip, tail = np.asarray(tip, dtype=np.float64), np.asarray(tail, dtype=np.float64)
        if np.linalg.norm(tail - tip) > 0.0:
            self.frames[index] = frame_towards(self.frames[index], tail - tip)
        self.frames[index] = turned_about_axis(self.frames[index], roll - self.rolls[index])
        self.rolls[index] = float(roll)
        frame = self.frames[index]
        self.tips[index] = tip
        place_tool(
            self,
            index,
            tip,
            tail,
            float(radius),
            int(active),
            frame,
            tip - jaw_length * frame[:, 2],
            JAW_RADIUS * float(radius) if jaw_length > 0.0 else 0.0,
            int(self._jump[index] or not active),
        )
        self._jump[index] = not active
        self.grasp[index] = bool(grasp and active)
        self.jaw_length[index] = float(jaw_length)

    def set_tool_shapes(self, index: int, shapes):
        """Make tool ``index`` the union of ``shapes`` (at most :data:`MAX_TOOL_SHAPES`
        :class:`~taichi_lap.core.instruments.ToolShape`, in its frame [m]); ``shaft``
        and ``jaws`` follow :meth:`set_tool`."""
        if not 0 <= index < MAX_TOOLS:
            raise IndexError(f"tool index {index} outside 0..{MAX_TOOLS - 1}")
        geometry = ToolGeometry(tuple(shapes), length=0.0, radius=0.0)
        rows = slice(index * MAX_TOOL_SHAPES, (index + 1) * MAX_TOOL_SHAPES)
        targets = (self.shape_kind, self.shape_a, self.shape_b, self.shape_size)
        tables = fields.read(targets)
        for table, values in zip(tables, shape_rows(geometry.shapes)):
            table[rows] = values
        fields.write(zip(targets, tables))
        self.tool_reach[index] = geometry.reach()

    def advance(self, begin: float, end: float):
        """Place every tool for a substep from fraction ``begin`` to ``end`` of the way
        from where it was before the last :meth:`set_tool` to where that put it
        (:func:`~taichi_lap.kernels.collision.tool_shapes.interpolate_tools`)."""
        interpolate_tools(self, begin, end)

    def reset(self):
        """Forget the tools' frames and motion, open every grasper and take every tool
        out (inactive until :meth:`set_tool` places it again: a session that reuses a
        closed one's Control gets only its own scene's tools)."""
        self.tool_active.fill(0)
        self.frames = [np.eye(3) for _ in range(MAX_TOOLS)]
        self.rolls = [0.0] * MAX_TOOLS
        self.tips = [np.zeros(3) for _ in range(MAX_TOOLS)]
        self.grasp = [False] * MAX_TOOLS
        self._jump = [True] * MAX_TOOLS
