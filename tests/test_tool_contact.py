"""The contact that holds: instruments push the drawn surface of every tissue model as
far as they go into it, at a hand's speed, whatever the scene's tissue collision
(``perf/bench_contact.py`` measures the whole matrix; these are its corners)."""

from __future__ import annotations

import numpy as np
import pytest

from taichi_lap.perf import bench_contact as contact
from taichi_lap.sim import Control
from tests.archrun import assert_backend_matches_cpu

TOLERANCE = (0.8, 1.25)
"""Displacement of the drawn surface under the tool over the tool's depth."""
SLOW, HAND = 0.005, 0.25
"""Press speeds [m/s]: a careful push and a fast hand (4.2 mm per substep at 60 Hz)."""


def pressed(
    model: str, collision: str, depth: float, speed: float, solver, *, kind: str = "probe"
) -> contact.Press:
    session, target = contact.press_scene(model, collision, *solver, kind=kind)
    try:
        press = contact.press(session, target, depth, speed)
    finally:
        session.close()
    assert press.ratio is not None, "the press faulted"
    return press


def test_a_probe_indents_the_tet_block_as_deep_as_it_goes():
    """The probe's 6 mm tip slipped between the 2 mm particles (0.22 mm for 7 mm) with
    collision off (the circumsphere setting, which pushed the surface 5 mm beyond the
    tool, is in perf/bench_contact.py)."""
    press = pressed("tet_clusters", "off", 0.004, SLOW, contact.SOLVERS[0])
    assert TOLERANCE[0] <= press.ratio <= TOLERANCE[1]
    assert press.flight == 0.0


@pytest.mark.parametrize("model", ["tet_clusters", "fascia_lra"])
def test_a_fast_press_with_one_undamped_substep_holds(model):
    """0.25 m/s with 1 substep, no damping, η = 1: no fault, no tunnelling through the
    block or the 2 mm fascia sheet, no over-push."""
    press = pressed(model, "off", 0.008, HAND, contact.SOLVERS[1])
    assert TOLERANCE[0] <= press.ratio <= TOLERANCE[1]


@pytest.mark.parametrize("model", ["mass_spring", "mesentery"])
def test_a_probe_pushes_the_intestine_tube_and_the_mesentery_between_masses(model):
    """The tube is drawn 2 cm around masses a tube diameter apart: pressed between two
    of them it moves with the probe (contact acted on the masses alone)."""
    press = pressed(model, "off", 0.008, SLOW, contact.SOLVERS[0])
    assert TOLERANCE[0] <= press.ratio <= TOLERANCE[1]


def test_a_fast_tap_flings_the_loose_intestine_off_the_stopped_probe():
    """At 0.25 m/s the probe gives the free tube its speed and stops dead 2 mm deep: the
    tube pressed as deep as the probe while they touched, then flew on (2.4 mm past
    it after the hold), which the press reports as flight, not as over-push."""
    press = pressed("mass_spring", "off", 0.002, HAND, contact.SOLVERS[0])
    assert TOLERANCE[0] <= press.ratio <= TOLERANCE[1]
    assert press.flight > contact.TOUCH_GAP


@pytest.mark.parametrize(
    "kind, depth, speed",
    [("hook", 0.004, SLOW), ("hook", 0.008, HAND), ("grasper", 0.02, HAND)],
    ids=["hook-4mm", "hook-8mm", "grasper-20mm"],
)
def test_thin_instruments_indent_the_block_as_deep_as_they_go(kind, depth, speed):
    """The hook's electrode wire (0.9 mm in radius, thinner than the 2 mm particle
    spacing) presses with its foot, the tool's lowest point; the grasper with its
    closed jaws (2.1 mm) and, 20 mm deep, its shaft behind them. Under 4 substeps and
    η on contact 0.7 the stretched triangles wrapping the wire (the jaws) let it
    through with one Jacobi pass of the contact (indent_ratio 0.22 at 8 mm, 0.41 at
    20 mm); collision.tissue.TOOL_PASSES projects it twice."""
    press = pressed("tet_clusters", "off", depth, speed, contact.SOLVERS[0], kind=kind)
    assert TOLERANCE[0] <= press.ratio <= TOLERANCE[1]


def test_tools_move_a_fraction_of_the_frame_per_substep():
    control = Control()
    control.set_tool(0, [0.0, 0.0, 0.0], [0.0, 0.1, 0.0], 0.003)  # appears: no sweep
    assert np.allclose(control.tool_last.tip.to_numpy()[0], 0.0)
    control.set_tool(0, [0.0, -0.004, 0.0], [0.0, 0.096, 0.0], 0.003)
    control.advance(0.25, 0.5)
    assert np.allclose(control.tool_last.tip.to_numpy()[0], [0.0, -0.001, 0.0], atol=1e-7)
    assert np.allclose(control.tool_a.to_numpy()[0], [0.0, -0.002, 0.0], atol=1e-7)
    frame = control.tool_frame.to_numpy()[0]
    assert np.allclose(frame.T @ frame, np.eye(3), atol=1e-6)
    control.advance(0.5, 1.0)
    assert np.array_equal(control.tool_a.to_numpy()[0], np.float32([0.0, -0.004, 0.0]))


def compute_press_case() -> dict:
    """A fast press into the tet block (also run on Vulkan)."""
    session, target = contact.press_scene("tet_clusters", "off", *contact.SOLVERS[1])
    ratio = contact.press(session, target, 0.004, HAND, hold=0.1).ratio
    return {"x": session.state.x.to_numpy(), "indent": np.float32([ratio * 0.004])}  # [m]


@pytest.mark.vulkan
def test_vulkan_agrees_with_cpu():
    assert_backend_matches_cpu("tests.test_tool_contact:compute_press_case", 2e-4)


def haptic_rows(presses, model: str = "tet_clusters") -> dict[tuple, dict]:
    """Per ``(depth [m], inside)`` of ``presses`` the haptic press's rows by metric (the
    stylus of the scripted device pressed into the ``model`` body at 5 mm/s, or there
    from the start, and held, seed 002 §3.4; the press setting of the quick
    benchmark)."""
    setting = ("off", contact.SOLVERS[0])
    session, target = contact.press_scene(model, setting[0], *setting[1])
    out = {}
    try:
        for depth, inside in presses:
            rows = contact.haptic_press(session, target, depth, *setting, inside=inside)
            by_metric = {row["metric"]: row for row in rows}
            assert by_metric["faults"]["median"] == 0 and by_metric["faults"]["reached_depth"]
            out[depth, inside] = by_metric
    finally:
        session.close()
    return out


def assert_indents_and_grows(rows: dict[tuple, dict]):
    """The 2 and 6 mm presses of ``rows`` (:func:`haptic_rows`) indent the tissue at
    least 70 % of the stylus depth; the force the coupling asks for grows with the
    depth, above zero and below the device's maximum, and the force sent to the device
    never passes that maximum. (What the device got is not compared between depths:
    the safety filter's watchdog fades it out when a frame stalls past 100 ms, as it
    may on a loaded test machine; tests/test_force_safety.py tests the fade.)"""
    from taichi_lap.haptics.servo import ScriptedHapticDevice

    limit = ScriptedHapticDevice().max_force
    for depth in (0.002, 0.006):
        measured = rows[depth, False]["faults"]
        assert measured["indent_mm"] >= 0.7 * measured["stylus_depth_mm"]
    forces = [rows[d, False]["contact_force_n"]["median"] for d in (0.002, 0.006)]
    assert 0.0 < forces[0] < forces[1] < limit
    assert all(row["force_n"]["max"] <= limit + 1e-6 for row in rows.values())


def test_a_haptic_stylus_indents_the_tissue_and_feels_it_grow_with_depth():
    """The tissue gives way under the stylus (at least 70 % of its depth), the device
    force grows with the depth below the device's maximum, a 20 mm press keeps the
    stylus in contact through the whole hold (the force never drops to zero), a
    stylus held still settles, and one that starts 4 mm inside the tissue is felt
    (before: no force at all)."""
    rows = haptic_rows([(0.002, False), (0.006, False), (0.020, False), (0.004, True)])
    assert_indents_and_grows(rows)
    held = rows[0.006, False]["contact_force_n"]
    assert held["max"] - held["min"] < 0.05 * held["median"]  # settles: no energy gain
    assert rows[0.020, False]["contact_force_n"]["min"] > 0.0
    assert rows[0.004, True]["contact_force_n"]["min"] > 0.01


@pytest.mark.parametrize("model", ["fascia_lra", "truss"])
def test_a_haptic_stylus_indents_a_membrane_and_a_truss_and_feels_them(model):
    """The coupling of seed 002 §3.4 for the tissues without shape matching: their
    distance constraints and long-range attachments push the tool back (before: no
    reaction, and the stylus met a wall)."""
    assert_indents_and_grows(haptic_rows([(0.002, False), (0.006, False)], model))


def test_a_probe_shaft_swept_through_the_intestines_root_pushes_without_faulting():
    """The shaft crosses the mesentery's fixed root (its triangles' corners beside the
    root would take depth / b of each push, CORNER_PUSH_LIMIT caps them): the scene
    runs on, no mass faster than half the fault threshold (the mesentery snaps off the
    shaft at about 12 m/s; uncapped it faulted at frame 116), the root where it was."""
    from taichi_lap import scene as scene_mod
    from taichi_lap.session import Session, scene_script

    keys = [
        {"time": 0.0, "tip": [0.14, -0.05, 0.02]},
        {"time": 0.8, "tip": [0.14, -0.15, 0.02]},
        {"time": 2.4, "tip": [-0.06, -0.14, 0.02]},
    ]
    scene = scene_mod.load("intestine", {"tools.probe.script": keys})
    with Session(scene, progress=False) as session:
        device = scene_script(scene)
        root = session.data.inverse_mass() == 0.0
        rest = session.state.positions()[root]
        last, fastest = session.state.positions(), 0.0
        for _ in range(140):  # the shaft reaches the root at about 1.9 s
            now = session.state.time
            session.step(device.poses(now), device.buttons(now))
            x = session.state.positions()
            fastest = max(fastest, float(np.linalg.norm(x - last, axis=1).max()) / session.dt)
            last = x
        assert np.abs(last[root] - rest).max() < 1e-6
    assert fastest < 0.5 * scene.settings["speed_limit"], fastest
