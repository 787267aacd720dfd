"""Tissue collision benchmark: the rigid-cylinder experiment of seed 000 §4.4
(Fig. 9-11, Qian et al. VRST 2015).

A rigid cylinder (a capsule longer than the block, radius ρ = 8 mm, axis along z) is
pressed 6 mm into a deformable 60 x 30 x 40 mm tissue block (``tet_clusters``, BCC
spacing 2 mm, 4 mm with ``--quick``; bottom face fixed; stiffness 0.5, η on contact
0.7 as in seed 000 §7), held, and lifted by half over 60 frames of 1/60 s, once per
method (``circumsphere``, ``bounding_sphere``, ``polygon``) and per solver iteration
count 1-10 (24 frames and 1, 2, 5 with ``--quick``). An iteration is one
shape-matching pass (seed 000 Alg. 1 lines 7-23, :mod:`kernels.shape_matching`)
followed by one collision step (:class:`taichi_lap.collision.TissueCollision`), as
the solver runs it (:meth:`Solver.substep`; tissue pairs after the last pass).
The cylinder reaches the tissue only through the collision pipeline (the solver's
particle contacts get no tools).

Metrics per (method, iterations), over the frames with contact:

* ``rel_error`` — (d_ave - d_exa) / d_exa, d_ave the mean distance of the collided
  particles to the cylinder's axis, d_exa = ρ (Fig. 10); results carry ``q1`` and
  ``q3`` besides median, min and max; negative means the tissue is inside the
  cylinder.
* ``ms_per_frame`` — milliseconds of collision detection and response per frame
  (synchronised around each collision step; Fig. 11).

Case ``cylinder`` has tool-tissue contacts only (the experiment); ``cylinder+self``
adds tissue-tissue (self) detection with the spatial hash (every method pays the same
broad phase). A box plot like Fig. 10 is written next to the JSON (matplotlib).

Cases ``rectum`` and ``liver``: the scene (detail 1, 0.2 with ``--quick``, its
script driving the tools) with circumsphere collision as the solver runs it, against
none, over the same frames: ``start`` (the first 30 frames from the session's start
state, the liver's after its ``settle_time``, with collision from the start) and
``steady`` (frames 61-120, collision switched on at frame 60, its first frame left
out; not with ``--quick``). Metrics ``frame_ms_off``, ``frame_ms_on`` and
``collision_ms`` (synchronised around each collision step) per frame, and
``collision_phase_ms`` per phase of :meth:`TissueCollision.step` (median per frame).

Usage: python perf/bench_circumsphere.py [--quick] [--arch cpu] [--json OUT]
"""

from __future__ import annotations

import statistics
from dataclasses import replace
from pathlib import Path

import numpy as np

from taichi_lap import plots
from taichi_lap.perf.common import arguments, report, result

METHODS = ("circumsphere", "bounding_sphere", "polygon")
RADIUS = 0.008  # cylinder radius ρ = d_exa [m]
HALF = (0.03, 0.015, 0.02)  # block half extents [m]
DEPTH = 0.006  # indentation [m]
PRESS, HOLD, LIFT = 30, 20, 10  # frames


def block_session(spacing: float):
    from taichi_lap.scene import from_tables
    from taichi_lap.session import Session

    organ = {
        "name": "block",
        "model": "tet_clusters",
        "geometry": {"generator": "box", "half_extents": list(HALF)},
        "material": {
            "particle_spacing": spacing,
            "stiffness": 0.5,
            "damping": 1.0,
            "recover_rate": 0.05,
            "eta_on_contact": 0.7,
        },
        "attachments": [
            {"kind": "fixed", "box_min": [-1, -1, -1], "box_max": [1, -HALF[1] + 0.5 * spacing, 1]}
        ],
    }
    return Session(from_tables([organ], gravity=[0.0, 0.0, 0.0]), use_cache=False, progress=False)


def cylinder_height(frame: int) -> float:
    """Axis height [m] at ``frame``: touching, pressed by DEPTH, held, lifted by half."""
    top = HALF[1] + RADIUS
    if frame < PRESS:
        return top - DEPTH * (frame + 1) / PRESS
    if frame < PRESS + HOLD:
        return top - DEPTH
    return top - DEPTH + 0.5 * DEPTH * (frame + 1 - PRESS - HOLD) / LIFT


def run(session, collision, controls, iterations: int, frames: int):
    """Per-frame relative errors and collision milliseconds of one run; ``controls``
    are (no tools, the cylinder), created once so that kernels compile once."""
    from taichi_lap.sim import Solver

    session.reset()
    collision.reset()
    no_tools, tools = controls
    settings = replace(session.solver.settings, shape_iterations=iterations)
    solver = Solver(session.model, settings, collision=collision)
    h = session.dt / settings.substeps
    errors, times = [], []
    for frame in range(frames):
        y = cylinder_height(frame)
        tools.set_tool(0, [0.0, y, -2 * HALF[2]], [0.0, y, 2 * HALF[2]], RADIUS)
        spent = collision.total_ms
        n = solver.settings.substeps
        for k in range(n):
            tools.advance(k / n, (k + 1) / n)
            solver.substep(session.state, no_tools, h, collision_control=tools)
        times.append(collision.total_ms - spent)
        collided = session.state.collided.to_numpy() > 0
        if collided.any():
            x = session.state.x.to_numpy()[collided]
            d_ave = float(np.hypot(x[:, 0], x[:, 1] - y).mean())
            errors.append((d_ave - RADIUS) / RADIUS)
    return errors, times


WINDOWS = {"start": (0, 30, 0), "steady": (60, 120, 1)}
"""Scene windows: first frame, end frame, frames dropped after collision starts."""


def scene_window(session, script, collision, first: int, end: int, drop: int) -> dict:
    """Frame times [ms] over frames first..end-1, the tools driven by ``script``, with
    the session's ``collision`` (None: collision off) on from frame ``first``, the
    first ``drop`` of them left out."""
    session.reset()

    def step(collide: bool):
        time = session.state.time
        session.step(script.poses(time), script.buttons(time), collide=collide)

    for _ in range(first):
        step(False)
    out = {"frame": [], "collision": [], "phases": []}
    if collision is not None:
        collision.reset()
    for frame in range(first, end):
        spent, phases = (collision.total_ms, dict(collision.phase_ms)) if collision else (0, {})
        step(collision is not None)
        if frame >= first + drop:
            out["frame"].append(session.timings["physics"])
            if collision is not None:
                out["collision"].append(collision.total_ms - spent)
                out["phases"].append({k: collision.phase_ms[k] - phases[k] for k in phases})
    return out


def scene_cases(quick: bool) -> list[dict]:
    """The rectum and liver scenes with and without circumsphere collision."""
    from taichi_lap import scene as scene_mod
    from taichi_lap.session import Session, scene_script

    detail = 0.2 if quick else 1.0
    results = []
    for name in ("rectum", "liver"):
        scene = scene_mod.load(name, {"scene.detail": detail, "scene.collision": "circumsphere"})
        session = Session(scene, progress=False)
        script = scene_script(scene)
        collision = session.solver.collision  # the scene's own pipeline, timed
        collision.timing = True
        scene_window(session, script, collision, 0, 2, 0)  # compile
        params = {
            "particles": session.model.particle_count,
            "triangles": len(session.data.surface_triangles),
            "detail": detail,
            "substeps": session.solver.settings.substeps,
            "settle_time_s": scene.settings["settle_time"],
            "shape_iterations": session.solver.settings.shape_iterations,
        }
        windows = {"start": WINDOWS["start"]} if quick else WINDOWS
        for window, (first, end, drop) in windows.items():
            off = scene_window(session, script, None, first, end, drop)
            on = scene_window(session, script, collision, first, end, drop)
            case = f"{name}-{window}"
            rows = [
                result(case, params, "frame_ms_off", off["frame"]),
                result(case, params, "frame_ms_on", on["frame"]),
                result(case, params, "collision_ms", on["collision"]),
            ]
            print(case, " ".join(f"{r['metric']} {r['median']:.1f}" for r in rows), flush=True)
            results += rows + [
                result(
                    case,
                    {**params, "phase": phase},
                    "collision_phase_ms",
                    [p[phase] for p in on["phases"]],
                )
                for phase in on["phases"][0]
            ]
    return results


def quartiles(samples: list[float]) -> dict:
    q1, _, q3 = statistics.quantiles(samples, n=4, method="inclusive")
    return {"q1": q1, "q3": q3}


def box_plot(results: list[dict], path: Path):
    """Fig. 10-like box plot of rel_error per iteration count, one colour per method."""
    rows = [r for r in results if r["metric"] == "rel_error" and r["case"] == "cylinder"]
    iterations = sorted({r["params"]["iterations"] for r in rows})
    fig, axes = plots.figure(size=(10, 4.5))
    ax = axes[0, 0]
    colours = {"circumsphere": "tab:blue", "bounding_sphere": "tab:orange", "polygon": "tab:green"}
    for m, method in enumerate(METHODS):
        stats = [
            {
                "med": r["median"],
                "q1": r["q1"],
                "q3": r["q3"],
                "whislo": r["min"],
                "whishi": r["max"],
                "label": str(r["params"]["iterations"]),
            }
            for it in iterations
            for r in rows
            if r["params"]["method"] == method and r["params"]["iterations"] == it
        ]
        positions = [k * 4 + m for k in range(len(stats))]
        parts = ax.bxp(stats, positions=positions, widths=0.8, showfliers=False, patch_artist=True)
        for box in parts["boxes"]:
            box.set_facecolor(colours[method])
        ax.plot([], [], color=colours[method], lw=6, label=method)
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xticks([k * 4 + 1 for k in range(len(iterations))], [str(i) for i in iterations])
    ax.set_xlabel("solver iterations")
    ax.set_ylabel("(d_ave - d_exa) / d_exa")
    ax.set_title("Rigid cylinder pressed into a tissue block (seed 000 Fig. 10)")
    ax.legend()
    plots.save_png(fig, path, dpi=120)
    print(f"wrote {path}")


def main():
    args = arguments("circumsphere")
    from taichi_lap import runtime

    runtime.init(args.arch)
    from taichi_lap.collision.tissue import TissueCollision
    from taichi_lap.sim import Control

    controls = (Control(), Control())
    quick = args.quick
    session = block_session(0.004 if quick else 0.002)
    frames = 24 if quick else PRESS + HOLD + LIFT
    counts = (1, 2, 5) if quick else tuple(range(1, 11))
    cases = [("cylinder", False, counts)]
    if not quick:
        cases.append(("cylinder+self", True, (1, 5, 10)))
    params_base = {
        "particles": session.model.particle_count,
        "triangles": len(session.data.surface_triangles),
        "radius_m": RADIUS,
    }
    results = []
    for case, self_collision, iteration_counts in cases:
        collisions = {
            method: TissueCollision(
                session.model,
                method=method,
                timing=True,
                tissue_pairs=self_collision,
                method_tools=True,
            )
            for method in METHODS
        }
        for method, collision in collisions.items():  # compile the kernels once
            run(session, collision, controls, 1, 2)
        for iterations in iteration_counts:
            for method in METHODS:
                errors, times = run(session, collisions[method], controls, iterations, frames)
                params = {**params_base, "method": method, "iterations": iterations}
                results.append({**result(case, params, "rel_error", errors), **quartiles(errors)})
                results.append(result(case, params, "ms_per_frame", times))
                print(
                    case,
                    method,
                    iterations,
                    f"rel_error median {results[-2]['median']:+.4f} "
                    f"[{results[-2]['min']:+.4f}, {results[-2]['max']:+.4f}]",
                    f"{results[-1]['median']:.2f} ms/frame",
                    flush=True,
                )
    results += scene_cases(quick)
    report("circumsphere", args.arch, results, args.json)
    box_plot(results, Path(args.json).with_suffix(".png"))


if __name__ == "__main__":
    main()
