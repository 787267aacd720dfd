"""Tearing and cutting of spring sheets: the mesentery of seed 001 (§3.1-3.2, rows of
masses joined by damped springs, row 0 the intestine).

* It tears where it is pulled, after Müller et al. 2007 ("Position based dynamics",
  the tearing of its cloth) as it acts on a spring network: per sheet and frame, the
  mesentery spring stretched most beyond the organ's ``tear_strain``
  (|x_i - x_j| / L - 1) breaks, and the tear runs on where the strain concentrates
  next.
* Scissors cut it: every mesentery spring the closed jaws swept through between two
  frames breaks (the swept volume of seed 000 §5.1, as it cuts a truss's struts).

A broken spring pulls no more (:meth:`Model.break_springs`) and stays broken until the
session is reset. The intestine's own springs (along row 0, and those skipping one of
its masses) neither tear nor are cut: the bowel stays whole (its drawn tube and its
self-collision cannot part). The drawn membrane leaves out the cells a broken spring
crossed (:class:`~taichi_lap.render.scene_mesh.SceneMesh`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from taichi_lap.core.mesh import pair_lengths
from taichi_lap.dissection.sheet_cut import struts_crossed
from taichi_lap.dissection.surface_cut import Sweep
from taichi_lap.preprocess.sheets import spring_pieces


@dataclass
class _Sheet:
    organ: int  # index in the model's organs
    members: np.ndarray  # (S,) bool: its rows of data.spring_pair
    springs: np.ndarray  # the rows of data.spring_pair that may break
    tear_strain: float  # 0: it does not tear
    pieces: int  # connected pieces of its unbroken springs


class SpringSheets:
    """Tears and cuts the spring sheets of ``model`` (module docstring); the organs'
    ``materials`` (the scene organs' material tables) give their ``tear_strain``.
    ``separations``: the organs the last :meth:`tear` or :meth:`cut` parted into more
    connected pieces, with their pieces now."""

    def __init__(self, model, materials: list[dict]):
        self.model = model
        data = model.data
        self.separations: list[tuple[str, int]] = []
        self.sheets = []
        self.pairs = np.asarray(data.spring_pair, dtype=np.int64).reshape(-1, 2)
        for k, organ in enumerate(data.organs):
            if not organ.row_length:
                continue
            first, end = organ.particles
            inside = (self.pairs >= first).all(axis=1) & (self.pairs < end).all(axis=1)
            intestine = (self.pairs < first + organ.row_length).all(axis=1)  # both on row 0
            springs = np.flatnonzero(inside & ~intestine)
            pieces = spring_pieces(self.pairs[inside], first, end)
            tear_strain = float(materials[k].get("tear_strain", 0.0))
            self.sheets.append(_Sheet(k, inside, springs, tear_strain, pieces))

    def tear(self, x: np.ndarray) -> list[tuple[str, int]]:
        """Break, in each sheet with a ``tear_strain``, its mesentery spring stretched
        most beyond it at positions ``x`` (N, 3) [m], if any; returns the organs' names
        and the springs broken (rows of ``data.spring_pair``)."""
        out, self.separations = [], []
        for sheet in self.sheets:
            if sheet.tear_strain <= 0.0:
                continue
            live = self._live(sheet)
            if not len(live):
                continue
            rest = self.model.data.spring_rest[live]
            strain = pair_lengths(x, self.pairs[live]) / rest - 1.0
            worst = int(np.argmax(strain))
            if strain[worst] > sheet.tear_strain:
                out.append((self._break(sheet, live[[worst]]), int(live[worst])))
        return out

    def cut(self, sweep: Sweep, x: np.ndarray) -> list[tuple[str, np.ndarray]]:
        """Break every mesentery spring ``sweep`` passes through, the springs at
        positions ``x`` (N, 3) [m]; returns the organs' names and the springs broken
        (rows of ``data.spring_pair``), for each sheet cut."""
        out, self.separations = [], []
        for sheet in self.sheets:
            live = self._live(sheet)
            crossed = live[struts_crossed(self.pairs[live], sweep, sweep.bounds, x)]
            if len(crossed):
                out.append((self._break(sheet, crossed), crossed))
        return out

    def _live(self, sheet: _Sheet) -> np.ndarray:
        """The sheet's springs that may break and are not broken."""
        return sheet.springs[~self.model.broken_springs[sheet.springs]]

    def _break(self, sheet: _Sheet, springs: np.ndarray) -> str:
        """Break ``springs`` of ``sheet``; a separation when its pieces grew. Returns
        the organ's name."""
        self.model.break_springs(springs)
        data = self.model.data
        name = data.organs[sheet.organ].name
        held = self.pairs[sheet.members & ~self.model.broken_springs]
        pieces = spring_pieces(held, *data.organs[sheet.organ].particles)
        if pieces > sheet.pieces:
            self.separations.append((name, pieces))
        sheet.pieces = pieces
        return name
