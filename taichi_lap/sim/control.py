"""Inputs to a step (the Warp/Newton ``Control``): kinematic tool capsules.

Each tool is a capsule from its tip ``a`` to ``b`` with radius [m], placed by a
device (mouse, script, haptic) before every frame. A particle the tool pushes is
flagged as collided, which holds its goal (seed 000 Alg. 1, line 13-14).
"""

from __future__ import annotations

import numpy as np
import taichi as ti

from taichi_lap.kernels.contact import MAX_TOOLS
from taichi_lap.sim.fields import FieldGroup

__all__ = ["Control", "MAX_TOOLS"]


@ti.data_oriented
class Control:
    """Tool capsules: ``tool_a``, ``tool_b`` [m], ``tool_radius`` [m], ``tool_active``."""

    def __init__(self):
        group = FieldGroup()
        self.tool_a = group.field(ti.f32, MAX_TOOLS, vector=3)
        self.tool_b = group.field(ti.f32, MAX_TOOLS, vector=3)
        self.tool_radius = group.field(ti.f32, MAX_TOOLS)
        self.tool_active = group.field(ti.i32, MAX_TOOLS)
        group.finalize()

    def set_tool(self, index: int, tip, tail, radius: float, active: bool = True):
        """Place tool ``index`` as a capsule from ``tip`` to ``tail`` [m]."""
        if not 0 <= index < MAX_TOOLS:
            raise IndexError(f"tool index {index} outside 0..{MAX_TOOLS - 1}")
        self.tool_a[index] = np.asarray(tip, dtype=np.float32)
        self.tool_b[index] = np.asarray(tail, dtype=np.float32)
        self.tool_radius[index] = float(radius)
        self.tool_active[index] = int(active)

    def clear_tool(self, index: int):
        self.tool_active[index] = 0
