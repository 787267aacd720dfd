"""Whole-frame benchmark (issue: performance): what a user feels.

Each built-in scene at its default settings and at a smaller size (case
``<scene>-small``: the liver and the rectum at detail 0.3, the intestine with 50
masses per row instead of 100; the two rows of a scene are a ``series``, to show how
the cost grows with the model; ``--quick``: detail 0.2 alone) runs from its
session's start with its scripted tools, headless: the physics of a frame
(:meth:`Session.step`: deformation, contacts, both collision pipelines) and its render
at 640x480 (:meth:`Renderer.render`: vertex, visibility and shading passes), each
synchronised. The first frames (kernel compilation, first pair listing) are not
counted. Metrics per scene: ``ms_per_frame`` (physics + render), ``ms_physics``,
``ms_render``, ``ms_<pass>`` of the renderer and ``frames_per_second`` (from the
median frame). Time to the first frame is measured by ``perf/bench_deform.py``
(``cold-start``, ``cached-start*``).

Usage: python perf/bench_frame.py [--quick] [--arch cpu] [--json OUT] [--runs N]
"""

from __future__ import annotations

import time

from taichi_lap.perf.common import arguments, report, result

SCENES = ("liver", "rectum", "intestine")
SMALL = {
    "liver": {"scene.detail": 0.3},
    "rectum": {"scene.detail": 0.3},
    "intestine": {"organs.intestine.geometry.points_per_row": 50},
}
"""The smaller size of each scene (the intestine's masses are set by its rows, not
by the detail)."""
QUICK = {"scene.detail": 0.2}
SIZE = (640, 480)
WARMUP = 3
"""Frames run before the timed ones."""


def frame_case(name: str, case: str, overrides: dict, runs: int) -> list[dict]:
    """Time ``runs`` frames of scene ``name`` with ``overrides`` (scene keys, as
    ``--set`` takes them) after :data:`WARMUP` frames: the rows of ``case``."""
    import taichi as ti

    from taichi_lap import scene as scene_mod
    from taichi_lap.render.renderer import Renderer
    from taichi_lap.session import Session, scene_script

    scene = scene_mod.load(name, overrides)
    samples = {"physics": [], "render": [], "vertex": [], "visibility": [], "shading": []}
    with Session(scene, progress=False) as session:
        renderer = Renderer.for_scene(scene, session.model, size=SIZE)
        device = scene_script(scene)
        for frame in range(WARMUP + runs):
            now = session.state.time
            start = time.perf_counter()
            session.step(device.poses(now), device.buttons(now))  # synchronises
            middle = time.perf_counter()
            renderer.render(session.state, session.control)  # synchronises its passes
            ti.sync()
            if frame >= WARMUP:
                samples["physics"].append((middle - start) * 1e3)
                samples["render"].append((time.perf_counter() - middle) * 1e3)
                for stage, ms in renderer.timings.items():
                    samples[stage].append(ms)
        params = {
            "detail": scene.settings["detail"],
            "particles": session.data.particle_count,
            "triangles": renderer.mesh.triangle_count,
            "width": SIZE[0],
            "height": SIZE[1],
        }
    frames = [p + r for p, r in zip(samples["physics"], samples["render"])]
    out = [result(case, params, "ms_per_frame", frames, series=name)]
    out.append(result(case, params, "frames_per_second", [1e3 / out[0]["median"]]))
    return out + [result(case, params, f"ms_{stage}", ms) for stage, ms in samples.items()]


def main():
    args = arguments("frame")
    from taichi_lap import runtime

    runtime.init(args.arch)
    runs = args.runs or (10 if args.quick else 60)
    results = []
    for name in SCENES:
        sizes = [(name, QUICK)] if args.quick else [(name, {}), (f"{name}-small", SMALL[name])]
        for case, overrides in sizes:
            rows = frame_case(name, case, overrides, runs)
            results += rows
            ms, particles = rows[0]["median"], rows[0]["params"]["particles"]
            print(
                f"{rows[0]['case']} ({particles} particles): {ms:.1f} ms per frame "
                f"({1e3 / ms:.1f} frames per second)",
                flush=True,
            )
    report("frame", args.arch, results, args.json)


if __name__ == "__main__":
    main()
