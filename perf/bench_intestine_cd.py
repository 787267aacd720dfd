"""Intestine self-collision detection benchmark (seed 001 §7, Fig. 14).

The intestine scene (4 m of intestine and its mesentery, seed 001 §3) falls under
gravity from its folded rest shape while the scene's probe sweeps through it, so
folds press on each other. Every substep runs the stochastic detector and the
displacement-velocity response (seed 001 §4) between the prediction and the
velocity update (the substep is written out here: prediction, collisions, goal
and velocity update; the scene has no constraints or clusters). After a warm-up
of 10 frames from rest, at the last substep of every frame and at the same
predicted positions, the stochastic detection is compared with the exact O(n²)
detector over all non-neighbouring (segment, segment) and (segment, triangle)
pairs (with a bounding-sphere test before each distance).

A *colliding pair* is a non-neighbouring element pair closer than r1 + r2 (gap
d - r1 - r2 < 0); a pair is *in contact* when its gap is below the detector's
skin (1 mm). Two pairs are *adjacent* when each element of one is the same as or
adjacent to (shares an edge or an end-point with) the corresponding element of the
other: the neighbourhood the detector's local updates walk. A *colliding region*
is a connected group of adjacent pairs in contact that holds at least one
colliding pair (the skin keeps a resting contact, which the response holds at
gap ~ 0, one region instead of specks). A region is *found* when the stochastic
contact list holds any of its colliding pairs.

Cases: ``1x`` (the seed's sampling, 100 intestine masses, 99 segments) and ``10x``
(1001 masses per row, 1000 segments; ``scene.detail`` does not change a spring
sheet, so the generator's ``points_per_row`` is set; 40 substeps instead of 10,
see :data:`CASES`). The detector runs with its defaults. Per case, over frames:

* ``recall`` — found / exact colliding regions (frames with at least one region);
* ``pair_recall`` — exact colliding pairs that the stochastic contact list holds;
* ``ms_stochastic``, ``ms_bruteforce`` — one detection, synchronised;
  ``time_ratio_vs_bruteforce`` — their ratio per frame;
* ``ms_response`` — the response of that substep; ``regions`` — exact regions.

Usage: python perf/bench_intestine_cd.py [--quick] [--arch cpu] [--json OUT] [--runs FRAMES]
"""

from __future__ import annotations

import time

import numpy as np

from taichi_lap.perf.common import arguments, report, result

WARMUP_FRAMES = 10
"""Frames (1/6 s) from rest, with an empty pair list, before measuring."""
CASES = {"1x": (100, 10), "10x": (1001, 40)}
"""Case: (masses per row, substeps per frame). The springs keep their stiffness at
10x, so the lighter masses need four times the substeps to stay stable."""


def found_fraction(
    exact: np.ndarray, exact_gap: np.ndarray, stochastic: np.ndarray, neighbour: np.ndarray
):
    """(found regions, colliding regions, pair recall) of the stochastic colliding
    pairs against the exact pairs in contact and their gaps [m]."""
    from taichi_lap.collision.intestine_reference import region_labels

    colliding = exact_gap < 0.0
    if not colliding.any():
        return 0, 0, 1.0
    label = region_labels(exact, neighbour)
    key = exact[:, 0].astype(np.int64) * (1 << 31) + exact[:, 1]
    hit = colliding & np.isin(key, stochastic[:, 0].astype(np.int64) * (1 << 31) + stochastic[:, 1])
    return (
        len(np.unique(label[hit])),
        len(np.unique(label[colliding])),
        float(hit.sum() / colliding.sum()),
    )


def run_case(case: str, points: int, substeps: int, frames: int) -> list[dict]:
    import taichi as ti
    from taichi_lap.kernels import shape_matching

    from taichi_lap import scene as scene_mod
    from taichi_lap.collision.intestine import IntestineCollision
    from taichi_lap.collision.intestine_reference import ExactDetector
    from taichi_lap.devices import apply_poses
    from taichi_lap.session import Session, scene_script

    scene = scene_mod.load(
        "intestine",
        {"organs.intestine.geometry.points_per_row": points, "scene.substeps": substeps},
    )
    session = Session(scene, use_cache=False, progress=False)
    model, state, control = session.model, session.state, session.control
    settings = session.solver.settings
    collision = IntestineCollision(model, seed=scene.settings["seed"])
    exact = ExactDetector(collision, skin=collision.skin)
    neighbour = collision.element_neighbour.to_numpy()
    device = scene_script(scene)
    h = session.dt / substeps
    exact.run(state.p)  # compile outside the timings
    samples = {
        k: []
        for k in (
            "recall",
            "pair_recall",
            "ms_stochastic",
            "ms_bruteforce",
            "time_ratio_vs_bruteforce",
            "ms_response",
            "regions",
        )
    }
    for frame in range(frames):
        apply_poses(control, scene.tools, device.poses(state.time) if device else {})
        for k in range(substeps):
            shape_matching.predict(model, state, control, settings.gravity, h, int(k > 0))
            measured = k == substeps - 1 and frame >= WARMUP_FRAMES
            start = time.perf_counter()
            collision.detect(state)
            ti.sync()
            detect_ms = (time.perf_counter() - start) * 1e3
            if measured:
                start = time.perf_counter()
                exact.run(state.p)
                ti.sync()
                exact_ms = (time.perf_counter() - start) * 1e3
                found, total, pair_recall = found_fraction(
                    *exact.pairs(), collision.colliding_pairs(), neighbour
                )
            start = time.perf_counter()
            collision.respond(state, h)
            ti.sync()
            respond_ms = (time.perf_counter() - start) * 1e3
            shape_matching.update_goals(
                model,
                state,
                control,
                h,
                settings.speed_limit,
                settings.gravity,
                int(k < substeps - 1),
            )
        state.time += session.dt
        if state.fault[None]:
            raise RuntimeError(f"{case}: simulation fault at frame {frame}")
        if measured:
            if total:
                samples["recall"].append(found / total)
                samples["pair_recall"].append(pair_recall)
            samples["regions"].append(total)
            samples["ms_stochastic"].append(detect_ms)
            samples["ms_bruteforce"].append(exact_ms)
            samples["time_ratio_vs_bruteforce"].append(detect_ms / exact_ms)
            samples["ms_response"].append(respond_ms)
    params = {
        "segments": collision.segment_count,
        "triangles": collision.element_count - collision.segment_count,
        "frames": frames,
        "substeps": substeps,
        "random_pairs": collision.random_pairs,
        "threshold_m": collision.threshold,
    }
    out = [result(case, params, metric, values) for metric, values in samples.items() if values]
    for r in out:
        print(case, r["metric"], f"median {r['median']:.4g} min {r['min']:.4g}", flush=True)
    return out


def main():
    args = arguments("intestine_cd")
    from taichi_lap import runtime

    runtime.init(args.arch)
    frames = WARMUP_FRAMES + (args.runs or (10 if args.quick else 170))
    results = []
    for case, (points, substeps) in CASES.items():
        results += run_case(case, points, substeps, frames)
    report("intestine_cd", args.arch, results, args.json)


if __name__ == "__main__":
    main()
