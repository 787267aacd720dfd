"""Procedural surface detail of tissue (issue: endoscopic realism), evaluated per
pixel in the deferred shading (seed 000 §6.3) at the surface's rest-space coordinate,
so that it stays on the tissue as it deforms and never swims.

Value noise on the integer lattice (a hash per corner, smoothstep-weighted trilinear
blend) with its analytic gradient (Quilez, "Value noise derivatives", 2017) gives,
per material (:class:`~taichi_lap.scene.materials.Material`):

* mottling: the albedo scaled by 1 + 2 ``mottling`` (n - ½) over two octaves of
  features ``scale`` [m] across (lobules, folds);
* vessels: where a coarser noise crosses ½, a thin line darkened and reddened by
  ``vessels``, fading in and out with the relief: capillaries over the serosa;
* bump: the normal tilted against the gradient of the relief (the two octaves), by
  ``bump`` per unit slope.

No image assets; the same value on every backend up to rounding.
"""

import taichi as ti

VESSEL_TINT = (0.55, 0.18, 0.16)
"""Albedo factors of a capillary line at full ``vessels``: darker and redder."""
VESSEL_WIDTH = 0.03
"""Half-width of a capillary line in noise units around the crossing of ½."""


@ti.func
def lattice_hash(cell):
    """A value in [0, 1) for an integer cell (ivec3): Teschner's primes mixed by a
    MurmurHash-style finaliser, in u32 (the same on every backend)."""
    c = ti.cast(cell, ti.u32)
    h = (c[0] * ti.u32(73856093)) ^ (c[1] * ti.u32(19349663)) ^ (c[2] * ti.u32(83492791))
    h ^= h >> ti.u32(13)
    h *= ti.u32(0x5BD1E995)
    h ^= h >> ti.u32(15)
    return ti.cast(h & ti.u32(0xFFFFFF), ti.f32) / 16777216.0


@ti.func
def value_noise(p):
    """Value noise at ``p`` (vec3, lattice units) in [0, 1] and its gradient (vec3)."""
    cell = ti.cast(ti.floor(p), ti.i32)
    f = p - ti.floor(p)
    u = f * f * (3.0 - 2.0 * f)
    du = 6.0 * f * (1.0 - f)
    a = lattice_hash(cell)
    b = lattice_hash(cell + ti.Vector([1, 0, 0]))
    c = lattice_hash(cell + ti.Vector([0, 1, 0]))
    d = lattice_hash(cell + ti.Vector([1, 1, 0]))
    e = lattice_hash(cell + ti.Vector([0, 0, 1]))
    g = lattice_hash(cell + ti.Vector([1, 0, 1]))
    h = lattice_hash(cell + ti.Vector([0, 1, 1]))
    k = lattice_hash(cell + ti.Vector([1, 1, 1]))
    k1, k2, k3 = b - a, c - a, e - a
    k4, k5, k6 = a - b - c + d, a - c - e + h, a - b - e + g
    k7 = -a + b + c - d + e - g - h + k
    value = (
        a
        + k1 * u[0]
        + k2 * u[1]
        + k3 * u[2]
        + k4 * u[0] * u[1]
        + k5 * u[1] * u[2]
        + k6 * u[2] * u[0]
        + k7 * u[0] * u[1] * u[2]
    )
    gradient = du * ti.Vector(
        [
            k1 + k4 * u[1] + k6 * u[2] + k7 * u[1] * u[2],
            k2 + k5 * u[2] + k4 * u[0] + k7 * u[2] * u[0],
            k3 + k6 * u[0] + k5 * u[1] + k7 * u[0] * u[1],
        ]
    )
    return value, gradient


@ti.func
def surface_detail(materials: ti.template(), m, texcoord, albedo, n):
    """The albedo and unit normal ``n`` of material ``m`` at rest-space point
    ``texcoord`` [m] with its detail (module docstring); unchanged where the material
    has none."""
    mottling, vessels, bump = materials.mottling[m], materials.vessels[m], materials.bump[m]
    if mottling > 0.0 or vessels > 0.0 or bump > 0.0:
        q = texcoord / materials.scale[m]
        fine, fine_slope = value_noise(q)
        finer, finer_slope = value_noise(2.7 * q + 17.0)
        relief = 0.65 * fine + 0.35 * finer
        slope = 0.65 * fine_slope + 2.7 * 0.35 * finer_slope
        albedo = albedo * (1.0 + 2.0 * mottling * (relief - 0.5))
        coarse, _ = value_noise(0.35 * q + 41.0)
        line = 1.0 - ti.math.smoothstep(0.0, VESSEL_WIDTH, ti.abs(coarse - 0.5))
        line *= ti.math.smoothstep(0.3, 0.7, relief)  # lines fade in and out
        albedo = albedo * ti.math.mix(
            ti.Vector([1.0, 1.0, 1.0]), ti.Vector(VESSEL_TINT), vessels * line
        )
        tangential = slope - slope.dot(n) * n
        n = (n - bump * tangential).normalized(1e-12)
    return ti.math.clamp(albedo, 0.0, 1.0), n
