"""Removals written to the device model (seed 002 §3.3): after the neck of a
dumbbell is cut its halves move independently, while joined they pull each other;
removed particles stay where they were."""

import logging

import numpy as np
import pytest

from taichi_lap.cli import main
from taichi_lap.core.errors import SimulationFault
from taichi_lap.core.topology import check_topology
from taichi_lap.devices import ScriptedDevice
from taichi_lap.replay import read_recording
from taichi_lap.perf.bench_contact import HALF, PROBE_RADIUS, organ_table, press_scene
from taichi_lap.dissection.device import DeviceTopology
from taichi_lap.dissection.removal import MutableTopology
from taichi_lap.kernels.collision import spheres
from taichi_lap.kernels.skinning import skin_surface
from taichi_lap.scene import from_tables
from taichi_lap.render.renderer import Renderer
from taichi_lap.session import Session, release_parked, session_key
from taichi_lap.sim import model as model_module
from tests.blocks import block_scene_file
from tests.helpers import BOX, assert_incident_rows_packed, simulation

SHIFT = 0.005  # [m] the left half is moved this far along z


def rotation_about_x(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def assert_device_clusters_match(model, topology: MutableTopology):
    """The device's cluster tables, as written change by change, hold what the
    topology's clusters give from scratch: per live cluster its members' mass and
    mass centre, and every weighted member's and membership's offset (stored offset
    plus the cluster's shift) is x0 - x0_cm."""
    count = model.cluster_count[None]
    assert count == len(topology.cluster_members)
    mass, rest = model.data.mass, topology.rest
    member = model.cluster_member.to_numpy()
    weight = model.cluster_member_mass.to_numpy()
    offset = model.cluster_rest_offset.to_numpy() + 0.0
    shift = model.cluster_rest_shift.to_numpy()
    center = model.cluster_rest_center.to_numpy()
    begin, end = model.cluster_chunk_begin.to_numpy(), model.cluster_chunk_end.to_numpy()
    chunk_begin, chunk_end = model.chunk_begin.to_numpy(), model.chunk_end.to_numpy()
    for c, members in enumerate(topology.cluster_members):
        if not topology.cluster_alive[c]:
            continue
        rows = np.concatenate(
            [np.arange(chunk_begin[k], chunk_end[k]) for k in range(begin[c], end[c])]
        )
        weighted = rows[weight[rows] > 0]
        assert sorted(member[weighted]) == sorted(members.tolist())
        expected = (mass[members, None] * rest[members]).sum(axis=0) / mass[members].sum()
        assert np.abs(center[c] - expected).max() < 1e-6
        assert model.cluster_mass[c] == pytest.approx(mass[members].sum(), rel=1e-5)
        q = offset[weighted] + shift[c]
        assert np.abs(q - (rest[member[weighted]] - expected)).max() < 1e-6
    start = topology.membership_start
    cluster = model.membership_cluster.to_numpy()
    alive = np.flatnonzero(topology.particle_alive)
    for i in alive[:: max(1, len(alive) // 200)].tolist():
        for j in range(start[i], start[i + 1]):
            c = cluster[j]
            assert c == topology.membership_cluster[j]
            q = model.membership_offset[j].to_numpy() + shift[c]
            assert np.abs(q - (rest[i] - center[c])).max() < 1e-6


def displaced_dumbbell(cut_neck: bool, frames: int = 30) -> dict:
    """The test block carved into a dumbbell (a 6 mm slab across its length removed
    but for a neck), with or without the neck then cut; the left half moved by
    SHIFT (positions and goals), then ``frames`` frames without gravity."""
    _, data, model, state, control, solver = simulation([BOX], gravity=[0, 0, 0])
    topology = MutableTopology(data)
    device = DeviceTopology(model, topology)
    rest = data.rest_position
    slab = np.abs(rest[:, 0]) < 0.003
    neck = slab & (np.abs(rest[:, 1]) < 0.005) & (np.abs(rest[:, 2]) < 0.005)
    device.apply(topology.remove(np.flatnonzero(slab & ~neck)), state)
    if cut_neck:
        change = topology.remove(np.flatnonzero(neck))
        assert change.fragments == [] and len(change.clusters) > 0
        device.apply(change, state)
    assert_device_clusters_match(model, topology)
    left = topology.particle_alive & (rest[:, 0] < 0)
    right = topology.particle_alive & (rest[:, 0] > 0)
    for name in ("x", "p", "goal"):
        values = getattr(state, name).to_numpy()
        values[left, 2] += SHIFT
        getattr(state, name).from_numpy(values)
    before = state.x.to_numpy()
    for _ in range(frames):
        solver.step(state, control, 1.0 / 60.0)
    after = state.x.to_numpy()
    moved = after - rest
    return {
        "left": moved[left, 2].mean(),
        "right": np.abs(moved[right]).max(),
        "removed": np.abs(after - before)[~topology.particle_alive].max(),
        "finite": bool(np.isfinite(moved).all()),
    }


def test_a_cut_neck_lets_the_halves_of_a_dumbbell_move_independently():
    cut = displaced_dumbbell(cut_neck=True)
    joined = displaced_dumbbell(cut_neck=False)

    assert cut["finite"] and joined["finite"]
    assert cut["left"] == pytest.approx(SHIFT, abs=2e-4)  # moved rigidly, stays
    assert cut["right"] < 1e-4  # the other half does not follow
    assert joined["right"] > 5e-4 and joined["left"] < SHIFT - 5e-4  # joined: they pull
    assert cut["removed"] == 0.0 and joined["removed"] == 0.0


def test_the_drawn_wound_follows_the_body_and_stays_closed_and_outward():
    """A ball removed from the block's top, then the body turned 30° about x: the
    device's surface rows are the host's, and the skinned surface (wound vertices by
    their clusters) is the turned rest surface, closed and outward."""
    session = Session(from_tables([BOX], gravity=[0, 0, 0]), use_cache=False, progress=False)
    rest = session.data.rest_position
    top = np.array([0.0, 0.0, rest[:, 2].max()])
    change = session.remove_particles(np.flatnonzero(np.linalg.norm(rest - top, axis=1) < 0.007))
    assert len(change.new_vertices) > 0

    turn = rotation_about_x(np.radians(30.0))
    for name in ("x", "p", "goal"):
        getattr(session.state, name).from_numpy((rest @ turn.T).astype(np.float32))
    for _ in range(5):
        session.step()
    skin_surface(session.model, session.state)

    topology = session._dissection.topology
    assert_device_clusters_match(session.model, topology)
    used, live = topology.vertices.used, topology.triangles["alive"]
    device = session.model.surface_triangles.to_numpy()[: len(live)]
    assert (
        device[live[: len(device)]]
        == topology.triangles["vertices"][: len(device)][live[: len(device)]]
    ).all()
    assert (device[~live[: len(device)]] == 0).all()
    skinned = session.state.surface_position.to_numpy()[:used]
    view = topology.topology()  # the rest surface, wound vertices at their rest place
    expected = view.surface_position @ turn.T
    alive = view.vertex_alive
    assert np.abs(skinned[alive] - expected[alive]).max() < 2e-5
    view.surface_position = skinned
    assert check_topology(view) == []
    assert_incident_rows_packed(session)


def test_a_reset_puts_the_removed_tissue_back():
    session = Session(from_tables([BOX], gravity=[0, 0, 0]), use_cache=False, progress=False)
    built = {
        name: getattr(session.model, name).to_numpy()
        for name in ("inv_mass", "surface_triangles", "cluster_member_mass")
    }
    rest = session.data.rest_position
    session.remove_particles(np.flatnonzero(np.linalg.norm(rest - rest[0], axis=1) < 0.009))
    assert (session.model.inv_mass.to_numpy() == 0).sum() > (built["inv_mass"] == 0).sum()
    session.reset()
    for name, values in built.items():
        assert (getattr(session.model, name).to_numpy() == values).all(), name
    assert session.model.cluster_count[None] == session.model.data.cluster_count


def test_a_probe_in_a_removed_hole_touches_nothing_the_removal_left():
    """A hole of radius 8 mm removed from the top of the test block (circumsphere
    collision on); a probe of radius 3 mm going 6 mm down, 3 mm off its middle (2 mm
    from the nearest kept particle): the collision no longer has the removed
    surface triangles, so no tissue is pushed."""
    session, target = press_scene("tet_clusters", collision="circumsphere")
    rest = session.data.rest_position
    centre = np.array([target.x, target.height, target.z])
    change = session.remove_particles(np.flatnonzero(np.linalg.norm(rest - centre, axis=1) < 0.008))
    assert (session.solver.collision.tri_live.to_numpy() == 0).sum() > 0
    start = np.add(session.scene.tools[0]["tip"], [0.003, 0.0, 0.0]).tolist()
    end = [target.x + 0.003, target.height - 0.006 + PROBE_RADIUS, target.z]
    frames = [
        {"time": 0.0, "tool": "probe", "tip": list(start)},
        {"time": 1.0, "tool": "probe", "tip": end},
    ]
    device = ScriptedDevice.from_tables("press", frames, session.scene.tools)
    before = session.state.x.to_numpy()
    contacts = 0
    tool_contacts = list(spheres.COUNTERS).index("tool_contacts")
    for _ in range(int(round(1.0 / session.dt))):
        session.step(device.poses(session.state.time), device.buttons(session.state.time))
        contacts += session.solver.collision.counter.to_numpy()[tool_contacts]
    assert contacts == 0  # before the removed triangles were retired: over 10^6
    moved = np.linalg.norm(session.state.x.to_numpy() - before, axis=1)
    alive = np.ones(len(moved), dtype=bool)
    alive[change.removed_particles] = False
    assert moved[~alive].max() == 0.0
    assert moved[alive].max() < 1e-4


def dissection_run() -> dict:
    """A blunt dissector (radius 3 mm) pushed 6 mm into the top of the test block
    (fixed at its base, 2 mm particles) over 1 s and back out."""
    top = HALF[1]
    tool = {
        "name": "dissector",
        "kind": "dissector",
        "radius": PROBE_RADIUS,
        "length": 0.1,
        "tip": [0.0, top + 0.001 + PROBE_RADIUS, 0.0],
        "direction": [0.0, 1.0, 0.0],
    }
    scene = from_tables(
        [organ_table("tet_clusters", 6.0, 0.7)], tools=[tool], gravity=[0.0, 0.0, 0.0]
    )
    session = Session(scene, use_cache=False, progress=False)
    frames = [
        {"time": 0.0, "tool": "dissector", "tip": tool["tip"]},
        {"time": 1.0, "tool": "dissector", "tip": [0.0, top - 0.006 + PROBE_RADIUS, 0.0]},
        {"time": 1.5, "tool": "dissector", "tip": tool["tip"]},
    ]
    device = ScriptedDevice.from_tables("dissect", frames, session.scene.tools)
    events = []
    for _ in range(int(round(1.5 / session.dt))):
        session.step(device.poses(session.state.time), device.buttons(session.state.time))
        events += session.events
    skin_surface(session.model, session.state)
    topology = session._dissection.topology
    view = topology.topology(session.state.x.to_numpy().astype(np.float64))
    view.surface_position = session.state.surface_position.to_numpy()[: topology.vertices.used]
    return {
        "removed": np.flatnonzero(~topology.particle_alive),
        "events": events,
        "problems": check_topology(view),
        "x": session.state.x.to_numpy(),
        "rest": session.data.rest_position,
    }


def test_a_dissector_pushed_into_tissue_removes_what_its_tip_presses_on():
    run = dissection_run()
    removed, rest = run["removed"], run["rest"]

    assert len(removed) > 10
    assert sum(e["particles"] for e in run["events"] if e["kind"] == "dissect") == len(removed)
    # only under the tip: within its radius of the axis, down to the deepest point
    assert np.hypot(rest[removed, 0], rest[removed, 2]).max() < 1.5 * PROBE_RADIUS + 0.002
    assert rest[removed, 1].min() > HALF[1] - 0.006 - 1.5 * PROBE_RADIUS - 0.002
    assert run["problems"] == []  # the wound is closed and outward as the body deforms
    again = dissection_run()
    assert (again["removed"] == removed).all() and (again["x"] == run["x"]).all()


def test_the_topology_check_of_a_session_passes_a_dissection_and_names_a_broken_surface():
    session = Session(from_tables([BOX], gravity=[0, 0, 0]), use_cache=False, progress=False)
    session.check_topology()  # as built
    rest = session.data.rest_position
    session.remove_particles(np.flatnonzero(np.linalg.norm(rest - rest[0], axis=1) < 0.009))
    session.step()
    session.check_topology()  # the wound, deformed
    triangles = session.model.surface_triangles.to_numpy()
    live = np.flatnonzero(triangles.any(axis=1))
    triangles[live[0]] = triangles[live[0]][::-1]  # one triangle turned inside out
    session.model.surface_triangles.from_numpy(triangles)
    session._dissection.topology.triangles["vertices"][live[0]] = triangles[live[0]]
    session.model.topology_version += 1
    with pytest.raises(SimulationFault, match="orientation"):
        session.check_topology()


TOOL = """
[[tools]]
name = "dissector"
kind = "dissector"
radius = 0.003
length = 0.1
tip = [0.0, 0.016, 0.0]
script = [
  { time = 0.0, tip = [0.0, 0.016, 0.0] },
  { time = 0.5, tip = [0.0, %s, 0.0] },
]"""


def test_run_checks_the_topology_of_every_frame_that_removed_tissue(tmp_path, capsys):
    scene = tmp_path / "dissect.toml"
    scene.write_text(block_scene_file("dissect", TOOL % (HALF[1] - 0.004 + PROBE_RADIUS)))
    argv = ["run", str(scene), "--headless", "--frames", "40", "--size", "64x48"]
    record = tmp_path / "dissect.tlap"
    status = main(
        [*argv, "--out", str(tmp_path / "a"), "--check-topology", "--record", str(record)]
    )
    out, err = capsys.readouterr()
    assert status == 0, err
    removed = [e["particles"] for e in read_recording(record).events if e["kind"] == "dissect"]
    assert len(removed) > 3 and sum(removed) > 10  # frames that removed tissue were checked


def dumbbell_cut_with_growth(spare: bool, monkeypatch) -> dict:
    """The dumbbell of :func:`displaced_dumbbell` cut through a session, drawn before
    and after, stepped before, during and after the cut; without ``spare`` the
    model is built with no spare rows, so the cut must grow every kind of them (and
    the session is drawn before and after, the drawn mesh following the growth).
    Returns the positions after 22 frames, the renderer's triangle counts (without
    ``spare``) and the session."""
    scene = from_tables([BOX], gravity=[0, 0, 0])
    if not spare:
        monkeypatch.setattr(model_module, "spare_rows", lambda count, *_: count)
        release_parked(session_key(scene))  # the block built here, with no spare rows
    session = Session(scene, use_cache=False, progress=False)
    drawn = []
    if not spare:
        renderer = Renderer.for_scene(session.scene, session.model, size=(64, 48))
        renderer.render(session.state, session.control)
        drawn.append(renderer.mesh.triangle_count)
    before = session.state.snapshot()
    for _ in range(2):  # the step's kernels compiled before the rows grow
        session.step()
    rest = session.data.rest_position
    slab = np.abs(rest[:, 0]) < 0.003
    neck = slab & (np.abs(rest[:, 1]) < 0.005) & (np.abs(rest[:, 2]) < 0.005)
    session.remove_particles(np.flatnonzero(slab & ~neck))
    for _ in range(2):  # after the first growth, which destroys no tree
        session.step()
    session.remove_particles(np.flatnonzero(neck))
    for _ in range(18):
        session.step()
    if not spare:
        renderer.render(session.state, session.control)
        drawn.append(renderer.mesh.triangle_count)
    return {"x": session.state.x.to_numpy(), "drawn": drawn, "session": session, "before": before}


@pytest.mark.keeps_sessions  # one built without spare rows: other tests expect them
def test_a_cut_beyond_the_spare_rows_grows_the_model_and_changes_nothing_else(monkeypatch, caplog):
    """Built without spare rows, the dumbbell's cut grows the model's rows (one log
    line per growth) and the state's; the tables stay right, the topology valid, the
    drawn mesh follows, the motion is that of a model built with spare rows, and a
    snapshot taken before the growth still restores."""
    ample = dumbbell_cut_with_growth(spare=True, monkeypatch=monkeypatch)
    with caplog.at_level(logging.WARNING, logger="taichi_lap"):
        grown = dumbbell_cut_with_growth(spare=False, monkeypatch=monkeypatch)
    session = grown["session"]
    growths = [r for r in caplog.records if "spare rows ran out" in r.getMessage()]
    assert 1 <= len(growths) <= 2  # one line per removal that outgrew the rows
    assert session.model.layout_version == len(growths)
    built = session.model.data
    assert session.model.cluster_capacity > built.cluster_count
    assert session.model.surface_triangle_count > len(built.surface_triangles)
    assert session.model.cluster_total > built.cluster_count  # the neck's cut split clusters
    assert_device_clusters_match(session.model, session._dissection.topology)
    session.check_topology()
    assert grown["drawn"][1] > grown["drawn"][0]  # the renderer made its mesh again
    assert np.array_equal(grown["x"], ample["x"])
    session.state.restore(grown["before"])
    rows = len(grown["before"]["cluster_center"])
    assert np.array_equal(
        session.state.cluster_center.to_numpy()[:rows], grown["before"]["cluster_center"]
    )
