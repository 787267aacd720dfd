"""Volumetric cutting in a session (seed 000 §5.3 with its physics following:
:mod:`taichi_lap.dissection.volume_cut`): a cut through the polyp's stalk splits its
tets into two closed pieces of the volume as built, its clusters part so the head no
longer hangs from the stalk, the scissors cut it in a session, and the head lifted
out of the endoscope's view is excised."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from taichi_lap import scene
from taichi_lap.core.instruments import GRASP_BUTTON
from taichi_lap.core.mesh import element_pieces, tet_volumes
from taichi_lap.core.topology import assert_valid
from taichi_lap.devices import Pose
from taichi_lap.dissection.removal import MutableTopology
from taichi_lap.dissection.tet_cut import SNAP_FRACTION, cut_tets
from taichi_lap.preprocess import organs
from taichi_lap.preprocess.assemble import assemble
from taichi_lap.render.camera import EndoscopeCamera
from taichi_lap.session import Session
from tests.archrun import COMPARE_ARCH, run_on_arch
from tests.blocks import block
from tests.test_tet_cut import assert_closed_pieces, edge_lengths, slice_path

STALK_CUT = 0.0245
"""Height [m] at rest of the cut through the polyp's stalk (its foot at 0.02, its
head from 0.026)."""


def polyp(data) -> tuple[int, np.ndarray]:
    """The polyp's organ index and its particles as built (its reserve left out)."""
    k = next(i for i, o in enumerate(data.organs) if o.name == "polyp")
    first, end = data.organs[k].particles
    return k, np.arange(first, end - data.organs[k].reserve)


def live_pieces(topology: MutableTopology, organ: int) -> list[np.ndarray]:
    """The particles of each connected piece of ``organ``'s live tets."""
    tets = topology.tets[topology.live_tets(organ)]
    label = element_pieces(tets)
    return [np.unique(tets[label == k]) for k in np.unique(label)]


def test_after_a_removal_a_cut_and_a_second_removal_keep_a_valid_topology():
    """A removal takes the polyp's top off (120 of its surface triangles lose every
    corner, so nothing of them is left to clip), the stalk is cut, then the head is
    removed: the cut keeps in the index of clippable triangles only those with
    pieces left, with the corners they were built with (their slots hold other
    triangles by then); before, it listed the ones taken whole again with whatever
    their slots held, and the second removal failed (a KeyError)."""
    data = assemble(scene.load("rectum"))
    k, built = polyp(data)
    topology = MutableTopology(data)
    height = topology.rest[built, 1]
    top = built[height > height.max() - 0.003]
    assert np.isin(topology.original_particles, top).all(axis=1).sum() > 0
    topology.remove(top)
    corners = dict(zip(topology.original.tolist(), map(tuple, topology.original_particles)))
    tets = topology.live_tets(k)
    path = slice_path(np.array([0.0, STALK_CUT, 0.0]), [0.0, 1.0, 0.0], size=0.02, frames=8)
    cut = cut_tets(topology.rest, topology.tets[tets], path)
    end = data.organs[k].particles[1]
    rows = np.arange(end - 1, end - 1 - len(cut.vertex_parents), -1)
    made = set(topology.split_tets(cut, tets, rows).new_triangles.tolist())

    assert all(int(t) in topology.original_pieces for t in topology.original)
    for t, particles in zip(topology.original.tolist(), topology.original_particles):
        if t not in made:
            assert corners.get(t, tuple(particles)) == tuple(particles)
    head = max(live_pieces(topology, k), key=lambda piece: topology.rest[piece, 1].max())
    topology.remove(head)
    assert_valid(topology.topology())


def test_a_cut_through_the_stalk_parts_the_polyps_tets_and_clusters():
    """Split at rest: the topology validator passes (closed outward surfaces, the rest
    volume as built); the polyp is two pieces, the head above the cut; no cluster
    holds both, and the clusters joining the polyp to the rectum keep the stalk's
    foot (the piece where the organs touch), so the head hangs from nothing."""
    data = assemble(scene.load("rectum"))
    k, built = polyp(data)
    topology = MutableTopology(data)
    tets = topology.live_tets(k)
    path = slice_path(np.array([0.0, STALK_CUT, 0.0]), [0.0, 1.0, 0.0], size=0.02, frames=8)
    cut = cut_tets(topology.rest, topology.tets[tets], path)
    end = data.organs[k].particles[1]
    rows = np.arange(end - 1, end - 1 - len(cut.vertex_parents), -1)
    volume = tet_volumes(topology.rest, topology.tets[tets]).sum()

    change = topology.split_tets(cut, tets, rows)

    assert len(change.dead_tets) > 0 and len(change.joined) > 0
    assert_valid(topology.topology())
    live = topology.tets[topology.live_tets(k)]
    assert tet_volumes(topology.rest, live).sum() == pytest.approx(volume, rel=1e-9)
    pieces = live_pieces(topology, k)
    assert len(pieces) == 2
    head, foot = sorted(pieces, key=lambda p: -topology.rest[p, 1].max())
    # the cut runs through the vertices snapped onto it, SNAP_FRACTION of an edge at
    # most from where the plane crosses it
    reach = SNAP_FRACTION * edge_lengths(topology.rest, topology.tets[tets]).max()
    assert topology.rest[head, 1].min() >= STALK_CUT - reach
    assert topology.rest[foot, 1].max() <= STALK_CUT + reach
    for c in np.flatnonzero(topology.cluster_alive):
        members = topology.cluster_members[c]
        assert not (np.isin(members, head).any() and np.isin(members, foot).any())
    joining = [
        c
        for c in np.flatnonzero(topology.cluster_alive)
        if len(np.unique(topology.organ_of[topology.cluster_members[c]])) > 1
    ]
    assert joining and all(not np.isin(topology.cluster_members[c], head).any() for c in joining)
    assert np.isin(rows, np.concatenate(topology.cluster_members)).all()  # new ones shape-match


_POLYP_SCENE = []


def roomy_rectum():
    """The rectum scene built with 8 times the polyp's particles in reserve rows (room
    for several cuts through all of it), built once for the examples of a property
    test."""
    if not _POLYP_SCENE:
        kept, organs.VOLUME_CUT_RESERVE = organs.VOLUME_CUT_RESERVE, 8.0
        try:
            _POLYP_SCENE.append(assemble(scene.load("rectum")))
        finally:
            organs.VOLUME_CUT_RESERVE = kept
    return _POLYP_SCENE[0]


@settings(max_examples=8, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.tuples(*[st.floats(-1.0, 1.0)] * 3).filter(lambda n: np.linalg.norm(n) > 0.1),
            st.tuples(*[st.floats(0.0, 1.0)] * 3),
        ),
        min_size=1,
        max_size=3,
    )
)
def test_random_plane_cuts_through_the_polyp_keep_a_valid_topology(cuts):
    """Planes of random directions through random points of the polyp cut it one after
    the other (later ones cross earlier ones' sub-tets and twins) until its reserve
    rows run out: the topology validator passes after each."""
    data = roomy_rectum()
    k, built = polyp(data)
    topology = MutableTopology(data)
    low, high = topology.rest[built].min(axis=0), topology.rest[built].max(axis=0)
    free = list(
        range(data.organs[k].particles[1] - data.organs[k].reserve, data.organs[k].particles[1])
    )
    for normal, where in cuts:
        tets = topology.live_tets(k)
        path = slice_path(low + np.multiply(where, high - low), normal, size=0.03, frames=4)
        cut = cut_tets(topology.rest, topology.tets[tets], path)
        if len(cut.vertex_parents) > len(free):
            break
        rows = np.array([free.pop() for _ in range(len(cut.vertex_parents))], dtype=np.int64)
        topology.split_tets(cut, tets, rows)
        assert_valid(topology.topology())


def test_tets_kept_whole_leave_the_cut_partial_around_them():
    """``keep_whole``: a tet kept whole is not split, nor its neighbours on the edges
    it shares where that would leave the mesh non-conforming: a plane cut through
    the block waits where a tet it stops at stops its neighbours (it goes on only
    beyond vertices snapped onto it), the block stays one conforming piece; a tet
    kept whole away from the cut changes nothing."""
    b = block(3)
    points, tets = b["rest_positions"], b["tets"]
    path = slice_path(np.array([0.013, 0.015, 0.014]), [1.0, 0.2, 0.1], size=0.04, frames=12)
    whole = cut_tets(points, tets, path)
    on_cut = np.zeros(len(tets), dtype=bool)
    on_cut[whole.split[0]] = True
    cut = cut_tets(points, tets, path, keep_whole=on_cut)
    assert len(cut.deferred) > 0 and len(cut.split) < len(whole.split) / 2
    assert whole.split[0] not in cut.removed
    assert_closed_pieces(*cut.apply(points, tets), 1, tet_volumes(points, tets).sum())
    away = np.zeros(len(tets), dtype=bool)
    normal = np.array([1.0, 0.2, 0.1]) / np.linalg.norm([1.0, 0.2, 0.1])
    above = np.abs((points[tets] - [0.013, 0.015, 0.014]) @ normal).min(axis=1)
    away[np.argmax(above)] = True
    kept_away = cut_tets(points, tets, path, keep_whole=away)
    assert kept_away.removed.tolist() == whole.removed.tolist()
    assert (kept_away.added == whole.added).all()


def test_the_camera_sees_what_lies_in_its_view():
    camera = EndoscopeCamera(
        eye=np.zeros(3),
        target=np.array([0.0, 0.0, -1.0]),
        up=np.array([0.0, 1.0, 0.0]),
        fov=60.0,
        near=0.01,
        far=10.0,
    )
    points = np.array([[0.0, 0.0, -1.0], [0.0, 0.6, -1.0], [1.0, 0.0, -1.0], [0, 0, 1.0]])
    assert camera.sees(points, aspect=16 / 9).tolist() == [True, False, True, False]
    assert camera.sees(points, aspect=1.0).tolist() == [True, False, False, False]


def assert_vessel_in_two_hanging_pieces(session: Session):
    """The rectum scene's vessel, cut through, is two pieces, each holding a fixed end."""
    vessel = [organ.name for organ in session.data.organs].index("vessel")
    triangles = session.live_triangles(vessel)
    pieces = element_pieces(triangles)
    assert pieces.max() == 1
    for piece in range(2):
        assert session.data.pinned[np.unique(triangles[pieces == piece])].any()


def stalk_height(session: Session) -> float:
    """Where the stalk's particles at STALK_CUT at rest are now (the rectum sags)."""
    x = session.state.x.to_numpy()
    rest = session.data.rest_position
    _, built = polyp(session.data)
    near = built[np.abs(rest[built, 1] - STALK_CUT) < 0.001]
    return float(x[near, 1].mean())


def test_scissors_cut_the_stalk_the_head_is_excised_and_they_cut_through_the_vessel():
    """Scissors swept through the stalk with closed jaws: event ``cut`` of the polyp,
    a valid topology, the head loose: five frames after the sweep it is lower than it
    stood before the cut by more than half a free fall over those five frames (uncut,
    the head stays within 0.1 mm; no cluster holds it to the stalk now; it may fall
    during the sweep, which severs the stalk before its end). With the view turned
    away from it, it is excised: event ``excised`` with its rest volume, its
    particles gone. Then, as the scene's script goes on (one session for both: the
    rectum's kernels compile once), the level jaws press the vessel beside the gland
    to the floor and cut through it (a truss, :mod:`tests.test_truss_cut`): two
    pieces, each holding a fixed end."""
    session = Session(scene.load("rectum"), progress=False)
    k, built = polyp(session.data)
    height = stalk_height(session)
    top = built[session.data.rest_position[built, 1] > STALK_CUT + 0.004]
    start = session.state.x.to_numpy()[top, 1].mean()  # the head before the cut
    direction = np.array([0.0, 0.0, 1.0])
    events = []
    for sx in np.linspace(-0.016, 0.016, 34):
        session.step(
            {"scissors": Pose(np.array([sx, height, 0.005]), direction)}, {"scissors": GRASP_BUTTON}
        )
        events += session.events
    session.step({"scissors": Pose(np.array([0.03, 0.04, 0.005]), direction)}, {})
    cuts = [e for e in events if e["kind"] == "cut" and e.get("organ") == "polyp"]
    assert cuts and sum(e["tets"] for e in cuts) > 0
    assert session.model.layout_version == 0  # the spare rows held the cuts: no recompiling
    session.check_topology()
    loose = [piece for organ, piece in session._loose if organ == k]
    assert len(loose) >= 1
    head = max(loose, key=len)
    alive = session._dissection.topology.particle_alive[top]
    assert alive.mean() > 0.95  # a few chips the blade cut off went as fragments
    assert np.isin(top[alive], head).all()

    for _ in range(5):
        session.step()
    drop = start - session.state.x.to_numpy()[head, 1].mean()
    assert drop > 0.5 * 0.5 * 9.81 * (5 * session.dt) ** 2  # half a free fall (34 mm)
    for _ in range(15):  # the stalk's foot, crushed by the jaws, takes its shape again
        session.step()

    session.camera.target = session.camera.eye + (session.camera.eye - session.camera.target)
    session.step()
    excised = [e for e in session.events if e["kind"] == "excised"]
    assert [e["organ"] for e in excised] == ["polyp"] * len(excised) and excised
    assert max(e["particles"] for e in excised) == len(head)
    assert not session._dissection.topology.particle_alive[head].any()
    assert sum(e["volume"] for e in excised) > 0.8 * (4 / 3) * np.pi * 0.008**3
    session.check_topology()

    for z in np.linspace(0.045, -0.0245, 15):  # the script's way round under the rectum
        session.step({"scissors": Pose(np.array([0.045, -0.024, z]), direction)}, {})
    events = []
    for y in np.linspace(-0.024, -0.044, 24):
        pose = Pose(np.array([0.045, y, -0.0245]), direction)
        session.step({"scissors": pose}, {"scissors": GRASP_BUTTON})
        events += session.events
    assert any(e["kind"] == "cut" and e["organ"] == "vessel" for e in events)
    session.check_topology()
    assert_vessel_in_two_hanging_pieces(session)


@pytest.mark.xfail(
    strict=True,
    raises=AssertionError,
    reason="the head falls through the rectum wall (README: Not yet)",
)
def test_a_head_cut_free_and_let_go_comes_to_rest_on_the_rectum_wall():
    """The middle of the stalk removed, no instrument near: the head falls onto the
    rectum's top and stays on it. It does not yet: the tissue contacts slow it (moved
    2 cm beside the stalk's foot, its mean speed after four frames was 0.31 m/s,
    against 0.65 m/s in free fall), but it passes through both skins of the wall
    and lands on the floor. A tet-cluster body held from below keeps its shape
    (:func:`tests.test_shape_matching.
    test_a_block_fixed_at_its_base_keeps_its_shape_under_gravity`), and the head
    falls through with 8 or 12 substeps too: the contacts with the wall's coarse
    triangles do not hold it."""
    session = Session(scene.load("rectum"), progress=False)
    _, built = polyp(session.data)
    x = session.state.x.to_numpy()
    height = stalk_height(session)
    session.remove_particles(built[np.abs(x[built, 1] - height) < 0.0012])
    head = built[x[built, 1] > height + 0.0012]
    rectum = x[slice(*session.data.organs[0].particles)]
    centre = x[head].mean(axis=0)
    under = np.hypot(rectum[:, 0] - centre[0], rectum[:, 2] - centre[2]) < 0.004
    wall_top = rectum[under, 1].max()
    for _ in range(20):
        session.step()
    lowest = session.state.x.to_numpy()[head, 1].min()
    session.close()
    assert lowest > wall_top - 0.003


def quick_volume_cut(frames: int = 20) -> dict[str, np.ndarray]:
    """The test block of tet clusters, its lower part fixed, under gravity: scissors
    with 4 cm jaws, level, sweep through it 2 mm above its middle at 0.3 m/s (the
    jaws closed), then wait beside it, open; the tets split, the block's pieces (particle counts) and
    where its particles are after ``frames`` frames."""
    from tests.helpers import BOX

    half = BOX["geometry"]["half_extents"]
    block_organ = dict(
        BOX,
        attachments=[{"kind": "fixed", "box_min": [-1, -1, -1], "box_max": [1, -0.006, 1]}],
    )
    height, z = 0.002, half[2] + 0.005
    tool = {
        "name": "scissors",
        "kind": "scissors",
        "radius": 0.01,
        "length": 0.2,
        "tip": [-0.035, height, z],
        "direction": [0.0, 0.0, 1.0],
    }
    cutting = scene.from_tables([block_organ], tools=[tool], gravity=[0.0, -9.81, 0.0])
    session = Session(cutting, use_cache=False, progress=False)
    direction = np.array([0.0, 0.0, 1.0])
    split, sweep = 0, 15
    for frame in range(frames):
        x = -0.035 + 0.005 * min(frame, sweep)
        closed = {"scissors": GRASP_BUTTON} if 0 < frame <= sweep else {}
        session.step({"scissors": Pose(np.array([x, height, z]), direction)}, closed)
        split += sum(e["tets"] for e in session.events if e["kind"] == "cut")
    session.check_topology()
    topology = session._dissection.topology
    sizes = sorted(len(piece) for piece in live_pieces(topology, 0))
    x = session.state.x.to_numpy()
    built = np.arange(*session.data.organs[0].particles)[: -session.data.organs[0].reserve]
    weighed = cluster_weights(session)
    session.close()
    return {"split": np.array([split]), "pieces": np.array(sizes), "x": x[built], **weighed}


def cluster_weights(session: Session) -> dict[str, np.ndarray]:
    """``mass`` [kg]: the organ's as built, its live particles' now with those the cut
    removed since (chips), the live particles' alone, and theirs in the model; each
    live cluster's mass and rest centre in the model, and as its live members' weights
    in the fits (their masses, a fixed member's more) and rest positions give them."""
    model, topology = session.model, session._dissection.topology
    organ = session.data.organs[0]
    live = np.flatnonzero(topology.particle_alive)
    spare = session._volume_cutter.organs[0].free  # reserve rows no cut has taken
    removed = np.setdiff1d(np.flatnonzero(~topology.particle_alive), spare)
    clusters = [c for c in range(model.cluster_total) if len(topology.cluster_members[c])]
    members = [topology.cluster_members[c] for c in clusters]
    members = [m[topology.particle_alive[m]] for m in members]
    weight = [topology.fit_mass(m) for m in members]  # a fixed member weighs more
    mass = [w.sum() for w in weight]
    return {
        "mass": np.array(
            [
                session.data.mass[organ.particles[0] : organ.particles[1] - organ.reserve].sum(),
                topology.mass[live].sum() + topology.mass[removed].sum(),
                topology.mass[live].sum(),
                model.mass.to_numpy()[live].sum(),
            ]
        ),
        "cluster_mass": np.stack([model.cluster_mass.to_numpy()[clusters], mass], axis=1),
        "cluster_center": np.stack(
            [
                model.cluster_rest_center.to_numpy()[clusters],
                [w @ topology.rest[m] / w.sum() for m, w in zip(members, weight)],
            ],
            axis=1,
        ),
    }


def test_scissors_cut_a_block_through_and_its_upper_part_falls():
    """The quick cut parts the block in two; the upper piece, held by nothing, falls
    (more than a centimetre in the frames after the cut) while the fixed lower one
    stays."""
    from tests.helpers import BOX

    result = quick_volume_cut()
    assert result["split"][0] > 0 and len(result["pieces"]) == 2
    # the block keeps its mass (but for a chip cut off, removed); each cluster weighs
    # what its live members weigh now (a twin or new vertex took its parents' mass
    # before: the block gained 28 %)
    built, kept, live, model = result["mass"]
    assert kept == pytest.approx(built, rel=1e-9) and live > 0.99 * built
    assert model == pytest.approx(live, rel=1e-6)
    device, members = result["cluster_mass"].T
    assert device == pytest.approx(members, rel=1e-5)
    assert np.abs(np.diff(result["cluster_center"], axis=1)).max() < 1e-6
    rest = assemble(scene.from_tables([BOX])).rest_position
    upper = rest[:, 1] > 0.004
    lower = rest[:, 1] < -0.006
    assert np.mean(rest[upper, 1] - result["x"][upper, 1]) > 0.01
    assert np.abs(result["x"][lower] - rest[lower]).max() < 1e-6


@pytest.mark.vulkan
def test_a_volume_cut_on_vulkan_matches_cpu():
    """The same tets split and pieces; nine particles in ten within 0.1 mm, every one
    within 5 mm. Which side of a closing jaw a particle beside it ends on follows the
    rounding: on an Intel Xeon 45 of the 980 particles were 0.1 to 2.5 mm apart
    after the 20 frames (on an AMD EPYC all within 1 mm)."""
    cpu = quick_volume_cut()
    other = run_on_arch(COMPARE_ARCH, "tests.test_volume_cut:quick_volume_cut")
    assert np.array_equal(cpu["split"], other["split"])
    assert np.array_equal(cpu["pieces"], other["pieces"])
    apart = np.linalg.norm(cpu["x"] - other["x"], axis=1)
    assert np.quantile(apart, 0.9) < 1e-4 and apart.max() < 5e-3
