"""Instruments: the one definition of a tool's shape that particle contacts, tissue
collision, the haptic proxy and the drawn instrument meshes all use.

Seed 000 §5.1 represents the working part of an instrument by "a combination of
implicit shapes" (column, sphere, polyhedron). A tool here is a union of at most
:data:`MAX_TOOL_SHAPES` shapes in its tool frame (origin at the tip, columns x, y and
z, z from the tip towards the handle):

* ``shaft`` — the capsule from the tip ``length`` [m] towards the handle, of the
  tool's ``radius`` [m] (placed by the device's tip and tail every frame);
* ``jaws`` — the closed jaws of graspers and scissors, the capsule from
  :data:`JAW_LENGTH` shaft radii ahead of the tip to the tip, of :data:`JAW_RADIUS`
  shaft radii (nothing for other instruments);
* ``sphere`` — centre ``a``, radius ``size[0]``;
* ``capsule`` — segment ``a``-``b``, radius ``size[0]``;
* ``box`` — centre ``a``, half extents ``size``, along the frame's axes.

The distance of a union is the minimum over its shapes; its gradient is the nearest
shape's, pointing out of the tool. Kernels evaluate the table a
:class:`~taichi_lap.sim.control.Control` holds
(:mod:`taichi_lap.kernels.collision.tool_shapes`); :func:`tool_distance` is the same
evaluation in NumPy. All lengths in metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MAX_TOOLS = 4
"""Tools a scene and a Control hold (kernels unroll their tool loop over them)."""
MAX_TOOL_SHAPES = 4
"""Shapes one tool's union holds."""

TOOL_KINDS = ("probe", "grasper", "scissors", "hook", "dissector")
JAW_KINDS = ("grasper", "scissors")
"""Instruments with two closed jaws ahead of the tip (seed 002 §3.4)."""
JAW_LENGTH = 4.0
"""Length of a grasper's jaws ahead of its tip, in shaft radii (drawn and grasping)."""
JAW_REACH = 1.5
"""How far from their axis the open jaws take tissue, in shaft radii."""
JAW_RADIUS = 0.7
"""Radius of the closed jaws' capsule, in shaft radii."""
DISSECTOR_REACH = 1.5
"""A blunt dissector removes the tissue particles within this many shaft radii of its
tip's centre: those its tip presses on (contact keeps them at one radius)."""
HOOK_STEM = 2.5
"""An electrocautery hook's electrode runs this many shaft radii ahead of the tip (a
5 mm L-hook's wire reaches about 6 mm beyond its insulated shaft) ..."""
HOOK_FOOT = 1.5
"""... then bends by a right angle, along the tool frame's x, for this many shaft radii
(the L's foot, about 4 mm)."""
HOOK_WIRE = 0.3
"""Radius of the hook's electrode wire, in shaft radii (under 1 mm)."""
HOOK_HEAT_GAP = 0.2
"""An energised hook heats the tissue particles whose cell (half the lattice spacing
around them) reaches within this many shaft radii of its electrode's surface (stem
and foot): those the wire touches, where it rests on the surface between them."""
CUT_REACH = 0.2
"""A cutting shape reaches this many shaft radii beyond the shape the tissue touches
(:func:`cutting_geometry`)."""
GRASP_BUTTON = 1
"""Bitmask of the button that closes a grasper's jaws (button 1, as on a stylus)."""
CAUTERY_BUTTON = 2
"""Bitmask of the button that energises a hook (button 2: the foot pedal's role)."""

SHAPE_NONE, SHAPE_SHAFT, SHAPE_SPHERE, SHAPE_CAPSULE, SHAPE_BOX, SHAPE_JAWS = range(6)
SHAPE_KINDS = {
    "shaft": SHAPE_SHAFT,
    "jaws": SHAPE_JAWS,
    "sphere": SHAPE_SPHERE,
    "capsule": SHAPE_CAPSULE,
    "box": SHAPE_BOX,
}
FAR = 1e9
"""A distance beyond anything in a scene [m] (an empty shape slot's distance)."""


@dataclass(frozen=True)
class ToolShape:
    """One shape of a tool's union (module docstring): ``kind`` a key of
    :data:`SHAPE_KINDS`; ``a``, ``b``, ``size`` in the tool frame [m] (unused for
    ``shaft`` and ``jaws``, which the tool's dimensions place)."""

    kind: str
    a: tuple[float, float, float] = (0.0, 0.0, 0.0)
    b: tuple[float, float, float] = (0.0, 0.0, 0.0)
    size: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        if self.kind not in SHAPE_KINDS:
            raise ValueError(
                f"ToolShape.kind: one of {', '.join(SHAPE_KINDS)} was expected, found {self.kind!r}"
            )

    @classmethod
    def sphere(cls, center, radius: float) -> ToolShape:
        return cls("sphere", tuple(center), tuple(center), (radius, 0.0, 0.0))

    @classmethod
    def capsule(cls, a, b, radius: float) -> ToolShape:
        return cls("capsule", tuple(a), tuple(b), (radius, 0.0, 0.0))

    @classmethod
    def box(cls, center, half_extents) -> ToolShape:
        return cls("box", tuple(center), tuple(center), tuple(np.broadcast_to(half_extents, 3)))


@dataclass(frozen=True)
class ToolGeometry:
    """A tool's union of shapes and the dimensions that place ``shaft`` and ``jaws``:
    shaft ``length`` and ``radius`` [m], jaws ``jaw_length`` ahead of the tip and
    ``jaw_radius`` [m] (both 0 without jaws)."""

    shapes: tuple[ToolShape, ...]
    length: float
    radius: float
    jaw_length: float = 0.0
    jaw_radius: float = 0.0

    def __post_init__(self):
        if not 1 <= len(self.shapes) <= MAX_TOOL_SHAPES:
            raise ValueError(f"a tool has 1 to {MAX_TOOL_SHAPES} shapes, found {len(self.shapes)}")
        for name in ("length", "radius", "jaw_length", "jaw_radius"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0.0):
                raise ValueError(
                    f"ToolGeometry.{name}: a non-negative length [m] was expected, found {value!r}"
                )

    def round_shapes(self) -> list[tuple[np.ndarray, np.ndarray, float]]:
        """Every shaft, jaws, sphere and capsule as a segment (a, b) and radius, in the
        tool frame (jaws of length 0 are left out)."""
        out = []
        for shape in self.shapes:
            if shape.kind == "shaft":
                out.append((np.zeros(3), np.array([0.0, 0.0, self.length]), self.radius))
            elif shape.kind == "jaws" and self.jaw_length > 0.0:
                out.append((np.array([0.0, 0.0, -self.jaw_length]), np.zeros(3), self.jaw_radius))
            elif shape.kind in ("sphere", "capsule"):
                out.append((np.asarray(shape.a, float), np.asarray(shape.b, float), shape.size[0]))
        return out

    def boxes(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Every box as (centre, half extents) in the tool frame."""
        return [
            (np.asarray(s.a, float), np.asarray(s.size, float))
            for s in self.shapes
            if s.kind == "box"
        ]

    def reach(self) -> float:
        """How far [m] from the tip any shape but the shaft reaches (the tool's extent
        ahead of and around the tip, beyond the shaft's capsule)."""
        reach = 0.0
        for shape in self.shapes:
            a, b, size = (np.linalg.norm(v) for v in (shape.a, shape.b, shape.size))
            if shape.kind == "jaws" and self.jaw_length > 0.0:
                reach = max(reach, self.jaw_length + self.jaw_radius)
            elif shape.kind in ("sphere", "capsule"):
                reach = max(reach, max(a, b) + shape.size[0])
            elif shape.kind == "box":
                reach = max(reach, a + size)
        return reach


def tool_geometry(tool) -> ToolGeometry:
    """The shapes of a scene tool (a ``[[tools]]`` table: ``kind``, shaft ``radius``
    and ``length`` [m]): the jaws of graspers and scissors, or the L-shaped electrode
    of a hook (:func:`hook_electrode`, wire of HOOK_WIRE radii), then the shaft."""
    kind, radius, length = tool["kind"], float(tool["radius"]), float(tool["length"])
    if kind in JAW_KINDS:
        return ToolGeometry(
            (ToolShape("jaws"), ToolShape("shaft")),
            length,
            radius,
            JAW_LENGTH * radius,
            JAW_RADIUS * radius,
        )
    if kind == "hook":
        stem, foot = hook_electrode(radius)
        wire = HOOK_WIRE * radius
        return ToolGeometry(
            (ToolShape.capsule(*foot, wire), ToolShape.capsule(*stem, wire), ToolShape("shaft")),
            length,
            radius,
        )
    return ToolGeometry((ToolShape("shaft"),), length, radius)


def cutting_geometry(tool) -> ToolGeometry | None:
    """The part of a scene tool that cuts sheets (seed 000 §5.1, the "implicit shapes"
    swept by :class:`~taichi_lap.dissection.surface_cut.Sweep`), or None for a tool
    that does not cut: the closed jaws of scissors and the electrode of a hook, each
    :data:`CUT_REACH` shaft radii thicker than the shape the tissue touches (the
    contact keeps the tissue on that shape's surface, where a cut of the shape alone
    would never reach it)."""
    kind, radius, length = tool["kind"], float(tool["radius"]), float(tool["length"])
    reach = CUT_REACH * radius
    if kind == "scissors":
        jaws = (np.array([0.0, 0.0, -JAW_LENGTH * radius]), np.zeros(3))
        shapes = (ToolShape.capsule(*jaws, JAW_RADIUS * radius + reach),)
    elif kind == "hook":
        wire = HOOK_WIRE * radius + reach
        shapes = tuple(ToolShape.capsule(*segment, wire) for segment in hook_electrode(radius))
    else:
        return None
    return ToolGeometry(shapes, length, radius)


def hook_electrode(radius: float) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    """The L-shaped electrode of a hook of shaft ``radius`` [m] as two segments in the
    tool frame: the stem from the tip straight ahead (-z) for HOOK_STEM radii, then the
    foot along +x for HOOK_FOOT radii."""
    bend = np.array([0.0, 0.0, -HOOK_STEM * radius])
    foot_end = bend + np.array([HOOK_FOOT * radius, 0.0, 0.0])
    return (np.zeros(3), bend), (bend, foot_end)


def tool_distance(
    geometry: ToolGeometry,
    points: np.ndarray,
    tip: np.ndarray | None = None,
    rotation: np.ndarray | None = None,
    *,
    gradients: bool = True,
) -> tuple[np.ndarray, ...]:
    """Signed distances [m] of ``points`` (n, 3) from the union of ``geometry``'s shapes
    placed at ``tip`` [m] with the tool frame ``rotation`` (3×3, columns; default: the
    points are in the tool frame); the unit gradients (n, 3) of the nearest shape (out
    of the tool); and a flag per point that lies on a round shape's axis, where the
    gradient is undefined (zero there). ``gradients=False``: the distances alone (None
    for the rest; the haptic proxy's cluster test runs this every 1 kHz tick)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    tip = np.zeros(3) if tip is None else np.asarray(tip, dtype=np.float64)
    rotation = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
    dist = np.full(len(points), FAR)
    grad = np.zeros((len(points), 3)) if gradients else None
    on_axis = np.zeros(len(points), dtype=bool) if gradients else None
    for a, b, r in geometry.round_shapes():  # placed in the world, the points stay
        ab = rotation @ (b - a)
        offset = points - (tip + rotation @ a)
        t = np.clip(offset @ ab / max(ab @ ab, 1e-30), 0.0, 1.0)
        offset -= np.multiply.outer(t, ab)
        length = np.sqrt(np.einsum("ij,ij->i", offset, offset))
        d = length - r
        nearer = d < dist
        dist[nearer] = d[nearer]
        if gradients:
            axial = length[nearer] < 1e-9
            g = offset[nearer] / np.maximum(length[nearer], 1e-30)[:, None]
            g[axial] = 0.0
            grad[nearer], on_axis[nearer] = g, axial
    boxes = geometry.boxes()
    local = (points - tip) @ rotation if boxes else points
    for center, half in boxes:
        offset = local - center
        q = np.abs(offset) - half
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
        d = outside + np.minimum(q.max(axis=1), 0.0)
        nearer = d < dist
        dist[nearer] = d[nearer]
        if gradients:
            side = np.where(offset >= 0.0, 1.0, -1.0)
            g = side * np.maximum(q, 0.0) / np.maximum(outside, 1e-30)[:, None]
            inside = outside <= 0.0
            face = np.argmax(q, axis=1)
            g[inside] = 0.0
            g[inside, face[inside]] = side[inside, face[inside]]
            grad[nearer], on_axis[nearer] = g[nearer] @ rotation.T, False
    return dist, grad, on_axis
