"""Cutting a fascia sheet in a session (seed 000 Alg. 3 with its physics following:
:mod:`taichi_lap.dissection.sheet_cut`): scissors cut a hanging sheet in two, the
constraints across the cut are gone, the piece cut free loses its long-range
attachments and falls, the topology stays valid, a reset puts the sheet back."""

from __future__ import annotations

import numpy as np
import pytest

from taichi_lap.core.csr import rows_of_extents
from taichi_lap.core.instruments import CAUTERY_BUTTON, GRASP_BUTTON
from taichi_lap.core.mesh import element_pieces, masses_after_cut, triangle_areas, unique_edges
from taichi_lap.devices import ScriptedDevice
from taichi_lap.preprocess.organs import CUT_RESERVE
from taichi_lap.scene import Scene, from_tables
from taichi_lap.session import Session
from taichi_lap.sim.model import LISTS
from tests.archrun import assert_backend_matches_cpu, cpu_result
from tests.helpers import assert_incident_rows_packed, instrument, run_script
from tests.test_lra import fascia

# the LRA tests' sheet (10 x 6 cm, 16 x 10 cells, anchored along its edge at x = -0.05:
# settled, it hangs below that edge) with its edges and bending stiff, and damping
SHEET = fascia(0.25, 4, edge_stiffness=1.0, bending_stiffness=0.05, damping=4.0)
CUT_HEIGHT = -0.05
"""The blade crosses the hanging sheet halfway down."""


def cutting_session(kind: str) -> Session:
    tool = instrument(kind, [0.0, CUT_HEIGHT, -0.045], [1.0, 0.0, 0.0])
    scene = from_tables([SHEET], tools=[tool], gravity=[0.0, -9.81, 0.0], settle_time=1.0)
    return Session(scene, use_cache=False, progress=False)


def sweep_across(session: Session, button: int, frames: int = 50) -> list[dict]:
    """Move the tool's cutting part through the hanging sheet along z (10 cm in 0.5 s)
    with ``button`` held, then away; the session's events."""
    name = session.scene.tools[0]["name"]
    x = session.state.x.to_numpy()
    band = np.abs(x[:, 1] - CUT_HEIGHT) < 0.006
    x0 = float(x[band, 0].mean()) + 0.004  # the jaws / electrode reach back through it
    held = {GRASP_BUTTON: "grasp", CAUTERY_BUTTON: "cautery"}.get(button)
    script = [
        {"time": 0.0, "tool": name, "tip": [x0, CUT_HEIGHT, -0.045]},
        {"time": 0.5, "tool": name, "tip": [x0, CUT_HEIGHT, 0.045]},
        {"time": 0.6, "tool": name, "tip": [x0 + 0.04, CUT_HEIGHT, 0.045]},
    ]
    if held:
        script[0][held], script[2][held] = True, False
    return run_script(session, script, frames)


def sheet_particles(session: Session) -> np.ndarray:
    """The particles the sheet was built with (its reserve rows left out)."""
    organ = session.data.organs[0]
    return np.arange(organ.particles[0], organ.particles[1] - organ.reserve)


def model_lists(model, kind: str, *columns: str, tables=None) -> tuple[np.ndarray, ...]:
    """Every entry of the per-particle ``kind`` lists ("distance" or "lra") the
    model's Jacobi gather reads (or those of host ``tables``), particle by particle:
    its particle and its values of ``columns``."""
    read = (lambda name: tables[name]) if tables else (lambda name: getattr(model, name).to_numpy())
    begin, end = read(f"{kind}_begin"), read(f"{kind}_end")
    rows = rows_of_extents(begin, end - begin)
    owner = np.repeat(np.arange(len(begin)), end - begin)
    return (owner, *(read(name)[rows] for name in columns))


def model_pairs(model) -> np.ndarray:
    """The distance constraints the model's Jacobi gather reads, (i, j) i < j."""
    owner, other = model_lists(model, "distance", "distance_other")
    return np.unique(np.sort(np.stack([owner, other], axis=1), axis=1), axis=0)


@pytest.fixture(scope="module")
def cut_sheet():
    session = cutting_session("scissors")
    before = session.state.x.to_numpy()
    events = sweep_across(session, GRASP_BUTTON)
    yield session, before, events
    session.close()


def test_scissors_cut_the_sheet_in_two_and_the_free_piece_falls(cut_sheet):
    session, before, events = cut_sheet
    cuts = [e for e in events if e["kind"] == "cut"]
    assert len(cuts) > 10 and all(e["tool"] == "scissors" for e in cuts)
    # the cut that parted the sheet says so, once (the kerf's fragments are no pieces)
    (separated,) = [e for e in events if e["kind"] == "separated"]
    assert separated == {"kind": "separated", "organ": "fascia", "pieces": 2, "tool": "scissors"}
    assert 0 < events.index(separated) < len(events) - 1
    session.check_topology()  # raises on any problem
    triangles = session.live_triangles()
    pieces = element_pieces(triangles)
    sizes = np.bincount(pieces)
    big = np.argsort(sizes)[::-1][:2]
    assert sizes[big].min() > 100  # two halves of 160 triangles (fragments of the kerf aside)
    x = session.state.x.to_numpy()
    built = sheet_particles(session)
    heights = {}
    for piece in big:
        particles = np.unique(triangles[pieces == piece])
        anchors = np.intersect1d(particles, built[session.data.pinned[built]])
        heights[len(anchors) > 0] = x[particles, 1].mean()
    # the free piece fell for about 0.6 s; the anchored one hangs where it hung
    assert heights[False] < CUT_HEIGHT - 0.5
    assert heights[True] > before[built, 1].mean() - 0.01


def test_no_constraint_joins_the_pieces_and_the_free_piece_has_no_anchor(cut_sheet):
    session, _, _ = cut_sheet
    model = session.model
    triangles = session.live_triangles()
    piece_of = np.full(session.data.particle_count, -1)
    piece_of[triangles.ravel()] = np.repeat(element_pieces(triangles), 3)
    pairs = model_pairs(model)
    assert len(pairs) > 0
    assert (piece_of[pairs] >= 0).all()  # every constraint is between live sheet particles
    assert (piece_of[pairs[:, 0]] == piece_of[pairs[:, 1]]).all()
    owner, anchor = model_lists(model, "lra", "lra_anchor")
    assert (piece_of[owner] == piece_of[anchor]).all()
    anchored_pieces = np.unique(piece_of[anchor])
    free = np.setdiff1d(np.unique(piece_of[piece_of >= 0]), anchored_pieces)
    assert len(free) >= 1 and not np.isin(piece_of[owner], free).any()


def test_the_cut_sheet_holds_each_constraint_once(cut_sheet):
    """Its edges and bending pairs found again on the cut sheet, none twice (a sheet
    has no struts: its constraints that are not edges are its bending pairs)."""
    session, _, _ = cut_sheet
    pairs = np.sort(session.model.constraints()["pairs"], axis=1)
    assert len(np.unique(pairs, axis=0)) == len(pairs)


def test_the_lists_written_after_each_cut_are_those_of_a_whole_write(cut_sheet):
    """A cut writes the sheet's changed constraint lists after the rows in use; each
    particle's lists equal those of all constraints written whole."""
    session, _, _ = cut_sheet
    model = session.model
    whole = model.jacobi_lists(model.constraints())
    for kind, columns in LISTS.items():
        names = columns[1]
        written = model_lists(model, kind, *names)
        expected = model_lists(model, kind, *names, tables=whole)
        for name, got, want in zip(("particle", *names), written, expected):
            np.testing.assert_array_equal(got, want.astype(got.dtype), err_msg=f"{kind} {name}")


def test_a_relist_writes_only_the_lists_that_changed(cut_sheet):
    session, _, _ = cut_sheet
    model = session.model
    first, end = session.data.organs[0].particles
    now = model.constraints()
    mine = (now["pairs"][:, 0] >= first) & (now["pairs"][:, 0] < end)
    attached = (now["lra_particle"] >= first) & (now["lra_particle"] < end)
    lists = [now[name][attached if name.startswith("lra") else mine] for name in now]
    used = dict(model._list_rows)  # rows of each kind of list in use
    model.replace_constraints(first, end, *lists)  # the same lists: nothing written
    assert model._list_rows == used
    pair = lists[0][0]
    lists[1] = lists[1].copy()
    lists[1][0] *= 1.5  # one constraint longer: its two particles' lists change
    model.replace_constraints(first, end, *lists)
    sizes = model._jacobi["distance_end"][pair] - model._jacobi["distance_begin"][pair]
    assert model._list_rows == {"distance": used["distance"] + sizes.sum(), "lra": used["lra"]}
    owner, other, rest = model_lists(model, "distance", "distance_other", "distance_rest")
    longer = (owner == pair[0]) & (other == pair[1])
    assert np.isclose(rest[longer], 1.5 * now["rest"][mine][0], rtol=1e-6).all()


def test_each_surface_vertex_lists_its_live_triangles_first_for_the_normals(cut_sheet):
    assert_incident_rows_packed(cut_sheet[0])


def test_new_vertices_take_reserve_rows_where_their_parents_were(cut_sheet):
    session, _, _ = cut_sheet
    built = sheet_particles(session)
    assert session.data.organs[0].reserve == int(np.ceil(CUT_RESERVE * len(built)))
    taken = np.setdiff1d(session.live_triangles(), built)
    assert len(taken) > 20
    inverse_mass = session.model.inv_mass.to_numpy()
    assert (inverse_mass[taken] > 0.0).all()
    rest = session.model.rest_position.to_numpy()[taken]
    # the cut ran at the height CUT_HEIGHT of the settled sheet: its new vertices at
    # rest lie on the sheet's rest plane y = 0, inside its extent
    assert np.allclose(rest[:, 1], 0.0, atol=1e-6)
    assert (np.abs(rest[:, 0]) <= 0.05 + 1e-6).all() and (np.abs(rest[:, 2]) <= 0.03 + 1e-6).all()


def test_a_cut_keeps_the_sheets_mass_but_for_the_area_it_cut_away(cut_sheet):
    """The mass the cut triangles held goes to the triangles that replace them, by
    area: the sheet loses the share of the kerf and its fragments (not the mass of
    every new vertex gained, as blended from its parents), every live vertex keeps a
    positive mass whose inverse the model holds."""
    session, _, _ = cut_sheet
    data, topology = session.data, session._dissection.topology
    built = sheet_particles(session)
    faces = session.live_triangles()
    live = np.unique(faces)
    mass_before, mass_after = data.mass[built].sum(), topology.mass[live].sum()
    built_faces = data.surface_index.reshape(-1, 4)[data.surface_triangles.reshape(-1, 3), 0]
    area_before = triangle_areas(data.rest_position, built_faces).sum()
    area_after = triangle_areas(topology.rest, faces).sum()
    assert area_after < area_before
    assert mass_after / mass_before == pytest.approx(area_after / area_before, abs=0.01)
    assert (topology.mass[live] > 0.0).all()
    free = live[~topology.pinned[live]]
    inverse_mass = session.model.inv_mass.to_numpy()[free]
    assert np.allclose(inverse_mass, 1.0 / topology.mass[free], rtol=1e-5)


def test_the_collision_weighs_every_live_corner_by_the_masses_after_the_cut(cut_sheet):
    """A cut changes the masses of the vertices around it, and so the inverse masses
    of the corners of triangles it left as they were: the tissue collision holds, for
    every live triangle, those of the masses now."""
    from taichi_lap.collision.surface_tables import corner_binding

    session, _, _ = cut_sheet
    surface = session._dissection.surface_rows()
    live = np.flatnonzero(surface.live)
    expected, _ = corner_binding(
        surface.triangles[live],
        surface.index,
        surface.weight,
        surface.inverse_mass,
        surface.contact_radius,
    )
    corners = (3 * live[:, None] + np.arange(3)).ravel()
    held = session.solver.collision.corner_inv_mass.to_numpy()[corners]
    assert held == pytest.approx(expected, rel=1e-5)


def test_masses_after_a_cut_move_the_cut_triangles_mass_to_their_replacements():
    """A square of two triangles, a vertex of 1 kg each: the triangle (0, 1, 2) is cut
    away for one on half of it with a new vertex 4 at the middle of the edge 1-2;
    vertex 3, only in the kept triangle, keeps its mass."""
    rest = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [1, 0.5, 0]], float)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    old, new = masses_after_cut(
        rest, faces, np.array([True, False]), np.array([[0, 1, 4]]), np.ones(4)
    )
    # each corner of the cut triangle gave the half of its area there: 0.5 + 1 + 0.5
    # = 2 kg over 0.5 m², taken back over 0.25 m², a third by each corner
    assert old == pytest.approx([0.5 + 1 / 3, 1 / 3, 0.5, 1.0])
    assert new == pytest.approx([1 / 3])
    assert old.sum() + new.sum() == pytest.approx(4.0 - 1.0)


def test_a_reset_puts_the_sheet_and_its_constraints_back(cut_sheet):
    session, _, _ = cut_sheet
    session.reset()
    data = session.data
    expected = np.unique(np.sort(data.distance_pair.reshape(-1, 2), axis=1), axis=0)
    assert np.array_equal(model_pairs(session.model), expected)
    assert len(model_lists(session.model, "lra")[0]) == len(data.lra_particle)
    assert np.array_equal(session.model.inv_mass.to_numpy(), data.inverse_mass().astype(np.float32))
    session.step()
    session.check_topology()


def test_an_energised_hook_cuts_the_sheet_and_a_cold_one_does_not():
    session = cutting_session("hook")
    try:
        assert not [e for e in sweep_across(session, 0, frames=20) if e["kind"] == "cut"]
        session.reset()
        cuts = [e for e in sweep_across(session, CAUTERY_BUTTON) if e["kind"] == "cut"]
        assert len(cuts) > 10
        session.check_topology()
        assert np.bincount(element_pieces(session.live_triangles())).max() < 300
    finally:
        session.close()


def quick_cut_scene() -> tuple[Scene, ScriptedDevice]:
    """The flat sheet (no settling) and scissors pointing down through it that cut it
    along x = -0.035, 1.5 cm from its anchored edge, in two frames (2.7 m/s: the sheet
    sags 5 mm a frame there), then leave."""
    tool = instrument("scissors", [-0.035, -0.001, -0.045], [0.0, 1.0, 0.0])
    scene = from_tables([SHEET], tools=[tool], gravity=[0.0, -9.81, 0.0])
    script = [
        {"time": 0.0, "tool": "scissors", "tip": [-0.035, -0.001, -0.045], "grasp": True},
        {"time": 0.034, "tool": "scissors", "tip": [-0.035, -0.001, 0.045]},
        {"time": 0.05, "tool": "scissors", "tip": [-0.035, 0.03, 0.045], "grasp": False},
    ]
    return scene, ScriptedDevice.from_tables("cut", script, scene.tools)


def quick_cut(frames: int = 30) -> dict[str, np.ndarray]:
    """:func:`quick_cut_scene` run on (the sheet falls on after the cut): the live
    triangles, the pieces' sizes and where the built particles are."""
    scene, device = quick_cut_scene()
    session = Session(scene, use_cache=False, progress=False)
    for _ in range(frames):
        time = session.state.time
        session.step(device.poses(time), device.buttons(time))
    session.check_topology()
    triangles = session.live_triangles()
    out = {
        "triangles": np.array([len(triangles)]),
        "pieces": np.sort(np.bincount(element_pieces(triangles))),
        "x": session.state.x.to_numpy()[sheet_particles(session)],
    }
    session.close()
    return out


def test_a_cut_while_the_sheet_sags_frees_the_part_beyond_it():
    result = cpu_result("tests.test_sheet_cut:quick_cut")
    assert len(result["pieces"]) == 2 and result["pieces"].min() > 20
    x = result["x"]
    beyond, before = x[:, 0] > -0.03, x[:, 0] < -0.04
    assert x[beyond, 1].mean() < x[before, 1].mean() - 0.01  # the free part falls away


@pytest.mark.vulkan
def test_a_cut_on_vulkan_matches_cpu():
    """The same cut decisions (triangles and pieces alike) and positions within 1 mm."""
    assert_backend_matches_cpu(
        "tests.test_sheet_cut:quick_cut", 1e-3, per_key={"triangles": 0, "pieces": 0}
    )


def pull(tear_strain: float) -> tuple[Session, list[dict]]:
    """A grasper closes on the flat sheet (no gravity) 4.5 cm from its anchored edge
    and pulls that patch 8 cm further away in 1.5 s; the session after 100 frames and
    its events."""
    sheet = dict(SHEET, material=dict(SHEET["material"], tear_strain=tear_strain))
    tool = instrument("grasper", [0.04, 0.005, 0.0], [0.0, 1.0, 0.0])
    scene = from_tables([sheet], tools=[tool], gravity=[0.0, 0.0, 0.0])
    session = Session(scene, use_cache=False, progress=False)
    script = [
        {"time": 0.0, "tool": "grasper", "tip": [0.04, 0.005, 0.0]},
        {"time": 0.1, "tool": "grasper", "tip": [0.04, 0.005, 0.0], "grasp": True},
        {"time": 1.6, "tool": "grasper", "tip": [0.12, 0.005, 0.0]},
    ]
    device = ScriptedDevice.from_tables("pull", script, scene.tools)
    events = []
    for _ in range(100):
        time = session.state.time
        session.step(device.poses(time), device.buttons(time))
        events += session.events
    return session, events


def test_a_pulled_sheet_tears_round_the_grip_and_the_rest_lets_go():
    """Müller et al. 2007's tearing: split by split, the patch in the jaws tears free;
    it holds no anchor and no long-range attachment after, and the rest of the sheet,
    no longer pulled across the tear, relaxes below the tear strain; mass is kept."""
    tear_strain = 0.3
    session, events = pull(tear_strain)
    try:
        tears = [e for e in events if e["kind"] == "tear"]
        assert len(tears) >= 5 and all(e["organ"] == "fascia" for e in tears)
        (separated,) = [e for e in events if e["kind"] == "separated"]
        assert separated == {"kind": "separated", "organ": "fascia", "pieces": 2}
        session.check_topology()
        triangles = session.live_triangles()
        pieces = element_pieces(triangles)
        held = np.flatnonzero(session.state.grasp_tool.to_numpy() >= 0)
        assert len(held) > 0
        piece_of = np.full(session.data.particle_count, -1)
        piece_of[triangles.ravel()] = np.repeat(pieces, 3)
        grip = np.unique(piece_of[held])
        assert len(grip) == 1 and grip[0] >= 0
        in_grip = pieces == grip[0]
        assert in_grip.sum() < 0.1 * len(triangles)  # the patch alone tore off
        owner = model_lists(session.model, "lra")[0]
        assert not np.isin(owner, triangles[in_grip]).any()
        x, rest = session.state.x.to_numpy(), session._dissection.topology.rest
        edges = unique_edges(triangles[~in_grip])
        strain = np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1) / np.linalg.norm(
            rest[edges[:, 0]] - rest[edges[:, 1]], axis=1
        )
        assert strain.max() - 1.0 < tear_strain
        live = np.unique(triangles)
        mass = session.model.mass.to_numpy()
        built = sheet_particles(session)
        assert mass[live].sum() == pytest.approx(session.data.mass[built].sum(), rel=1e-5)
    finally:
        session.close()


def test_the_rectum_fascia_tears_free_where_a_grasper_pulls_it():
    """The rectum scene's fascia tears (its ``tear_strain``): hanging from its
    attachment it does not; a grasper closing on its hanging part and pulling that
    patch 8 cm away and 2 cm up tears it round the grip, split by split, until the
    patch comes away in the jaws, hanging from no long-range attachment, and the
    sheet's topology stays valid."""
    from taichi_lap import scene as scene_mod

    session = Session(scene_mod.load("rectum"), progress=False)
    try:
        grip, start = [0.0, -0.022, 0.027], [0.0, -0.022, 0.07]
        script = [
            {"time": 0.0, "tool": "grasper", "tip": start},
            {"time": 0.5, "tool": "grasper", "tip": grip},
            {"time": 0.6, "tool": "grasper", "tip": grip, "grasp": True},
            {"time": 2.6, "tool": "grasper", "tip": [0.0, 0.0, 0.11], "grasp": True},
        ]
        events = run_script(session, script, 36)
        assert not [e for e in events if e["kind"] == "tear"]
        events = run_script(session, script[2:], 140)
        tears = [e for e in events if e["kind"] == "tear"]
        assert len(tears) >= 5 and all(e["organ"] == "fascia" for e in tears)
        assert {"kind": "separated", "organ": "fascia", "pieces": 2} in events
        session.check_topology()
        k = [organ.name for organ in session.data.organs].index("fascia")
        faces = session._dissection.topology.live_faces(k)
        pieces = element_pieces(faces)
        held = np.flatnonzero(session.state.grasp_tool.to_numpy() >= 0)
        in_grip = np.isin(faces, held).any(axis=1)
        assert in_grip.any() and len(np.unique(pieces[in_grip])) == 1
        patch = faces[pieces == pieces[in_grip][0]]
        assert len(patch) < 0.2 * len(faces)
        assert not np.isin(model_lists(session.model, "lra")[0], patch).any()
    finally:
        session.close()


def test_a_sheet_without_a_tear_strain_does_not_tear():
    session, events = pull(0.0)
    try:
        assert not [e for e in events if e["kind"] == "tear"]
        assert session._dissection is None
    finally:
        session.close()


def test_a_fragment_is_a_small_piece_neither_anchored_nor_held():
    """Four pieces after a cut: a large one, and three of two triangles each, one
    holding an anchor, one held by a grasper and one free: only the free one is a
    fragment (its four particles), and three pieces are left."""
    import taichi as ti
    from types import SimpleNamespace

    from taichi_lap.dissection.sheet_cut import FRAGMENT_TRIANGLES, SheetCutter
    from taichi_lap.kernels.collision.particle_contact import FREE

    def strip(first: int, quads: int) -> list[list[int]]:
        return [
            face
            for q in range(quads)
            for face in ([first + q, first + q + 1, first + q + 10],)
            + ([first + q + 1, first + q + 11, first + q + 10],)
        ]

    large = strip(0, FRAGMENT_TRIANGLES)  # 16 triangles, particles 0-8 and 10-18
    anchored, held, free = strip(30, 1), strip(50, 1), strip(70, 1)
    faces = np.array(large + anchored + held + free)
    particles = np.arange(100) + 1000  # the sheet's particle of each local vertex
    grasp = ti.field(ti.i32, 1100)
    grasp.fill(FREE)
    grasp[1051] = 0  # a grasper holds a corner of the third piece
    sheet = SimpleNamespace(anchors=np.array([1000, 1030]))
    fragment, counts, left = SheetCutter._fragments(
        None, sheet, faces, particles, SimpleNamespace(grasp_tool=grasp)
    )
    assert fragment.tolist() == [False] * (len(faces) - 2) + [True, True]
    assert counts == [4] and left == 3
