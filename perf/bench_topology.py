"""Topology benchmark (issue: Dissection I, seed 002 §3.3).

Cases
* ``liver-cautery``: the liver scene (settled start, tissue collision) driven by the
  built-in script ``liver-deep-transection``: the electrocautery hook, energised,
  transects the parenchyma along a 3 cm line at 5 mm/s in three passes, each deeper,
  down to a branch of the hepatic vein (20.4 s). Metrics ``ms_per_update`` (the topology
  update alone of each frame that removed tissue: host topology and the rows written
  to the device; median, p95, max; the first update, which compiles the row writes,
  is the parameter ``first_update_ms``) and ``ms_per_frame`` (a whole simulation
  step: physics, heat and the update) while cutting and, for the same frames from the
  same start with the hook not energised, without.
* ``random-removals-liver``: random removal events at full scale (a ball of radius
  1.5-4 mm around a random live liver particle each, the vessels' particles in it
  too: their tubes are capped), the topology validator after
  every one: ``validator_failures`` (events whose topology failed it) and the host's
  ``ms_per_update``.

* ``fascia-cut-host`` (issue Dissection II, seed 000 Alg. 3, the host's part only: the
  sheet is not yet a physical one that follows): the rectum scene's fascia sheet as
  built (32 x 16 cells over 12 x 6 cm), a blade 0.5 mm thick drawn through it along its
  attachment at 2 cm/s (0.33 mm a frame): ``ms_per_update`` (:func:`cut_surface` per
  frame), ``validator_failures`` (frames after which the sheet had a
  :func:`sheet_problems` problem) and the ``pieces`` at the end (2: the sheet is cut
  free of its attached strip).
* ``random-cuts-fascia-host``: random straight cuts through the same sheet, one after
  the other (random ends beyond its edges, blades 0.2-2 mm thick, tilted up to 35°):
  ``validator_failures`` and ``ms_per_update``.

* ``rectum-fascia-cut`` (issue Dissection II, the cut in a session): the rectum
  scene's own script (settled start, tissue collision): after the grasper's work, the
  scissors, closing, cut the hanging fascia along its attachment at 5 cm/s (2.7 s),
  and its physics follows (reserve particles, edges, bending pairs and relaxed LRAs
  rebuilt, surface rows, drawn mesh and collision). Metrics ``ms_per_update`` (the
  session's topology stage of each frame that cut: the cut on the host and every
  row written; the first, which compiles the row writes, is ``first_update_ms``),
  ``ms_per_frame`` while cutting and, for the same frames with the scissors' jaws
  open, without, and ``validator_failures`` (frames after which the topology
  validator found a problem). Parameters: the sheet's pieces at the end and how far
  the piece cut free fell.

* ``polyp-excision`` (issue Dissection II, seed 000 §5.3 in a session): the same run
  goes on: the grasper holds the polyp's head, the scissors cut through its stalk, the
  grasper lifts the head out of the view, where it is excised. Metrics
  ``ms_per_update`` (the topology stage of each frame whose scissors split tets: the
  cut on the host and every row written) and ``validator_failures``; parameters: tets
  split, and the particles and rest volume excised.
* ``vessel-cut`` (issue Dissection II, a truss cut in a session): the same run goes
  on: the scissors' level jaws press the vessel beside the gland to the floor and cut
  through it (Alg. 3 on its surface, the struts the cut crosses or parts removed).
  Metrics ``ms_per_update`` (the topology stage of each frame that cut the vessel)
  and ``validator_failures``; parameter: the vessel's pieces at the end.
* ``random-cuts-polyp-host``: random plane cuts (a blade drawn across a random plane
  through a random point of the polyp, in 4 frames, reaching beyond it: a cut that
  ends inside waits, :func:`cut_tets`) split the rectum scene's polyp again and again
  (:meth:`MutableTopology.split_tets`, host only; the polyp built with 20 times its
  particles in reserve rows) until the rows run out: ``validator_failures`` and
  ``ms_per_update``.

Seed 002 reports 98.3 ms per topology update on one CPU thread; the targets of this
project are a median of at most 10 ms, p95 20 ms, no validator failure and frames
while cutting at most 1.5 times frames without.

``--quick``: smaller and shorter cases, without the session's (:data:`QUICK`).

Usage: python perf/bench_topology.py [--quick] [--arch cpu] [--json OUT]
       [--cases cautery,removals,fascia,polyp,session]
"""

from __future__ import annotations

import time

import numpy as np

from taichi_lap.perf.common import arguments, report, result

QUICK = {"detail": 0.3, "events": 20, "cautery_seconds": 6.6, "polyp_cuts": 2}
"""``--quick`` (a smoke run): the liver at detail 0.3, the cautery script's first 6.6 s
(its first two removals, at 4.3 and 6.4 s; the first compiles) without the frames of
the hook not energised, 20 random removals and fascia cuts, 2 random polyp cuts, and
not the session case (the rectum script's 12 s)."""


def cautery_cases(detail: float, seconds: float | None = None, plain: bool = True) -> list[dict]:
    """``liver-cautery`` at ``detail`` (module docstring), the script's first
    ``seconds`` (None: all of it); with ``plain``, the same frames again with the hook
    not energised."""
    from taichi_lap import scene as scene_mod
    from taichi_lap.devices import ScriptedDevice
    from taichi_lap.session import Session

    session = Session(scene_mod.load("liver", {"scene.detail": detail}), progress=False)
    script = scene_mod.resolve_script("liver-deep-transection")
    device = ScriptedDevice.from_file(script, session.scene.tools)
    frames = int(round(min(device.duration(), seconds or np.inf) / session.dt))
    session.step()  # compile
    updates, cutting, uncut, removed, alive = [], [], [], 0, 0
    for cut in (True, False) if plain else (True,):
        session.reset()
        for _ in range(frames):
            time = session.state.time
            buttons = device.buttons(time) if cut else None
            begin = time_ms()
            session.step(device.poses(time), buttons)
            (cutting if cut else uncut).append(time_ms() - begin)
            if "topology" in session.timings:
                updates.append(session.timings["topology"])
        if cut and session._dissection is None:
            raise RuntimeError(f"the hook removed nothing from the liver at detail {detail}")
        if cut:
            removed = int((~session._dissection.topology.particle_alive).sum())
            alive = int(session._dissection.topology.triangles["alive"].sum())
    params = {
        "detail": detail,
        "particles": session.data.particle_count,
        "frames": frames,
        "removed": removed,
        "updates": len(updates),
        "first_update_ms": round(updates[0], 1),  # compiles the row writes
        "triangles_alive": alive,
    }
    session.close()
    rows = [
        result("liver-cautery", params, "ms_per_update", updates[1:]),
        result("liver-cautery", dict(params, cutting=True), "ms_per_frame", cutting),
    ]
    if plain:
        rows.append(result("liver-cautery", dict(params, cutting=False), "ms_per_frame", uncut))
    return rows


def time_ms() -> float:
    return time.perf_counter() * 1e3


def random_removal_cases(detail: float, events: int, seed: int = 0) -> list[dict]:
    """``random-removals-liver`` at ``detail`` (module docstring)."""
    from taichi_lap import scene as scene_mod
    from taichi_lap.core.topology import check_topology
    from taichi_lap.dissection.removal import MutableTopology, cuttable_organs
    from taichi_lap.preprocess.cache import build_model

    data = build_model(scene_mod.load("liver", {"scene.detail": detail}), progress=False)
    topology = MutableTopology(data)
    rng = np.random.default_rng(seed)
    rest = data.rest_position
    liver = np.flatnonzero(data.organ == 0)
    cuttable = np.flatnonzero(cuttable_organs(data)[data.organ])  # the vessels too
    failures, times, checks = 0, [], []
    for _ in range(events):
        alive = liver[topology.particle_alive[liver]]
        if not len(alive):
            break
        centre = rest[rng.choice(alive)]
        radius = rng.uniform(0.0015, 0.004)
        near = cuttable[topology.particle_alive[cuttable]]
        ball = near[np.linalg.norm(rest[near] - centre, axis=1) < radius]
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
        "removed_vessel_particles": int((~topology.particle_alive[data.organ != 0]).sum()),
        "validator_ms_median": round(float(np.median(checks)), 1),
    }
    return [
        result("random-removals-liver", params, "validator_failures", [failures]),
        result("random-removals-liver", params, "ms_per_update", times),
    ]


def fascia_sheet():
    """The rectum scene's fascia sheet, placed as the scene places it (points,
    triangles)."""
    from taichi_lap import scene as scene_mod
    from taichi_lap.preprocess.organs import make_geometry

    scene = scene_mod.load("rectum")
    organ = next(o for o in scene.organs if o.name == "fascia")
    mesh = make_geometry(organ, "rectum")
    return mesh.vertices.astype(np.float64), mesh.triangles.astype(np.int64)


def blade(radius: float):
    """A column through the sheet (along y) of ``radius`` [m]: a blade's cutting edge."""
    from taichi_lap.core.instruments import ToolGeometry, ToolShape

    return ToolGeometry((ToolShape.capsule((0, -0.01, 0), (0, 0.01, 0), radius),), 0.0, 0.0)


def fascia_cut_cases(quick: bool, random_cuts: int, seed: int = 0) -> list[dict]:
    """``fascia-cut-host`` and ``random-cuts-fascia-host`` (module docstring)."""
    from taichi_lap.core.mesh import piece_count
    from taichi_lap.dissection.surface_cut import Sweep, cut_surface, sheet_problems

    points, triangles = fascia_sheet()
    level = np.eye(3)
    z = points[:, 2].min() + 0.004  # beside the attached strip
    start, end = points[:, 0].min() - 0.005, points[:, 0].max() + 0.005
    frames = np.arange(start, end, 0.02 / 60.0)
    if quick:
        frames = frames[: len(frames) // 4]
    times, failures = [], 0
    for a, b in zip(frames[:-1], frames[1:]):
        sweep = Sweep.between(blade(0.00025), (a, 0, z), level, (b, 0, z), level)
        begin = time.perf_counter()
        cut = cut_surface(points, triangles, sweep)
        points, triangles = cut.apply(points, triangles)
        times.append((time.perf_counter() - begin) * 1e3)
        failures += bool(sheet_problems(points, triangles))
    params = {
        "frames": len(times),
        "speed_m_s": 0.02,
        "blade_radius_m": 0.00025,
        "cut_at_z_m": round(float(z), 4),
        "vertices_after": len(points),
        "triangles_after": len(triangles),
        "pieces": piece_count(triangles),
    }
    out = [
        result("fascia-cut-host", params, "ms_per_update", times),
        result("fascia-cut-host", params, "validator_failures", [failures]),
    ]
    points, triangles = fascia_sheet()
    low, high = points.min(axis=0) - 0.01, points.max(axis=0) + 0.01
    rng = np.random.default_rng(seed)
    times, failures = [], 0
    for _ in range(random_cuts):
        a, b = rng.uniform(low, high, (2, 3))
        a[1] = b[1] = 0.0
        tilt = rng.uniform(-0.6, 0.6)
        lean = np.array(
            [[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]]
        )
        sweep = Sweep.between(blade(rng.uniform(0.0001, 0.001)), a, lean, b, lean)
        begin = time.perf_counter()
        cut = cut_surface(points, triangles, sweep)
        points, triangles = cut.apply(points, triangles)
        times.append((time.perf_counter() - begin) * 1e3)
        failures += bool(sheet_problems(points, triangles))
        if not len(triangles):
            break
    params = {"cuts": len(times), "seed": seed, "triangles_after": len(triangles)}
    out += [
        result("random-cuts-fascia-host", params, "validator_failures", [failures]),
        result("random-cuts-fascia-host", params, "ms_per_update", times),
    ]
    return out


def rectum_cut_cases() -> list[dict]:
    """``rectum-fascia-cut`` (module docstring)."""
    from taichi_lap import scene as scene_mod
    from taichi_lap.core.errors import SimulationFault
    from taichi_lap.core.mesh import element_pieces
    from taichi_lap.session import Session, scene_script

    session = Session(scene_mod.load("rectum"), progress=False)
    device = scene_script(session.scene)
    names = [organ.name for organ in session.data.organs]
    fascia, vessel = names.index("fascia"), names.index("vessel")
    frames = int(round(device.duration() / session.dt))
    session.step()  # compile
    organ = session.data.organs[fascia]
    built = organ.particles[1] - organ.reserve  # the sheet's rows below are as built
    updates = {"fascia": [], "volume": [], "vessel": []}
    cut_frames, frame_ms, excised, split = [], {True: [], False: []}, [], 0
    failures = dict.fromkeys(updates, 0)
    for cut in (True, False):
        session.reset()
        start = session.state.x.to_numpy()
        for frame in range(frames):
            time = session.state.time
            buttons = device.buttons(time)
            if not cut:
                buttons.pop("scissors", None)
            begin = time_ms()
            session.step(device.poses(time), buttons)
            frame_ms[cut].append(time_ms() - begin)
            cuts = [e for e in session.events if e["kind"] == "cut"]
            excised += [e for e in session.events if e["kind"] == "excised"] if cut else []
            if cut and cuts:
                organs = {"volume" if "tets" in e else e["organ"] for e in cuts}
                kind = next(k for k in ("volume", "vessel", "fascia") if k in organs)
                updates[kind].append(session.timings["topology"])
                if kind == "fascia":
                    cut_frames.append(frame)
                split += sum(e.get("tets", 0) for e in cuts)
                try:
                    session.check_topology()
                except SimulationFault:
                    failures[kind] += 1
        if cut:
            vessel_pieces = np.bincount(element_pieces(session.live_triangles(vessel))).tolist()
            triangles = session.live_triangles(fascia)
            pieces = element_pieces(triangles)
            x = session.state.x.to_numpy()
            sizes, drops = np.bincount(pieces).tolist(), []
            for piece in range(len(sizes)):
                particles = np.unique(triangles[pieces == piece])
                old = particles[particles < built]
                drops.append(round(float(start[old, 1].mean() - x[old, 1].mean()), 4))
    params = {
        "particles": session.data.particle_count,
        "frames": frames,
        "updates": len(updates["fascia"]),
        "first_update_ms": round(updates["fascia"][0], 1),
        "fascia_pieces_triangles": sizes,
        "fascia_pieces_drop_m": drops,
    }
    cutting = [frame_ms[True][k] for k in cut_frames]
    plain = [frame_ms[False][k] for k in cut_frames]
    polyp = {
        "tets_split": split,
        "updates": len(updates["volume"]),
        "excised_particles": [e["particles"] for e in excised],
        "excised_volume_m3": [float(f"{e['volume']:.4g}") for e in excised],
    }
    vessel_cut = {"updates": len(updates["vessel"]), "vessel_pieces_triangles": vessel_pieces}
    session.close()
    return [
        result("rectum-fascia-cut", params, "ms_per_update", updates["fascia"][1:]),
        result("rectum-fascia-cut", params, "validator_failures", [failures["fascia"]]),
        result("polyp-excision", polyp, "ms_per_update", updates["volume"]),
        result("polyp-excision", polyp, "validator_failures", [failures["volume"]]),
        result("vessel-cut", vessel_cut, "ms_per_update", updates["vessel"]),
        result("vessel-cut", vessel_cut, "validator_failures", [failures["vessel"]]),
        result("rectum-fascia-cut", dict(params, cutting=True), "ms_per_frame", cutting),
        result("rectum-fascia-cut", dict(params, cutting=False), "ms_per_frame", plain),
    ]


def random_polyp_cut_cases(cuts: int, seed: int = 0) -> list[dict]:
    """``random-cuts-polyp-host`` (module docstring)."""
    from taichi_lap import scene as scene_mod
    from taichi_lap.core.topology import check_topology
    from taichi_lap.dissection.removal import MutableTopology
    from taichi_lap.dissection.tet_cut import BladePath, cut_tets
    from taichi_lap.preprocess import organs
    from taichi_lap.preprocess.assemble import assemble

    kept, organs.VOLUME_CUT_RESERVE = organs.VOLUME_CUT_RESERVE, 20.0
    try:  # built here, not cached: the reserve is this benchmark's
        data = assemble(scene_mod.load("rectum"))
    finally:
        organs.VOLUME_CUT_RESERVE = kept
    k = next(i for i, o in enumerate(data.organs) if o.name == "polyp")
    record = data.organs[k]
    free = list(range(record.particles[1] - record.reserve, record.particles[1]))
    topology = MutableTopology(data)
    rest = topology.rest
    built = np.arange(record.particles[0], record.particles[1] - record.reserve)
    low, high = rest[built].min(axis=0), rest[built].max(axis=0)
    size = float(np.linalg.norm(high - low))
    rng = np.random.default_rng(seed)
    times, failures, made = [], 0, 0
    for _ in range(cuts):
        normal = rng.normal(size=3)
        normal /= np.linalg.norm(normal)
        u = np.cross(normal, rng.normal(size=3))
        u /= np.linalg.norm(u)
        w = np.cross(normal, u)
        centre = rng.uniform(low, high)
        steps = np.linspace(-size, size, 5)
        path = BladePath.of([[centre - size * u + t * w, centre + size * u + t * w] for t in steps])
        begin = time.perf_counter()
        tets = topology.live_tets(k)
        cut = cut_tets(rest, topology.tets[tets], path)
        if cut.empty:
            continue
        if len(cut.vertex_parents) > len(free):
            break
        rows = np.array([free.pop() for _ in range(len(cut.vertex_parents))])
        topology.split_tets(cut, tets, rows)
        times.append((time.perf_counter() - begin) * 1e3)
        made += 1
        failures += bool(check_topology(topology.topology()))
    params = {
        "cuts": made,
        "seed": seed,
        "reserve_rows": record.reserve,
        "rows_left": len(free),
        "tets_after": len(topology.live_tets(k)),
    }
    return [
        result("random-cuts-polyp-host", params, "validator_failures", [failures]),
        result("random-cuts-polyp-host", params, "ms_per_update", times),
    ]


def main():
    args = arguments("topology", ("cautery", "removals", "fascia", "polyp", "session"))
    from taichi_lap import runtime

    runtime.init(args.arch)
    detail = QUICK["detail"] if args.quick else 1.0
    events = QUICK["events"] if args.quick else (args.runs or 1000)
    results = []
    if "cautery" in args.cases:
        if args.quick:
            results += cautery_cases(detail, QUICK["cautery_seconds"], plain=False)
        else:
            results += cautery_cases(detail)
    if "removals" in args.cases:
        results += random_removal_cases(detail, events)
    if "fascia" in args.cases:
        results += fascia_cut_cases(args.quick, events)
    if "polyp" in args.cases:
        results += random_polyp_cut_cases(QUICK["polyp_cuts"] if args.quick else events)
    if "session" in args.cases and not args.quick:
        results += rectum_cut_cases()
    report("topology", args.arch, results, args.json)


if __name__ == "__main__":
    main()
