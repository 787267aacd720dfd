"""Tearing and cutting of the mesentery (taichi_lap.dissection.spring_sheets): a
spring stretched beyond the tear strain breaks, one a frame, the intestine's own
springs never; scissors break the springs their closed jaws sweep through; a broken
spring pulls no more, the drawn membrane leaves out the cells it crossed, and a reset
mends it all."""

import numpy as np
import pytest

from taichi_lap import scene as scene_mod
from taichi_lap.dissection.spring_sheets import SpringSheets
from taichi_lap.preprocess.assemble import assemble
from taichi_lap.preprocess.sheets import (
    shell_cells,
    shell_triangles,
    spring_pieces,
    torn_cells,
)
from taichi_lap.render.scene_mesh import SceneMesh
from taichi_lap.session import Session
from tests.test_membrane import ALONG, ACROSS, membrane_shell
from tests.archrun import assert_backend_matches_cpu
from tests.helpers import instrument, run_script

TEAR_STRAIN = 0.05
"""Low enough that the mesentery of a short intestine tears as it sags."""


def test_torn_cells_are_those_a_broken_spring_lay_in_or_bordered():
    rows, cols = 4, 5  # particle r * 5 + c
    expected = {
        (5, 6): [(0, 0), (1, 0)],  # along row 1: the cells above and below
        (1, 6): [(0, 0), (0, 1)],  # across rows 0-1 at column 1: either side
        (0, 6): [(0, 0)],  # a diagonal: its cell
        (18, 19): [(2, 3)],  # along the last row: the cell above only
    }
    for pair, cells in expected.items():
        torn = torn_cells([pair], rows, cols)
        assert sorted(zip(*np.nonzero(torn))) == cells, pair


def test_each_shell_triangle_lies_in_its_cell():
    """Through a flat grid of masses at (column, row, 0), every triangle of the
    membrane's shell, front, back and rim, has its centre in the cell
    :func:`shell_cells` gives it (the last row's and column's border in the cell
    before it)."""
    rows, cols = 3, 4
    grid = np.stack([*np.meshgrid(np.arange(cols), np.arange(rows)), np.zeros((rows, cols))], -1)
    positions, _ = membrane_shell(grid.astype(np.float32), 0.01)
    fine = ((rows - 1) * ACROSS + 1, (cols - 1) * ALONG + 1)
    triangles, cells = shell_triangles(*fine), shell_cells(*fine, ACROSS, ALONG)
    assert len(cells) == len(triangles)
    centre = positions[triangles].mean(axis=1)
    row = np.minimum(np.floor(centre[:, 1] + 1e-6), rows - 2)
    column = np.minimum(np.floor(centre[:, 0] + 1e-6), cols - 2)
    assert np.array_equal(row * (cols - 1) + column, cells)


def sagging(frames: int) -> tuple[Session, list[list[dict]]]:
    """A short intestine (20 masses a row) whose mesentery tears at
    :data:`TEAR_STRAIN`, after ``frames`` frames sagging from its rest shape, and the
    events of each frame."""
    scene = scene_mod.load(
        "intestine",
        {
            "scene.detail": 0.05,
            "organs.intestine.geometry.points_per_row": 20,
            "organs.intestine.material.tear_strain": TEAR_STRAIN,
        },
    )
    session = Session(scene, progress=False)
    events = []
    for _ in range(frames):
        session.step()
        events.append(list(session.events))
    return session, events


@pytest.fixture(scope="module")
def torn():
    session, events = sagging(25)  # about half the cells torn
    yield session, events
    session.close()


def broken_springs(session: Session) -> dict[str, np.ndarray]:
    """The springs broken in ``session`` and where the masses are; the session closed."""
    out = {
        "broken": np.flatnonzero(session.model.broken_springs),
        "x": session.state.x.to_numpy(),
    }
    session.close()
    return out


def early_tears() -> dict[str, np.ndarray]:
    """:func:`broken_springs` after the first 12 frames of :func:`sagging` (a spring a
    frame breaks from the fourth: 9)."""
    return broken_springs(sagging(12)[0])


def test_a_sagging_mesentery_tears_spring_by_spring_and_the_intestine_stays_whole(torn):
    session, events = torn
    model, data = session.model, session.data
    tears = [[e for e in frame if e["kind"] == "tear"] for frame in events]
    assert all(len(frame) <= 1 for frame in tears)  # one spring a frame
    assert sum(map(len, tears)) == model.broken_springs.sum() > 10
    assert all(e == {"kind": "tear", "organ": "intestine", "springs": 1} for f in tears for e in f)
    pairs = np.asarray(data.spring_pair)
    organ = data.organs[0]
    first, end = organ.particles
    intestine = (pairs < first + organ.row_length).all(axis=1)
    assert not model.broken_springs[intestine].any()  # the bowel's own springs hold
    broken = np.flatnonzero(model.broken_springs)
    entries = np.isin(model._spring_edge, broken)
    assert entries.sum() == 2 * len(broken)  # both ends of each
    assert (model.spring_stiffness.to_numpy()[: len(entries)][entries] == 0.0).all()
    assert (model.spring_damping.to_numpy()[: len(entries)][entries] == 0.0).all()
    held = ~entries & (data.spring_stiffness[model._spring_edge] > 0.0)
    assert (model.spring_stiffness.to_numpy()[: len(entries)][held] > 0.0).all()
    separated = [e for frame in events for e in frame if e["kind"] == "separated"]
    pieces = spring_pieces(pairs[~model.broken_springs], first, end)
    assert (separated[-1]["pieces"] if separated else 1) == pieces


def test_the_torn_cells_triangles_collide_no_more(torn):
    """The intestine's self-collision takes the mesentery's triangles in torn cells
    out: not live, and in no active pair or contact after the next detection."""
    session, _ = torn
    model, data = session.model, session.data
    collision = session.solver.self_collision
    organ = data.organs[0]
    first = organ.particles[0]
    rows = (organ.particles[1] - first) // organ.row_length
    pairs = np.asarray(data.spring_pair)[model.broken_springs] - first
    torn_cell = torn_cells(pairs, rows, organ.row_length).ravel()
    corners = data.surface_index[data.surface_triangles[slice(*organ.triangles)], 0] - first
    cell = (corners // organ.row_length).min(axis=1) * (organ.row_length - 1) + (
        corners % organ.row_length
    ).min(axis=1)
    live = collision.element_live.to_numpy()
    assert (live[: collision.segment_count] == 1).all()
    assert np.array_equal(live[collision.segment_count :] == 0, torn_cell[cell])
    assert torn_cell[cell].any()
    collision.detect(session.state)
    dead = np.flatnonzero(live == 0)
    for pairs, _ in (collision.active_pairs(), collision.contacts()):
        assert not np.isin(pairs, dead).any()


def test_the_membrane_leaves_out_the_torn_cells_until_a_reset_mends_the_springs(torn):
    session, _ = torn
    model, data = session.model, session.data
    organ = data.organs[0]
    mesh = SceneMesh(session.scene, model)
    mesh.update(session.state, session.control)
    _, start, shell, cells = mesh._membrane_cells[0]
    rows = (organ.particles[1] - organ.particles[0]) // organ.row_length
    pairs = np.asarray(data.spring_pair)[model.broken_springs] - organ.particles[0]
    torn_cell = torn_cells(pairs, rows, organ.row_length).ravel()[cells]
    assert torn_cell.any() and not torn_cell.all()
    drawn = mesh.triangles.to_numpy().reshape(-1, 3)[start : start + len(shell)]
    assert (drawn[torn_cell] == drawn[torn_cell][:, :1]).all()  # degenerate: not drawn
    assert np.array_equal(drawn[~torn_cell], shell[~torn_cell])
    session.reset()
    assert not model.broken_springs.any()
    built = data.spring_stiffness[model._spring_edge]
    assert np.array_equal(model.spring_stiffness.to_numpy()[: len(built)], built.astype(np.float32))
    mesh.update(session.state, session.control)
    drawn = mesh.triangles.to_numpy().reshape(-1, 3)[start : start + len(shell)]
    assert np.array_equal(drawn, shell)
    assert (session.solver.self_collision.element_live.to_numpy() == 1).all()


CUT_COLUMN = 10
"""The scissors cut the spring between rows 1 and 2 at this column."""


def cutting(monkeypatch=None) -> tuple[Session, list[dict], list[tuple]]:
    """A short intestine without gravity (it keeps its built shape) and scissors that
    pierce the mesentery at the middle of the spring between rows 1 and 2 at
    :data:`CUT_COLUMN`, the shaft across the sheet, and close and slide 6 cm along
    the rows through it; the session after 25 frames, its events and (with
    ``monkeypatch``) each :meth:`SpringSheets.cut`'s sweep, positions and result."""
    overrides = {
        "scene.detail": 0.05,
        "scene.gravity": [0.0, 0.0, 0.0],
        "organs.intestine.geometry.points_per_row": 20,
    }
    data = assemble(scene_mod.load("intestine", overrides), progress=False)
    length = data.organs[0].row_length
    x = np.asarray(data.rest_position, dtype=np.float64)
    below, above = x[length + CUT_COLUMN], x[2 * length + CUT_COLUMN]
    along = x[length + CUT_COLUMN + 1] - below
    along /= np.linalg.norm(along)
    normal = np.cross(above - below, along)
    normal /= np.linalg.norm(normal)
    start = 0.5 * (below + above) + 0.005 * normal - 0.03 * along  # the jaws across the sheet
    end = start + 0.06 * along
    tools = scene_mod.load("intestine").raw["tools"]
    tools = tools + [instrument("scissors", start.tolist(), normal.tolist())]
    session = Session(scene_mod.load("intestine", {**overrides, "tools": tools}), progress=False)
    calls = []
    if monkeypatch is not None:
        cut = SpringSheets.cut

        def recorded(self, sweep, x):
            out = cut(self, sweep, x)
            calls.append((sweep, x.copy(), out))
            return out

        monkeypatch.setattr(SpringSheets, "cut", recorded)
    script = [
        {"time": 0.0, "tool": "scissors", "tip": start.tolist(), "grasp": True},
        {"time": 0.3, "tool": "scissors", "tip": end.tolist(), "grasp": True},
    ]
    return session, run_script(session, script, 25), calls


def test_scissors_cut_the_mesentery_springs_their_closed_jaws_sweep_through(monkeypatch):
    """Seed 000 §5.1's swept volume on a spring network: each frame the springs
    broken are those a fine sampling of each spring finds inside the sweep (but for
    ones that only graze it); the spring the scissors slid through is broken, the
    intestine's own are not, and each cut event counts the springs it broke."""
    session, events, calls = cutting(monkeypatch)
    try:
        data, model = session.data, session.model
        first = data.organs[0].particles[0]
        length = data.organs[0].row_length
        pairs = np.asarray(data.spring_pair)
        broken = np.zeros(len(pairs), dtype=bool)
        s = np.linspace(0.0, 1.0, 400)[None, :, None]
        for sweep, x, out in calls:
            a, b = x[pairs[:, 0]], x[pairs[:, 1]]
            depth = sweep.distance((a[:, None] + s * (b - a)[:, None]).reshape(-1, 3))
            depth = depth.reshape(len(pairs), -1).min(axis=1)
            cut = np.zeros(len(pairs), dtype=bool)
            for _, springs in out:
                cut[springs] = True
            clear = np.abs(depth) > 1e-4  # not grazing
            intestine = (pairs < first + length).all(axis=1)
            expected = (depth < 0.0) & ~broken & ~intestine
            assert np.array_equal(cut[clear], expected[clear])
            broken |= cut
        assert np.array_equal(broken, model.broken_springs)
        target = [first + length + CUT_COLUMN, first + 2 * length + CUT_COLUMN]
        assert model.broken_springs[(pairs == target).all(axis=1)].all()
        assert not model.broken_springs[(pairs < first + length).all(axis=1)].any()
        cuts = [e for e in events if e["kind"] == "cut"]
        assert cuts and all(e["organ"] == "intestine" and e["tool"] == "scissors" for e in cuts)
        assert sum(e["springs"] for e in cuts) == model.broken_springs.sum()
    finally:
        session.close()


def scissor_cut() -> dict[str, np.ndarray]:
    """:func:`broken_springs` after :func:`cutting`."""
    return broken_springs(cutting()[0])


@pytest.mark.vulkan
@pytest.mark.parametrize("run, least", [("early_tears", 6), ("scissor_cut", 1)])
def test_tears_and_cuts_on_vulkan_match_cpu(run, least):
    """The same springs break, the masses within 1 mm."""
    cpu = assert_backend_matches_cpu(f"tests.test_spring_sheets:{run}", 1e-3, per_key={"broken": 0})
    assert len(cpu["broken"]) >= least
