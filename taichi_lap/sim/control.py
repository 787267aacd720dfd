"""Inputs to a step (the Warp/Newton ``Control``): kinematic tool capsules and
grasp commands.

Each tool is a capsule from its tip ``a`` to ``b`` with radius [m], placed by a
device (mouse, script, haptic) before every frame, with an orthonormal frame whose
third column points from the tip towards the handle. A particle the tool pushes is
flagged as collided, which holds its goal (seed 000 Alg. 1, lines 13-14). A grasper
whose jaws are closed holds the particles between them in its frame (seed 002
§3.4; :mod:`taichi_lap.kernels.grasp`).
"""

from __future__ import annotations

import numpy as np
import taichi as ti

from taichi_lap.core.instruments import JAW_RADIUS, MAX_TOOLS
from taichi_lap.core.fields import FieldGroup


def frame_towards(frame: np.ndarray, direction) -> np.ndarray:
    """``frame`` (3×3, columns) turned by the smallest rotation that takes its third
    column onto the unit ``direction``, so a tool's roll does not jump as it turns."""
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    z = frame[:, 2]
    axis = np.cross(z, d)
    s, c = np.linalg.norm(axis), float(np.dot(z, d))
    if s < 1e-12:
        if c > 0.0:
            return frame.copy()
        return frame @ np.diag([1.0, -1.0, -1.0])  # half turn about the frame's x
    k = axis / s
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    rotation = np.eye(3) + s * cross + (1.0 - c) * cross @ cross
    return rotation @ frame


@ti.data_oriented
class Control:
    """Tool capsules: the shaft from ``tool_a`` (tip) to ``tool_b`` [m] of ``tool_radius``
    [m], the jaws from ``tool_jaw`` [m] (ahead of the tip) to the tip of
    ``tool_jaw_radius`` [m] (0: no jaws), ``tool_active``, ``tool_frame`` (columns x, y,
    tip-to-handle); per tool on the Python side ``grasp`` (jaws closed) and
    ``jaw_length`` [m]."""

    def __init__(self):
        group = FieldGroup()
        self.tool_a = group.field(ti.f32, MAX_TOOLS, vector=3)
        self.tool_b = group.field(ti.f32, MAX_TOOLS, vector=3)
        self.tool_radius = group.field(ti.f32, MAX_TOOLS)
        self.tool_active = group.field(ti.i32, MAX_TOOLS)
        self.tool_frame = group.field(ti.f32, MAX_TOOLS, matrix=(3, 3))
        self.tool_jaw = group.field(ti.f32, MAX_TOOLS, vector=3)
        self.tool_jaw_radius = group.field(ti.f32, MAX_TOOLS)
        group.finalize()
        self.frames = [np.eye(3) for _ in range(MAX_TOOLS)]
        self.grasp = [False] * MAX_TOOLS
        self.jaw_length = [0.0] * MAX_TOOLS

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
    ):
        """Place tool ``index`` as a capsule from ``tip`` to ``tail`` [m]; its frame is
        the previous one turned onto the new axis (the roll follows from the path of
        the axis alone, so a replayed run rebuilds it). Jaws of ``jaw_length`` [m] (0:
        none) collide as a capsule ahead of the tip; ``grasp`` closes them."""
        if not 0 <= index < MAX_TOOLS:
            raise IndexError(f"tool index {index} outside 0..{MAX_TOOLS - 1}")
        tip, tail = np.asarray(tip, dtype=np.float64), np.asarray(tail, dtype=np.float64)
        if np.linalg.norm(tail - tip) > 0.0:
            self.frames[index] = frame_towards(self.frames[index], tail - tip)
        frame = self.frames[index]
        self.tool_a[index] = tip.astype(np.float32)
        self.tool_b[index] = tail.astype(np.float32)
        self.tool_radius[index] = float(radius)
        self.tool_active[index] = int(active)
        self.tool_frame[index] = frame.astype(np.float32)
        self.tool_jaw[index] = (tip - jaw_length * frame[:, 2]).astype(np.float32)
        self.tool_jaw_radius[index] = JAW_RADIUS * float(radius) if jaw_length > 0.0 else 0.0
        self.grasp[index] = bool(grasp and active)
        self.jaw_length[index] = float(jaw_length)

    def reset(self):
        """Forget the tools' frames and open every grasper."""
        self.frames = [np.eye(3) for _ in range(MAX_TOOLS)]
        self.grasp = [False] * MAX_TOOLS

    def clear_tool(self, index: int):
        self.tool_active[index] = 0
        self.grasp[index] = False
