"""Deferred shading of the G-buffer (seed 000 §6.3, reduced deferred shading):
per pixel, the material of the visible triangle lit by the endoscope headlight and
by image-based lighting (seed 000 §6.2), then exposure, tone mapping and sRGB.

The headlight is a spotlight at the scope tip along the view axis with inverse
square falloff, the dominant light in laparoscopy. Tissue the electrocautery charred
is drawn with the wound's own look: each pixel's material blends towards dark, dry,
rough char by the G-buffer's ``char`` (seed 002 §3.3). Debug views show one G-buffer
channel instead of the shaded colour.
"""

import taichi as ti
from taichi_lap.kernels.brdf import headlight_brdf_cos
from taichi_lap.kernels.ibl import ibl_diffuse, ibl_specular
from taichi_lap.kernels.subsurface import vessel_tint
from taichi_lap.kernels.surface_detail import surface_detail
from taichi_lap.scene.planned_plane import MARK_COLOUR
from taichi_lap.scene.materials import (
    BLOOD_ALBEDO,
    BLOOD_FILM,
    BLOOD_ROUGHNESS,
    CHAR_ALBEDO,
    CHAR_ROUGHNESS,
)

VIEWS = (
    "shaded",
    "albedo",
    "normal",
    "depth",
    "roughness",
    "metalness",
    "mucus",
    "object",
    "char",
    "blood",
)
"""What :func:`shade` writes: the image or one G-buffer channel."""


SMOKE_RADIANCE = (0.3, 0.29, 0.27)
"""Exposed radiance of thick cautery smoke lit by the headlight: a light warm grey
after tone mapping (chosen by eye, not measured)."""


@ti.func
def srgb_encode(x):
    """The sRGB transfer function of a linear value in [0, 1]; above the linear toe
    1.055 x^(1/2.4) - 0.055 by Taylor's fit in square roots (within 0.25/255 of the
    exact curve, tested), which costs far less than exp and log per channel."""
    s1 = ti.sqrt(x)
    s2 = ti.sqrt(s1)
    s3 = ti.sqrt(s2)
    curve = 0.662002687 * s1 + 0.684122060 * s2 - 0.323583601 * s3 - 0.0225411470 * x
    return ti.select(x <= 0.0031308, 12.92 * x, curve)


@ti.func
def tone_map(c):
    """ACES filmic curve (Narkowicz 2015 fit), then sRGB encoding."""
    mapped = ti.math.clamp((c * (2.51 * c + 0.03)) / (c * (2.43 * c + 0.59) + 0.14), 0.0, 1.0)
    return ti.Vector([srgb_encode(mapped[k]) for k in ti.static(range(3))])


@ti.func
def object_colour(index):
    """A distinct colour per object index (golden-ratio hue steps)."""
    h = ti.math.fract(0.61803398875 * index + 0.1)
    return ti.Vector([0.5 + 0.5 * ti.cos(6.2831853 * (h + k / 3.0)) for k in range(3)])


@ti.func
def rest_point(mesh: ti.template(), triangle, weights):
    """The texcoord (rest-space point [m]) of the point of ``triangle`` whose
    barycentric weights of the second and third corners are ``weights`` (the
    G-buffer's): the same mix of the corners' ``texcoord``."""
    first = 3 * triangle
    i0, i1, i2 = mesh.triangles[first], mesh.triangles[first + 1], mesh.triangles[first + 2]
    w1, w2 = weights[0], weights[1]
    return (1.0 - w1 - w2) * mesh.texcoord[i0] + w1 * mesh.texcoord[i1] + w2 * mesh.texcoord[i2]


SIMILAR_NORMAL = 0.9
"""Checkerboard shading fills a pixel only where its neighbours' normals are within
this cosine of its own (about 25°)."""
SIMILAR_DEPTH = 0.03
"""... and their depths within this fraction of its own (not a fold behind it)."""
_NEIGHBOURS = ((1, 0), (-1, 0), (0, 1), (0, -1))


@ti.func
def filled(gbuffer: ti.template(), materials: ti.template(), x, y):
    """Whether checkerboard shading fills pixel (x, y) from its four neighbours instead
    of shading it: a pixel of odd x + y inside the border whose four neighbours show
    the same object at depths within SIMILAR_DEPTH and normals within SIMILAR_NORMAL of
    its own. Edges, silhouettes and creases are shaded at full rate."""
    width, height = ti.static(gbuffer.triangle.shape)
    result = False
    if (x + y) % 2 == 1 and 0 < x < width - 1 and 0 < y < height - 1:
        triangle = gbuffer.triangle[x, y]
        if triangle >= 0:
            result = True
            drawn = materials.triangle_object[triangle]
            depth, normal = gbuffer.depth[x, y], gbuffer.normal[x, y]
            for k in ti.static(range(4)):
                i, j = x + _NEIGHBOURS[k][0], y + _NEIGHBOURS[k][1]
                other = gbuffer.triangle[i, j]
                if other < 0:
                    result = False
                else:  # nested: Taichi evaluates both sides of `or`
                    near = ti.abs(gbuffer.depth[i, j] - depth) <= SIMILAR_DEPTH * depth
                    alike = gbuffer.normal[i, j].dot(normal) >= SIMILAR_NORMAL
                    if materials.triangle_object[other] != drawn or not near or not alike:
                        result = False
    return result


@ti.func
def edge_distance2(x, y, frame: ti.template()):
    """r² of pixel (x, y): its squared distance from the image's centre in
    half-diagonals."""
    width, height = ti.static(frame.shape)
    half = ti.Vector([0.5 * width, 0.5 * height])
    return (ti.Vector([x + 0.5, y + 0.5]) - half).norm_sqr() / half.norm_sqr()


UNSHADED = -1.0
"""What :func:`shade` leaves in the red channel of a pixel it skips for
:func:`fill_checkerboard` (a shaded colour is never negative)."""


@ti.kernel
def fill_checkerboard(frame: ti.template()):
    """Checkerboard shading's second half: each pixel :func:`shade` skipped (its red
    channel :data:`UNSHADED`; one :func:`filled`) takes the mean of its four neighbours'
    colours (shaded, never skipped themselves), as checkerboard rendering reconstructs
    its unshaded half (El Mansouri 2016, without the previous frame). Only the pixels
    of odd x + y inside the border are looked at."""
    width, height = ti.static(frame.shape)
    for i, y in ti.ndrange(width // 2, (1, height - 1)):
        x = 2 * i + 1 - y % 2  # odd x + y
        if 0 < x < width - 1 and frame[x, y][0] == UNSHADED:
            frame[x, y] = 0.25 * (
                frame[x - 1, y] + frame[x + 1, y] + frame[x, y - 1] + frame[x, y + 1]
            )


@ti.kernel
def shade(
    gbuffer: ti.template(),
    materials: ti.template(),
    lighting: ti.template(),
    light: ti.template(),
    frame: ti.template(),
    view: ti.i32,
    checkerboard: ti.i32,
):
    """Write ``frame[x, y]`` from the G-buffer (both ``(width, height)``, x right,
    y up: GGUI's layout).

    ``light`` holds the camera: ``eye`` [m], ``forward``, ``intensity`` of the
    headlight [W/sr], its cone ``cos_inner``/``cos_outer``, ``ambient`` (IBL
    scale), ``exposure``, ``far`` [m] for the depth view, ``smoke`` [1/m] (the density
    of cautery smoke in front of the scope: a pixel at distance d is veiled by
    1 - exp(-smoke d) of SMOKE_RADIANCE), ``vignetting`` v (the shaded colour falls
    by 1 - v r² towards the corners, r the radius in half-diagonals: the laparoscope's
    lens, its distortion being the G-buffer's) and ``background``. The
    material of a pixel with char c is blended towards the charred wound: albedo to
    CHAR_ALBEDO and roughness to CHAR_ROUGHNESS by c, the mucus film scaled by
    1 - c (the wound is dry), metalness kept; then towards blood (BLOOD_ALBEDO,
    BLOOD_ROUGHNESS, a full wet film) by its cover 1 - exp(-film / BLOOD_FILM), the
    G-buffer's ``blood`` film [m]. Before that the material gets its procedural detail
    (:func:`~taichi_lap.kernels.surface_detail.surface_detail`) and the tint of the
    vessels under it (:func:`~taichi_lap.kernels.subsurface.vessel_tint`) at the
    pixel's rest-space point (:func:`rest_point`). With ``checkerboard`` (view 0
    only) the pixels :func:`filled` are skipped, marked :data:`UNSHADED` for
    :func:`fill_checkerboard`."""
    for x, y in frame:
        triangle = gbuffer.triangle[x, y]
        colour = light.background[None]
        skipped = False
        if checkerboard and view == 0:
            skipped = filled(gbuffer, materials, x, y)
        if triangle >= 0 and not skipped:
            m, c = materials.triangle_material[triangle], gbuffer.char[x, y]
            p = gbuffer.position[x, y]
            rest = rest_point(materials, triangle, gbuffer.weights[x, y])
            albedo, n = surface_detail(
                materials, m, rest, materials.albedo[m], gbuffer.normal[x, y]
            )
            albedo = vessel_tint(materials, m, rest, albedo)
            albedo = ti.math.mix(albedo, ti.Vector(CHAR_ALBEDO), c)
            roughness = ti.math.mix(materials.roughness[m], CHAR_ROUGHNESS, c)
            metalness, mucus = materials.metalness[m], materials.mucus[m] * (1.0 - c)
            blood = 0.0
            if gbuffer.blood[x, y] > 0.0:  # most pixels: no exp
                blood = 1.0 - ti.exp(-gbuffer.blood[x, y] / BLOOD_FILM)  # the film's cover
                albedo = ti.math.mix(albedo, ti.Vector(BLOOD_ALBEDO), blood)
                roughness = ti.math.mix(roughness, BLOOD_ROUGHNESS, blood)
                mucus = ti.math.mix(mucus, 1.0, blood)
            to_eye = light.eye[None] - p
            distance = to_eye.norm(1e-9)
            v = to_eye / distance
            if view == 0:
                spot = ti.math.smoothstep(
                    light.cos_outer[None], light.cos_inner[None], -v.dot(light.forward[None])
                )
                direct = headlight_brdf_cos(n, v, albedo, roughness, metalness, mucus) * (
                    light.intensity[None] * spot / (distance * distance)
                )
                ambient = ibl_diffuse(lighting, n, v, albedo, metalness, mucus) + ibl_specular(
                    lighting, n, v, albedo, roughness, metalness, mucus
                )
                lit = (direct + light.ambient[None] * ambient) * light.exposure[None]
                if light.smoke[None] > 0.0:
                    haze = 1.0 - ti.exp(-light.smoke[None] * distance)  # Beer-Lambert
                    lit = ti.math.mix(lit, ti.Vector(SMOKE_RADIANCE), haze)
                colour = tone_map(lit)
                colour *= ti.max(1.0 - light.vignetting[None] * edge_distance2(x, y, frame), 0.0)
            elif view == 1:
                colour = albedo
            elif view == 2:
                colour = 0.5 * n + 0.5
            elif view == 3:
                colour = ti.Vector([1.0, 1.0, 1.0]) * (
                    1.0 - ti.min(distance / light.far[None], 1.0)
                )
            elif view == 4:
                colour = ti.Vector([roughness, roughness, roughness])
            elif view == 5:
                colour = ti.Vector([metalness, metalness, metalness])
            elif view == 6:
                colour = ti.Vector([mucus, mucus, mucus])
            elif view == 7:
                colour = object_colour(materials.triangle_object[triangle])
            elif view == 8:
                colour = ti.Vector([c, c, c])
            else:
                colour = ti.Vector([blood, blood, blood])
        if skipped:
            colour = ti.Vector([UNSHADED, 0.0, 0.0])
        frame[x, y] = colour


DEPTH_BINS = 64
"""Bins of :func:`depth_histogram`: 8 per octave over 8 octaves from the near plane."""
DEPTH_BINS_PER_OCTAVE = 8


HISTOGRAM_STRIDE = 4
""":func:`depth_histogram` counts every this many rows and columns (a sixteenth of a
640x480 image is 19,200 pixels: plenty for a quantile; two threads adding to 64 bins
make it a kernel of contended atomics)."""


@ti.kernel
def depth_histogram(gbuffer: ti.template(), counts: ti.template(), near: ti.f32):
    """How many pixels show a surface at each depth, counted on every
    :data:`HISTOGRAM_STRIDE`-th row and column: ``counts[k]`` (i32, exact in any order)
    of the pixels whose depth d [m] lies in octave bin k = floor(8 log2(d / near)),
    clamped to the :data:`DEPTH_BINS`; the background is not counted."""
    width, height = ti.static(gbuffer.depth.shape)
    ti.loop_config(serialize=True)  # 64 bins: less than a thread-pool launch
    for k in range(DEPTH_BINS):
        counts[k] = 0
    stride = ti.static(HISTOGRAM_STRIDE)
    for i, j in ti.ndrange((width + stride - 1) // stride, (height + stride - 1) // stride):
        x, y = stride * i, stride * j
        if gbuffer.triangle[x, y] >= 0:
            octave = ti.log(ti.max(gbuffer.depth[x, y], near) / near) / ti.log(2.0)
            k = ti.min(ti.cast(octave * DEPTH_BINS_PER_OCTAVE, ti.i32), DEPTH_BINS - 1)
            ti.atomic_add(counts[k], 1)


MARK_HALF_WIDTH = 0.0006  # [m]
MARK_DASH = 0.004  # [m] one dash and its gap along the line


@ti.func
def _mark(gbuffer: ti.template(), frame: ti.template(), x, y, smoke):
    """Pixel (x, y) of ``frame`` blended towards MARK_COLOUR, the less the thicker the
    cautery ``smoke`` [1/m] between it and the scope (by exp(-smoke depth), as
    :func:`shade` veils the tissue)."""
    clear = ti.exp(-smoke * gbuffer.depth[x, y])  # what the smoke lets through
    frame[x, y] = ti.math.mix(frame[x, y], ti.Vector(MARK_COLOUR), 0.75 * clear)


@ti.kernel
def mark_plane(
    gbuffer: ti.template(),
    materials: ti.template(),
    frame: ti.template(),
    organ: ti.i32,
    point: ti.types.vector(3, ti.f32),
    normal: ti.types.vector(3, ti.f32),
    start: ti.types.vector(3, ti.f32),
    along: ti.types.vector(3, ti.f32),
    length: ti.f32,
    smoke: ti.f32,
):
    """Draw a task's planned transection on the tissue (``[task.plane]``): the pixels
    of ``organ`` (object index) whose surface point lies within MARK_HALF_WIDTH [m] of
    the plane through ``point`` with unit ``normal``, beside the planned line (from
    ``start`` along unit ``along``, ``length`` [m]), dashed every MARK_DASH, are
    marked in MARK_COLOUR, veiled by the cautery ``smoke`` [1/m] (:func:`_mark`). It
    follows the tissue as it deforms and is cut."""
    for x, y in frame:
        triangle = gbuffer.triangle[x, y]
        if triangle >= 0 and materials.triangle_object[triangle] == organ:
            p = gbuffer.position[x, y]
            s = (p - start).dot(along)
            on_plane = ti.abs((p - point).dot(normal)) < MARK_HALF_WIDTH
            if on_plane and 0.0 <= s <= length and ti.math.mod(s, MARK_DASH) < 0.6 * MARK_DASH:
                _mark(gbuffer, frame, x, y, smoke)


TARGET_OUTLINE = 2
"""[pixels] how far inside a task's view target its outline reaches."""


@ti.kernel
def outline_target(
    gbuffer: ti.template(),
    materials: ti.template(),
    frame: ti.template(),
    target: ti.i32,
    smoke: ti.f32,
):
    """Outline a task's view target (``[task.view]``, object index ``target``) in the
    marker's colour: the pixels showing it within TARGET_OUTLINE pixels of a pixel
    that does not (another object, the background; past the image's edge it runs on)
    are marked as :func:`mark_plane` marks the planned line (:func:`_mark`). Only what
    shows is outlined: the trainee sees where the target is uncovered."""
    width, height = ti.static(frame.shape)
    for x, y in frame:
        triangle = gbuffer.triangle[x, y]
        if triangle >= 0 and materials.triangle_object[triangle] == target:
            edge = False
            for step in ti.static(range(1, TARGET_OUTLINE + 1)):
                for d in ti.static(_NEIGHBOURS):
                    u, v = x + d[0] * step, y + d[1] * step
                    if 0 <= u < width and 0 <= v < height:  # it runs on past the image
                        other = gbuffer.triangle[u, v]
                        if other < 0:
                            edge = True
                        elif materials.triangle_object[other] != target:
                            edge = True
            if edge:
                _mark(gbuffer, frame, x, y, smoke)
