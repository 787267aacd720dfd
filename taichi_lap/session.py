"""A scene ready to run: model built (or loaded from the cache), the device-side
Model / State / Control, the solver, and per-stage timings."""

from __future__ import annotations

import hashlib
import json
import logging
import time
from dataclasses import dataclass

import numpy as np
import taichi as ti

from taichi_lap import runtime
from taichi_lap.core.errors import SimulationFault
from taichi_lap.core.instruments import (
    CAUTERY_BUTTON,
    DISSECTOR_REACH,
    GRASP_BUTTON,
    MAX_TOOLS,
    cutting_geometry,
    tool_geometry,
)
from taichi_lap.core.mesh import tet_volumes
from taichi_lap.core.topology import Topology, TopologyError
from taichi_lap.core.topology import check_topology as topology_problems
from taichi_lap.devices import Pose, ScriptedDevice, apply_poses
from taichi_lap.dissection.cautery import Cautery
from taichi_lap.dissection.device import DeviceTopology
from taichi_lap.dissection.removal import FRAGMENT_PARTICLES, MutableTopology
from taichi_lap.dissection.sheet_cut import SheetCutter
from taichi_lap.dissection.spring_sheets import SpringSheets
from taichi_lap.dissection.surface_cut import Sweep
from taichi_lap.dissection.volume_cut import VolumeCutter, scissor_blade
from taichi_lap.kernels.skinning import skin_surface, skin_surface_rows
from taichi_lap.render.camera import EndoscopeCamera
from taichi_lap.preprocess.cache import (
    build_model,
    cache_dir,
    code_digest,
    load_arrays,
    save_arrays,
    scene_digest,
)
from taichi_lap.scene import Scene
from taichi_lap.scene.schema import PLANE_LOOK
from taichi_lap.scenes.anatomy.tubes import environment_centreline
from taichi_lap.sim import Control, Model, Solver, SolverSettings, State

log = logging.getLogger("taichi_lap")


def model_for(scene: Scene, data) -> Model:
    """Upload a built model with the scene's environment and solver choices."""
    planes = [(p["point"], p["normal"], p["friction"]) for p in scene.planes]
    tubes = [(environment_centreline(t["points"]), t["radius"], t["friction"]) for t in scene.tubes]
    return Model(
        data,
        planes=planes,
        tubes=tubes,
        iterations=scene.settings["iterations"],
        constraint_solver=scene.settings["constraint_solver"],
    )


def scene_script(scene: Scene) -> ScriptedDevice | None:
    """The tools' inline scripts as one device, or ``None`` when no tool has one."""
    frames = [dict(frame, tool=tool["name"]) for tool in scene.tools for frame in tool["script"]]
    return ScriptedDevice.from_tables(scene.source, frames, scene.tools) if frames else None


def session_key(scene: Scene) -> str:
    """What a session's device objects and settled start depend on: the model (its cache
    key: validated organs, detail, mesh files, builder code), the settings, the planes
    (how they collide, not how they are drawn), environment tubes and tools."""
    content = {
        "model": scene_digest(scene),
        "settings": scene.settings,
        "planes": [{k: v for k, v in p.items() if k not in PLANE_LOOK} for p in scene.planes],
        "tubes": scene.tubes,
        "tools": scene.tools,
    }
    return hashlib.sha256(json.dumps(content, sort_keys=True, default=str).encode()).hexdigest()


def settled_start_digest(key: str) -> str:
    """Cache key of a scene's settled start: the session key, the code that simulates
    (every package module a session reads) and the backend (another rounds
    differently)."""
    content = [key, code_digest(("taichi_lap.session",)), str(runtime.current_arch())]
    return hashlib.sha256("/".join(content).encode()).hexdigest()[:32]


@dataclass
class _Parts:
    """The device objects of a closed session, kept for the next one of its scene."""

    key: str
    model: Model
    state: State
    control: Control
    solver: Solver
    start_state: dict | None
    settle_seconds: float
    cautery: Cautery | None
    dissection: DeviceTopology | None  # tissue removed or cut: restored when taken

    def close(self):
        owners = (self.solver, self.control, self.state, self.model)
        for owner in owners + ((self.cautery.heat,) if self.cautery is not None else ()):
            owner.close()


_parked: list[_Parts] = []
"""The parts of the last closed sessions, oldest first (:func:`keep_closed_sessions`)."""
_parked_capacity = 1


def keep_closed_sessions(count: int):
    """Keep the parts of the last ``count`` closed sessions (at least 1; the default
    1) for sessions of their scenes; the fields of older ones are freed when another
    closes. Freeing fields makes Taichi compile every kernel of the process again
    (:meth:`taichi_lap.core.fields.FieldGroup.close`): a process that alternates
    between a few scenes (the tests) keeps them all."""
    global _parked_capacity
    if count < 1:
        raise ValueError(f"keep_closed_sessions: count must be at least 1, not {count}")
    _parked_capacity = count


def release_parked(key: str | None = None):
    """Free the fields of the sessions kept for reuse: those of the scene ``key``
    (:func:`session_key`), or all of them."""
    kept = []
    for parts in _parked:
        if key is None or parts.key == key:
            parts.close()
        else:
            kept.append(parts)
    _parked[:] = kept


class Session:
    """Owns everything one running scene needs. ``timings`` holds the last frame's
    milliseconds per stage (``physics``, of which ``collision`` the collision
    pipelines; ``topology`` when it removed tissue, the host topology and the rows
    written to the device; ``heat`` while the cautery's heat runs; the run loop adds
    ``devices``, renderers theirs); ``events`` the last
    step's simulation events (grasp, release), each with the tool's name.

    A scene with ``settle_time`` starts settled: once, at construction, the solver runs
    that long from the rest shape with the tools at their scene poses and both
    collision pipelines off (an organ sagging from the shape it was built in moves
    every surface triangle, which the collision broad phase pays for in every
    substep), and :meth:`reset` returns to that state (``settle_seconds``: the wall
    time it took). The tissue collision's pair lists are then built for the start
    state, so that the first frame does not pay for them.

    :meth:`close` (or leaving a ``with`` block) ends the session. Its Model, State,
    Control and Solver are kept for the next session of the same scene in this
    process (:func:`session_key`), which takes them, with the settled start, instead
    of allocating new fields: Taichi compiles a kernel once per object it is given, so
    that session compiles nothing and starts at once (the tissue the closed session
    removed or cut is put back then, not at closing; so are the tools' shapes). Only
    the last closed session is kept, unless :func:`keep_closed_sessions` asks for
    more; closing another frees the fields of the oldest one kept
    (:func:`release_parked` frees them too), after which Taichi compiles every
    kernel again (:meth:`taichi_lap.core.fields.FieldGroup.close`)."""

    def __init__(self, scene: Scene, *, use_cache: bool = True, progress: bool = True):
        start = time.perf_counter()
        self.scene = scene
        self.dt = scene.settings["dt"]
        self.timings: dict[str, float] = {}
        self.events: list[dict] = []
        self.key = session_key(scene)
        self._closed = False
        self._dissection = None  # a DeviceTopology once tissue was removed
        self._checked_version = None  # what check_topology last validated
        self._cautery = None  # a Cautery once a hook was energised
        self._cutter = None  # a SheetCutter once a tool cut
        self._volume_cutter = None  # a VolumeCutter once scissors closed
        self._springs = None  # a SpringSheets once a spring sheet tore or was cut
        self._loose: list[tuple[int, np.ndarray]] = []  # pieces cut free: (organ, particles)
        self.camera = EndoscopeCamera.from_scene(scene.camera)  # a window sets its own
        self._cut_poses: dict[int, tuple] = {}  # each cutting tool's tip and frame
        self._energised: set[str] = set()  # the hooks energised in the last step
        parts = _take_parked(self.key)
        if parts is not None:
            self.data = parts.model.data
            self.model, self.state, self.control = parts.model, parts.state, parts.control
            self.solver, self._start_state = parts.solver, parts.start_state
            self._cautery, self._dissection = parts.cautery, parts.dissection
            self.settle_seconds = parts.settle_seconds
            self.build_seconds = time.perf_counter() - start
            self._restore_topology()  # the closed session's cuts and removals
            self._set_tool_shapes()  # as the scene gives them, whatever changed them since
            self.solver.reset(pairs=True)
            self.reset()
        else:
            self.data = build_model(scene, use_cache=use_cache, progress=progress)
            self.build_seconds = time.perf_counter() - start
            self.model = model_for(scene, self.data)
            self.state = State(self.model)
            self.control = Control()
            self._set_tool_shapes()
            self.solver = Solver(self.model, SolverSettings.from_scene(scene.settings))
            self._start_state = None
            self.settle_seconds = 0.0
            self.reset()
            frames = round(scene.settings["settle_time"] / self.dt)
            if frames > 0:
                self._start_state = self._settled_start(frames, use_cache)
                self.reset()
        if self.solver.collision is not None:
            self.solver.collision.prime(self.state, self.control)

    def __enter__(self) -> Session:
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        """End the session (class docstring); it must not be used afterwards."""
        if self._closed:
            return
        self._closed = True
        while len(_parked) >= _parked_capacity:
            _parked.pop(0).close()
        _parked.append(
            _Parts(
                self.key,
                self.model,
                self.state,
                self.control,
                self.solver,
                self._start_state,
                self.settle_seconds,
                self._cautery,
                self._dissection,
            )
        )

    def reset(self):
        """Back to the start state (the rest shape, or the settled one), tools at their
        scene poses, surface skinned; removed tissue is back, at body temperature."""
        self._restore_topology()
        if self._cautery is not None:
            self._cautery.reset()
        self._energised = set()
        self._cut_poses = {}
        if self._start_state is None:
            self.state.reset(self.model)
        else:
            self.state.restore(self._start_state)
        self.control.reset()
        self.solver.reset()
        apply_poses(self.control, self.scene.tools, {})
        skin_surface(self.model, self.state)

    def remove_particles(self, particles, event: dict | None = None):
        """Dissection between frames (seed 002 §3.3): remove ``particles`` (indices)
        and what goes with them; returns the
        :class:`~taichi_lap.dissection.removal.TopologyChange`. A fragment cut off is
        reported in :attr:`events` (``fragment``, with its particle count); so is the
        removal when ``event`` (its kind and fields) is given: with ``particles`` (how
        many were removed), ``volume`` [m^3] (their tets' rest volume) and ``removed``
        (:meth:`_removed_tissue`)."""
        start = time.perf_counter()
        positions = self.state.x.to_numpy() if event is not None else None
        change = self._dissected().topology.remove(particles)
        if not change.empty:
            self._dissection.apply(change, self.state)
            self._follow(change)
            if event is not None:
                self.events.append(
                    {
                        **event,
                        "particles": len(change.removed_particles),
                        "volume": change.removed_volume,
                        "removed": self._removed_tissue(change, positions),
                    }
                )
        spent = (time.perf_counter() - start) * 1e3
        self.timings["topology"] = self.timings.get("topology", 0.0) + spent
        return change

    def _removed_tissue(self, change, positions: np.ndarray) -> dict[str, dict]:
        """Per organ (name) a removal ``change`` took tissue of: ``positions``, where
        its removed particles were [m] (``positions``: all particles before the
        removal), rounded to 0.1 mm, and ``volume``, the rest volume [m^3] of its dead
        tets; what a task's goal is judged on (``docs/training.md``)."""
        topology = self._dissection.topology
        removed = change.removed_particles
        organ_of_particle = topology.organ_of[removed]
        dead = topology.tets[change.dead_tets]
        organ_of_tet = topology.organ_of[dead[:, 0]]
        volumes = tet_volumes(topology.rest, dead)
        tissue = {}
        for k in np.unique(organ_of_particle):
            where = np.round(positions[removed[organ_of_particle == k]].astype(np.float64), 4)
            tissue[self.data.organs[k].name] = {
                "positions": where.tolist(),
                "volume": float(volumes[organ_of_tet == k].sum()),
            }
        return tissue

    def _follow(self, change):
        """After a topology ``change`` was written to the model: the heat, the tissue
        collision and the drawn surface follow it; a fragment it cut off is reported in
        :attr:`events` (``fragment``, with its particle count)."""
        self.events += [{"kind": "fragment", "particles": count} for count in change.fragments]
        if self._cautery is not None:
            self._cautery.remove(change.removed_particles)
        collision = self.solver.collision
        if collision is not None:
            surface = self._dissection.surface_rows()
            if (collision.triangle_count, collision.vertex_count) != (
                self.model.surface_triangle_count,
                self.model.surface_vertex_count,
            ):
                collision = self.solver.collision = collision.regrown(surface)
            rows = [change.dead_triangles, change.new_triangles]
            if len(change.reweighed):  # their corners' masses changed
                rows.append(surface.triangles_at(change.reweighed))
            collision.rewrite(np.unique(np.concatenate(rows)), surface)
        bound = np.union1d(change.new_vertices, change.rebound_vertices)
        if len(bound):  # the wound is drawn where it is
            skin_surface_rows(self.model, self.state, bound.astype(np.int32))
        ti.sync()

    def _cut(self, buttons: dict[str, int]):
        """Cutting (seed 000 Alg. 3, :mod:`taichi_lap.dissection.sheet_cut`): scissors
        whose GRASP_BUTTON is held and hooks whose CAUTERY_BUTTON is held cut the
        sheets their cutting shapes (:func:`cutting_geometry`) swept from their pose
        at the last step to the one the devices gave now, before the physics moves
        the tissue; event ``cut`` with the tool, the organ and the triangles made.
        Scissors also cut the spring sheets (:meth:`_cut_springs`) and the tet organs
        (:meth:`_cut_volumes`)."""
        springs = any(organ.row_length for organ in self.data.organs)
        if not (self.model.cuttable or springs):
            return
        control = self.control
        for k, tool in enumerate(self.scene.tools[:MAX_TOOLS]):
            geometry = cutting_geometry(tool)
            if geometry is None:
                continue
            pose = (control.tips[k].copy(), control.frames[k].copy())
            before = self._cut_poses.get(k, pose)
            self._cut_poses[k] = pose
            scissors = tool["kind"] == "scissors"
            button = GRASP_BUTTON if scissors else CAUTERY_BUTTON
            if not buttons.get(tool["name"], 0) & button:
                if scissors and self._volume_cutter is not None:
                    self._volume_cutter.release(k)
                continue
            if not (self.model.cuttable or springs and scissors):
                continue  # a hook where only spring sheets could be cut: nothing to cut
            start = time.perf_counter()
            sweep = Sweep.between(geometry, *before, *pose)
            x, v = self._motion(velocities=self.model.cuttable)  # spring cuts need no v
            if self.model.cuttable:
                cutter = self._sheet_cutter()
                for organ, change in cutter.cut(sweep, x, v, self.state):
                    self._follow(change)
                    made = len(change.new_triangles)
                    self.events.append(
                        {"kind": "cut", "tool": tool["name"], "organ": organ, "triangles": made}
                    )
                self._separated(cutter, tool["name"])
            if springs and scissors:
                self._cut_springs(sweep, x, tool["name"])
            if scissors and self.model.cuttable:
                self._cut_volumes(k, tool, pose, pose[0] - before[0], x, v)
            spent = (time.perf_counter() - start) * 1e3
            self.timings["topology"] = self.timings.get("topology", 0.0) + spent

    def _cut_springs(self, sweep: Sweep, x: np.ndarray, tool: str):
        """Scissors cut the mesentery (:meth:`SpringSheets.cut`): the springs ``sweep``
        passed through break, at ``x`` (the particles before the step); event
        ``cut`` with the tool, the organ and the ``springs`` broken."""
        sheets = self._spring_sheets()
        cuts = sheets.cut(sweep, x)
        for organ, springs in cuts:
            self.events.append(
                {"kind": "cut", "tool": tool, "organ": organ, "springs": len(springs)}
            )
        if cuts and self.solver.self_collision is not None:
            self.solver.self_collision.follow_tears()
        self._separated(sheets, tool)

    def _spring_sheets(self) -> SpringSheets:
        """The session's tearing and cutting of spring sheets, made at its first use."""
        if self._springs is None:
            materials = [organ.material for organ in self.scene.organs]
            self._springs = SpringSheets(self.model, materials)
        return self._springs

    def _cut_volumes(self, k: int, tool: dict, pose, motion, x: np.ndarray, v: np.ndarray):
        """Volumetric cutting (seed 000 §5.3, :mod:`taichi_lap.dissection.volume_cut`):
        scissors ``k`` with closed jaws at ``pose``, moved by ``motion`` [m] since the
        last step, cut the tet organs their blade's path has passed through; event ``cut`` with the tool, the organ and the tets
        split (``x``, ``v``: the particles before the step; a sheet cut just now
        changed only the sheets' rows). The pieces cut loose are looked for again
        (:meth:`_excise`); one of at most FRAGMENT_PARTICLES (a chip the blade cut off
        between its cuts) goes at once, event ``fragment``."""
        if self._volume_cutter is None:
            cutter = VolumeCutter(self._dissected())
            if not cutter.organs:
                return
            self._volume_cutter = cutter
        blade = scissor_blade(tool, *pose, motion)
        cuts = self._volume_cutter.stroke(k, blade, x, v, self.state)
        for organ, change in cuts:
            self._follow(change)
            self.events.append(
                {"kind": "cut", "tool": tool["name"], "organ": organ, "tets": change.split_tets}
            )
        if cuts:
            self._loose = self._volume_cutter.loose_pieces()
            chips = [piece for _, piece in self._loose if len(piece) <= FRAGMENT_PARTICLES]
            for piece in chips:
                self.remove_particles(piece, {"kind": "fragment"})
            if chips:
                self._loose = self._volume_cutter.loose_pieces()

    def _excise(self):
        """Excision (seed 000 §7): a piece a cut left loose that has been lifted out of
        the endoscope's view (no particle of it in :attr:`camera`'s view) is taken
        out of the body; event ``excised`` with its organ, particles and rest volume
        [m^3]."""
        if not self._loose:
            return
        x = self.state.x.to_numpy().astype(np.float64)
        gone = [(k, piece) for k, piece in self._loose if not self.camera.sees(x[piece]).any()]
        for k, piece in gone:
            self.remove_particles(piece, {"kind": "excised", "organ": self.data.organs[k].name})
        if gone:
            self._loose = self._volume_cutter.loose_pieces()

    def _tear(self):
        """Tearing of the tissue with a ``tear_strain``, after the physics stretched it:
        the sheets (:meth:`SheetCutter.tear`; event ``tear`` with the organ and the
        triangles made) and the spring sheets, the mesentery
        (:meth:`SpringSheets.tear`; event ``tear`` with the organ and ``springs``: 1)."""
        models = {o.model for o in self.scene.organs if o.material.get("tear_strain", 0.0) > 0.0}
        if not models:
            return
        start = time.perf_counter()
        x, _ = self._motion(velocities=False)  # a split reads its vertex's velocity
        torn = []
        if models - {"mass_spring"}:
            cutter = self._sheet_cutter()
            torn = cutter.tear(x, self.state)
            for organ, change in torn:
                self._follow(change)
                self.events.append(
                    {"kind": "tear", "organ": organ, "triangles": len(change.new_triangles)}
                )
            self._separated(cutter)
        if "mass_spring" in models:
            sheets = self._spring_sheets()
            broken = sheets.tear(x)
            torn += broken
            for organ, _ in broken:
                self.events.append({"kind": "tear", "organ": organ, "springs": 1})
            if broken and self.solver.self_collision is not None:
                self.solver.self_collision.follow_tears()
            self._separated(sheets)
        if torn:
            spent = (time.perf_counter() - start) * 1e3
            self.timings["topology"] = self.timings.get("topology", 0.0) + spent

    def _separated(self, cutter: SheetCutter | SpringSheets, tool: str | None = None):
        """Event ``separated`` (with the organ, its connected pieces now and the
        ``tool`` that cut, none for a tear) for each sheet, truss or spring sheet the
        cutter's last cut or tear parted (its ``separations``)."""
        for organ, pieces in cutter.separations:
            event = {"kind": "separated", "organ": organ, "pieces": pieces}
            self.events.append(event if tool is None else dict(event, tool=tool))

    def _motion(self, velocities: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """The particles' positions and velocities (N, 3) [m, m/s] on the host (no
        velocities, None, unless ``velocities``)."""
        x = self.state.x.to_numpy().astype(np.float64)
        return x, self.state.v.to_numpy().astype(np.float64) if velocities else None

    def _sheet_cutter(self) -> SheetCutter:
        """The session's sheet cutter, made at its first use."""
        if self._cutter is None:
            materials = [organ.material for organ in self.scene.organs]
            self._cutter = SheetCutter(self._dissected(), materials)
        return self._cutter

    def _dissect(self):
        """Blunt dissection (seed 002 §3.3: "physical particles are removed
        directly"): each dissector removes the particles of dissectable organs its
        tip presses on (within DISSECTOR_REACH shaft radii of its tip's centre);
        event ``dissect`` with the tool and the particles removed."""
        dissectors = [
            (k, tool)
            for k, tool in enumerate(self.scene.tools[:MAX_TOOLS])
            if tool["kind"] == "dissector"
        ]
        if not dissectors or not self.model.dissectable:
            return
        x = self.state.x.to_numpy()
        tips = self.control.tool_a.to_numpy()
        for k, tool in dissectors:
            reach = DISSECTOR_REACH * tool["radius"]
            near = np.flatnonzero(((x - tips[k]) ** 2).sum(axis=1) < reach * reach)
            near = near[self._dissectable(near)]
            if len(near):
                self.remove_particles(near, {"kind": "dissect", "tool": tool["name"]})

    def _energise(self, buttons: dict[str, int]):
        """The hooks whose CAUTERY_BUTTON is held are energised; events
        ``cautery_on`` / ``cautery_off`` (with the tool) where that changed."""
        energised = {
            tool["name"]
            for tool in self.scene.tools[:MAX_TOOLS]
            if tool["kind"] == "hook" and buttons.get(tool["name"], 0) & CAUTERY_BUTTON
        }
        for kind, names in (
            ("cautery_on", energised - self._energised),
            ("cautery_off", self._energised - energised),
        ):
            self.events += [{"kind": kind, "tool": name} for name in sorted(names)]
        self._energised = energised

    def _cauterize(self):
        """Electrocautery (seed 002 §3.3, :mod:`taichi_lap.dissection.cautery`): the
        energised hooks heat the tissue for this frame; particles at their ablation
        temperature are removed (event ``cautery``, with the tool names and the
        particles removed) and new vessel damage is reported (``vessel_damage``)."""
        if self._cautery is None:
            if not self._energised or not self.model.dissectable:
                return
            self._cautery = Cautery(self.scene, self.data)
        start = time.perf_counter()
        ablated, damage = self._cautery.step(self.dt, self.state, self.control, self._energised)
        self.timings["heat"] = (time.perf_counter() - start) * 1e3
        self.events += damage
        if len(ablated):
            self.remove_particles(ablated, {"kind": "cautery", "tools": sorted(self._energised)})

    def surface_particles(self) -> np.ndarray:
        """Sorted particles the drawn organ surfaces follow now (as built, or after
        dissection: alive, with the kept ends of the wound's vertices); for the haptic
        proxy's collision."""
        if self._dissection is None:
            return self.data.surface_particles()
        return self._dissection.topology.surface_particles()

    @property
    def energised(self) -> set[str]:
        """The hooks (names) energised in the last step."""
        return set(self._energised)

    @property
    def peak_temperature(self):
        """The particles' highest temperatures [°C] so far (a field, for the wound's
        look), or None while no hook was energised."""
        return None if self._cautery is None else self._cautery.heat.peak

    def _dissectable(self, particles: np.ndarray) -> np.ndarray:
        """(P,) bool: ``particles`` alive and of an organ that can lose particles."""
        topology = self._dissected().topology
        return (
            topology.particle_alive[particles] & topology.dissectable[topology.organ_of[particles]]
        )

    def _dissected(self) -> DeviceTopology:
        """The session's mutable topology, made at its first use."""
        if self._dissection is None:
            self._dissection = DeviceTopology(self.model, MutableTopology(self.data))
        return self._dissection

    def live_triangles(self, organ: int | None = None) -> np.ndarray:
        """The surface triangles alive now, ``organ``'s only when given, as particle
        triples (T, 3) (for organs whose surface vertices are their particles: sheets,
        trusses, tet organs bound directly)."""
        if self._dissection is None:
            data = self.data
            triangles = np.asarray(data.surface_triangles).reshape(-1, 3)
            if organ is not None:
                triangles = triangles[slice(*data.organs[organ].triangles)]
            return np.asarray(data.surface_index).reshape(-1, 4)[triangles, 0]
        return self._dissection.topology.live_faces(organ)

    def check_topology(self):
        """Run the topology validator (:mod:`taichi_lap.core.topology`) on the tissue
        as it is now (the skinned surface) when it was not checked since the last
        change; raises SimulationFault listing the problems."""
        if self._checked_version == (id(self._dissection), self.model.topology_version):
            return
        self._checked_version = (id(self._dissection), self.model.topology_version)
        skin_surface(self.model, self.state)
        x = self.state.x.to_numpy().astype(np.float64)
        surface = self.state.surface_position.to_numpy().astype(np.float64)
        if self._dissection is None:
            view = Topology.of_model(self.data, x)
        else:
            view = self._dissection.topology.topology(x)
        view.surface_position = surface[: len(view.surface_index)]
        problems = topology_problems(view)
        if problems:
            raise SimulationFault(f"frame {self.state.frame}: {TopologyError(problems)}")

    def _set_tool_shapes(self):
        """Each scene tool's union of implicit shapes into the control."""
        for index, tool in enumerate(self.scene.tools):
            self.control.set_tool_shapes(index, tool_geometry(tool).shapes)

    def _restore_topology(self):
        """Put the model back as built if tissue was removed or cut (through this
        session, or through a DeviceTopology of its own on the model:
        :attr:`~taichi_lap.sim.model.Model.as_built` tells either)."""
        self._cutter = self._volume_cutter = self._springs = None
        self._loose = []
        self._dissection = None
        if not self.model.as_built:
            self.model.reset_topology()
            if self.solver.collision is not None:
                self.solver.collision.revive()

    def _settled_start(self, frames: int, use_cache: bool) -> dict:
        """The state after ``frames`` frames from the rest state with collision off
        (class docstring): from the cache when a run of this scene, code and backend
        stored it, else simulated (and stored)."""
        path = cache_dir() / f"{settled_start_digest(self.key)}.start.npz"
        if use_cache and path.is_file():
            try:
                snapshot = load_arrays(path)
                self.state.restore(snapshot)  # checks every array against its field
                log.info("settled start loaded from cache %s", path)
                return snapshot
            except (OSError, ValueError, KeyError) as exc:
                log.warning("ignoring unreadable settled start %s: %s", path, exc)
        start = time.perf_counter()
        for _ in range(frames):
            self.solver.step(self.state, self.control, self.dt, collide=False)
        snapshot = self.state.snapshot()
        self.settle_seconds = time.perf_counter() - start
        log.info(
            "%s settled for %.2f s of simulated time in %.1f s",
            self.scene.settings["name"],
            frames * self.dt,
            self.settle_seconds,
        )
        if use_cache:
            save_arrays(path, snapshot)
        return snapshot

    def step(
        self,
        poses: dict[str, Pose] | None = None,
        buttons: dict[str, int] | None = None,
        *,
        collide: bool = True,
    ):
        """Place the tools (``buttons`` per tool name close graspers), advance one
        frame of ``dt``, time it; ``collide=False``: without the collision pipelines
        (:meth:`Solver.step`)."""
        if self._closed:
            raise RuntimeError("the session is closed")
        start = time.perf_counter()
        for stage in ("topology", "heat"):
            self.timings.pop(stage, None)
        apply_poses(self.control, self.scene.tools, poses or {}, buttons)
        self.events = []
        self._cut(buttons or {})
        self.solver.step(self.state, self.control, self.dt, collide=collide)
        ti.sync()
        spent = (time.perf_counter() - start) * 1e3
        self.timings["physics"] = spent - self.timings.get("topology", 0.0)
        self.timings["collision"] = self.solver.collision_ms  # a part of physics
        self.events += self._grasp_events()
        self._energise(buttons or {})
        self._tear()
        self._excise()
        self._dissect()
        self._cauterize()

    def _grasp_events(self) -> list[dict]:
        """The solver's grasp and release events with the tool's name; a grasp also
        with ``organs``: the particles of each organ the jaws took (by name)."""
        names = [tool["name"] for tool in self.scene.tools]
        events = []
        for event in self.solver.events:
            named = dict(event, tool=names[event["tool"]])
            if event["kind"] == "grasp":
                held = self.data.organ[self.state.grasp_tool.to_numpy() == event["tool"]]
                organs = np.bincount(held, minlength=len(self.data.organs))
                named["organs"] = {
                    organ.name: int(n) for organ, n in zip(self.data.organs, organs) if n
                }
            events.append(named)
        return events

    def tool_reaction(self, tool: int) -> np.ndarray:
        """The force [N] (3,) the tissue pushed scene tool ``tool`` (an index) with at
        the end of the last step."""
        return self.tool_contact(tool)[0]

    def tool_contact(self, tool: int) -> tuple[np.ndarray, dict[str, int]]:
        """``(force, touching)`` of scene tool ``tool`` (an index) at the end of the last
        step: the force [N] (3,) the tissue pushed it with and, by organ name, the
        particles of each organ touching it (organs that touch it only)."""
        force, touching = self.solver.tool_contact(self.state, self.control, tool, self.dt)
        organs = self.data.organs
        return force, {organs[k].name: int(n) for k, n in enumerate(touching) if n}


def _take_parked(key: str) -> _Parts | None:
    """The last kept parts of the scene ``key`` names (then no longer kept), if any."""
    for index in range(len(_parked) - 1, -1, -1):
        if _parked[index].key == key:
            return _parked.pop(index)
    return None
