"""Cutting a vessel, a truss structure (seed 000 §3.3, Alg. 2), in a session: the
scissors' jaws, closed, sweep across the tube (Alg. 3 on its surface,
:mod:`taichi_lap.dissection.sheet_cut`); the struts the sweep passes through and those
whose ends the cut parts go, so the two halves hang from their own fixed ends."""

from __future__ import annotations

import numpy as np
import pytest

from taichi_lap.core.mesh import element_pieces, rows_in
from taichi_lap.dissection.sheet_cut import built_struts
from taichi_lap.scene import from_tables
from taichi_lap.session import Session
from tests.archrun import assert_backend_matches_cpu
from tests.helpers import instrument, run_script
from tests.test_sheet_cut import model_pairs

HALF_LENGTH = 0.04  # [m] the vessel runs along x from -HALF_LENGTH to HALF_LENGTH
RADIUS = 0.003  # [m]
VESSEL = {
    "name": "vessel",
    "model": "truss",
    "geometry": {
        "generator": "vessel",
        "radius": RADIUS,
        "points": [[-HALF_LENGTH, 0.0, 0.0], [0.0, 0.0, 0.0], [HALF_LENGTH, 0.0, 0.0]],
    },
    "material": {"mass": 0.01, "cone_angle": 0.4, "damping": 4.0},
    "attachments": [
        {"kind": "fixed", "box_min": [-0.1, -0.1, -0.1], "box_max": [-0.035, 0.1, 0.1]},
        {"kind": "fixed", "box_min": [0.035, -0.1, -0.1], "box_max": [0.1, 0.1, 0.1]},
    ],
}
SCISSORS = instrument("scissors", [0.0, 0.05, 0.0], [0.0, 1.0, 0.0])
"""The shaft above, the jaws (1 cm) hang down from the tip."""
FRAMES = 90


def vessel_session() -> Session:
    scene = from_tables([VESSEL], tools=[SCISSORS], gravity=[0.0, -9.81, 0.0], settle_time=1.0)
    return Session(scene, use_cache=False, progress=False)


def sweep(session: Session) -> list[dict]:
    """The scissors' closed jaws across the settled (sagging) vessel at x = 0, from
    1.5 cm before it to 1.5 cm beyond it at 4 cm/s, then up and away."""
    x = session.state.x.to_numpy()
    middle = np.abs(session.data.rest_position[:, 0]) < 0.002
    top, z = float(x[middle, 1].max()), float(x[middle, 2].mean())
    tip = [0.0, top + 0.002, z - 0.015]  # the jaws reach 8 mm below the vessel's top
    return [
        {"time": 0.0, "tip": tip},
        {"time": 0.05, "tip": tip, "grasp": True},
        {"time": 0.8, "tip": [0.0, tip[1], z + 0.015]},
        {"time": 0.85, "tip": [0.0, tip[1], z + 0.015], "grasp": False},
        {"time": 1.2, "tip": [0.0, tip[1] + 0.05, z + 0.015]},
    ]


def run(session: Session, script: list[dict], frames: int = FRAMES) -> list[dict]:
    """Step ``frames`` frames with the scissors on ``script``; the session's events."""
    return run_script(session, [dict(step, tool="scissors") for step in script], frames)


@pytest.fixture(scope="module")
def cut_vessel():
    session = vessel_session()
    before = session.state.x.to_numpy()
    events = run(session, sweep(session))
    yield session, before, events
    session.close()


def test_scissors_cut_the_vessel_in_two_and_the_halves_hang_from_their_ends(cut_vessel):
    session, before, events = cut_vessel
    assert sum(e["kind"] == "cut" for e in events) > 5
    session.check_topology()  # raises on any problem
    triangles = session.live_triangles()
    pieces = element_pieces(triangles)
    assert len(np.unique(pieces)) == 2
    x = session.state.x.to_numpy()
    rest = session._dissection.topology.rest  # the new vertices' too
    for piece in range(2):
        particles = np.unique(triangles[pieces == piece])
        assert session.data.pinned[particles].any()  # each half holds a fixed end
        side = np.sign(rest[particles, 0])[np.abs(rest[particles, 0]) > 0.005]
        assert np.all(side == side[0])  # the cut parted the tube at x = 0 (kerf aside)
    middle = np.abs(rest[:, 0]) < 0.004
    middle &= np.arange(len(rest)) < len(before)
    # uncut, the truss held its middle up as a beam; cut, each half hangs from its end
    assert x[middle, 1].mean() < before[middle, 1].mean() - 0.02


def test_no_strut_or_edge_joins_the_halves(cut_vessel):
    session, _, _ = cut_vessel
    triangles = session.live_triangles()
    piece_of = np.full(session.data.particle_count, -1)
    piece_of[triangles.ravel()] = np.repeat(element_pieces(triangles), 3)
    pairs = model_pairs(session.model)
    assert (piece_of[pairs] >= 0).all()
    assert (piece_of[pairs[:, 0]] == piece_of[pairs[:, 1]]).all()
    struts = built_struts(session.data, 0)[0]
    kept = rows_in(struts, pairs)
    assert 0.5 * len(struts) < kept.sum() < len(struts)  # the halves keep theirs


def quick_truss_cut(frames: int = 20) -> dict[str, np.ndarray]:
    """The vessel straight as built (no settling), the scissors' closed jaws across it
    at x = 0 in two frames (0.7 m/s), then up and away while its halves fall: the
    live triangles, the pieces' sizes, the constraints left and where the built
    particles are."""
    scene = from_tables([VESSEL], tools=[SCISSORS], gravity=[0.0, -9.81, 0.0])
    session = Session(scene, use_cache=False, progress=False)
    tip = [0.0, 0.005, -0.012]
    script = [
        {"time": 0.0, "tip": tip, "grasp": True},
        {"time": 0.034, "tip": [0.0, 0.005, 0.012]},
        {"time": 0.05, "tip": [0.0, 0.05, 0.012], "grasp": False},
    ]
    run(session, script, frames)
    session.check_topology()
    triangles = session.live_triangles()
    organ = session.data.organs[0]
    out = {
        "triangles": np.array([len(triangles)]),
        "pieces": np.sort(np.bincount(element_pieces(triangles))),
        "constraints": np.array([len(model_pairs(session.model))]),
        "x": session.state.x.to_numpy()[organ.particles[0] : organ.particles[1] - organ.reserve],
    }
    session.close()
    return out


@pytest.mark.vulkan
def test_a_truss_cut_on_vulkan_matches_cpu():
    """The same cut decisions (triangles, pieces and constraints alike) and positions
    within 1 mm; the quick cut parts the vessel."""
    cpu = assert_backend_matches_cpu(
        "tests.test_truss_cut:quick_truss_cut",
        1e-3,
        per_key={"triangles": 0, "pieces": 0, "constraints": 0},
    )
    assert len(cpu["pieces"]) == 2 and cpu["pieces"].min() > 100
