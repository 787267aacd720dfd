"""Topology benchmark (issue: Dissection I, seed 002 §3.3).

Cases
* ``liver-groove``: a groove cut into the top of the liver scene as it runs (settled
  start, tissue collision): a tip 4 mm deep moving 5 mm/s along a 4 cm line removes
  the particles within 3 mm of it every frame (blunt removal, the same topology
  update a cautery hook's ablation makes; at lower detail depth and reach grow with
  the particle spacing). Metrics ``ms_per_update`` (the update alone: host topology
  and the rows written to the device; median, p95, max; the first update, which
  compiles the row writes, is the parameter ``first_update_ms``) and
  ``ms_per_frame`` (a simulation step plus its update) while cutting and, for the
  same frames from the same start, without.
* ``random-removals-liver``: random removal events at full scale (a ball of radius
  1.5-4 mm around a random live liver particle each), the topology validator after
  every one: ``validator_failures`` (events whose topology failed it) and the host's
  ``ms_per_update``.

Seed 002 reports 98.3 ms per topology update on one CPU thread; the targets of this
project are a median of at most 10 ms, p95 20 ms, no validator failure and frames
while cutting at most 1.5 times frames without.

Usage: python perf/bench_topology.py [--quick] [--arch cpu] [--json OUT]
"""

from __future__ import annotations

import time

import numpy as np

from taichi_lap.perf.common import arguments, report, result

DEPTH = 0.004  # [m] of the groove's tip below the surface (at full scale)
REACH = 0.003  # [m] particles this close to the tip are removed (at full scale)
SPEED = 0.005  # [m/s] of the tip along the groove
LENGTH = 0.04  # [m] of the groove


def groove_tip(
    positions: np.ndarray, surface: np.ndarray, x: float, z: float, reach: float, depth: float
) -> np.ndarray:
    """The tip [m] ``depth`` below the highest of the ``surface`` particles within
    ``reach`` of the vertical line through (x, z)."""
    near = surface[np.hypot(positions[surface, 0] - x, positions[surface, 2] - z) < reach]
    top = positions[near, 1].max() if len(near) else positions[surface, 1].max()
    return np.array([x, top - depth, z])


def groove_cases(detail: float) -> list[dict]:
    """``liver-groove`` at ``detail`` (module docstring)."""
    from taichi_lap import scene as scene_mod
    from taichi_lap.session import Session

    session = Session(scene_mod.load("liver", {"scene.detail": detail}), progress=False)
    data, dt = session.data, session.dt
    liver = data.organs[0]
    surface = np.unique(data.surface_index[slice(*liver.surface_vertices), 0])
    start = session.state.x.to_numpy()
    top = surface[np.argmax(start[surface, 1])]
    x0, z0 = start[top, 0] - LENGTH / 2, start[top, 2]
    frames = int(round(LENGTH / SPEED / dt))
    scale = detail ** (-1.0 / 3.0)  # the particle spacing grows so at lower detail
    reach, depth = REACH * scale, DEPTH * scale
    session.step()  # compile
    updates, cutting, plain, removed, alive = [], [], [], 0, 0
    for cut in (True, False):
        session.reset()
        for k in range(frames):
            begin = time.perf_counter()
            session.step()
            if cut:
                x = session.state.x.to_numpy()
                tip = groove_tip(x, surface, x0 + SPEED * dt * k, z0, reach, depth)
                near = np.flatnonzero((np.linalg.norm(x - tip, axis=1) < reach) & (data.organ == 0))
                mark = time.perf_counter()
                change = session.remove_particles(near)
                if not change.empty:
                    updates.append((time.perf_counter() - mark) * 1e3)
                    removed += len(change.removed_particles)
            (cutting if cut else plain).append((time.perf_counter() - begin) * 1e3)
        if cut and session._dissection is not None:
            alive = int(session._dissection.topology.triangles["alive"].sum())
    params = {
        "detail": detail,
        "particles": data.particle_count,
        "frames": frames,
        "removed": removed,
        "first_update_ms": round(updates[0], 1),  # compiles the row writes
        "triangles_alive": alive,
    }
    session.close()
    rows = [
        result("liver-groove", params, "ms_per_update", updates[1:]),
        result("liver-groove", dict(params, cutting=True), "ms_per_frame", cutting),
        result("liver-groove", dict(params, cutting=False), "ms_per_frame", plain),
    ]
    return rows


def random_removal_cases(detail: float, events: int, seed: int = 0) -> list[dict]:
    """``random-removals-liver`` at ``detail`` (module docstring)."""
    from taichi_lap import scene as scene_mod
    from taichi_lap.core.topology import check_topology
    from taichi_lap.dissection.removal import MutableTopology
    from taichi_lap.preprocess.cache import build_model

    data = build_model(scene_mod.load("liver", {"scene.detail": detail}), progress=False)
    topology = MutableTopology(data)
    rng = np.random.default_rng(seed)
    rest = data.rest_position
    liver = np.flatnonzero(data.organ == 0)
    failures, times, checks = 0, [], []
    for _ in range(events):
        alive = liver[topology.particle_alive[liver]]
        if not len(alive):
            break
        centre = rest[rng.choice(alive)]
        radius = rng.uniform(0.0015, 0.004)
        ball = alive[np.linalg.norm(rest[alive] - centre, axis=1) < radius]
        begin = time.perf_counter()
        topology.remove(ball)
        times.append((time.perf_counter() - begin) * 1e3)
        begin = time.perf_counter()
        failures += bool(check_topology(topology.topology()))
        checks.append((time.perf_counter() - begin) * 1e3)
    params = {
        "detail": detail,
        "particles": data.particle_count,
        "events": len(times),
        "removed": int((~topology.particle_alive).sum()),
        "validator_ms_median": round(float(np.median(checks)), 1),
    }
    return [
        result("random-removals-liver", params, "validator_failures", [failures]),
        result("random-removals-liver", params, "ms_per_update", times),
    ]


def main():
    args = arguments("topology")
    from taichi_lap import runtime

    runtime.init(args.arch)
    detail = 0.1 if args.quick else 1.0
    results = groove_cases(detail)
    results += random_removal_cases(detail, 100 if args.quick else (args.runs or 1000))
    report("topology", args.arch, results, args.json)


if __name__ == "__main__":
    main()
