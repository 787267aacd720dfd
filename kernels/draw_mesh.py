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


@ti.kernel
def surface_texcoords(model: ti.template(), texcoord: ti.template()):
    """texcoord[s] = the rest position [m] of the model's surface vertex s, skinned from
    its particles' rest positions as it is from their positions (a wound vertex: its
    place on the cut edge, as in :func:`surface_char`): the surface detail drawn there
    stays on the tissue as it deforms."""
    for s in range(model.surface_vertex_count):
        idx, w = model.surface_index[s], model.surface_weight[s]
        rest = ti.Vector([0.0, 0.0, 0.0])
        if model.surface_cluster[s] >= 0:
            rest = (1.0 - CUT_POINT) * model.rest_position[idx[0]]
            rest += CUT_POINT * model.rest_position[idx[1]]
        else:
            for k in ti.static(range(4)):
                rest += w[k] * model.rest_position[idx[k]]
        texcoord[s] = rest


@ti.kernel
def surface_char(model: ti.template(), peak: ti.template(), char: ti.template()):
    """char[s] = smoothstep(CHAR_START, CHAR_FULL, Σ_k w[s, k] peak[idx[s, k]]) for the
    model's surface vertices s: how charred each looks, from the peak temperatures
    ``peak`` [°C] its particles reached (a row of zero weights gives 0). A wound
    vertex (bound to a cluster, ``surface_cluster`` >= 0) takes the temperature at its
    place on the cut edge between its kept and removed particle (``surface_index``
    0 and 1; CUT_POINT along it), so a burnt-away neighbour chars the wound. As
    electrosurgery texts commonly state, the proteins of soft tissue begin to
    coagulate at about 50 to 60 °C and its water boils away at 100 °C, leaving dry,
    darkened tissue, so the look blends between the two."""
    for s in range(model.surface_vertex_count):
        idx, w = model.surface_index[s], model.surface_weight[s]
        temperature = 0.0
        if model.surface_cluster[s] >= 0:
            temperature = (1.0 - CUT_POINT) * peak[idx[0]] + CUT_POINT * peak[idx[1]]
        else:
            for k in ti.static(range(4)):
                temperature += w[k] * peak[idx[k]]
        char[s] = ti.math.smoothstep(CHAR_START, CHAR_FULL, temperature)


@ti.kernel
def copy_surface_triangles(
    model: ti.template(), triangles: ti.template(), material: ti.template(), owner: ti.template()
):
    """The model's surface triangles (flat, 3 per triangle) with their organ as
    material and object, into the first rows of a drawn mesh."""
    for t in range(model.surface_triangle_count):
        for k in ti.static(range(3)):
            triangles[3 * t + k] = model.surface_triangles[t][k]
        material[t] = model.surface_triangle_organ[t]
        owner[t] = model.surface_triangle_organ[t]


@ti.kernel
def gather_points(surface: ti.template(), source: ti.template(), points: ti.template()):
    """points[k] = surface[source[k]]: a tube's centre line [m]."""
    for k in points:
        points[k] = surface[source[k]]


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
