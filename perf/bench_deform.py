"""Deformation benchmark (issue: simulation core).

Cases
* ``10k``, ``50k``, ``liver-full``, ``500k``: the liver scene's step (seed 000
  Alg. 1 run as 5 substeps, each with integration, environment contact and one
  shape-matching pass; seed 002 clusters) at about that many particles;
  ``liver-full`` is the full-scale scene with its vessels (seed 002 Table 1); the
  deformation alone: from the rest shape, tissue collision off. Metric
  ``ms_per_step``, and ``numpy_ms_per_step`` for the same step in the NumPy
  reference (:mod:`taichi_lap.sim.reference`). ``--quick``: ``10k`` alone.
* ``fascia-128``: a 128 x 128 fascia sheet (relaxed LRA, edge and bending
  constraints) hanging from one edge, for the Jacobi and the graph-coloured
  Gauss-Seidel solver at 5-40 iterations per step: ``ms_per_step`` and the edge
  strain after one second of hanging (``mean_strain``, ``p99_strain``), to compare
  convergence per millisecond.
* ``kernel-launch``: what one launch of a kernel doing almost nothing costs
  (``us_per_launch``, 2000 launches): a top-level loop of 16 items run in parallel
  (the default on the CPU backend: its thread pool is woken), the same loop with
  ``ti.loop_config(parallelize=1)`` (one thread, no pool) and a kernel without a
  loop. A step launches about 17 parallel loops per substep, so on a 2-core CPU
  this, not the arithmetic, bounds the small cases.
* ``cold-start`` / ``cached-start``: seconds from launch to the first stepped frame
  of the full liver scene as it runs (its 2 s settling and tissue collision included;
  params ``model_build_s``, ``settle_s``) with empty caches, then with the model cache
  and Taichi's kernel cache filled (child processes).

Usage: python perf/bench_deform.py [--quick] [--arch cpu] [--json OUT]
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from functools import partial
from pathlib import Path

from taichi_lap.perf.common import arguments, report, result, timed

LIVER_ONLY_PARTICLES = 146_000  # liver organ of scenes/liver.toml at detail 1 (approx.)
SERIES = "liver deformation"
"""The series of the size cases (how their cost grows with the particles)."""
DT = 1.0 / 60.0


def liver_session(detail: float, vessels: bool, as_scene: bool = False):
    """The liver scene at ``detail`` (``vessels``: with its vessels). ``as_scene``: as
    it runs (settled start, tissue collision); else the deformation alone, as this
    benchmark times it (rest start, tissue collision off)."""
    from taichi_lap import scene as scene_mod
    from taichi_lap.session import Session

    overrides = {"scene.detail": detail}
    if not as_scene:
        overrides.update({"scene.collision": "off", "scene.settle_time": 0.0})
    scene = scene_mod.load("liver", overrides)
    if not vessels:
        scene.organs = scene.organs[:1]
        scene.raw["organs"] = scene.raw["organs"][:1]
    return Session(scene, progress=False)


def deform_cases(quick: bool, runs: int) -> list[dict]:
    from taichi_lap.sim.reference import ReferenceShapeMatching

    sizes = (
        [("10k", 10_000, False)]
        if quick
        else [
            ("10k", 10_000, False),
            ("50k", 50_000, False),
            ("liver-full", None, True),
            ("500k", 500_000, False),
        ]
    )
    out = []
    for case, target, vessels in sizes:
        detail = 1.0 if target is None else target / LIVER_ONLY_PARTICLES
        session = liver_session(detail, vessels)
        params = {
            "particles": session.model.particle_count,
            "clusters": session.model.cluster_total,
            "memberships": int(len(session.data.cluster_member)),
            "substeps": session.solver.settings.substeps,
            "shape_iterations": session.solver.settings.shape_iterations,
        }
        steps = timed(session.step, runs)
        out.append(result(case, params, "ms_per_step", steps, series=SERIES))
        print(out[-1]["case"], out[-1]["metric"], f"{out[-1]['median']:.2f}", flush=True)
        settings, scene = session.solver.settings, session.scene
        reference = ReferenceShapeMatching(
            session.data,
            substeps=settings.substeps,
            shape_iterations=settings.shape_iterations,
            gravity=settings.gravity,
            planes=[(p["point"], p["normal"], p["friction"]) for p in scene.planes],
        )
        numpy_runs = max(2, min(runs, 5 if params["particles"] < 200_000 else 2))
        out.append(
            result(
                case,
                params,
                "numpy_ms_per_step",
                timed(partial(reference.step, DT), numpy_runs, warmup=1),
                series=f"{SERIES} (NumPy)",
            )
        )
        print(out[-1]["case"], out[-1]["metric"], f"{out[-1]['median']:.2f}", flush=True)
    return out


def fascia_session(size: int, solver: str, iterations: int):
    from taichi_lap.scene import from_tables
    from taichi_lap.session import Session

    organ = {
        "name": "fascia",
        "model": "fascia_lra",
        "geometry": {
            "generator": "sheet",
            "width": 0.2,
            "depth": 0.2,
            "resolution_x": size - 1,
            "resolution_z": size - 1,
            "sag": 0.0,
        },
        "material": {"lra_relaxation": 0.25, "lra_anchors": 4, "damping": 2.0},
        "attachments": [
            {"kind": "lra_anchor", "box_min": [-1, -1, -1], "box_max": [1, 1, -0.0995]}
        ],
    }
    return Session(
        from_tables([organ], iterations=iterations, constraint_solver=solver),
        use_cache=False,
        progress=False,
    )


def edge_strain(data, x):
    """|length / rest - 1| of the sheet's edges (stiffness 1; the soft bending pairs
    across triangles fold by design and are left out)."""
    import numpy as np

    edges = data.distance_stiffness >= 1.0
    pairs = data.distance_pair[edges]
    length = np.linalg.norm(x[pairs[:, 0]] - x[pairs[:, 1]], axis=1)
    return np.abs(length / data.distance_rest[edges] - 1.0)


def fascia_cases(quick: bool, runs: int) -> list[dict]:
    import numpy as np

    size = 64 if quick else 128
    out = []
    for solver in ("jacobi", "gauss_seidel"):
        for iterations in (10,) if quick else (5, 10, 20, 40):
            session = fascia_session(size, solver, iterations)
            model = session.model
            for _ in range(120):  # two seconds of hanging
                session.step()
            params = {
                "particles": model.particle_count,
                "constraints": model.distance_count,
                "solver": solver,
                "iterations": iterations,
                "colors": len(model.color_ranges) if solver == "gauss_seidel" else 0,
            }
            case = f"fascia-{size}"
            times, mean_strain, p99_strain = [], [], []
            for _ in range(runs):
                session.step()
                times.append(session.timings["physics"])  # the step alone, synchronised
                strain = edge_strain(session.data, session.state.x.to_numpy())
                mean_strain.append(float(strain.mean()))
                p99_strain.append(float(np.percentile(strain, 99)))
            out.append(result(case, params, "ms_per_step", times))
            out.append(result(case, params, "mean_strain", mean_strain))
            out.append(result(case, params, "p99_strain", p99_strain))
            print(
                case,
                solver,
                iterations,
                f"{out[-3]['median']:.2f} ms",
                f"strain mean {out[-2]['median']:.4f} p99 {out[-1]['median']:.4f}",
                flush=True,
            )
    return out


STARTUP_SCENES = ("liver", "rectum", "intestine")


def startup_probe(arch: str, name: str):
    """Child process: seconds from launch to the first stepped frame of scene ``name``
    as it runs (settled start, tissue collision), then of a second session of it in the
    same process, and the kernels that second session compiled."""
    from taichi_lap import runtime
    from taichi_lap import scene as scene_mod
    from taichi_lap.session import Session

    start = time.perf_counter()
    runtime.init(arch)
    scene = scene_mod.load(name)
    session = Session(scene, progress=False)
    session.step()
    first = time.perf_counter() - start
    session.close()
    compiled = runtime.kernel_compilations()
    start = time.perf_counter()
    with Session(scene, progress=False) as second:
        second.step()
    print(
        f"STARTUP {first:.3f} BUILD {session.build_seconds:.3f} "
        f"SETTLE {session.settle_seconds:.3f} SECOND {time.perf_counter() - start:.3f} "
        f"COMPILED {runtime.kernel_compilations() - compiled}"
    )


def run_probe(env: dict, arch: str, name: str) -> dict[str, float]:
    proc = subprocess.run(
        [sys.executable, __file__, "--startup-probe", arch, name],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    line = next(l for l in proc.stdout.splitlines() if l.startswith("STARTUP"))
    words = line.split()
    return {key.lower(): float(value) for key, value in zip(words[::2], words[1::2])}


def startup_cases(arch: str) -> list[dict]:
    """``cold-start``: the full liver with empty model, settled-start and kernel caches;
    ``cached-start[-scene]``: each built-in scene with warm caches (the liver's case
    keeps its old name); ``second-session-<scene>``: a second session of it in the
    same process (``kernel_compilations`` in its params)."""
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(
            os.environ,
            TAICHI_LAP_CACHE=str(Path(tmp) / "models"),
            TI_OFFLINE_CACHE_FILE_PATH=str(Path(tmp) / "kernels"),
        )
        for name in STARTUP_SCENES:
            cold = run_probe(env, arch, name)  # fills the caches
            warm = run_probe(env, arch, name)
            if name == "liver":
                params = {"model_build_s": cold["build"], "settle_s": cold["settle"]}
                out.append(result("cold-start", params, "seconds", [cold["startup"]]))
            case = "cached-start" if name == "liver" else f"cached-start-{name}"
            params = {"model_build_s": warm["build"], "settle_s": warm["settle"]}
            out.append(result(case, params, "seconds", [warm["startup"]]))
            params = {"kernel_compilations": int(warm["compiled"])}
            out.append(result(f"second-session-{name}", params, "seconds", [warm["second"]]))
            print(
                name,
                f"cold {cold['startup']:.2f} s, warm {warm['startup']:.2f} s, second "
                f"session {warm['second']:.2f} s compiling {int(warm['compiled'])} kernels",
                flush=True,
            )
    return out


def launch_cases(launches: int = 2000) -> list[dict]:
    """``kernel-launch`` (module docstring)."""
    import taichi as ti

    values = ti.field(ti.f32, 16)

    @ti.kernel
    def parallel():
        for i in range(16):
            values[i] += 1.0

    @ti.kernel
    def one_thread():
        ti.loop_config(parallelize=1)
        for i in range(16):
            values[i] += 1.0

    @ti.kernel
    def without_loop():
        values[0] += 1.0

    rows = []
    kernels = (("parallel", parallel), ("parallelize=1", one_thread), ("no loop", without_loop))
    for name, kernel in kernels:
        kernel()
        ti.sync()
        samples = []
        for _ in range(launches):
            start = time.perf_counter()
            kernel()
            samples.append((time.perf_counter() - start) * 1e6)
        ti.sync()
        rows.append(result("kernel-launch", {"loop": name, "items": 16}, "us_per_launch", samples))
    return rows


def main():
    if "--startup-probe" in sys.argv:
        startup_probe(*sys.argv[sys.argv.index("--startup-probe") + 1 :][:2])
        return
    args = arguments("deform")
    from taichi_lap import runtime

    runtime.init(args.arch)
    runs = args.runs or (5 if args.quick else 20)
    results = deform_cases(args.quick, runs) + fascia_cases(args.quick, runs) + launch_cases()
    if not args.quick:
        results += startup_cases(args.arch)
    report("deform", args.arch, results, args.json)


if __name__ == "__main__":
    main()
