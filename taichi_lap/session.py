"""A scene ready to run: model built (or loaded from the cache), the device-side
Model / State / Control, the solver, and per-stage timings."""

from __future__ import annotations

import logging
import time

import taichi as ti

from taichi_lap.core.instruments import tool_geometry
from taichi_lap.devices import Pose, ScriptedDevice, apply_poses
from taichi_lap.kernels.skinning import skin_surface
from taichi_lap.preprocess.cache import build_model
from taichi_lap.scene import Scene
from taichi_lap.sim import Control, Model, Solver, SolverSettings, State

log = logging.getLogger("taichi_lap")


def model_for(scene: Scene, data) -> Model:
    """Upload a built model with the scene's environment and solver choices."""
    planes = [(p["point"], p["normal"], p["friction"]) for p in scene.planes]
    return Model(
        data,
        planes=planes,
        iterations=scene.settings["iterations"],
        constraint_solver=scene.settings["constraint_solver"],
    )


def scene_script(scene: Scene) -> ScriptedDevice | None:
    """The tools' inline scripts as one device, or ``None`` when no tool has one."""
    frames = [dict(frame, tool=tool["name"]) for tool in scene.tools for frame in tool["script"]]
    return ScriptedDevice.from_tables(scene.source, frames, scene.tools) if frames else None


class Session:
    """Owns everything one running scene needs. ``timings`` holds the last frame's
    milliseconds per stage (``physics``; renderers add theirs); ``events`` the last
    step's simulation events (grasp, release), each with the tool's name.

    A scene with ``settle_time`` starts settled: once, at construction, the solver runs
    that long from the rest shape with the tools at their scene poses and both
    collision pipelines off (an organ sagging from the shape it was built in moves
    every surface triangle, which the collision broad phase pays for in every
    substep), and :meth:`reset` returns to that state (``settle_seconds``: the wall
    time it took). The tissue collision's pair lists are then built for the start
    state, so that the first frame does not pay for them."""

    def __init__(self, scene: Scene, *, use_cache: bool = True, progress: bool = True):
        start = time.perf_counter()
        self.scene = scene
        self.data = build_model(scene, use_cache=use_cache, progress=progress)
        self.build_seconds = time.perf_counter() - start
        self.model = model_for(scene, self.data)
        self.state = State(self.model)
        self.control = Control()
        for index, tool in enumerate(scene.tools):
            self.control.set_tool_shapes(index, tool_geometry(tool).shapes)
        self.solver = Solver(self.model, SolverSettings.from_scene(scene.settings))
        self.dt = scene.settings["dt"]
        self.timings: dict[str, float] = {}
        self.events: list[dict] = []
        self._start_state = None
        self.settle_seconds = 0.0
        self.reset()
        self._settle(round(scene.settings["settle_time"] / self.dt))
        if self.solver.collision is not None:
            self.solver.collision.prime(self.state, self.control)

    def reset(self):
        """Back to the start state (the rest shape, or the settled one), tools at their
        scene poses, surface skinned."""
        if self._start_state is None:
            self.state.reset(self.model)
        else:
            self.state.restore(self._start_state)
        self.control.reset()
        for collision in (self.solver.collision, self.solver.self_collision):
            if collision is not None:
                collision.reset()
        apply_poses(self.control, self.scene.tools, {})
        skin_surface(self.model, self.state)

    def _settle(self, frames: int):
        """Run ``frames`` frames from the rest state with collision off and keep the
        result as the start state (class docstring)."""
        if frames <= 0:
            return
        start = time.perf_counter()
        solver = self.solver
        pipelines = solver.collision, solver.self_collision
        solver.collision = solver.self_collision = None
        try:
            for _ in range(frames):
                solver.step(self.state, self.control, self.dt)
        finally:
            solver.collision, solver.self_collision = pipelines
        self._start_state = self.state.snapshot()
        self.reset()
        self.settle_seconds = time.perf_counter() - start
        log.info(
            "%s settled for %.2f s of simulated time in %.1f s",
            self.scene.settings["name"],
            frames * self.dt,
            self.settle_seconds,
        )

    def step(self, poses: dict[str, Pose] | None = None, buttons: dict[str, int] | None = None):
        """Place the tools (``buttons`` per tool name close graspers), advance one
        frame of ``dt``, time it."""
        start = time.perf_counter()
        apply_poses(self.control, self.scene.tools, poses or {}, buttons)
        self.solver.step(self.state, self.control, self.dt)
        ti.sync()
        self.timings["physics"] = (time.perf_counter() - start) * 1e3
        names = [tool["name"] for tool in self.scene.tools]
        self.events = [dict(event, tool=names[event["tool"]]) for event in self.solver.events]
