"""Rendering benchmark (issue: rendering).

A deforming blob (a sphere with moving bumps, 20k / 100k / 200k triangles)
filling most of a 640x480 or 1280x720 frame, drawn by the deferred renderer (seed
000 §6.3): ``vertex`` (gathered vertex normals), ``visibility`` (rasterized
visibility buffer and G-buffer resolve, near-plane clipping), ``shading`` (BRDF,
headlight, image-based light, tone mapping). Metric ``ms_per_frame`` (the three
passes; deforming the blob is not counted) and ``ms_<pass>`` per pass, cases like
``640x480-100k``. The shading is the scenes' default, checkerboard (``[camera]
checkerboard``); case ``640x480-100k-full`` shades every pixel.

Usage: python perf/bench_render.py [--quick] [--arch cpu] [--json OUT]
"""

import math
import time

import numpy as np

from taichi_lap.perf.common import arguments, report, result

RADIUS = 0.05  # [m]
EYE = (0.0, 0.01, 0.085)  # close, as an endoscope: the blob fills most of the frame


def cube_sphere(triangles: int) -> tuple[np.ndarray, np.ndarray]:
    """A sphere of about ``triangles`` triangles, each face of a cube gridded and
    projected onto it (no vertex in more than six triangles, as on an organ's mesh):
    (positions (V, 3), faces (F, 3), counter-clockwise seen from outside)."""
    n = max(2, int(round(math.sqrt(triangles / 12.0))))
    t = np.linspace(-1.0, 1.0, n + 1)
    u, v = np.meshgrid(t, t, indexing="ij")
    points, faces = [], []
    r, s = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    corner = lambda i, j: (i * (n + 1) + j).reshape(-1)
    for axis in range(3):
        for sign in (-1.0, 1.0):
            grid = np.zeros((n + 1, n + 1, 3))
            grid[..., axis] = sign
            grid[..., (axis + 1) % 3] = u
            grid[..., (axis + 2) % 3] = v
            base = sum(len(block) for block in points)
            a, b, c, d = corner(r, s), corner(r + 1, s), corner(r, s + 1), corner(r + 1, s + 1)
            faces += [base + np.stack([a, b, d], -1), base + np.stack([a, d, c], -1)]
            points.append(grid.reshape(-1, 3))
    cube, faces = np.concatenate(points), np.concatenate(faces)
    cube, shared = np.unique(np.round(cube, 9), axis=0, return_inverse=True)
    faces = shared.reshape(-1)[faces]
    positions = RADIUS * cube / np.linalg.norm(cube, axis=1, keepdims=True)
    x = positions[faces]
    outward = np.einsum("ij,ij->i", np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]), x.sum(1)) > 0
    faces = np.where(outward[:, None], faces, faces[:, ::-1])
    return positions.astype(np.float32), faces.astype(np.int32)


def blob_case(
    width: int, height: int, triangles: int, runs: int, checkerboard: bool = True
) -> list[dict]:
    import taichi as ti

    from taichi_lap.render.camera import EndoscopeCamera
    from taichi_lap.render.renderer import Renderer
    from taichi_lap.render.scene_mesh import ArrayMesh
    from taichi_lap.scene.materials import PRESETS

    rest, faces = cube_sphere(triangles)
    mesh = ArrayMesh.of_material(faces, rest, PRESETS["liver"])
    rest_field = ti.Vector.field(3, ti.f32, len(rest))
    rest_field.from_numpy(rest)

    @ti.kernel
    def deform(phase: ti.f32):
        for v in rest_field:
            p = rest_field[v]
            bump = (
                0.12
                * ti.sin(40.0 * p.x + phase)
                * ti.sin(35.0 * p.y - phase)
                * ti.sin(30.0 * p.z + 0.5 * phase)
            )
            mesh.positions[v] = p * (1.0 + bump)

    camera = EndoscopeCamera(
        eye=np.array(EYE),
        target=np.zeros(3),
        up=np.array([0.0, 1.0, 0.0]),
        fov=60.0,
        near=0.002,
        far=1.0,
    )
    renderer = Renderer(mesh, camera, size=(width, height), checkerboard=checkerboard)
    passes: dict[str, list[float]] = {}
    frames = []
    for k in range(runs + 2):
        deform(0.3 * k)
        ti.sync()
        start = time.perf_counter()
        renderer.render(None, None)
        elapsed = (time.perf_counter() - start) * 1e3
        if k >= 2:  # two warm-up frames (compilation)
            frames.append(elapsed)
            for name, ms in renderer.timings.items():
                passes.setdefault(name, []).append(ms)
    case = f"{width}x{height}-{triangles // 1000}k" + ("" if checkerboard else "-full")
    covered = int((renderer.gbuffer.triangle.to_numpy() >= 0).sum())
    params = {
        "width": width,
        "height": height,
        "triangles": len(faces),
        "covered_fraction": round(covered / (width * height), 3),
        "checkerboard": checkerboard,
    }
    return [result(case, params, "ms_per_frame", frames)] + [
        result(case, params, f"ms_{name}", samples) for name, samples in passes.items()
    ]


def main():
    args = arguments("render")
    from taichi_lap import runtime

    runtime.init(args.arch)
    runs = args.runs or (5 if args.quick else 20)
    sizes = [(640, 480)] if args.quick else [(640, 480), (1280, 720)]
    counts = [20_000, 100_000] if args.quick else [20_000, 100_000, 200_000]
    results = []
    for width, height in sizes:
        for triangles in counts:
            results += blob_case(width, height, triangles, runs)
    if not args.quick:
        results += blob_case(640, 480, 100_000, runs, checkerboard=False)
    report("render", args.arch, results, args.json)


if __name__ == "__main__":
    main()
