"""Electrocautery in a session (seed 002 §3.3): the L-hook's electrode, the pedal in
scripts, heat that removes only what the energised wire touches, vessel damage reported
once per place, and a recorded cautery session that replays to the same state."""

import numpy as np
import pytest

from taichi_lap.cli import main
from taichi_lap.core.instruments import (
    CAUTERY_BUTTON,
    GRASP_BUTTON,
    HOOK_FOOT,
    HOOK_HEAT_GAP,
    HOOK_STEM,
    HOOK_WIRE,
    tool_distance,
    tool_geometry,
)
from taichi_lap.devices import ScriptedDevice
from taichi_lap.dissection.cautery import DAMAGE_PLACE
from taichi_lap.perf.bench_contact import HALF, organ_table
from taichi_lap.replay import read_recording
from taichi_lap.scene import from_tables
from taichi_lap.session import Session
from tests.blocks import block_scene_file

RADIUS = 0.0025  # [m] a 5 mm hook
DEPTH = 0.002  # [m] how far the electrode's bottom goes below the block's top
HOOK = {
    "name": "hook",
    "kind": "hook",
    "radius": RADIUS,
    "length": 0.1,
    "power": 30.0,
    "tip": [-0.01, HALF[1] + HOOK_STEM * RADIUS + 0.001, 0.0],
    "direction": [0.0, 1.0, 0.0],
}


def test_the_hook_is_an_l_shaped_wire_ahead_of_its_shaft():
    """Its union: the foot along x and the stem along -z, both of the wire's radius,
    then the shaft; points on the electrode's axis are a wire radius inside it."""
    geometry = tool_geometry(HOOK)
    assert [shape.kind for shape in geometry.shapes] == ["capsule", "capsule", "shaft"]
    bend = np.array([0.0, 0.0, -HOOK_STEM * RADIUS])
    on_axis = np.array([[0.0, 0.0, -RADIUS], bend, bend + [HOOK_FOOT * RADIUS, 0.0, 0.0]])
    distance, _, _ = tool_distance(geometry, on_axis, gradients=False)
    np.testing.assert_allclose(distance, -HOOK_WIRE * RADIUS, atol=1e-12)
    beyond = bend + [(HOOK_FOOT + HOOK_WIRE + 0.5) * RADIUS, 0.0, 0.0]
    assert tool_distance(geometry, beyond[None], gradients=False)[0][0] == pytest.approx(
        0.5 * RADIUS
    )
    assert geometry.reach() == pytest.approx(
        np.hypot(HOOK_STEM, HOOK_FOOT) * RADIUS + HOOK_WIRE * RADIUS
    )


def test_keyframes_hold_the_pedal_and_the_jaws_until_changed():
    tools = [dict(HOOK)]
    frames = [
        {"time": 0.0, "tool": "hook", "tip": [0, 0.1, 0]},
        {"time": 1.0, "tool": "hook", "tip": [0, 0.1, 0], "cautery": True},
        {"time": 2.0, "tool": "hook", "tip": [0, 0.1, 0], "grasp": True},
        {"time": 3.0, "tool": "hook", "tip": [0, 0.1, 0], "cautery": False},
    ]
    device = ScriptedDevice.from_tables("pedal", frames, tools)
    held = [device.buttons(t)["hook"] for t in (0.5, 1.5, 2.5, 3.5)]
    assert held == [0, CAUTERY_BUTTON, CAUTERY_BUTTON | GRASP_BUTTON, GRASP_BUTTON]


def block_scene(**material) -> object:
    """The 4 x 2.4 x 3 cm test block (2 mm lattice, fixed at its base) with liver's
    mass density (30 g) and the hook above its top."""
    organ = organ_table("tet_clusters", 6.0, 0.7)
    organ["material"] = dict(organ["material"], mass=0.03, **material)
    return from_tables([organ], tools=[dict(HOOK)], gravity=[0.0, 0.0, 0.0])


def drag(session: Session, cautery: bool) -> list[dict]:
    """Lower the hook's electrode DEPTH into the top, drag it 2 cm along x at 5 mm/s
    (energised when ``cautery``), lift it; the session's events."""
    x0, y = HOOK["tip"][0], HOOK["tip"][1] - 0.001 - DEPTH
    frames = [
        {"time": 0.0, "tool": "hook", "tip": HOOK["tip"]},
        {"time": 0.3, "tool": "hook", "tip": [x0, y, 0.0], "cautery": cautery},
        {"time": 4.3, "tool": "hook", "tip": [x0 + 0.02, y, 0.0], "cautery": False},
        {"time": 4.6, "tool": "hook", "tip": [x0 + 0.02, HOOK["tip"][1], 0.0]},
    ]
    device = ScriptedDevice.from_tables("drag", frames, session.scene.tools)
    events = []
    for _ in range(int(round(4.6 / session.dt))):
        session.step(device.poses(session.state.time), device.buttons(session.state.time))
        events += session.events
    return events


@pytest.fixture(scope="module")
def burnt():
    """The block after an energised drag: (session, events, removed particles)."""
    session = Session(block_scene(damage_temperature=60.0), use_cache=False, progress=False)
    events = drag(session, cautery=True)
    removed = np.flatnonzero(~session._dissection.topology.particle_alive)
    yield session, events, removed
    session.close()


def test_an_energised_hook_cuts_a_groove_along_its_path(burnt):
    """The pedal's events come once each; what is removed lies along the path of the
    electrode (within its reach of the foot's and stem's sweep), was heated to the
    ablation temperature, and is the sum of the cautery events; the groove covers the
    path (every 4 mm of it lost tissue) and the wound is a valid closed surface."""
    session, events, removed = burnt
    kinds = [e["kind"] for e in events]
    assert kinds.count("cautery_on") == 1 and kinds.count("cautery_off") == 1
    assert kinds.index("cautery_on") < kinds.index("cautery") < kinds.index("cautery_off")
    assert sum(e["particles"] for e in events if e["kind"] == "cautery") == len(removed)
    rest = session.data.rest_position[removed]
    cell = 0.5 * 0.002  # the particles' cell radius: half the lattice spacing
    reach = (HOOK_WIRE + HOOK_HEAT_GAP) * RADIUS + cell
    x0 = HOOK["tip"][0]
    # each removal says where its tissue was (rounded to 0.1 mm) and its tets' volume
    burns = [e for e in events if e["kind"] == "cautery"]
    where = np.concatenate([e["removed"]["block"]["positions"] for e in burns])
    assert len(where) == len(removed)
    assert np.abs(where[:, 2]).max() < reach + 0.003 and where[:, 0].min() > x0 - reach
    volume = sum(e["removed"]["block"]["volume"] for e in burns)
    assert volume > 0.0 and volume == pytest.approx(session._dissection.topology.removed_volume)
    assert volume == pytest.approx(sum(e["volume"] for e in burns))
    assert (
        rest[:, 0].min() > x0 - reach and rest[:, 0].max() < x0 + 0.02 + HOOK_FOOT * RADIUS + reach
    )
    assert np.abs(rest[:, 2]).max() < reach + 0.003  # the tissue gives way a little
    assert rest[:, 1].min() > HALF[1] - DEPTH - reach - 0.003
    covered = np.unique(np.floor((rest[:, 0] - x0) / 0.004))
    assert set(range(5)) <= set(covered.tolist())
    # reached the ablation temperature, or went with a tet of a particle that did (a
    # particle left in no tet, a fragment cut off)
    peaks = session.peak_temperature.to_numpy()
    burnt_away = np.zeros(len(peaks), dtype=bool)
    burnt_away[removed[peaks[removed] >= 100.0]] = True
    tets = session.data.tets
    beside = np.unique(tets[burnt_away[tets].any(axis=1)])
    assert burnt_away.sum() > 0.5 * len(removed)
    assert np.isin(removed[peaks[removed] < 100.0], beside).all()
    session.check_topology()
    # the contact response clears the marks it sets (wound vertices follow fewer than
    # four particles): one left behind would keep its particle out of every later contact
    marked = session.solver.collision.particle_mark.to_numpy()
    assert not marked.any(), f"particles {np.flatnonzero(marked)} left marked"


def test_vessel_damage_is_reported_once_per_place(burnt):
    """With a damage temperature, each damaged place (DAMAGE_PLACE cell of the rest
    shape) is one event, whose peak reached the damage temperature."""
    session, events, _ = burnt
    damage = [e for e in events if e["kind"] == "vessel_damage"]
    assert damage and all(e["vessel"] == "block" for e in damage)
    assert all(e["peak_temperature"] >= 60.0 for e in damage)
    peaks = session.peak_temperature.to_numpy()
    hot = np.flatnonzero(peaks >= 60.0)
    cells = {tuple(c) for c in np.floor(session.data.rest_position[hot] / DAMAGE_PLACE).astype(int)}
    assert len(damage) == len(cells)


def test_contact_without_current_removes_nothing_and_a_reset_cools():
    """The same drag without the pedal leaves every particle; after an energised run a
    reset brings the tissue back at body temperature."""
    session = Session(block_scene(), use_cache=False, progress=False)
    events = drag(session, cautery=False)
    assert not [e for e in events if e["kind"] in ("cautery", "cautery_on", "fragment")]
    assert session._dissection is None and session.peak_temperature is None
    session.step(buttons={"hook": CAUTERY_BUTTON})
    session.reset()
    assert session.peak_temperature.to_numpy().max() == pytest.approx(37.0)
    session.close()


TOOL = """
[[tools]]
name = "hook"
kind = "hook"
radius = 0.0025
length = 0.1
tip = [-0.005, 0.01925, 0.0]
script = [
  { time = 0.0, tip = [-0.005, 0.01925, 0.0] },
  { time = 0.3, tip = [-0.005, %s, 0.0], cautery = true },
  { time = 1.0, tip = [0.0, %s, 0.0] },
]"""


def test_a_recorded_cautery_session_replays_to_the_same_state(tmp_path, capsys):
    scene = tmp_path / "cautery.toml"
    y = 0.01925 - 0.001 - DEPTH
    scene.write_text(block_scene_file("cautery", TOOL % (y, y), ", mass = 0.03"))
    record = tmp_path / "cautery.tlap"
    run = ["run", str(scene), "--headless", "--size", "64x48", "--frames", "60"]
    assert main([*run, "--out", str(tmp_path / "a"), "--record", str(record)]) == 0
    events = read_recording(record).events
    assert [e["kind"] for e in events].count("cautery_on") == 1
    assert sum(e["particles"] for e in events if e["kind"] == "cautery") > 0
    capsys.readouterr()
    status = main([*run, "--out", str(tmp_path / "b"), "--device", f"replay:{record}"])
    out, err = capsys.readouterr()
    assert status == 0, err
    assert "after 60 frames" in out
