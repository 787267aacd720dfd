"""The solver: the order of one simulation step, written once.

A frame of length dt runs ``substeps`` substeps of h = dt / substeps, each:

1. **predict** — seed 000 Alg. 1 lines 3-6 for every particle (goal pull, gravity,
   springs of seed 001 §3.2, damping), then tool and environment contacts;
2. **constraints** — ``iterations`` sweeps over distance constraints (struts, sheet
   edges) and relaxed long-range attachments (seed 000 Eq. 3), contacts re-applied;
3. **shape matching** — ``shape_iterations`` passes of Alg. 1 lines 7-23 (A, polar
   decomposition per cluster, limited goals); all passes but the last move p
   towards the goals;
4. **collision** — the drawn surface against the tools (the contact that holds,
   :func:`taichi_lap.kernels.collision.response.surface_tool`) after each
   shape-matching pass, whatever the scene chooses for tissue pairs; surface triangles
   against each other by adaptive circumspheres or a baseline (seed 000 §4, chosen
   per scene) after the last; self-collision of the intestine and mesentery (seed 001
   §4: stochastic detection, displacement-velocity response Eq. 2-9) on the predicted
   positions;
5. **update goals** — Alg. 1 lines 12-25 (η, goal limiting, v and x), health check.

Each substep places the tools a fraction of the way from where they were at the
frame's start to where the devices put them (:meth:`Control.advance`), so a tool
moves through the tissue in steps of a substep, not of a frame.

Before the substeps a grasper whose jaws just closed captures the particles between
them and one whose jaws opened releases them (seed 002 §3.4); every projection then
holds captured particles in the tool frame. Each capture and release is appended to
``events`` (cleared every step) for the session record.

After the substeps the render surface is skinned to the particles and the health
flag is read: a non-finite or exploding particle raises :class:`SimulationFault`.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, fields

import numpy as np
import taichi as ti

from taichi_lap.collision import IntestineCollision, TissueCollision
from taichi_lap.core.errors import SimulationFault
from taichi_lap.core.instruments import JAW_REACH, MAX_TOOLS
from taichi_lap.kernels import distance, grasp, shape_matching, skinning
from taichi_lap.kernels.collision import particle_contact
from taichi_lap.kernels.health import NO_FAULT
from taichi_lap.kernels.tool_reaction import measure_tool_contact
from taichi_lap.scene.schema import SCENE_PARAMS
from taichi_lap.sim.control import Control
from taichi_lap.sim.model import Model
from taichi_lap.sim.state import State


def _frozen(value):
    """Arrays of the schema as tuples (settings are immutable)."""
    return tuple(value) if isinstance(value, list) else value


def _default(key: str):
    """The scene schema's default of ``[scene]`` key ``key``."""
    return _frozen(SCENE_PARAMS[key].default)


@dataclass(frozen=True)
class SolverSettings:
    """Scene-wide solver parameters: the ``[scene]`` keys of the same names, whose
    defaults, units and meanings are those of
    :data:`taichi_lap.scene.schema.SCENE_PARAMS` (one default per key)."""

    substeps: int = _default("substeps")
    shape_iterations: int = _default("shape_iterations")
    iterations: int = _default("iterations")
    constraint_solver: str = _default("constraint_solver")
    over_relaxation: float = _default("over_relaxation")
    gravity: tuple[float, float, float] = _default("gravity")
    speed_limit: float = _default("speed_limit")
    collision: str = _default("collision")
    collision_scale_phi: float = _default("collision_scale_phi")
    self_collision: bool = _default("self_collision")
    collision_threshold: float = _default("collision_threshold")
    collision_random_pairs: int = _default("collision_random_pairs")
    collision_passes: int = _default("collision_passes")
    collision_skin: float = _default("collision_skin")
    seed: int = _default("seed")

    @classmethod
    def from_scene(cls, settings: dict) -> "SolverSettings":
        """The settings of a validated scene's ``settings`` table."""
        return cls(**{f.name: _frozen(settings[f.name]) for f in fields(cls)})


class Solver:
    """Advances a :class:`State` in place; see the module docstring for the order.

    The tissue collision holds the tools' contact with the drawn surface in every
    model with surface triangles and meets tissue pairs by the method
    ``settings.collision`` chooses (none for ``"off"``), or is ``collision`` when
    given (seed 000's cylinder experiment compares methods on one model); the
    intestine self-collision is on for organs with spring rows when
    ``settings.self_collision``."""

    def __init__(
        self,
        model: Model,
        settings: SolverSettings,
        *,
        collision: TissueCollision | None = None,
    ):
        if model.constraint_solver != settings.constraint_solver:
            raise ValueError("the model was built for another constraint solver")
        self.model = model
        self.settings = settings
        self._has_constraints = model.distance_count > 0 or model.lra_count > 0
        self._has_clusters = model.cluster_total > 0
        self._has_springs = model.spring_count > 0
        self.collision = collision
        if collision is None and len(model.data.surface_triangles):
            pairs = settings.collision != "off"
            self.collision = TissueCollision(
                model,
                method=settings.collision if pairs else "polygon",
                tissue_pairs=pairs,
                scale_phi=settings.collision_scale_phi,
            )
        self.self_collision = None
        if settings.self_collision and any(o.row_length for o in model.data.organs):
            self.self_collision = IntestineCollision(
                model,
                threshold=settings.collision_threshold,
                random_pairs=settings.collision_random_pairs or None,
                passes=settings.collision_passes,
                skin=settings.collision_skin,
                seed=settings.seed,
            )
        self.events: list[dict] = []
        self.collision_ms = 0.0  # wall time of the collision pipelines in the last step
        self.time_stages = False  # synchronise around them, so a GPU's time is theirs

    def step(self, state: State, control: Control, dt: float, *, collide: bool = True):
        """Advance one frame of ``dt`` [s]; raise :class:`SimulationFault` on a fault.
        ``collide=False`` leaves out both collision pipelines (particle contacts with
        tools and planes stay), e.g. while a scene settles from its rest shape. The
        time the collision pipelines took goes to :attr:`collision_ms` (exact on the
        CPU backend; on a GPU with :attr:`time_stages`, which waits for the device
        around them)."""
        h = dt / self.settings.substeps
        state.fault_particle[None] = NO_FAULT
        self.events = []
        self.collision_ms = 0.0
        self.update_grasps(state, control)
        n = self.settings.substeps
        for k in range(n):
            control.advance(k / n, (k + 1) / n)
            self.substep(
                state,
                control,
                h,
                first=k == 0,
                last=k == self.settings.substeps - 1,
                collide=collide,
            )
        skinning.skin_surface(self.model, state)
        state.time += dt
        state.frame += 1
        self.check_health(state)

    def tool_contact(
        self, state: State, control: Control, tool: int, dt: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(force, touching)`` at the end of the last step of ``dt`` [s]: the force [N]
        (3,) the tissue pushed tool ``tool`` with, and per organ of the model the
        particles touching it (:func:`~taichi_lap.kernels.tool_reaction.measure_tool_contact`)."""
        h = dt / self.settings.substeps
        measure_tool_contact(self.model, state, control, tool, h)
        force = control.tool_reaction.to_numpy()[tool].astype(np.float64)
        return force, control.tool_contacts.to_numpy()[tool, : len(self.model.data.organs)]

    def reset(self, *, pairs: bool = False):
        """Forget what the collision pipelines carry from frame to frame (after the
        state jumped); ``pairs``: the tissue collision's pair lists too."""
        if self.collision is not None:
            self.collision.reset(pairs=pairs)
        if self.self_collision is not None:
            self.self_collision.reset()

    def close(self):
        """Free the fields of the collision pipelines."""
        for pipeline in (self.collision, self.self_collision):
            if pipeline is not None:
                pipeline.close()

    def update_grasps(self, state: State, control: Control):
        """Capture for jaws that closed since the last step, release for jaws that
        opened; one event per change (``kind`` grasp or release, ``tool``, ``particles``)."""
        for tool in range(MAX_TOOLS):
            closed = control.grasp[tool] and control.jaw_length[tool] > 0.0
            if closed == state.jaws_closed[tool]:
                continue
            if closed:
                count = grasp.capture(
                    self.model,
                    state,
                    control,
                    tool,
                    control.jaw_length[tool],
                    JAW_REACH * float(control.tool_radius[tool]),
                )
            else:
                count = grasp.release(self.model, state, tool)
            state.jaws_closed[tool] = closed
            self.events.append(
                {"kind": "grasp" if closed else "release", "tool": tool, "particles": count}
            )

    def substep(
        self,
        state: State,
        control: Control,
        h: float,
        *,
        first: bool = True,
        last: bool = True,
        collide: bool = True,
        collision_control: Control | None = None,
    ):
        """One substep: predict, constraints, shape matching, update goals. Within a
        frame the update of one substep also predicts the next (``first``/``last``
        say where this substep lies), except for particles with springs.
        ``collision_control``: the tools the tissue collision sees when they differ
        from ``control`` (seed 000's cylinder experiment reaches the tissue through
        the collision pipeline only)."""
        model, settings = self.model, self.settings
        collision_control = collision_control or control
        collision = self.collision if collide else None
        if first or self._has_springs:
            shape_matching.predict(model, state, control, settings.gravity, h, int(not first))
        if model.tube_particle_count:
            particle_contact.push_tubes_out_of_tools(model, state, control)
        if self._has_constraints:
            self._solve_constraints(state, control)
        if self._has_clusters:
            for _ in range(settings.shape_iterations - 1):
                shape_matching.match_clusters(model, state)
                shape_matching.project_to_goals(model, state, control)
                if collision is not None:  # tool contacts after every pass
                    with self._collision_timer():
                        collision.step(state, collision_control, tissue=False)
            shape_matching.match_clusters(model, state)
        if collision is not None:  # the last move of p before the goal update
            with self._collision_timer():
                collision.step(state, collision_control)
        if self.self_collision is not None and collide:
            with self._collision_timer():
                self.self_collision.step(state, h)
        if model.tube_particle_count:  # the last move of the tubes
            particle_contact.push_tubes_out_of_tools(model, state, control)
        shape_matching.update_goals(
            model, state, control, h, settings.speed_limit, settings.gravity, int(not last)
        )

    @contextmanager
    def _collision_timer(self):
        """Adds the wall time of the block to :attr:`collision_ms`."""
        if self.time_stages:
            ti.sync()
        start = time.perf_counter()
        yield
        if self.time_stages:
            ti.sync()
        self.collision_ms += (time.perf_counter() - start) * 1e3

    def _solve_constraints(self, state: State, control: Control):
        model, settings = self.model, self.settings
        if settings.constraint_solver == "gauss_seidel":
            for _ in range(settings.iterations):
                for begin, end in model.color_ranges:
                    distance.gauss_seidel_color(model, state, begin, end)
                distance.gauss_seidel_finish(model, state, control)
            return
        buffers = (state.p, state.p_next)
        for it in range(settings.iterations):
            distance.jacobi_sweep(
                model,
                state,
                control,
                buffers[it % 2],
                buffers[(it + 1) % 2],
                settings.over_relaxation,
            )
        if settings.iterations % 2:
            distance.copy_positions(state.p_next, state.p)

    def check_health(self, state: State):
        """Raise :class:`SimulationFault` naming the first faulty particle and organ."""
        if not state.fault[None]:
            return
        particle = int(state.fault_particle[None])
        organ = "?"
        for record in self.model.data.organs:
            if record.particles[0] <= particle < record.particles[1]:
                organ = record.name
        raise SimulationFault(
            f"simulation fault at frame {state.frame}: particle {particle} of "
            f"organ {organ!r} has a non-finite position or a speed above "
            f"{self.settings.speed_limit:g} m/s"
        )
