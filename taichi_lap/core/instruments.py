"""The instruments every layer shares: how many tools a scene may hold, the kinds of
instrument, and the jaws of graspers and scissors (lengths in shaft radii)."""

MAX_TOOLS = 4
"""Tools a scene and a Control hold (kernels unroll their tool loop over them)."""

TOOL_KINDS = ("probe", "grasper", "scissors", "hook")
JAW_KINDS = ("grasper", "scissors")
"""Instruments with two closed jaws ahead of the tip (seed 002 §3.4)."""
JAW_LENGTH = 4.0
"""Length of a grasper's jaws ahead of its tip, in shaft radii (drawn and grasping)."""
JAW_REACH = 1.5
"""How far from their axis the open jaws take tissue, in shaft radii."""
JAW_RADIUS = 0.7
"""Radius of the closed jaws' capsule, in shaft radii (half the drawn jaws' width)."""
