"""Contact benchmark: do the instruments push tissue as drawn?

Cases
* ``press-<model>-<collision>``: a probe (radius 3 mm, length 0.1 m, axis vertical)
  starts with the bottom of its tip 1 mm above the drawn surface of a small test
  body and moves straight down at a constant speed to ``depth`` below that surface,
  then holds still for 0.5 s. Test bodies (:func:`organ_table`):

  - ``tet_clusters``: the 40 x 24 x 30 mm test block (2 mm particle spacing), its
    base fixed;
  - ``shape_matching``: the same box as a surface mesh (2 mm edges), base fixed;
  - ``fascia_lra``: a flat 4 x 4 cm sheet (2 mm quads), its border anchored;
  - ``truss``: a straight vessel (radius 6 mm, 8 cm long), fixed at its ends;
  - ``mass_spring``: a short intestine (0.5 m, 20 masses per row) lying flat (the
    cylinder axis vertical), pressed on the drawn tube (radius 2 cm around row 0)
    midway between two masses;
  - ``mesentery``: the same organ pressed on the mesentery between rows 1 and 2.

  Collision settings ``off``, ``polygon`` and ``circumsphere`` (the scene's
  ``collision``), each under two solver settings, 4 substeps with material damping 6
  and eta_on_contact 0.7 and 1 substep with damping 0 and eta_on_contact 1 (models
  without eta take only the damping). One session per (model, collision, solver)
  serves all its presses (``Session.reset`` between them): depths 2, 4, 8 mm, and
  20 mm where the body is thicker than that under the tool, at 5 mm/s and 0.25 m/s
  (``--quick``: tet_clusters and mass_spring, collision off, 4 substeps, 4 mm at
  5 mm/s).
* ``press-<model>-off-<kind>`` (not with ``--quick``): the same presses by a
  grasper (its jaws' capsule, 12 mm ahead of the tip, radius 2.1 mm, presses;
  scissors have the same shapes) and an electrocautery hook (not energised; the foot
  of its wire, 0.9 mm in radius, presses) of the probe's shaft, into the block and
  the sheet, collision off.
* ``haptic-press-<d>mm``: a scripted haptic stylus (``HapticBridge``, servo process
  at 1 kHz) pressed into the tet_clusters block (circumsphere collision, 4 substeps,
  damping 6, eta_on_contact 0.7) at 5 mm/s to ``d`` = 2, 4, 8, 20 mm below the top
  (``--quick``: 4 mm, in the press session: collision off) and held for 1.5 s of
  wall time once the stylus got there; the scene tool is the bridge's, coupled to
  the stylus by the tissue's push (:mod:`taichi_lap.haptics.bridge`).
* ``haptic-inside-4mm`` (not with ``--quick``): the same stylus held 4 mm inside the
  block from the session's start.
* ``sweep-intestine`` (not with ``--quick``): the built-in intestine scene and its
  scripted probe, 180 frames.

Metrics
* ``indent_ratio`` (press cases: median, min and max over the presses; haptic: one
  press): displacement of the drawn surface under the tool divided by the tool's
  depth below it. Both come from the drawn surface along the tool axis: h0 and h1,
  the height of the first surface hit by a ray cast straight down the axis from
  above, at the start and after the hold; the depth is h0 minus the tool's lowest
  point (tip height minus radius: the bottom of the tip sphere of a vertical probe)
  after the hold, and the displacement is h0 - h1. 1 is "as drawn", below 1 the tool
  went into the drawn tissue (slip-through), above 1 the tissue moved away from the
  tool (over-push). A loose body (the intestine) that a fast press flings off the
  tool as the tool stops is not pushed by the contact but carried by its momentum
  (inelastic contact gives it the tool's speed): where the surface touched the tool
  (within TOUCH_GAP = 0.5 mm below its lowest point) while the tool was at least
  half its depth deep, left it as the tool stopped (in the frame the tool reached its
  end or the next) at over 2.5 cm/s, and does not touch it after the hold, the ratio is
  that of the last frame it touched, and how far it flew off (the gap after the hold)
  is the press's ``flight_mm``. A surface the contact pushed ahead of the tool, or one
  that crept away from the stopped tool, is judged after the hold.
  The drawn surface is the skinned surface
  (``State.surface_position`` with the model's surface triangles); for a mass-spring
  organ also the tube of its row-0 radius around row 0 (a chain of capsules), the
  higher of the two counting as the first hit. The axis is the vertical line through
  the tool's lowest point (the tip of a probe or of closed jaws, the middle of a
  hook's foot).
  The haptic depth uses the tool the simulation contacts with, the Control's, which
  follows the graphical pose (not the stylus). The indent_ratio rows carry each
  press (``presses``) and the haptic rows what the press did (``tool_depth_mm``,
  ``stylus_depth_mm``, ``indent_mm``, ...) beside the usual keys.
* ``flight_mm``: how far the tissue flew off the stopped tool, per press (0 where it
  stayed against it).
* ``faults``: presses that raised ``SimulationFault`` (they end and get no
  indent_ratio; the session is reset for the next press). The row says whether the
  body also faults within 1 s with the tool held clear of it
  (``faults_without_contact``), i.e. whether the faults are the contact's.
* ``ms_per_frame``: ``Session.step`` wall time over every frame of the case's presses.
* ``force_n`` (haptic): magnitude of the force the servo sent to the device, median
  (min, max) over the frames of the last 0.5 s (simulated) of the hold;
  ``contact_force_n``: the same of the force the coupling asked for, before the
  safety filter (device limit, rate limit, and the watchdog, which fades the force
  out when a frame takes over 100 ms of wall time, as on a loaded machine).
* ``frames_inside`` (sweep): frames in which the probe's shaft capsule comes closer to
  the row-0 centre line than tube radius + tool radius - 2 mm (the shaft inside the
  drawn tube); ``min_gap_mm``: the smallest centre-line-to-shaft distance minus
  (tube radius + tool radius).

Usage: python perf/bench_contact.py [--quick] [--arch cpu] [--json OUT]
"""

from __future__ import annotations

import math
import statistics
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from taichi_lap.perf.common import arguments, report, result

BOX = {
    "name": "block",
    "model": "tet_clusters",
    "geometry": {"generator": "box", "half_extents": [0.02, 0.012, 0.015]},
    "material": {
        "particle_spacing": 0.004,
        "stiffness": 0.5,
        "damping": 0.0,
        "recover_rate": 0.05,
        "eta_on_contact": 1.0,
    },
}
"""The test block of the unit tests."""
HALF = BOX["geometry"]["half_extents"]
SPACING = 0.002  # [m] particle spacing / mesh edge of the test bodies
PROBE_RADIUS = 0.003  # [m]
PROBE_LENGTH = 0.1  # [m]
GAP = 0.001  # [m] from the bottom of the tip to the drawn surface at the start
TOUCH_GAP = 0.0005  # [m] the drawn surface within this below the tool touches it
HELD_DEPTH = 0.5
FLIGHT_FRAMES = 1
FLIGHT_SPEED = 0.025  # [m/s]
"""A tissue that touched the tool down to HELD_DEPTH of the press depth and left it
as the tool stopped (touching it no later than FLIGHT_FRAMES frames into the hold),
at over FLIGHT_SPEED (five times a careful push), flew off it: it is judged where it
last touched (module docstring). Tissue that creeps away from a stopped tool is not
flying: measured, the test block left the probe at 14 mm/s after a slow 20 mm push
(4 substeps), the loose intestine at 41 mm/s (1 substep) and 118 mm/s (4 substeps)
after a 2 mm tap at 0.25 m/s."""
HOLD = 0.5  # [s] of simulated time after each press
DEPTHS = (0.002, 0.004, 0.008)  # [m]
DEEP = 0.020  # [m] the deep press, for bodies thicker than this under the tool
SPEEDS = (0.005, 0.25)  # [m/s]
SOLVERS = ((4, 6.0, 0.7), (1, 0.0, 1.0))
"""(substeps, damping, eta_on_contact) of the two solver settings."""
COLLISIONS = ("off", "polygon", "circumsphere")
MODELS = ("tet_clusters", "shape_matching", "fascia_lra", "truss", "mass_spring", "mesentery")
INSTRUMENTS = ("grasper", "hook")
"""Instruments pressed like the probe (jaws closed or open alike: their closed jaws'
capsule is always part of the tool; scissors have the grasper's shapes,
:func:`~taichi_lap.core.instruments.tool_geometry`; the hook not energised)."""
INSTRUMENT_MODELS = ("tet_clusters", "fascia_lra")
"""The bodies the instruments press: a solid and a membrane (collision off)."""
INTESTINE_GEOMETRY = {
    "generator": "intestine",
    "length": 0.5,
    "cylinder_radius": 0.15,
    "vessel_length": 0.1,
    "folds": 1,
    "intestine_radius": 0.02,
    "mesentery_thickness": 0.01,
    "rows": 4,
    "points_per_row": 20,
    "rotate": [90.0, 0.0, 0.0],  # cylinder axis vertical: the mesentery lies flat
}
HAPTIC = ("circumsphere", SOLVERS[0])
"""Collision and solver setting of the haptic presses (those of the contact issue)."""
HAPTIC_SPEED = 0.005  # [m/s]
# The hold and the force window are simulated time: the tool settles frame by frame (the
# bridge's admittance), and a loaded machine runs fewer frames in a second of wall time.
HAPTIC_HOLD = 1.5  # [s] of simulated time at depth
HAPTIC_FORCE_WINDOW = 0.5  # [s] of simulated time the force median is taken over
SWEEP_FRAMES = 180
INSIDE_MARGIN = 0.002  # [m]

_mesh_dir: tempfile.TemporaryDirectory | None = None


def box_mesh_file() -> str:
    """An OBJ of the test block's surface with edges of about SPACING, triangles
    facing out (the surface models take meshes, not the box solid); written once
    per process into a temporary directory."""
    global _mesh_dir
    if _mesh_dir is None:
        _mesh_dir = tempfile.TemporaryDirectory(prefix="bench_contact_")
    path = Path(_mesh_dir.name) / "box.obj"
    if path.is_file():
        return str(path)
    axes = [np.linspace(-h, h, max(1, round(2 * h / SPACING)) + 1) for h in HALF]
    vertices, triangles = [], []
    for normal_axis in range(3):
        u_axis, v_axis = [a for a in range(3) if a != normal_axis]
        us, vs = axes[u_axis], axes[v_axis]
        for side in (-1.0, 1.0):
            grid = np.zeros((len(us), len(vs), 3))
            grid[..., u_axis] = us[:, None]
            grid[..., v_axis] = vs[None, :]
            grid[..., normal_axis] = side * HALF[normal_axis]
            first = sum(len(v) for v in vertices)
            index = first + np.arange(len(us) * len(vs)).reshape(len(us), len(vs))
            vertices.append(grid.reshape(-1, 3))
            a, b = index[:-1, :-1].ravel(), index[1:, :-1].ravel()
            c, d = index[:-1, 1:].ravel(), index[1:, 1:].ravel()
            triangles.append(np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]))
    vertices, triangles = np.concatenate(vertices), np.concatenate(triangles)
    corners = vertices[triangles]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    inward = np.einsum("ij,ij->i", normal, corners.mean(axis=1)) < 0.0  # convex, centred
    triangles[inward] = triangles[inward][:, ::-1]
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in vertices.tolist()]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in triangles.tolist()]
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def organ_table(model: str, damping: float, eta: float) -> dict:
    """The test body of ``model`` (module docstring) with the solver setting's
    material damping and, for the cluster models, eta_on_contact."""
    base_fixed = {"kind": "fixed", "box_min": [-1, -1, -1], "box_max": [1, -HALF[1] + 0.001, 1]}
    if model == "tet_clusters":
        material = dict(
            BOX["material"], damping=damping, eta_on_contact=eta, particle_spacing=SPACING
        )
        return dict(BOX, material=material, attachments=[base_fixed])
    if model == "shape_matching":
        material = {k: v for k, v in BOX["material"].items() if k != "particle_spacing"}
        return {
            "name": "block",
            "model": "shape_matching",
            "geometry": {"mesh": box_mesh_file()},
            "material": dict(material, damping=damping, eta_on_contact=eta),
            "attachments": [base_fixed],
        }
    if model == "fascia_lra":
        edge = 0.0195  # [m] the border vertices of the 4 cm sheet lie beyond this
        border = [
            {"kind": "lra_anchor", "box_min": lo, "box_max": hi}
            for lo, hi in (
                ([-1, -1, -1], [-edge, 1, 1]),
                ([edge, -1, -1], [1, 1, 1]),
                ([-1, -1, -1], [1, 1, -edge]),
                ([-1, -1, edge], [1, 1, 1]),
            )
        ]
        return {
            "name": "fascia",
            "model": "fascia_lra",
            "geometry": {
                "generator": "sheet",
                "width": 0.04,
                "depth": 0.04,
                "resolution_x": 20,
                "resolution_z": 20,
                "sag": 0.0,
            },
            "material": {"mass": 0.005, "damping": damping},
            "attachments": border,
        }
    if model == "truss":
        return {
            "name": "vessel",
            "model": "truss",
            "geometry": {
                "generator": "vessel",
                "radius": 0.006,
                "segments_around": 16,
                "points": [[-0.04, 0.0, 0.0], [0.0, 0.0, 0.0], [0.04, 0.0, 0.0]],
            },
            "material": {"mass": 0.01, "cone_angle": 0.4, "damping": damping},
            "attachments": [
                {"kind": "fixed", "box_min": [-1, -1, -1], "box_max": [-0.03, 1, 1]},
                {"kind": "fixed", "box_min": [0.03, -1, -1], "box_max": [1, 1, 1]},
            ],
        }
    if model in ("mass_spring", "mesentery"):
        return {
            "name": "intestine",
            "model": "mass_spring",
            "geometry": dict(INTESTINE_GEOMETRY),
            "material": {"damping": damping},
            "attachments": [{"kind": "fixed", "rows": [-1]}],
        }
    raise ValueError(f"model: one of {', '.join(MODELS)} was expected, found {model!r}")


# ---- the drawn surface along a vertical axis (NumPy) ----


def ray_hits(vertices: np.ndarray, triangles: np.ndarray, x: float, z: float) -> np.ndarray:
    """Heights [m] where the vertical line through (x, z) crosses the triangles
    (Möller-Trumbore with the ray pointing down from above everything)."""
    if not len(triangles):
        return np.zeros(0)
    corners = np.asarray(vertices, dtype=np.float64)[triangles]
    top = float(corners[..., 1].max()) + 1.0
    origin, direction = np.array([x, top, z]), np.array([0.0, -1.0, 0.0])
    e1, e2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    p = np.cross(direction, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-18
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = origin - corners[:, 0]
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = (q @ direction) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    eps = 1e-9
    hit = ok & (u >= -eps) & (v >= -eps) & (u + v <= 1.0 + eps) & (t > 0.0)
    return top - t[hit]


def tube_span(centres: np.ndarray, radius: float, x: float, z: float, samples: int = 64):
    """(top, bottom) [m] of the vertical line through (x, z) inside the chain of
    capsules of ``radius`` around the polyline ``centres``; (nan, nan) if it misses."""
    a, b = centres[:-1], centres[1:]
    t = np.linspace(0.0, 1.0, samples + 1)[None, :, None]
    q = a[:, None] + t * (b - a)[:, None]  # (segments, samples, 3)
    h2 = (q[..., 0] - x) ** 2 + (q[..., 2] - z) ** 2
    inside = h2 <= radius * radius
    if not inside.any():
        return math.nan, math.nan
    half = np.sqrt(np.maximum(radius * radius - h2, 0.0))
    return float((q[..., 1] + half)[inside].max()), float((q[..., 1] - half)[inside].min())


def drawn_span(session, organ: int, x: float, z: float, positions=None, particles=None):
    """(top, bottom) [m] of the drawn surface of organ ``organ`` (its live triangles,
    a wound included) along the vertical line through (x, z): the first and last hit
    of a ray cast down from above
    (nan, nan if it misses). ``positions`` / ``particles``: surface vertex and
    particle positions to use instead of the session's current ones."""
    model = session.model
    data = model.data
    record = data.organs[organ]
    if positions is None:
        positions = session.state.surface_position.to_numpy()
    triangles = model.surface_triangles.to_numpy()  # as a dissection left them
    live = (triangles != 0).any(axis=1) & (model.surface_triangle_organ.to_numpy() == organ)
    heights = list(ray_hits(positions, triangles[live], x, z))
    if record.row_length:
        if particles is None:
            particles = session.state.x.to_numpy()
        start = record.particles[0]
        row = particles[start : start + record.row_length]
        top, bottom = tube_span(row, float(data.radius[start]), x, z)
        heights += [h for h in (top, bottom) if not math.isnan(h)]
    if not heights:
        return math.nan, math.nan
    return max(heights), min(heights)


def surface_height(session, organ: int, x: float, z: float, positions=None) -> float:
    """Height [m] of the drawn surface of organ ``organ`` where a ray cast straight
    down through (x, z) first meets it (nan where it misses)."""
    return drawn_span(session, organ, x, z, positions)[0]


# ---- the press ----


def _mm(metres: float) -> float | None:
    """Millimetres, rounded, or None where not finite (JSON has no nan)."""
    return round(float(metres) * 1e3, 3) if math.isfinite(metres) else None


class Target(NamedTuple):
    """Where a body is pressed: organ index, the tool axis' (x, z) [m], the drawn
    surface's height there at the start and the body's thickness under it [m]."""

    organ: int
    x: float
    z: float
    height: float
    thickness: float


def press_point(model: str, geometry) -> tuple[float, float]:
    """(x, z) [m] of the tool axis on the body's rest geometry: the middle of the
    block, sheet and vessel; on the intestine, midway between the two row-0 masses
    of its flattest segment (``mass_spring``), or the middle of the mesentery quad
    between rows 1 and 2 beside it (``mesentery``)."""
    if model not in ("mass_spring", "mesentery"):
        return 0.0, 0.0
    rows = geometry.rows
    inner = np.arange(2, rows.shape[1] - 3)  # away from the free ends
    k = int(inner[np.argmin(np.abs(rows[0, inner + 1, 1] - rows[0, inner, 1]))])
    if model == "mass_spring":
        corners = rows[0, k : k + 2]
    else:
        corners = rows[1:3, k : k + 2].reshape(-1, 3)
    centre = corners.mean(axis=0)
    return float(centre[0]), float(centre[2])


def start_height(model: str, geometry, x: float, z: float) -> float:
    """The rest geometry's drawn top at (x, z) [m], where the probe starts."""
    from taichi_lap.core.geometry import Solid, SpringSheet, TriangleMesh

    if isinstance(geometry, SpringSheet):
        from taichi_lap.preprocess.sheets import sheet_triangles

        rows, cols = geometry.rows.shape[:2]
        sheet = ray_hits(geometry.rows.reshape(-1, 3), sheet_triangles(rows, cols), x, z)
        tube = tube_span(geometry.rows[0], float(geometry.row_radius[0]), x, z)[0]
        return float(np.nanmax(np.concatenate([sheet, [tube]])))
    if isinstance(geometry, TriangleMesh):
        return float(ray_hits(geometry.vertices, geometry.triangles, x, z).max())
    assert isinstance(geometry, Solid)
    return float(geometry.bounds[1][1])


def probe_table(tip, kind: str = "probe") -> dict:
    """The pressing instrument: ``kind`` (a probe by default) of the probe's radius
    and length, axis vertical, its tip at ``tip`` [m]."""
    return {
        "name": kind,
        "kind": kind,
        "radius": PROBE_RADIUS,
        "length": PROBE_LENGTH,
        "tip": [float(c) for c in tip],
        "direction": [0.0, 1.0, 0.0],
    }


def tip_above_bottom(kind: str) -> float:
    """How far [m] the tip of a vertical ``kind`` (tip down) is above the tool's
    lowest point: the probe's radius, the closed jaws' length and radius, the hook's
    stem and wire."""
    from taichi_lap.core.instruments import tool_geometry

    geometry = tool_geometry(probe_table((0.0, 0.0, 0.0), kind))
    return max(r - min(a[2], b[2]) for a, b, r in geometry.round_shapes())


def press_scene(
    model: str,
    collision: str = "off",
    substeps: int = 4,
    damping=6.0,
    eta=0.7,
    *,
    kind: str = "probe",
):
    """(session, target) of the test body of ``model`` under ``collision`` and the
    solver setting, gravity off, the lowest point of the instrument ``kind`` 1 mm
    above the drawn surface at the press point (the scene's tool pose, so that a
    reset puts it there)."""
    from taichi_lap.preprocess.organs import make_geometry
    from taichi_lap.scene import from_tables
    from taichi_lap.session import Session

    organ = organ_table(model, damping, eta)
    bare = from_tables([organ], gravity=[0.0, 0.0, 0.0])
    geometry = make_geometry(bare.organs[0], bare.source)
    x, z = press_point(model, geometry)
    tip = (x, start_height(model, geometry, x, z) + GAP + tip_above_bottom(kind), z)
    scene = from_tables(
        [organ],
        tools=[probe_table(tip, kind)],
        gravity=[0.0, 0.0, 0.0],
        collision=collision,
        substeps=substeps,
    )
    session = Session(scene, use_cache=False, progress=False)
    session.step()  # compile the step's kernels (the tool is still clear of the body)
    session.reset()
    top, bottom = drawn_span(session, 0, x, z)
    return session, Target(0, x, z, top, top - bottom)


def tool_bottom(session) -> tuple[np.ndarray, float]:
    """Where [m] the instrument reaches lowest, as the simulation placed it, and that
    height [m]: the bottom of the round shape that reaches lowest (for a probe the
    tip sphere's, for a hook the middle of its foot's underside)."""
    from taichi_lap.core.instruments import tool_geometry

    tip = session.control.tool_a.to_numpy()[0].astype(np.float64)
    frame = session.control.tool_frame.to_numpy()[0].astype(np.float64)
    lowest, height = tip, math.inf
    for a, b, r in tool_geometry(session.scene.tools[0]).round_shapes():
        a, b = tip + frame @ a, tip + frame @ b
        bottom = min(a[1], b[1]) - r
        if bottom < height - 1e-9:
            level = abs(a[1] - b[1]) < 1e-9  # a level segment: its middle
            lowest, height = ((a + b) / 2 if level else min(a, b, key=lambda p: p[1])), bottom
    return lowest, float(height)


class Press(NamedTuple):
    """What one press did: its indent_ratio (None after a SimulationFault), the
    milliseconds of each frame, and how far [m] the tissue flew off the stopped tool
    (0 where it stayed against it)."""

    ratio: float | None
    frame_ms: list[float]
    flight: float = 0.0


def press(session, target: Target, depth: float, speed: float, hold: float = HOLD) -> Press:
    """One press from the reset state: the instrument's lowest point down from 1 mm
    above the drawn surface to ``depth`` [m] below it at ``speed`` [m/s], then
    ``hold`` [s] still. A tissue the stopped tool flung off is judged at the last
    frame it touched the tool, and its flight is reported (module docstring,
    HELD_DEPTH, FLIGHT_FRAMES, FLIGHT_SPEED)."""
    from taichi_lap.core.errors import SimulationFault
    from taichi_lap.devices import ScriptedDevice

    session.reset()
    tool = session.scene.tools[0]
    start = tool["tip"]
    end = [target.x, target.height - depth + tip_above_bottom(tool["kind"]), target.z]
    reach = (start[1] - end[1]) / speed
    frames = [
        {"time": 0.0, "tool": tool["name"], "tip": list(start)},
        {"time": reach, "tool": tool["name"], "tip": end},
        {"time": reach + hold, "tool": tool["name"], "tip": end},
    ]
    device = ScriptedDevice.from_tables("press", frames, session.scene.tools)
    count = math.ceil((reach + hold) / session.dt - 1e-6)
    times, touched, still, gap = [], None, 0, math.nan  # still: frames the tool stood
    try:
        for _ in range(count):
            now = session.state.time
            poses, buttons = device.poses(now), device.buttons(now)
            begin = time.perf_counter()
            session.step(poses, buttons)
            times.append((time.perf_counter() - begin) * 1e3)
            still += now >= reach - 1e-9  # this step took the tool to its end pose
            last_gap, (ratio, gap, tool_depth) = gap, indent_ratio(session, target)
            if not gap > TOUCH_GAP:
                deep = tool_depth >= HELD_DEPTH * depth and still <= FLIGHT_FRAMES
                touched = ratio if deep else None  # touching later: no flight
            elif not last_gap > TOUCH_GAP and touched is not None:  # it left the tool
                touched = touched if gap - last_gap >= FLIGHT_SPEED * session.dt else None
    except SimulationFault as fault:
        print(f"    fault: {fault}", flush=True)
        session.reset()
        return Press(None, times)
    if touched is None or not gap > TOUCH_GAP:  # against the tool, or not flung off it
        return Press(ratio, times)
    return Press(touched, times, gap)


def indent_ratio(session, target: Target) -> tuple[float, float, float]:
    """Displacement of the drawn surface under the tool's lowest point over the
    tool's depth below the starting surface (module docstring); the gap [m] between
    the tool's lowest point and that surface (negative: the tool is inside the drawn
    tissue); the tool's depth [m]. nan when the ray no longer meets the surface."""
    lowest, height = tool_bottom(session)
    surface = surface_height(session, target.organ, lowest[0], lowest[2])
    tool_depth = target.height - height
    return (target.height - surface) / tool_depth, height - surface, tool_depth


def fault_without_contact(session, seconds: float = 1.0) -> bool:
    """Whether the body alone, the tool held still above it, raises a
    SimulationFault within ``seconds`` (then the press faults are not the
    contact's); the session is reset afterwards."""
    from taichi_lap.core.errors import SimulationFault

    session.reset()
    try:
        for _ in range(math.ceil(seconds / session.dt)):
            session.step()
    except SimulationFault:
        return True
    finally:
        session.reset()
    return False


def thick_enough(target: Target, depth: float) -> bool:
    """Whether a press of ``depth`` [m] is made: the deep one only into a body
    thicker than that under the tool (not into a sheet, a thin vessel)."""
    return depth < DEEP or target.thickness > depth


def press_case(session, target, model, collision, solver, depths, speeds) -> list[dict]:
    """The rows of one press case: every depth (the deep one where the body is
    thick enough) at every speed. The indent_ratio row also lists each press
    (``presses``: depth, speed, ratio, or ``fault`` / ``surface lost`` where the
    press gave none, and ``flight_mm`` where the tissue flew off the stopped tool);
    a ``flight_mm`` row gives the flights. The case is ``press-<model>-<collision>``,
    with ``-<kind>`` for an instrument other than the probe."""
    substeps, damping, eta = solver
    kind = session.scene.tools[0]["kind"]
    ratios, times, faults, done, log, flights = [], [], 0, [], [], []
    alone = fault_without_contact(session)
    if alone:
        print("    the body faults without contact too", flush=True)
    for depth in depths:
        if not thick_enough(target, depth):
            print(f"    skip {depth * 1e3:g} mm: {target.thickness * 1e3:.1f} mm thick")
            continue
        done.append(depth)
        for speed in speeds:
            ratio, frame_ms, flight = press(session, target, depth, speed)
            times += frame_ms
            flights.append(flight)
            if ratio is None:
                faults += 1
                shown = "fault"
            elif math.isnan(ratio):
                shown = "surface lost"  # the ray down the axis meets no drawn surface
            else:
                ratios.append(ratio)
                shown = round(float(ratio), 4)
            entry = {"depth_mm": _mm(depth), "speed_mm_s": _mm(speed), "indent_ratio": shown}
            flew = f", flew {flight * 1e3:.2f} mm off the tool" if flight else ""
            if flight:
                entry["flight_mm"] = _mm(flight)
            log.append(entry)
            ms = statistics.median(frame_ms) if frame_ms else math.nan
            print(
                f"  {kind} {model} {collision} substeps {substeps} depth {depth * 1e3:g} mm "
                f"speed {speed * 1e3:g} mm/s: indent_ratio {shown}{flew}, {ms:.2f} ms/frame",
                flush=True,
            )
    data = session.model.data
    first, last = data.organs[target.organ].triangles
    params = {
        "model": model,
        "collision": collision,
        "substeps": substeps,
        "damping": damping,
        "eta_on_contact": eta if model in ("tet_clusters", "shape_matching") else None,
        "particles": session.model.particle_count,
        "triangles": int(last - first),
        "depths_mm": [_mm(d) for d in done],
        "speeds_mm_s": [_mm(v) for v in speeds],
        "instrument": kind,
    }
    case = f"press-{model}-{collision}" + ("" if kind == "probe" else f"-{kind}")
    rows = []
    if ratios:
        rows.append({**result(case, params, "indent_ratio", ratios), "presses": log})
    if flights:
        rows.append(result(case, params, "flight_mm", [f * 1e3 for f in flights]))
    faults_row = result(case, params, "faults", [faults])
    rows.append({**faults_row, "presses": len(log), "faults_without_contact": alone})
    if times:
        rows.append(result(case, params, "ms_per_frame", times))
    return rows


# ---- haptic stylus ----


def haptic_press(
    session, target: Target, depth: float, collision: str, solver, *, inside: bool = False
) -> list[dict]:
    """The ``haptic-press-<d>mm`` rows: a scripted stylus pressed ``depth`` [m] into
    the body (the scene tool follows the bridge), held HAPTIC_HOLD s of simulated time;
    ``inside``: the ``haptic-inside-<d>mm`` rows, the stylus there from the start."""
    from taichi_lap.core.errors import SimulationFault
    from taichi_lap.haptics.bridge import HapticBridge
    from taichi_lap.haptics.servo import scripted_device

    session.reset()
    start = np.array(session.scene.tools[0]["tip"], dtype=np.float64)
    end = np.array([target.x, target.height - depth + PROBE_RADIUS, target.z])
    reach = 0.0 if inside else (start[1] - end[1]) / HAPTIC_SPEED
    up = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # stylus z is +y
    keys = [(0.0, tuple(end))] if inside else [(0.0, tuple(start)), (reach, tuple(end))]
    device = scripted_device(keys + [(reach + 3600.0, tuple(end))], rotation=up)
    bridge = HapticBridge(session.scene.tools[0], device)
    bridge.attach(session)
    forces, frame_ms, reached, fault = [], [], None, False
    try:
        deadline = time.monotonic() + 30.0 + reach
        while time.monotonic() < deadline:
            now = session.state.time
            poses, buttons = bridge.poses(now), bridge.buttons(now)
            begin = time.perf_counter()
            try:
                session.step(poses, buttons)
            except SimulationFault as exc:
                print(f"    fault: {exc}", flush=True)
                fault = True
                break
            frame_ms.append((time.perf_counter() - begin) * 1e3)
            feedback = bridge.feedback
            if feedback is None:
                continue
            simulated = session.state.time
            forces.append(
                (
                    simulated,
                    float(np.linalg.norm(feedback.force)),
                    np.linalg.norm(feedback.contact_force),
                )
            )
            if reached is None and feedback.haptic_pose[1, 3] <= end[1] + 1e-6:
                reached = simulated
            if reached is not None and simulated - reached >= HAPTIC_HOLD:
                break
        # The simulation's contacts use the Control's tool, which the bridge sets
        # from the servo's graphical (proxy) pose before each step: the depth and
        # the axis are taken from it, not from the stylus (haptic) pose.
        tip, lowest = tool_bottom(session)
        ratio = None if fault else indent_ratio(session, target)[0]
        surface = surface_height(session, target.organ, tip[0], tip[2])
        feedback = bridge.feedback
        stylus = feedback.haptic_pose[1, 3] - PROBE_RADIUS if feedback else math.nan
    finally:
        bridge.close()
    case = f"haptic-{'inside' if inside else 'press'}-{depth * 1e3:g}mm"
    params = {
        "model": "tet_clusters",
        "collision": collision,
        "substeps": solver[0],
        "damping": solver[1],
        "eta_on_contact": solver[2],
        "particles": session.model.particle_count,
        "triangles": len(session.data.surface_triangles),
        "depth_mm": _mm(depth),
        "speed_mm_s": _mm(HAPTIC_SPEED),
        "hold_s": HAPTIC_HOLD,
    }
    measured = {  # what the press did, beside the metrics
        "reached_depth": reached is not None,
        "tool_depth_mm": _mm(target.height - lowest),
        "stylus_depth_mm": _mm(target.height - stylus),
        "indent_mm": _mm(target.height - surface),
        "frames": len(frame_ms),
        "frame_ms": round(statistics.median(frame_ms), 2) if frame_ms else None,
    }
    rows, force = [], math.nan
    if ratio is not None and not math.isnan(ratio):
        rows.append({**result(case, params, "indent_ratio", [ratio]), **measured})
    if forces:
        last = forces[-1][0]
        window = [f for f in forces if f[0] >= last - HAPTIC_FORCE_WINDOW]
        rows.append(result(case, params, "force_n", [f[1] for f in window]))
        rows.append(result(case, params, "contact_force_n", [float(f[2]) for f in window]))
        force = rows[-2]["median"]
    rows.append({**result(case, params, "faults", [int(fault)]), **measured})
    shown = "fault" if ratio is None else f"{ratio:.3f}"
    missed = "" if reached is not None else " (the stylus did not reach the depth)"
    print(
        f"  {case}: indent_ratio {shown} (tool {measured['tool_depth_mm']} mm below the "
        f"surface, stylus {measured['stylus_depth_mm']} mm, surface down "
        f"{measured['indent_mm']} mm), force {force:.3f} N{missed}",
        flush=True,
    )
    return rows


# ---- the intestine scene's probe ----


def segment_distances(a, b, c, d) -> np.ndarray:
    """Distances between segment a-b and each segment c[i]-d[i] (Ericson 2004, 5.1.9)."""
    d1, d2 = b - a, d - c
    r = a - c
    aa, ee = float(d1 @ d1), np.einsum("ij,ij->i", d2, d2)
    f = np.einsum("ij,ij->i", d2, r)
    cc = r @ d1
    bb = d2 @ d1
    denom = aa * ee - bb * bb
    s = np.where(denom > 1e-20, np.clip((bb * f - cc * ee) / np.maximum(denom, 1e-20), 0, 1), 0.0)
    t = (bb * s + f) / np.maximum(ee, 1e-20)
    s = np.where(t < 0.0, np.clip(-cc / max(aa, 1e-20), 0, 1), s)
    s = np.where(t > 1.0, np.clip((bb - cc) / max(aa, 1e-20), 0, 1), s)
    t = np.clip(t, 0.0, 1.0)
    p = a + s[:, None] * d1
    q = c + t[:, None] * d2
    return np.linalg.norm(p - q, axis=1)


def sweep_intestine() -> list[dict]:
    """The ``sweep-intestine`` rows (module docstring)."""
    from taichi_lap import scene as scene_mod
    from taichi_lap.session import Session, scene_script

    scene = scene_mod.load("intestine")
    session = Session(scene, progress=False)
    organ = next(o for o in session.model.data.organs if o.row_length)
    first, count = organ.particles[0], organ.row_length
    tube = float(session.model.data.radius[first])
    script = scene_script(scene)
    session.step(script.poses(0.0), script.buttons(0.0))  # compile the step's kernels
    session.reset()
    distances, times = [], []
    for _ in range(SWEEP_FRAMES):
        now = session.state.time
        begin = time.perf_counter()
        session.step(script.poses(now), script.buttons(now))
        times.append((time.perf_counter() - begin) * 1e3)
        row = session.state.x.to_numpy()[first : first + count].astype(np.float64)
        a = session.control.tool_a.to_numpy()[0].astype(np.float64)
        b = session.control.tool_b.to_numpy()[0].astype(np.float64)
        distances.append(float(segment_distances(a, b, row[:-1], row[1:]).min()))
    radius = float(session.control.tool_radius.to_numpy()[0])
    session.close()
    distances = np.array(distances)
    inside = int(np.count_nonzero(distances < tube + radius - INSIDE_MARGIN))
    gaps = (distances - (tube + radius)) * 1e3
    params = {
        "model": "mass_spring",
        "collision": scene.settings["collision"],
        "substeps": scene.settings["substeps"],
        "damping": scene.organs[0].material["damping"],
        "particles": session.model.particle_count,
        "triangles": len(session.data.surface_triangles),
        "frames": SWEEP_FRAMES,
        "tube_radius_m": tube,
        "tool_radius_m": radius,
    }
    print(f"  sweep-intestine: {inside} frames inside, min gap {gaps.min():.1f} mm", flush=True)
    return [
        result("sweep-intestine", params, "frames_inside", [inside]),
        {
            **result("sweep-intestine", params, "min_gap_mm", [float(gaps.min())]),
            "median_gap_mm": round(float(np.median(gaps)), 2),
        },
        result("sweep-intestine", params, "ms_per_frame", times),
    ]


def main():
    args = arguments("contact")
    from taichi_lap import runtime

    runtime.init(args.arch)
    quick = args.quick
    models = ("tet_clusters", "mass_spring") if quick else MODELS
    collisions = ("off",) if quick else COLLISIONS
    solvers = SOLVERS[:1] if quick else SOLVERS
    depths = (0.004,) if quick else DEPTHS + (DEEP,)
    speeds = SPEEDS[:1] if quick else SPEEDS
    haptic_depths = (0.004,) if quick else DEPTHS + (DEEP,)
    haptic = (collisions[0], solvers[0]) if quick else HAPTIC  # --quick: no second session
    results, haptic_rows = [], []

    def haptic_cases(session, target):
        for depth in haptic_depths:
            haptic_rows.extend(haptic_press(session, target, depth, *haptic))
        if not quick:
            haptic_rows.extend(haptic_press(session, target, 0.004, *haptic, inside=True))

    for model in models:
        for collision in collisions:
            for solver in solvers:
                begin = time.perf_counter()
                session, target = press_scene(model, collision, *solver)
                if collision != "off" and session.solver.collision is None:
                    print(f"  {model}: no surface triangles, no {collision} case")
                    session.close()
                    continue
                print(
                    f"{model} {collision} substeps {solver[0]}: session in "
                    f"{time.perf_counter() - begin:.1f} s, surface at "
                    f"{target.height * 1e3:.2f} mm, {target.thickness * 1e3:.1f} mm thick",
                    flush=True,
                )
                results += press_case(session, target, model, collision, solver, depths, speeds)
                if model == "tet_clusters" and (collision, solver) == haptic:
                    haptic_cases(session, target)
                session.close()
    for kind in () if quick else INSTRUMENTS:
        for model in INSTRUMENT_MODELS:
            for solver in solvers:
                session, target = press_scene(model, "off", *solver, kind=kind)
                print(f"{kind} on the {model} body, substeps {solver[0]}", flush=True)
                results += press_case(session, target, model, "off", solver, depths, speeds)
                session.close()
    results += haptic_rows
    if not quick:
        results += sweep_intestine()
    report("contact", args.arch, results, args.json)


if __name__ == "__main__":
    main()
