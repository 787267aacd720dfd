"""Small scenes built in the tests, without files."""

from __future__ import annotations

import time

import numpy as np

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


def instrument(kind: str, tip, direction, *, name: str | None = None) -> dict:
    """A scene tool table: a ``kind`` instrument of the 5 mm class (radius 2.5 mm,
    20 cm long) at ``tip`` with its shaft along ``direction``, named after its kind
    unless ``name`` is given."""
    return {
        "name": name or kind,
        "kind": kind,
        "radius": 0.0025,
        "length": 0.2,
        "tip": list(tip),
        "direction": list(direction),
    }


def run_script(session: Session, script: list[dict], frames: int) -> list[dict]:
    """Step ``session`` ``frames`` frames with its tools on ``script`` (rows of a scene
    script, each naming its ``tool``); the session's events."""
    from taichi_lap.devices import ScriptedDevice

    device = ScriptedDevice.from_tables("test", script, session.scene.tools)
    events = []
    for _ in range(frames):
        time = session.state.time
        session.step(device.poses(time), device.buttons(time))
        events += session.events
    return events


def assert_incident_rows_packed(session: Session):
    """The model's incident rows (what the drawn normals gather) hold each live surface
    vertex's live triangles, then -1 only: the normals stop at a row's first -1, so a
    triangle left after a hole would be dropped."""
    topology = session._dissection.topology
    used = topology.vertices.used
    incident = session.model.surface_incident.to_numpy()[:used]
    live, corners = topology.triangles["alive"], topology.triangles["vertices"]
    for vertex in np.flatnonzero(topology.vertices["alive"][:used]):
        row = incident[vertex]
        count = int((row >= 0).sum())
        assert (row[count:] == -1).all(), row
        expected = np.flatnonzero(live & (corners == vertex).any(axis=1))
        assert sorted(row[:count].tolist()) == expected.tolist()
