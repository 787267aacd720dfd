"""Vessels seen through the tissue above them (issue: endoscopic realism): the liver's
vessels show where they run close under the capsule, and a wound's floor takes
their colour as the cut nears them, before it opens them.

A :func:`~taichi_lap.render.subsurface.vessel_tint_grid` holds, on a regular grid
over the tissue in rest space, the nearest vessel's albedo premultiplied by its
weight exp(-d / SUBSURFACE_DEPTH) (d its distance [m]) and the weight. The shading
samples it trilinearly at a pixel's rest-space point (the surface detail's
coordinate, so the tint stays on the tissue as it deforms) and blends the albedo
towards the vessel's by the weight times the material's ``subsurface``: light
scattered back from under a thin layer of tissue carries the colour of what lies
there (an albedo blend, the cheap stand-in for the diffusion of subsurface
scattering; seed 000 §6 has no subsurface term).
"""

import taichi as ti


@ti.func
def tint_sample(mesh: ti.template(), point):
    """The tint grid of ``mesh`` trilinearly at rest-space ``point`` [m]: (premultiplied
    albedo, weight) as a vec4, zero outside the grid."""
    shape = mesh.tint_shape[None]
    g = (point - mesh.tint_origin[None]) / mesh.tint_cell[None]
    out = ti.Vector([0.0, 0.0, 0.0, 0.0])
    if (g >= 0.0).all() and (g < ti.cast(shape - 1, ti.f32)).all():
        cell = ti.cast(ti.floor(g), ti.i32)
        f = g - ti.cast(cell, ti.f32)
        for corner in ti.static(ti.ndrange(2, 2, 2)):
            c = cell + ti.Vector(corner)
            w = (
                (f[0] if corner[0] else 1.0 - f[0])
                * (f[1] if corner[1] else 1.0 - f[1])
                * (f[2] if corner[2] else 1.0 - f[2])
            )
            out += w * mesh.tint[(c[0] * shape[1] + c[1]) * shape[2] + c[2]]
    return out


@ti.func
def vessel_tint(mesh: ti.template(), m, point, albedo):
    """``albedo`` of material ``m`` at rest-space ``point`` [m] blended towards the
    vessels under it (module docstring); unchanged for a material without
    ``subsurface``."""
    strength = mesh.subsurface[m]
    if strength > 0.0:
        tint = tint_sample(mesh, point)
        if tint[3] > 1e-6:
            colour = ti.Vector([tint[0], tint[1], tint[2]]) / tint[3]
            albedo = ti.math.mix(albedo, colour, strength * ti.min(tint[3], 1.0))
    return albedo
