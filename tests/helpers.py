"""Small scenes built in the tests, without files."""

from __future__ import annotations

import time

from taichi_lap.perf.bench_contact import BOX as BOX  # the test block: one definition
from taichi_lap.scene import from_tables
from taichi_lap.session import Session


def simulation(organs: list[dict], **settings):
    """(scene, data, model, state, control, solver) for a small in-memory scene."""
    session = Session(from_tables(organs, **settings), use_cache=False, progress=False)
    return (
        session.scene,
        session.data,
        session.model,
        session.state,
        session.control,
        session.solver,
    )


def state_after(organs: list[dict], frames: int, **settings) -> dict:
    """Positions and recovery factors after ``frames`` frames of 1/60 s (the
    computations the Vulkan comparisons run on both backends)."""
    _, _, _, state, control, solver = simulation(organs, **settings)
    for _ in range(frames):
        solver.step(state, control, 1.0 / 60.0)
    return {"x": state.x.to_numpy(), "eta": state.eta.to_numpy()}


def wait_for(predicate, timeout: float) -> bool:
    """Poll ``predicate`` every millisecond until it holds (True) or ``timeout`` [s]
    passes (False): for devices and processes that tick on their own."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.001)
    return True
