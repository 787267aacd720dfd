"""Image-based lighting of the abdominal cavity (seed 000 §6.2, Eq. 13-15).

The cavity is lit by :func:`environment_radiance`, a procedural, smooth, low-frequency
warm red and pink surround without bright sources. :class:`ImageLighting` precomputes
once, in one SNode tree:

- ``sh_coeffs``: the environment projected on 9 spherical harmonics, for the diffuse
  sum of Eq. 15 (irradiance by Ramamoorthi & Hanrahan 2001, Eq. 13 there);
- ``dfg``: the first sum of Eq. 14 (the DFG term) as scale A and bias B of F0, by the
  split sum of Karis 2013 (the seed cites it as Kasyan 2013);
- ``prefiltered``: the second sum of Eq. 14 (the LD term), the environment convolved
  with GGX lobes under Karis's n = v = r assumption, at ``PREFILTER_LEVELS`` roughnesses.

Directions are world unit vectors, y up. Latitude-longitude maps put theta = acos(y)
along rows (row 0 at +y) and phi = atan2(z, x) in [0, 2 pi) along columns. Tables are
1-D fields (FieldGroup), indexed as documented on :class:`ImageLighting`. Precomputation
sums in a fixed order (no float atomics), so it is deterministic on every backend.
"""

import math

import taichi as ti
from taichi_lap.kernels.brdf import (
    ALPHA_MIN,
    INV_PI,
    MUCUS_F0,
    MUCUS_ROUGHNESS,
    N_DOT_MIN,
    PI,
    fresnel,
    fresnel_weight,
    mucus_fresnel,
    smith_visibility,
    specular_f0,
)

from taichi_lap.core.fields import FieldGroup

SH_ROWS, SH_COLUMNS = 128, 256  # latitude-longitude quadrature grid of the SH projection
DFG_SIZE, DFG_SAMPLES = 32, 256
PREFILTER_WIDTH, PREFILTER_HEIGHT, PREFILTER_LEVELS, PREFILTER_SAMPLES = 64, 32, 5, 512
assert PREFILTER_WIDTH & (PREFILTER_WIDTH - 1) == 0, "columns wrap by a bit mask"
FRESNEL_WEIGHT_MEAN = 0.048864
"""Cosine-weighted hemispherical mean of the Eq. 11 weight, 2 ∫ fresnel_weight(mu) mu dmu."""


def _unit(x, y, z):
    s = math.sqrt(x * x + y * y + z * z)
    return (x / s, y / s, z / s)


# (colour, axis, sharpness) of the spherical Gaussians on the cavity wall
_PERITONEUM = ((0.45, 0.22, 0.20), _unit(0.3, 0.8, -0.5), 3.0)  # pink anterior wall
_FAT = ((0.30, 0.22, 0.10), _unit(-0.7, 0.2, 0.4), 4.0)  # yellowish omentum
_BOWEL = ((0.25, 0.04, 0.03), _unit(0.5, -0.3, 0.6), 5.0)  # deep red below


@ti.func
def spherical_gaussian(direction, axis, sharpness):
    """exp(sharpness (direction·axis - 1)): 1 on the axis, smooth elsewhere."""
    return ti.exp(sharpness * (direction.dot(ti.Vector(axis)) - 1.0))


@ti.func
def environment_radiance(direction):
    """Radiance [relative units] of the abdominal cavity seen along unit ``direction``:
    a red wall, darker below (y < 0), with pink, yellowish and deep red patches; RGB in
    about [0.05, 1.1]."""
    wall = ti.math.mix(
        ti.Vector([0.20, 0.05, 0.045]), ti.Vector([0.55, 0.20, 0.17]), 0.5 + 0.5 * direction.y
    )
    for patch in ti.static((_PERITONEUM, _FAT, _BOWEL)):
        wall += ti.Vector(patch[0]) * spherical_gaussian(direction, patch[1], patch[2])
    return wall


@ti.func
def latlong_direction(theta, phi):
    """Unit direction at polar angle ``theta`` from +y and azimuth ``phi`` from +x to +z."""
    s = ti.sin(theta)
    return ti.Vector([s * ti.cos(phi), ti.cos(theta), s * ti.sin(phi)])


@ti.func
def sh9_basis(d):
    """The 9 real spherical harmonics Y00, Y1-1, Y10, Y11, Y2-2, Y2-1, Y20, Y21, Y22 at
    unit ``d`` (Ramamoorthi & Hanrahan 2001; x, y, z = d)."""
    x, y, z = d.x, d.y, d.z
    return ti.Vector(
        [
            0.282095,
            0.488603 * y,
            0.488603 * z,
            0.488603 * x,
            1.092548 * x * y,
            1.092548 * y * z,
            0.315392 * (3.0 * z * z - 1.0),
            1.092548 * x * z,
            0.546274 * (x * x - y * y),
        ]
    )


@ti.kernel
def project_sh9(
    environment: ti.template(), intensity: ti.f32, row_sums: ti.template(), coeffs: ti.template()
):
    """coeffs[k] = intensity ∫ L(w) Y_k(w) dw (Ramamoorthi & Hanrahan 2001)
    by the midpoint rule on a SH_ROWS x SH_COLUMNS latitude-longitude grid. One latitude
    ring per thread into ``row_sums[row * 9 + k]``, then rings summed in order."""
    d_theta, d_phi = PI / SH_ROWS, 2.0 * PI / SH_COLUMNS
    for row in range(SH_ROWS):
        theta = (row + 0.5) * d_theta
        ring = ti.Matrix.zero(ti.f32, 9, 3)
        for col in range(SH_COLUMNS):
            d = latlong_direction(theta, (col + 0.5) * d_phi)
            ring += sh9_basis(d).outer_product(environment(d))
        d_omega = ti.sin(theta) * d_theta * d_phi
        for k in ti.static(range(9)):
            row_sums[row * 9 + k] = d_omega * ti.Vector([ring[k, 0], ring[k, 1], ring[k, 2]])
    for k in range(9):
        total = ti.Vector([0.0, 0.0, 0.0])
        for row in range(SH_ROWS):
            total += row_sums[row * 9 + k]
        coeffs[k] = intensity * total


@ti.func
def sh9_irradiance(coeffs, n):
    """Irradiance E(n) = ∫ L(w) max(n·w, 0) dw from 9 SH coefficients, Ramamoorthi &
    Hanrahan 2001 Eq. 13 (c1..c5 fold the clamped-cosine lobe). Includes no 1/pi: a
    Lambertian surface reflects radiance albedo · E(n) / pi. A constant L gives pi L."""
    c1, c2, c3, c4, c5 = 0.429043, 0.511664, 0.743125, 0.886227, 0.247708
    x, y, z = n.x, n.y, n.z
    e = (
        c1 * coeffs[8] * (x * x - y * y)
        + c3 * coeffs[6] * z * z
        + c4 * coeffs[0]
        - c5 * coeffs[6]
        + 2.0 * c1 * (coeffs[4] * x * y + coeffs[7] * x * z + coeffs[5] * y * z)
        + 2.0 * c2 * (coeffs[3] * x + coeffs[1] * y + coeffs[2] * z)
    )
    return ti.max(e, 0.0)


@ti.func
def radical_inverse(i):
    """Van der Corput radical inverse of i >= 0 in base 2 (Hammersley's second coordinate)."""
    x, f, k = 0.0, 0.5, i
    while k > 0:
        if k & 1:
            x += f
        f *= 0.5
        k >>= 1
    return x


@ti.func
def tangent_frame(n):
    """Two unit vectors completing unit ``n`` to an orthonormal frame (Duff et al. 2017)."""
    sign = ti.select(n.z >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n.z)
    b = n.x * n.y * a
    return ti.Vector([1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x]), ti.Vector(
        [b, sign + n.y * n.y * a, -n.y]
    )


@ti.func
def ggx_half_vector(i, count, alpha, n):
    """Hammersley point i of ``count``, mapped to a GGX-distributed half vector around unit
    ``n`` (pdf D(h) n·h; Walter et al. 2007, Eq. 35-36; Karis 2013)."""
    a2 = ti.max(alpha, ALPHA_MIN) ** 2
    u = radical_inverse(i)
    cos_theta = ti.sqrt((1.0 - u) / (1.0 + (a2 - 1.0) * u))
    sin_theta = ti.sqrt(ti.max(1.0 - cos_theta * cos_theta, 0.0))
    phi = 2.0 * PI * (i + 0.5) / count
    tangent, bitangent = tangent_frame(n)
    return (tangent * ti.cos(phi) + bitangent * ti.sin(phi)) * sin_theta + n * cos_theta


@ti.kernel
def integrate_dfg(dfg: ti.template()):
    """Split-sum DFG term (seed 000 Eq. 14 first sum; Karis 2013): for n·v = (i + 0.5) /
    DFG_SIZE and roughness = (j + 0.5) / DFG_SIZE, dfg[j * DFG_SIZE + i] = (A, B) with
    ∫ F D V n·l dl = F0 A + B, F from Eq. 11, V from Eq. 10, DFG_SAMPLES GGX samples."""
    for i, j in ti.ndrange(DFG_SIZE, DFG_SIZE):
        n_dot_v = (i + 0.5) / DFG_SIZE
        roughness = (j + 0.5) / DFG_SIZE
        alpha = roughness * roughness
        n = ti.Vector([0.0, 0.0, 1.0])
        v = ti.Vector([ti.sqrt(1.0 - n_dot_v * n_dot_v), 0.0, n_dot_v])
        scale, bias = 0.0, 0.0
        for s in range(DFG_SAMPLES):
            h = ggx_half_vector(s, DFG_SAMPLES, alpha, n)
            v_dot_h = v.dot(h)
            l = 2.0 * v_dot_h * h - v
            if l.z > 0.0 and v_dot_h > 0.0:
                # estimator F D V n·l / pdf_l with pdf_l = D n·h / (4 v·h)
                g_vis = smith_visibility(n_dot_v, l.z, alpha) * 4.0 * l.z * v_dot_h / h.z
                fc = fresnel_weight(v_dot_h)
                scale += (1.0 - fc) * g_vis
                bias += fc * g_vis
        dfg[j * DFG_SIZE + i] = ti.Vector([scale, bias]) / DFG_SAMPLES


@ti.func
def _dfg_cell(coordinate):
    """Cell and fraction of a DFG table axis at ``coordinate`` in [0, 1] (n·v or
    roughness; samples at (i + 0.5) / DFG_SIZE), clamped at the edges."""
    x = ti.math.clamp(coordinate * DFG_SIZE - 0.5, 0.0, DFG_SIZE - 1.0)
    i0 = ti.min(ti.cast(x, ti.i32), DFG_SIZE - 2)
    return i0, x - i0


@ti.func
def dfg_lookup(dfg, n_dot_v, roughness):
    """(A, B) of the DFG table at n·v and roughness, bilinear, clamped at the edges."""
    i0, fx = _dfg_cell(n_dot_v)
    j0, fy = _dfg_cell(roughness)
    row0 = ti.math.mix(dfg[j0 * DFG_SIZE + i0], dfg[j0 * DFG_SIZE + i0 + 1], fx)
    row1 = ti.math.mix(dfg[(j0 + 1) * DFG_SIZE + i0], dfg[(j0 + 1) * DFG_SIZE + i0 + 1], fx)
    return ti.math.mix(row0, row1, fy)


@ti.func
def dfg_row_lookup(row, n_dot_v):
    """(A, B) of one roughness's row of the DFG table (``row[i]`` at n·v = (i + 0.5) /
    DFG_SIZE) at n·v, linear, clamped at the edges."""
    i0, fx = _dfg_cell(n_dot_v)
    return ti.math.mix(row[i0], row[i0 + 1], fx)


@ti.kernel
def prefilter_environment(environment: ti.template(), intensity: ti.f32, maps: ti.template()):
    """LD term of seed 000 Eq. 14 (Karis 2013): for each level k (roughness k / (LEVELS - 1))
    and texel direction r, the n·l-weighted mean of intensity · L(l) over PREFILTER_SAMPLES
    GGX reflections about n = v = r. Writes maps[(k * HEIGHT + row) * WIDTH + col]."""
    for level, row, col in ti.ndrange(PREFILTER_LEVELS, PREFILTER_HEIGHT, PREFILTER_WIDTH):
        roughness = level / (PREFILTER_LEVELS - 1.0)
        r = latlong_direction(
            PI * (row + 0.5) / PREFILTER_HEIGHT, 2.0 * PI * (col + 0.5) / PREFILTER_WIDTH
        )
        total = ti.Vector([0.0, 0.0, 0.0])
        weight = 0.0
        for s in range(PREFILTER_SAMPLES):
            h = ggx_half_vector(s, PREFILTER_SAMPLES, roughness * roughness, r)
            l = 2.0 * r.dot(h) * h - r
            n_dot_l = r.dot(l)
            if n_dot_l > 0.0:
                total += environment(l) * n_dot_l
                weight += n_dot_l
        maps[(level * PREFILTER_HEIGHT + row) * PREFILTER_WIDTH + col] = intensity * total / weight


@ti.func
def polar_angle(y):
    """acos(y) for y in [-1, 1] (clamped) within 7e-5 rad: Abramowitz & Stegun 4.4.45,
    acos(|y|) ~ sqrt(1 - |y|) (a0 + a1 |y| + a2 |y|^2 + a3 |y|^3), mirrored for y < 0.
    A hundredth of a map texel (0.1 rad), for a square root instead of libm's acos."""
    a = ti.min(ti.abs(y), 1.0)
    angle = ti.sqrt(1.0 - a) * (1.5707288 + a * (-0.2121144 + a * (0.0742610 - 0.0187293 * a)))
    return ti.select(y < 0.0, PI - angle, angle)


@ti.func
def azimuth(z, x):
    """atan2(z, x) in (-pi, pi] within 1.5e-5 rad (the fit's 1e-5 and f32 rounding): atan of the smaller over the larger
    of |z|, |x| by a minimax polynomial (Abramowitz & Stegun 4.4.49, odd terms to
    x^9), then put in its octant; 0 at the origin."""
    big, small = ti.max(ti.abs(x), ti.abs(z)), ti.min(ti.abs(x), ti.abs(z))
    t = small / ti.max(big, 1e-30)
    t2 = t * t
    angle = t * (
        0.9998660 + t2 * (-0.3302995 + t2 * (0.1801410 + t2 * (-0.0851330 + 0.0208351 * t2)))
    )
    angle = ti.select(ti.abs(z) > ti.abs(x), 0.5 * PI - angle, angle)
    angle = ti.select(x < 0.0, PI - angle, angle)
    return ti.select(z < 0.0, -angle, angle)


@ti.func
def latlong_taps(d):
    """The bilinear taps of the prefiltered maps along unit direction ``d``: columns
    c0, c1 (wrapped in phi), the upper row r0 (rows r0, r0 + 1; clamped in theta) and
    the fractions (fx, fy) towards c1 and r0 + 1. Texel centres lie at integers. The
    angles are :func:`polar_angle` and :func:`azimuth` (per shaded pixel)."""
    theta = polar_angle(d.y)
    phi = azimuth(d.z, d.x)
    phi = ti.select(phi < 0.0, phi + 2.0 * PI, phi)
    x = phi * (PREFILTER_WIDTH / (2.0 * PI)) - 0.5
    y = ti.math.clamp(theta * (PREFILTER_HEIGHT / PI) - 0.5, 0.0, PREFILTER_HEIGHT - 1.0)
    x0 = ti.floor(x)
    c0 = ti.cast(x0, ti.i32) & (PREFILTER_WIDTH - 1)  # wraps: the width is a power of two
    r0 = ti.min(ti.cast(y, ti.i32), PREFILTER_HEIGHT - 2)
    return c0, (c0 + 1) & (PREFILTER_WIDTH - 1), r0, x - x0, y - r0


@ti.func
def latlong_sample(maps, level, taps):
    """Bilinear sample of level ``level`` of latitude-longitude ``maps`` at ``taps``
    (from :func:`latlong_taps`)."""
    c0, c1, r0, fx, fy = taps
    top = (level * PREFILTER_HEIGHT + r0) * PREFILTER_WIDTH
    bottom = top + PREFILTER_WIDTH
    return ti.math.mix(
        ti.math.mix(maps[top + c0], maps[top + c1], fx),
        ti.math.mix(maps[bottom + c0], maps[bottom + c1], fx),
        fy,
    )


@ti.func
def _prefilter_level(roughness):
    """The lower of the two prefiltered levels nearest ``roughness`` (clamped to [0,
    1]) and the fraction towards the upper one."""
    level = ti.math.clamp(roughness, 0.0, 1.0) * (PREFILTER_LEVELS - 1)
    k0 = ti.min(ti.cast(level, ti.i32), PREFILTER_LEVELS - 2)
    return k0, level - k0


@ti.func
def prefiltered_at(maps, taps, roughness):
    """Prefiltered environment radiance at ``taps`` for ``roughness`` in [0, 1]:
    bilinear in the map, linear between the two nearest levels."""
    k0, f = _prefilter_level(roughness)
    return ti.math.mix(latlong_sample(maps, k0, taps), latlong_sample(maps, k0 + 1, taps), f)


@ti.func
def prefiltered_radiance(maps, direction, roughness):
    """Prefiltered environment radiance along unit ``direction`` for ``roughness``."""
    return prefiltered_at(maps, latlong_taps(direction), roughness)


@ti.kernel
def fix_roughness(
    prefiltered: ti.template(),
    dfg: ti.template(),
    roughness: ti.f32,
    map_out: ti.template(),
    dfg_out: ti.template(),
):
    """The maps and DFG table of one ``roughness`` (the mucus film's): ``map_out``
    the prefiltered levels mixed as :func:`prefiltered_at` mixes them (one level,
    read with :func:`latlong_sample` at level 0), ``dfg_out`` the table's rows mixed
    as :func:`dfg_lookup` mixes them (read with :func:`dfg_row_lookup`). Sampling
    these equals sampling the full tables at that roughness (both are linear in the
    texels), with half the taps."""
    k0, f = _prefilter_level(roughness)
    size = PREFILTER_HEIGHT * PREFILTER_WIDTH
    for texel in range(size):
        lower, upper = prefiltered[k0 * size + texel], prefiltered[(k0 + 1) * size + texel]
        map_out[texel] = ti.math.mix(lower, upper, f)
    j0, fy = _dfg_cell(roughness)
    for i in range(DFG_SIZE):
        dfg_out[i] = ti.math.mix(dfg[j0 * DFG_SIZE + i], dfg[(j0 + 1) * DFG_SIZE + i], fy)


@ti.func
def ibl_diffuse(lighting, n, v, albedo, metalness, mucus):
    """Diffuse radiance under the environment, seed 000 Eq. 15 with a Lambertian f_d:
    albedo (1 - metalness) E(n) / pi (E from :func:`sh9_irradiance`) times the energy
    factors of :func:`~taichi_lap.kernels.brdf.surface_brdf_cos`, (1 - F) at n·v and the
    film's (1 - mucus F_c) at n·v; on the light side, where l spans the hemisphere, F and
    F_c take their cosine-weighted means. RGB, the environment's units."""
    n_dot_v = ti.max(n.dot(v), N_DOT_MIN)
    f0 = specular_f0(albedo, metalness)
    base = (1.0 - fresnel(f0, n_dot_v)) * (1.0 - f0 - (1.0 - f0) * FRESNEL_WEIGHT_MEAN)
    film = (1.0 - mucus * mucus_fresnel(n_dot_v)) * (
        1.0 - mucus * (MUCUS_F0 + (1.0 - MUCUS_F0) * FRESNEL_WEIGHT_MEAN)
    )
    return (
        albedo * ((1.0 - metalness) * INV_PI * film) * sh9_irradiance(lighting.sh_coeffs, n) * base
    )


@ti.func
def ibl_specular(lighting, n, v, albedo, roughness, metalness, mucus):
    """Specular radiance under the environment, seed 000 Eq. 14 by the split sum:
    prefiltered(r, roughness) (F0 A + B), r the mirror of v about n, for the base layer
    (through the film twice, n·l ~ n·v: (1 - mucus F_c(n·v))^2) plus ``mucus`` times the
    same for the water film (F0 = 0.02, roughness 0.08). RGB, the environment's units."""
    n_dot_v = ti.max(n.dot(v), N_DOT_MIN)
    r = 2.0 * n.dot(v) * n - v
    taps = latlong_taps(r)
    ab = dfg_lookup(lighting.dfg, n_dot_v, roughness)
    base = prefiltered_at(lighting.prefiltered, taps, roughness) * (
        specular_f0(albedo, metalness) * ab[0] + ab[1]
    )
    coat_ab = dfg_row_lookup(lighting.coat_dfg, n_dot_v)
    coat = latlong_sample(lighting.coat_map, 0, taps) * (MUCUS_F0 * coat_ab[0] + coat_ab[1])
    film = 1.0 - mucus * mucus_fresnel(n_dot_v)
    return film * film * base + mucus * coat


@ti.data_oriented
class ImageLighting:
    """Precomputed image-based lighting of ``environment`` (a ti.func direction -> RGB,
    default :func:`environment_radiance`) times ``intensity`` (radiance scale); all fields in one
    FieldGroup, filled once here:

    - ``sh_coeffs``: 9 x vec3 f32, SH coefficients in :func:`sh9_basis` order;
    - ``dfg``: DFG_SIZE^2 x vec2 f32, (A, B) at ``j * DFG_SIZE + i`` (roughness row j,
      n·v column i), read with :func:`dfg_lookup`;
    - ``prefiltered``: PREFILTER_LEVELS * PREFILTER_HEIGHT * PREFILTER_WIDTH x vec3 f32 at
      ``(level * HEIGHT + row) * WIDTH + col``, read with :func:`prefiltered_radiance`;
    - ``coat_map`` (PREFILTER_HEIGHT * PREFILTER_WIDTH x vec3) and ``coat_dfg``
      (DFG_SIZE x vec2): both at the mucus film's roughness (:func:`fix_roughness`);
    - ``sh_row_sums``: SH_ROWS * 9 x vec3 f32, scratch of the projection.

    Pass the object to a kernel as ``lighting: ti.template()`` and call
    ``ibl_diffuse(lighting, ...) + ibl_specular(lighting, ...)``, or pass single fields.
    """

    def __init__(self, intensity: float = 1.0, *, environment=environment_radiance):
        group = FieldGroup()
        self.sh_coeffs = group.field(ti.f32, 9, vector=3)
        self.sh_row_sums = group.field(ti.f32, SH_ROWS * 9, vector=3)
        self.dfg = group.field(ti.f32, DFG_SIZE * DFG_SIZE, vector=2)
        self.prefiltered = group.field(
            ti.f32, PREFILTER_LEVELS * PREFILTER_HEIGHT * PREFILTER_WIDTH, vector=3
        )
        self.coat_map = group.field(ti.f32, PREFILTER_HEIGHT * PREFILTER_WIDTH, vector=3)
        self.coat_dfg = group.field(ti.f32, DFG_SIZE, vector=2)
        group.finalize()
        project_sh9(environment, float(intensity), self.sh_row_sums, self.sh_coeffs)
        integrate_dfg(self.dfg)
        prefilter_environment(environment, float(intensity), self.prefiltered)
        fix_roughness(self.prefiltered, self.dfg, MUCUS_ROUGHNESS, self.coat_map, self.coat_dfg)
