"""Visibility buffer and G-buffer resolve of the reduced deferred shading pipeline
(seed 000 §6.3), rasterized in software so it runs unchanged on every backend.

Two passes (Burns & Hunt 2013, "The Visibility Buffer"):

1. Visibility: each triangle is clipped against the near plane ``w >= near`` (an
   endoscope sees tissue right at the lens; a crossing triangle leaves one or two),
   snapped to 1/256 px, and the pixel centres of its bounding box are tested with
   Pineda (1988) edge functions in exact i64 arithmetic and the top-left rule of
   Direct3D, so triangles sharing an edge or a vertex cover each centre exactly once.
   A covered centre takes ``atomic_min`` of one i64 key ``(depth_key << 32) |
   triangle``: the nearest fragment wins, equal depths go to the lowest triangle id.
   :func:`rasterize_visibility` walks a triangle's box in one thread (CPU);
   :func:`rasterize_visibility_by_pixel` gives each box pixel a thread (GPUs, and
   Mesa's lavapipe, which loses atomics inside loops). Both give the same ids.
2. :func:`resolve_gbuffer`, per pixel: the pixel's camera ray meets the winning
   triangle (Möller & Trumbore 1997) for perspective-correct barycentrics.

Conventions. Images are fields of shape ``(width, height)`` indexed ``[x, y]``,
origin bottom-left, y up (as ``ti.ui.Canvas.set_image`` takes them); pixel (x, y)
has its centre at NDC ``(2 (x + 0.5) / width - 1, 2 (y + 0.5) / height - 1)``.
Matrices act on column vectors, OpenGL style (:func:`camera_matrices`). The
rasterizer's depth is ``1 / w`` (w = view depth [m]): affine in screen space, ordered
as NDC z, no far plane needed; ``depth_key`` = f32 bits of +inf minus those of 1/w.
Triangles wholly outside a side or the far plane are skipped (one crossing the far
plane is drawn whole), back faces (clockwise on screen) are skipped for objects drawn
one-sided (closed surfaces facing out, whose back faces lie behind their front ones)
and drawn for the others (a sheet is seen from both sides), and triangles of zero
snapped area are skipped. Vertices farther than 2^20 px from the
image centre are pulled toward it along the line through it, so coordinates stay
below 2^29 and edge terms below 2^61; the pull depends on the vertex alone, so
meshes stay watertight.
"""

import math

import numpy as np
import taichi as ti

from taichi_lap.core.fields import FieldGroup, FieldOwner

SUBPIXEL_BITS = 8
SUBPIXEL = 1 << SUBPIXEL_BITS  # snapping grid: 1/256 px
GUARD_BAND = float(2**20)  # [px] from the image centre
VISIBILITY_CLEAR = 2**63 - 1  # no fragment: larger than every key
BACKGROUND_DEPTH = 1.0e30  # [m], finite so fast-math arithmetic on it stays defined
INF_BITS = 0x7F800000  # f32 bits of +inf
SAME_SURFACE = 1e-3
"""A triangle a bent ray crosses this fraction farther than its pixel's triangle's
plane continues that surface (a neighbour across a shared edge), not one behind it."""
PIXEL_ITEMS = 2**31 - 1  # most box pixels per frame on the by-pixel path


def camera_matrices(
    eye, target, up, fov_deg: float, aspect: float, near: float, far: float
) -> tuple[np.ndarray, np.ndarray]:
    """``(view, projection)``, float32 4x4, OpenGL conventions.

    View space is right-handed with the camera at the origin looking down -z, y up;
    positions in [m]. ``fov_deg`` is the vertical field of view [deg], ``aspect`` =
    width / height, ``near`` < ``far`` [m]. The projection maps view depth d = -z to
    clip ``w = d`` and z in [-w, w] (near -> -1, far -> +1); the renderer's kernels
    take ``view_projection = projection @ view`` acting on ``(x, y, z, 1)``.
    """
    eye, target, up = (np.asarray(v, np.float64) for v in (eye, target, up))
    if not 0.0 < near < far or not 0.0 < fov_deg < 180.0 or not aspect > 0.0:
        raise ValueError("need 0 < near < far, 0 < fov_deg < 180 and aspect > 0")
    forward = target - eye
    side = np.cross(forward, up)
    if np.linalg.norm(forward) == 0.0 or np.linalg.norm(side) < 1e-12 * np.linalg.norm(forward):
        raise ValueError("target must differ from eye and up must not be parallel to the view")
    forward /= np.linalg.norm(forward)
    side /= np.linalg.norm(side)
    true_up = np.cross(side, forward)
    view = np.eye(4)
    view[0, :3], view[1, :3], view[2, :3] = side, true_up, -forward
    view[:3, 3] = -view[:3, :3] @ eye
    focal = 1.0 / math.tan(math.radians(fov_deg) / 2.0)
    projection = np.zeros((4, 4))
    projection[0, 0], projection[1, 1] = focal / aspect, focal
    projection[2, 2] = (far + near) / (near - far)
    projection[2, 3] = 2.0 * far * near / (near - far)
    projection[3, 2] = -1.0
    return view.astype(np.float32), projection.astype(np.float32)


@ti.func
def _homogeneous(position):
    return ti.Vector([position.x, position.y, position.z, 1.0])


@ti.func
def _snap(clip, inv_w, width: ti.template(), height: ti.template()):
    """Screen position of clip-space ``(x, y, w)`` with ``inv_w`` = 1/w > 0, in 1/256 px
    as an i32 2-vector, pulled inside the guard band."""
    centre = ti.Vector([0.5 * width, 0.5 * height])
    offset = clip.xy * inv_w * centre
    reach = ti.max(ti.abs(offset.x), ti.abs(offset.y))
    if reach > GUARD_BAND:
        offset *= GUARD_BAND / reach
    return ti.floor((centre + offset) * SUBPIXEL + 0.5).cast(ti.i32)


@ti.func
def _near_crossing(inside, outside, near):
    """Point where edge inside -> outside (clip ``(x, y, w)``) meets w = near; computed
    from the inside end so triangles sharing the edge get the same point."""
    s = (inside.z - near) / (inside.z - outside.z)
    crossing = inside + s * (outside - inside)
    crossing.z = near
    return crossing


@ti.func
def _clip_and_snap(
    positions: ti.template(),
    triangles: ti.template(),
    t,
    view_projection,
    near,
    width: ti.template(),
    height: ti.template(),
):
    """Triangle t clipped to w >= near: ``(corners, screen, inv_w)`` with corners 3 or 4
    (0 if it lies outside a frustum plane), screen the 4x2 i32 corner positions
    [1/256 px] and inv_w their 1/w [1/m]."""
    c0 = view_projection @ _homogeneous(positions[triangles[3 * t]])
    c1 = view_projection @ _homogeneous(positions[triangles[3 * t + 1]])
    c2 = view_projection @ _homogeneous(positions[triangles[3 * t + 2]])
    x, y = ti.Vector([c0.x, c1.x, c2.x]), ti.Vector([c0.y, c1.y, c2.y])
    z, w = ti.Vector([c0.z, c1.z, c2.z]), ti.Vector([c0.w, c1.w, c2.w])
    corners, screen, inv_w = 0, ti.Matrix.zero(ti.i32, 4, 2), ti.Vector.zero(ti.f32, 4)
    if not (
        (x > w).all()
        or (x < -w).all()
        or (y > w).all()
        or (y < -w).all()
        or (z > w).all()
        or (w < near).all()
    ):
        p0, p1, p2 = c0.xyw, c1.xyw, c2.xyw
        in0, in1, in2 = w[0] >= near, w[1] >= near, w[2] >= near
        inside_count = ti.cast(in0, ti.i32) + ti.cast(in1, ti.i32) + ti.cast(in2, ti.i32)
        q0, q1, q2, q3 = p0, p1, p2, p2
        corners = 3
        if inside_count == 2:  # rotate the outside corner to c: quad a, b, bc, ca
            a, b, c = p0, p1, p2
            if not in0:
                a, b, c = p1, p2, p0
            elif not in1:
                a, b, c = p2, p0, p1
            q0, q1, q2, q3 = a, b, _near_crossing(b, c, near), _near_crossing(a, c, near)
            corners = 4
        elif inside_count == 1:  # rotate the inside corner to a: triangle a, ab, ac
            a, b, c = p2, p0, p1
            if in0:
                a, b, c = p0, p1, p2
            elif in1:
                a, b, c = p1, p2, p0
            q0, q1, q2 = a, _near_crossing(a, b, near), _near_crossing(a, c, near)
        inv_w = 1.0 / ti.Vector([q0.z, q1.z, q2.z, q3.z])
        s0, s1 = _snap(q0, inv_w[0], width, height), _snap(q1, inv_w[1], width, height)
        s2 = s3 = _snap(q2, inv_w[2], width, height)
        if corners == 4:
            s3 = _snap(q3, inv_w[3], width, height)
        screen = ti.Matrix([[s0.x, s0.y], [s1.x, s1.y], [s2.x, s2.y], [s3.x, s3.y]], ti.i32)
    return corners, screen, inv_w


@ti.func
def _corner(screen, k: ti.template()):
    return ti.Vector([screen[k, 0], screen[k, 1]]).cast(ti.i64)


@ti.func
def _fan_part(screen, inv_w, part, one_sided):
    """Fan triangle ``part`` (0: corners 0, 1, 2; 1: corners 0, 2, 3) made counter-
    clockwise: ``(a, b, c, inv_w, area2)``, corners as i64 2-vectors, area2 = twice its
    area [1/256 px]^2, 0 for a back face (clockwise) when ``one_sided``."""
    a, b, c = _corner(screen, 0), _corner(screen, 1), _corner(screen, 2)
    corner_inv_w = inv_w.xyz
    if part == 1:
        b, c, corner_inv_w = c, _corner(screen, 3), inv_w.xzw
    area2 = _edge(a, b, c)
    if area2 < 0:
        b, c = c, b
        corner_inv_w = corner_inv_w.xzy
        area2 = 0 if one_sided else -area2
    return a, b, c, corner_inv_w, area2


@ti.func
def _edge(u, v, p):
    """Pineda edge function (v - u) x (p - u) [1/256 px]^2, > 0 left of u -> v."""
    return (v.x - u.x) * (p.y - u.y) - (v.y - u.y) * (p.x - u.x)


@ti.func
def _tie_bias(u, v):
    """0 if a centre exactly on edge u -> v of a counter-clockwise triangle is inside
    (a left edge, going down, or a top edge, going in -x), else 1: the top-left rule
    with y up. Used only in the inside test ``edge >= bias``, never in barycentrics."""
    d = v - u
    bias = 1
    if d.y < 0 or (d.y == 0 and d.x < 0):
        bias = 0
    return ti.cast(bias, ti.i64)


@ti.func
def _weights(a, b, c, x, y):
    """Unnormalised barycentric weights (edge functions opposite a, b, c) at the
    centre of pixel (x, y), i64."""
    p = ti.Vector([x, y]).cast(ti.i64) * SUBPIXEL + SUBPIXEL // 2
    return ti.Vector([_edge(b, c, p), _edge(c, a, p), _edge(a, b, p)])


@ti.func
def _box(a, b, c, width: ti.template(), height: ti.template()):
    """Pixels whose centres the bounding box of (a, b, c) holds, clamped to the image:
    ``x0, y0, x1, y1`` (empty when x0 > x1 or y0 > y1)."""
    low, high, half = ti.min(a, ti.min(b, c)), ti.max(a, ti.max(b, c)), SUBPIXEL // 2
    first = ((ti.max(low, 0) + half - 1) >> SUBPIXEL_BITS).cast(ti.i32)  # arithmetic shifts: floor
    last = ((ti.min(high, ti.Vector([width, height]) * SUBPIXEL) - half) >> SUBPIXEL_BITS).cast(
        ti.i32
    )
    return first.x, first.y, last.x, last.y


@ti.func
def _fragment_key(weight, inv_w, inv_area2, triangle):
    """Visibility key of a covered centre: 1/w interpolated with the exact, unbiased
    weights (a convex combination, so slivers stay between their corners)."""
    depth = ti.cast(weight, ti.f32).dot(inv_w) * inv_area2
    depth_key = ti.max(INF_BITS - ti.bit_cast(depth, ti.i32), 0)
    return (ti.cast(depth_key, ti.i64) << 32) | ti.cast(triangle, ti.i64)


@ti.func
def _row_span(weight, step, bias, last):
    """The pixels k in 0..``last`` of a row whose centres a triangle covers, the row's
    edge functions being ``weight + k step`` (i64 3-vectors) and covered where all are
    >= ``bias``: ``(first, final)`` (empty when first > final), solved per edge in exact
    integer arithmetic, so a row of a large triangle costs no test per pixel outside
    it."""
    first, final = ti.i64(0), ti.cast(last, ti.i64)
    for i in ti.static(range(3)):
        short = bias[i] - weight[i]  # > 0: edge i excludes k = 0
        if step[i] > 0:
            if short > 0:  # weight + k step >= bias from k = ceil(short / step)
                first = ti.max(first, (short + step[i] - 1) // step[i])
        elif step[i] < 0:  # ... while k <= (weight - bias) / |step|
            if short > 0:
                final = ti.i64(-1)
            else:
                final = ti.min(final, (-short) // (-step[i]))
        elif short > 0:
            final = ti.i64(-1)
    first = ti.min(first, final + 1)  # within 0..last + 1 before narrowing to i32
    return ti.cast(first, ti.i32), ti.cast(final, ti.i32)


@ti.func
def _clear(visibility: ti.template()):
    for x, y in visibility:
        visibility[x, y] = ti.i64(VISIBILITY_CLEAR)


@ti.kernel
def rasterize_visibility(
    positions: ti.template(),
    triangles: ti.template(),
    triangle_object: ti.template(),
    one_sided: ti.template(),
    triangle_count: ti.i32,
    view_projection: ti.math.mat4,
    near: ti.f32,
    visibility: ti.template(),
):
    """Clear ``visibility`` to VISIBILITY_CLEAR, then for each triangle t < triangle_count
    (vertex ids ``triangles[3t:3t+3]`` into ``positions`` [m]) write, per covered pixel,
    ``min(key)`` with key = ``(depth_key << 32) | t`` (i64, see the module docstring);
    a back face is skipped where ``one_sided`` (per object, i32) of its object
    ``triangle_object[t]`` is not 0.
    ``near`` [m] > 0 is the clipping distance on w. One thread per triangle walks the
    covered span of each row of its bounding box (:func:`_row_span`) with incremental
    edge functions (the CPU path). Reads positions, triangles."""
    _clear(visibility)
    width, height = ti.static(visibility.shape)
    for t in range(triangle_count):
        corners, screen, inv_w = _clip_and_snap(
            positions, triangles, t, view_projection, near, width, height
        )
        culled = one_sided[triangle_object[t]] != 0
        for part in range(corners - 2):
            a, b, c, corner_inv_w, area2 = _fan_part(screen, inv_w, part, culled)
            if area2 > 0:
                x0, y0, x1, y1 = _box(a, b, c, width, height)
                bias = ti.Vector([_tie_bias(b, c), _tie_bias(c, a), _tie_bias(a, b)])
                step = ti.Vector([b.y - c.y, c.y - a.y, a.y - b.y]) * SUBPIXEL
                inv_area2 = 1.0 / ti.cast(area2, ti.f32)
                for y in range(y0, y1 + 1):
                    weight = _weights(a, b, c, x0, y)
                    first, last = _row_span(weight, step, bias, x1 - x0)
                    weight += step * ti.cast(first, ti.i64)
                    for x in range(x0 + first, x0 + last + 1):
                        key = _fragment_key(weight, corner_inv_w, inv_area2, t)
                        if key < visibility[x, y]:  # skips most atomics of hidden fragments
                            ti.atomic_min(visibility[x, y], key)
                        weight += step


@ti.data_oriented
class BoxPixels(FieldOwner):
    """Per fan part (two per triangle) of :func:`rasterize_visibility_by_pixel`: snapped
    corners, their 1/w, pixel box ``(x0, y0, box width)`` and the running end of the
    box pixel counts; room for ``capacity`` triangles."""

    BLOCK = 512  # parts per block of the prefix sum

    def __init__(self, capacity: int):
        self.capacity = capacity
        parts, blocks = 2 * capacity, (2 * capacity + self.BLOCK - 1) // self.BLOCK
        # 32-bit types only: Vulkan misplaces small fields after i64 ones
        group = self._declare_in(None)
        self.corner = group.field(ti.i32, parts, matrix=(3, 2))
        self.inv_w = group.field(ti.f32, parts, vector=3)
        self.box = group.field(ti.i32, parts, vector=3)
        self.count = group.field(ti.i32, parts)
        self.end = group.field(ti.i32, parts)
        self.block_start = group.field(ti.i32, blocks)
        self.total = group.field(ti.i32, None)
        self._finalize()


@ti.func
def _add_counts(a, b):
    """a + b for counts a, b >= 0, saturating at PIXEL_ITEMS."""
    return ti.min(a, PIXEL_ITEMS - b) + b


@ti.kernel
def rasterize_visibility_by_pixel(
    positions: ti.template(),
    triangles: ti.template(),
    triangle_object: ti.template(),
    one_sided: ti.template(),
    triangle_count: ti.i32,
    view_projection: ti.math.mat4,
    near: ti.f32,
    visibility: ti.template(),
    box_pixels: ti.template(),
):
    """The same keys as :func:`rasterize_visibility`, one thread per bounding-box pixel
    of each fan part (the GPU path: big triangles spread over many threads, and the
    atomic stays at the top level of its loop, which Mesa's lavapipe needs). A thread
    finds its part by binary search in the prefix sums of box pixel counts (summed in
    blocks; at most 2^31 - 1 box pixels in all, the rest is dropped). Writes
    ``visibility`` and ``box_pixels``."""
    _clear(visibility)
    width, height = ti.static(visibility.shape)
    parts, block = 2 * triangle_count, ti.static(box_pixels.BLOCK)
    for t in range(triangle_count):
        corners, screen, inv_w = _clip_and_snap(
            positions, triangles, t, view_projection, near, width, height
        )
        culled = one_sided[triangle_object[t]] != 0
        for part in ti.static(range(2)):
            a, b, c, corner_inv_w, area2 = _fan_part(screen, inv_w, part, culled)
            x0, y0, x1, y1 = _box(a, b, c, width, height)
            count = 0
            if part < corners - 2 and area2 > 0 and x0 <= x1 and y0 <= y1:
                count = (x1 - x0 + 1) * (y1 - y0 + 1)
            p = 2 * t + part
            box_pixels.corner[p] = ti.Matrix([[a.x, a.y], [b.x, b.y], [c.x, c.y]], ti.i32)
            box_pixels.inv_w[p], box_pixels.count[p] = corner_inv_w, count
            box_pixels.box[p] = ti.Vector([x0, y0, x1 - x0 + 1])
    blocks = (parts + block - 1) // block
    for k in range(blocks):  # prefix sums of the counts: per block, over blocks, in each block
        total = 0
        for p in range(k * block, ti.min(k * block + block, parts)):
            total = _add_counts(total, box_pixels.count[p])
        box_pixels.block_start[k] = total
    ti.loop_config(serialize=True)  # one thread, without the CPU's thread-pool launch
    for _ in range(1):
        running = 0
        for k in range(blocks):
            running, box_pixels.block_start[k] = (
                _add_counts(running, box_pixels.block_start[k]),
                running,
            )
        box_pixels.total[None] = running
    for k in range(blocks):
        running = box_pixels.block_start[k]
        for p in range(k * block, ti.min(k * block + block, parts)):
            running = _add_counts(running, box_pixels.count[p])
            box_pixels.end[p] = running
    for item in range(box_pixels.total[None]):
        low, high = 0, parts - 1  # first part whose end passes item
        while low < high:
            middle = (low + high) // 2
            if box_pixels.end[middle] > item:
                high = middle
            else:
                low = middle + 1
        start = 0
        if low > 0:
            start = box_pixels.end[low - 1]
        box, corner = box_pixels.box[low], box_pixels.corner[low]
        x, y = box[0] + (item - start) % box[2], box[1] + (item - start) // box[2]
        a, b, c = _corner(corner, 0), _corner(corner, 1), _corner(corner, 2)
        weight = _weights(a, b, c, x, y)
        if (weight >= ti.Vector([_tie_bias(b, c), _tie_bias(c, a), _tie_bias(a, b)])).all():
            inv_area2 = 1.0 / ti.cast(_edge(a, b, c), ti.f32)
            key = _fragment_key(weight, box_pixels.inv_w[low], inv_area2, low // 2)
            ti.atomic_min(visibility[x, y], key)


@ti.func
def _visible(visibility: ti.template(), pixel):
    """The triangle the visibility buffer holds at ``pixel`` (ivec2), -1 for none or
    outside the image."""
    width, height = ti.static(visibility.shape)
    triangle = -1
    if 0 <= pixel[0] < width and 0 <= pixel[1] < height:
        key = visibility[pixel[0], pixel[1]]
        if key != ti.i64(VISIBILITY_CLEAR):
            triangle = ti.cast(key & ti.i64(0xFFFFFFFF), ti.i32)
    return triangle


@ti.func
def ray_barycentrics(positions: ti.template(), triangles: ti.template(), eye, ray, triangle):
    """(u, v, t): where the ray from ``eye`` along ``ray`` meets the plane of
    ``triangle`` (Möller-Trumbore in f32, vertices taken relative to the eye), as the
    weights of its second and third corners and the distance t in lengths of ``ray``
    ([m] for a unit ray); (1/3, 1/3, inf) when parallel or no triangle."""
    u, v, t = 1.0 / 3.0, 1.0 / 3.0, BACKGROUND_DEPTH
    if triangle >= 0:
        first = 3 * triangle
        v0 = positions[triangles[first]] - eye
        e1 = positions[triangles[first + 1]] - eye - v0
        e2 = positions[triangles[first + 2]] - eye - v0
        p = ray.cross(e2)
        det = e1.dot(p)
        if ti.abs(det) > 1e-30:
            q = v0.cross(e1)  # (origin - v0) x e1 with the origin at the eye
            u = -v0.dot(p) / det
            v = -ray.dot(q) / det
            t = -e2.dot(q) / det
    return u, v, t


@ti.func
def _inside(u, v):
    """Whether barycentric weights (u, v) lie on their triangle."""
    return u >= 0.0 and v >= 0.0 and u + v <= 1.0


def lens_coefficients(distortion: float, width: int, height: int) -> np.ndarray:
    """The wide-angle lens of :func:`resolve_gbuffer` as :func:`lens_ndc` applies it:
    ``(scale, bend)``, f32, with which the pixel at ``p`` pixels from the centre of a
    ``width`` x ``height`` image looks along the rectilinear ray at ``(scale + bend
    |p|²)`` times its NDC. ``scale`` keeps the middles of the left and right edges on
    their rays; bend = 0 for no distortion. Computed once per frame, not per pixel."""
    half2 = (0.5 * width) ** 2 + (0.5 * height) ** 2
    scale = 1.0 / (1.0 + distortion * (0.5 * width) ** 2 / half2)
    return np.array([scale, distortion * scale / half2], np.float32)


@ti.func
def lens_ndc(x, y, half, lens):
    """The rectilinear image point (NDC) the wide-angle lens ``lens``
    (:func:`lens_coefficients`) shows at the centre of pixel ``(x, y)`` of an image of
    ``half`` its size (:func:`resolve_gbuffer`)."""
    ndc = ti.Vector([(x + 0.5) / half[0] - 1.0, (y + 0.5) / half[1] - 1.0])
    if lens[1] != 0.0:
        ndc *= lens[0] + lens[1] * (ndc * half).norm_sqr()
    return ndc


@ti.kernel
def lens_sources(lens: ti.math.vec2, source: ti.template()):
    """``source[x, y]``: the pixel of the rectilinear image whose centre lies nearest
    where the ray of pixel (x, y) through the lens ``lens`` crosses it
    (:func:`lens_ndc`), packed as ``column << 16 | row``, -1 past the image. Made once
    per lens: the resolve then finds each pixel's triangle by a lookup that waits on
    no arithmetic (its lens arithmetic ahead of the lookup cost 1.5 ms a 640x480 frame
    on the CPU)."""
    width, height = ti.static(source.shape)
    half = ti.Vector([0.5 * width, 0.5 * height])
    for x, y in source:
        at = (lens_ndc(x, y, half, lens) + 1.0) * half
        packed = -1
        if 0.0 <= at[0] < width and 0.0 <= at[1] < height:
            pixel = ti.cast(at, ti.i32)  # >= 0: the floor
            packed = (pixel[0] << 16) | pixel[1]
        source[x, y] = packed


def ray_basis(view_projection) -> np.ndarray:
    """``(base, along_x, along_y)`` (rows, f32) with which the eye's ray through the
    image point ``ndc`` runs along ``base + ndc_x along_x + ndc_y along_y``
    (:func:`ray_towards`): the cross product of the clip planes x = ndc_x w and y =
    ndc_y w (rows r_x - ndc_x r_w and r_y - ndc_y r_w of ``view_projection``), which
    is linear in ndc since r_w x r_w = 0, turned towards increasing w. Computed once
    per frame, not per pixel."""
    matrix = np.asarray(view_projection, np.float64)
    row_x, row_y, row_w = matrix[0, :3], matrix[1, :3], matrix[3, :3]
    basis = np.stack([np.cross(row_x, row_y), np.cross(row_y, row_w), np.cross(row_w, row_x)])
    if basis[0] @ row_w < 0.0:  # along_x and along_y are normal to r_w: base decides
        basis = -basis
    return basis.astype(np.float32)


@ti.func
def ray_towards(rays, ndc):
    """The direction (not unit) from the eye through image point ``ndc``, of the ray
    basis ``rays`` (:func:`ray_basis`, a mat3 of rows)."""
    return rays[0, :] + ndc[0] * rays[1, :] + ndc[1] * rays[2, :]


@ti.kernel
def resolve_gbuffer(
    positions: ti.template(),
    normals: ti.template(),
    char: ti.template(),
    blood: ti.template(),
    triangles: ti.template(),
    visibility: ti.template(),
    eye: ti.math.vec3,
    rays: ti.math.mat3,
    lens: ti.math.vec2,
    lens_source: ti.template(),
    gbuffer_depth: ti.template(),
    gbuffer_position: ti.template(),
    gbuffer_normal: ti.template(),
    gbuffer_char: ti.template(),
    gbuffer_blood: ti.template(),
    gbuffer_weights: ti.template(),
    gbuffer_triangle: ti.template(),
):
    """Per pixel: the ray of the laparoscope's wide-angle lens through the pixel centre
    (one-term radial barrel distortion, Brown 1966: the pixel at radius r, in
    half-diagonals from the centre, looks along the rectilinear ray at r (1 +
    distortion r²), scaled so that the middles of the left and right edges keep
    their rays; ``lens`` from :func:`lens_coefficients` and ``lens_source`` from
    :func:`lens_sources` of it, the ray from the basis ``rays`` of :func:`ray_basis`),
    the winning triangle t of ``visibility`` at the pixel that ray
    crosses (or background, also past the image at the corners; through a lens, when
    the ray misses t, the nearest triangle of the four pixel centres around that point
    that it crosses, unless it lies behind t's plane: a silhouette keeps what is in
    front), intersected with the ray from ``eye`` [m] (:func:`ray_barycentrics`;
    barycentrics clamped to [0, 1] and
    renormalised, so slivers and edge-on hits stay on the triangle). Writes
    ``gbuffer_depth`` = |hit - eye| [m] (BACKGROUND_DEPTH if none), ``gbuffer_position``
    = hit [m] (0), ``gbuffer_normal`` = the barycentric mix of ``normals``, normalised
    and flipped to face the eye (0; the geometric normal if the mix vanishes),
    ``gbuffer_char`` and ``gbuffer_blood`` = the same mix of the vertices' ``char`` and
    ``blood`` (0), ``gbuffer_weights`` = the hit's barycentric weights of t's second
    and third corners (1/3, 1/3) and ``gbuffer_triangle`` = t (-1)."""
    width, height = ti.static(visibility.shape)
    half = ti.Vector([0.5 * width, 0.5 * height])
    for x, y in visibility:
        ndc = lens_ndc(x, y, half, lens)
        distorted = lens[1] != 0.0
        triangle, seen = _visible(visibility, ti.Vector([x, y])), True
        source = ti.Vector([x + 0.5, y + 0.5])  # where the ray crosses the rectilinear image
        if distorted:
            source = (ndc + 1.0) * half
            packed = lens_source[x, y]
            seen, triangle = packed >= 0, -1
            if seen:
                triangle = _visible(visibility, ti.Vector([packed >> 16, packed & 0xFFFF]))
        ray = ti.Vector([0.0, 0.0, 1.0])
        u, v, reach = 1.0 / 3.0, 1.0 / 3.0, BACKGROUND_DEPTH
        if triangle >= 0 or (distorted and seen):
            ray = ray_towards(rays, ndc)
            u, v, reach = ray_barycentrics(positions, triangles, eye, ray, triangle)
        if distorted and seen and (triangle < 0 or not _inside(u, v)):
            # a bent ray need not cross the triangle at its pixel's centre: the nearest
            # triangle of the four centres around it that it crosses, not behind the
            # first one's plane (so a silhouette keeps what is in front of it)
            corner = ti.cast(ti.floor(source - 0.5), ti.i32)
            nearest_hit = reach * (1.0 + SAME_SURFACE) if reach > 0.0 else BACKGROUND_DEPTH
            for k in ti.static(range(4)):
                other = _visible(visibility, corner + ti.Vector([k % 2, k // 2]))
                if other >= 0 and other != triangle:  # that one missed or was taken
                    ou, ov, hit_at = ray_barycentrics(positions, triangles, eye, ray, other)
                    if _inside(ou, ov) and 0.0 < hit_at < nearest_hit:
                        triangle, u, v, nearest_hit = other, ou, ov, hit_at
        depth = BACKGROUND_DEPTH
        position, normal = ti.Vector([0.0, 0.0, 0.0]), ti.Vector([0.0, 0.0, 0.0])
        charred, bloody = 0.0, 0.0
        weights = ti.Vector([1.0 / 3.0, 1.0 / 3.0])
        if triangle >= 0:
            first = 3 * triangle
            i0, i1, i2 = triangles[first], triangles[first + 1], triangles[first + 2]
            v0, v1, v2 = positions[i0] - eye, positions[i1] - eye, positions[i2] - eye
            e1, e2 = v1 - v0, v2 - v0
            b0 = ti.math.clamp(1.0 - u - v, 0.0, 1.0)
            b1, b2 = ti.math.clamp(u, 0.0, 1.0), ti.math.clamp(v, 0.0, 1.0)
            total = b0 + b1 + b2
            b0, b1, b2 = b0 / total, b1 / total, b2 / total
            weights = ti.Vector([b1, b2])
            hit = b0 * v0 + b1 * v1 + b2 * v2
            depth, position = hit.norm(), hit + eye
            mix = b0 * normals[i0] + b1 * normals[i1] + b2 * normals[i2]
            if mix.norm_sqr() < 1e-24:
                mix = e1.cross(e2)
            normal = mix.normalized()
            if normal.dot(hit) > 0.0:
                normal = -normal
            charred = b0 * char[i0] + b1 * char[i1] + b2 * char[i2]
            charred = ti.math.clamp(charred, 0.0, 1.0)  # the rounding of the mix
            bloody = ti.max(b0 * blood[i0] + b1 * blood[i1] + b2 * blood[i2], 0.0)
        gbuffer_triangle[x, y], gbuffer_depth[x, y] = triangle, depth
        gbuffer_position[x, y], gbuffer_normal[x, y] = position, normal
        gbuffer_char[x, y], gbuffer_blood[x, y] = charred, bloody
        gbuffer_weights[x, y] = weights


@ti.kernel
def draw_spheres(
    centres: ti.template(),
    sphere_triangle: ti.template(),
    count: ti.i32,
    radius: ti.f32,
    film: ti.f32,
    eye: ti.math.vec3,
    rays: ti.math.mat3,
    lens: ti.math.vec2,
    gbuffer: ti.template(),
):
    """The first ``count`` spheres of ``radius`` [m] at ``centres`` (falling drops of
    blood) into a resolved ``gbuffer``, where the pixel's ray (through the same lens as
    :func:`resolve_gbuffer`) meets one nearer than what the pixel holds: the depth and
    position of the hit, the sphere's normal there, no char, a blood film ``film`` [m]
    and the triangle ``sphere_triangle[k]`` (whose material the film covers) at its
    centre (weights 1/3)."""
    width, height = ti.static(gbuffer.depth.shape)
    half = ti.Vector([0.5 * width, 0.5 * height])
    for x, y in gbuffer.depth:
        ray = ray_towards(rays, lens_ndc(x, y, half, lens)).normalized()
        nearest, sphere = gbuffer.depth[x, y], -1
        for k in range(count):
            towards = centres[k] - eye
            along = towards.dot(ray)
            reach = along * along - towards.norm_sqr() + radius * radius
            if reach >= 0.0:
                hit_at = along - ti.sqrt(reach)
                if 0.0 < hit_at < nearest:
                    nearest, sphere = hit_at, k
        if sphere >= 0:
            hit = eye + nearest * ray
            gbuffer.depth[x, y], gbuffer.position[x, y] = nearest, hit
            gbuffer.normal[x, y] = (hit - centres[sphere]).normalized()
            gbuffer.char[x, y], gbuffer.blood[x, y] = 0.0, film
            gbuffer.triangle[x, y] = sphere_triangle[sphere]
            gbuffer.weights[x, y] = ti.Vector([1.0 / 3.0, 1.0 / 3.0])


class GBuffer:
    """Visibility buffer and G-buffer of a ``width`` x ``height`` image, fields of shape
    ``(width, height)`` indexed ``[x, y]`` (origin bottom-left), in one SNode tree:
    ``visibility`` (i64 keys) and the outputs of :func:`resolve_gbuffer`: ``depth``
    (f32 [m]), ``position`` (vec3 [m]), ``normal`` (unit vec3), ``char`` (f32, 0 fresh
    to 1 charred tissue), ``blood`` (f32, the blood film's thickness [m]), ``weights``
    (vec2, the barycentric weights of the triangle's second and third corners) and
    ``triangle`` (i32, -1 for background); ``lens_source`` (i32) holds the lens's
    lookup (:func:`lens_sources`). ``by_pixel`` picks
    :func:`rasterize_visibility_by_pixel` (default: on every backend but the CPU)."""

    def __init__(self, width: int, height: int, *, by_pixel: bool | None = None):
        if width < 1 or height < 1 or max(width, height) > 16384:
            raise ValueError(f"image size must lie in 1..16384, got {width} x {height}")
        self.width, self.height = int(width), int(height)
        if by_pixel is None:
            by_pixel = ti.lang.impl.current_cfg().arch not in (ti.x64, ti.arm64)
        self.by_pixel, self.box_pixels = by_pixel, None
        group = FieldGroup()  # the i64 field last (see BoxPixels)
        for name, dtype, vector in (
            ("depth", ti.f32, 0),
            ("position", ti.f32, 3),
            ("normal", ti.f32, 3),
            ("char", ti.f32, 0),
            ("blood", ti.f32, 0),
            ("weights", ti.f32, 2),
            ("triangle", ti.i32, 0),
            ("lens_source", ti.i32, 0),
            ("visibility", ti.i64, 0),
        ):
            setattr(self, name, group.field(dtype, self.width, vector=vector, columns=self.height))
        group.finalize()
        self._lens = None  # the lens coefficients lens_source was made for

    def render(
        self,
        positions,
        normals,
        char,
        blood,
        triangles,
        triangle_object,
        one_sided,
        triangle_count: int,
        eye,
        view_projection,
        near: float,
        distortion: float = 0.0,
    ) -> None:
        """Rasterize ``triangle_count`` triangles of ``positions`` [m] (flat vertex ids in
        ``triangles``; the back faces of those whose object, ``triangle_object``, is
        drawn ``one_sided``, skipped: :func:`rasterize_visibility`) seen from ``eye``
        [m] through ``view_projection`` (4x4, see
        :func:`camera_matrices`), clipped at view depth ``near`` [m], and resolve the
        G-buffer through a lens of barrel ``distortion`` (:func:`resolve_gbuffer`),
        interpolating the vertex ``normals``, ``char`` and ``blood``. Two kernel
        launches (three when the lens changes)."""
        if not near > 0.0:
            raise ValueError(f"near must be > 0, got {near}")
        matrix = np.asarray(view_projection, dtype=np.float32)
        args = (
            positions,
            triangles,
            triangle_object,
            one_sided,
            int(triangle_count),
            matrix,
            float(near),
            self.visibility,
        )
        if self.by_pixel:
            capacity = 0 if self.box_pixels is None else self.box_pixels.capacity
            if capacity < triangle_count:  # grows by doubling: cutting adds triangles
                if self.box_pixels is not None:
                    self.box_pixels.close()
                self.box_pixels = BoxPixels(max(int(triangle_count), 2 * capacity, 1024))
            rasterize_visibility_by_pixel(*args, self.box_pixels)
        else:
            rasterize_visibility(*args)
        resolve_gbuffer(
            positions,
            normals,
            char,
            blood,
            triangles,
            self.visibility,
            np.asarray(eye, np.float32),
            ray_basis(matrix),
            self._lens_for(distortion),
            self.lens_source,
            self.depth,
            self.position,
            self.normal,
            self.char,
            self.blood,
            self.weights,
            self.triangle,
        )

    def _lens_for(self, distortion: float) -> np.ndarray:
        """The lens coefficients of ``distortion``, with ``lens_source`` made for them."""
        lens = lens_coefficients(distortion, self.width, self.height)
        if lens[1] != 0.0 and (self._lens is None or not np.array_equal(lens, self._lens)):
            lens_sources(lens, self.lens_source)
            self._lens = lens
        return lens

    def add_spheres(
        self,
        centres,
        triangles,
        count: int,
        radius: float,
        film: float,
        eye,
        view_projection,
        distortion: float = 0.0,
    ) -> None:
        """Draw the first ``count`` spheres of ``centres`` into the resolved G-buffer
        (:func:`draw_spheres`; ``eye``, ``view_projection`` and ``distortion`` those
        :meth:`render` was given)."""
        draw_spheres(
            centres,
            triangles,
            int(count),
            float(radius),
            float(film),
            np.asarray(eye, np.float32),
            ray_basis(view_projection),
            lens_coefficients(distortion, self.width, self.height),
            self,
        )


@ti.kernel
def gather_object_triangles(
    triangles: ti.template(),
    triangle_object: ti.template(),
    triangle_count: ti.i32,
    target: ti.i32,
    out: ti.template(),
    out_object: ti.template(),
    out_count: ti.template(),
):
    """The triangles (vertex ids, 3 each) of object ``target`` among the first
    ``triangle_count`` into ``out`` and ``target`` into ``out_object`` for each, their
    number into ``out_count[None]`` (in no fixed order: only the pixels they cover are
    used)."""
    out_count[None] = 0
    for t in range(triangle_count):
        if triangle_object[t] == target:
            slot = ti.atomic_add(out_count[None], 1)
            out_object[slot] = target
            for c in ti.static(range(3)):
                out[3 * slot + c] = triangles[3 * t + c]


@ti.kernel
def count_object_pixels(
    triangle: ti.template(), triangle_object: ti.template(), target: ti.i32
) -> ti.math.ivec2:
    """Pixels of a resolved G-buffer's ``triangle`` image: (those showing object
    ``target``, those showing any triangle); ``target`` < 0 counts no object."""
    shown, covered = 0, 0
    for x, y in triangle:
        t = triangle[x, y]
        if t >= 0:
            covered += 1
            if target >= 0 and triangle_object[t] == target:
                shown += 1
    return ti.math.ivec2(shown, covered)
