"""Assembling the drawn mesh every frame: organ surfaces and tube centre lines
gathered from the skinned surface, and the instruments, whose meshes are built
once in the tool's own frame (tip at the origin, shaft along +z) and placed at the
tool capsules the devices set in :class:`taichi_lap.sim.control.Control`. Organ
surface vertices also carry a char from the peak temperature of their particles,
so the electrocautery wound is drawn with its own look (seed 002 §3.3)."""

import taichi as ti

from taichi_lap.dissection.removal import CUT_POINT

CHAR_START = 50.0  # [°C] peak temperature where tissue starts to look charred
CHAR_FULL = 100.0  # [°C] peak temperature of fully charred tissue


@ti.kernel
def copy_surface(surface: ti.template(), count: ti.i32, positions: ti.template()):
    """positions[:count] = surface[:count]: the skinned organ surfaces [m]."""
    for s in range(count):
        positions[s] = surface[s]


@ti.func
def at_surface_vertex(model: ti.template(), values: ti.template(), s):
    """A per-particle quantity ``values`` (scalar or vector) at the model's surface
    vertex s: the weighted sum over its particles (``surface_index``,
    ``surface_weight``; a row of zero weights gives 0), or, for a wound vertex (bound to
    a cluster, ``surface_cluster`` >= 0), the value at its place on the cut edge between
    its kept and removed particle (``surface_index`` 0 and 1; CUT_POINT along it)."""
    idx, w = model.surface_index[s], model.surface_weight[s]
    value = w[0] * values[idx[0]]
    if model.surface_cluster[s] >= 0:
        value = (1.0 - CUT_POINT) * values[idx[0]] + CUT_POINT * values[idx[1]]
    else:
        for k in ti.static(range(1, 4)):
            value += w[k] * values[idx[k]]
    return value


@ti.kernel
def surface_texcoords(model: ti.template(), texcoord: ti.template()):
    """texcoord[s] = the rest position [m] of the model's surface vertex s
    (:func:`at_surface_vertex` of the particles' rest positions, as the surface is
    skinned from their positions): the surface detail drawn there stays on the tissue
    as it deforms."""
    for s in range(model.surface_vertex_count):
        texcoord[s] = at_surface_vertex(model, model.rest_position, s)


@ti.kernel
def surface_char(model: ti.template(), peak: ti.template(), char: ti.template()):
    """char[s] = smoothstep(CHAR_START, CHAR_FULL, Σ_k w[s, k] peak[idx[s, k]]) for the
    model's surface vertices s: how charred each looks, from the peak temperatures
    ``peak`` [°C] its particles reached (:func:`at_surface_vertex`: a wound vertex
    takes the temperature at its place on the cut edge, so a burnt-away neighbour
    chars the wound). As electrosurgery texts commonly state, the proteins of soft
    tissue begin to coagulate at about 50 to 60 °C and its water boils away at 100 °C,
    leaving dry, darkened tissue, so the look blends between the two."""
    for s in range(model.surface_vertex_count):
        temperature = at_surface_vertex(model, peak, s)
        char[s] = ti.math.smoothstep(CHAR_START, CHAR_FULL, temperature)


@ti.kernel
def copy_surface_triangles(
    model: ti.template(),
    membrane: ti.template(),
    triangles: ti.template(),
    material: ti.template(),
    owner: ti.template(),
):
    """The model's surface triangles (flat, 3 per triangle) with their organ as
    material and object, into the first rows of a drawn mesh; degenerate (not drawn)
    for the organs whose ``membrane`` flag is set (drawn as their membrane)."""
    for t in range(model.surface_triangle_count):
        organ, corners = model.surface_triangle_organ[t], model.surface_triangles[t]
        for k in ti.static(range(3)):
            triangles[3 * t + k] = ti.select(membrane[organ] != 0, corners[0], corners[k])
        material[t] = organ
        owner[t] = organ


@ti.kernel
def gather_points(
    surface: ti.template(),
    source: ti.template(),
    across: ti.template(),
    points: ti.template(),
    reference: ti.template(),
):
    """points[k] = surface[source[k]]: a tube's centre line [m]; reference[k] =
    surface[across[k]] - points[k]: the direction to a vertex fixed beside it (the
    tube's material direction, :meth:`~taichi_lap.render.tubes.TubeMesh.update`)."""
    for k in points:
        points[k] = surface[source[k]]
        reference[k] = surface[across[k]] - points[k]


@ti.kernel
def place_instruments(
    local_position: ti.template(),
    local_normal: ti.template(),
    vertex_tool: ti.template(),
    count: ti.i32,
    control: ti.template(),
    positions: ti.template(),
    normals: ti.template(),
    offset: ti.i32,
):
    """positions[offset + v] = a + R · local_position[v] for the tool
    ``vertex_tool[v]`` (capsule tip ``a`` [m], frame R of the Control, the one
    grasped tissue is held in); normals likewise rotated. An inactive tool collapses
    onto its tip, so its triangles are degenerate and not drawn."""
    for v in range(count):
        t = vertex_tool[v]
        frame = control.tool_frame[t]
        local = local_position[v] * ti.cast(control.tool_active[t], ti.f32)
        positions[offset + v] = control.tool_a[t] + frame @ local
        normals[offset + v] = frame @ local_normal[v]
