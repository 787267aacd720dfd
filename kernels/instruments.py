"""Instrument geometry for drawing: points strung along each tool capsule."""

import taichi as ti

from taichi_lap.kernels.contact import MAX_TOOLS


@ti.kernel
def capsule_beads(control: ti.template(), beads: ti.template(), radius: ti.template(),
                  beads_per_tool: ti.i32):
    """``beads_per_tool`` points from tip to tail of every tool capsule; the radius
    of an inactive tool's beads is 0. Reads control; writes beads, radius."""
    for k, j in ti.ndrange(MAX_TOOLS, beads_per_tool):
        s = k * beads_per_tool + j
        a, b = control.tool_a[k], control.tool_b[k]
        beads[s] = a + (b - a) * (j / (beads_per_tool - 1))
        radius[s] = control.tool_radius[k] * control.tool_active[k]
