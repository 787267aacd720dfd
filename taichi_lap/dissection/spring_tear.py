"""Tearing of spring sheets: the mesentery of seed 001 (§3.1-3.2, rows of masses
joined by damped springs, row 0 the intestine) tears where it is pulled, after
Müller et al. 2007 ("Position based dynamics", the tearing of its cloth) as it acts
on a spring network: per sheet and frame, the mesentery spring stretched most beyond
the organ's ``tear_strain`` (|x_i - x_j| / L - 1) breaks (:meth:`Model.break_springs`:
it pulls no more), and the tear runs on where the strain concentrates next. The
intestine's own springs (along row 0, and those skipping one of its masses) do not
break: the mesentery tears, the bowel stays whole. A spring broken stays broken until
the session is reset. The drawn membrane leaves out the cells a broken spring
crossed (:class:`~taichi_lap.render.scene_mesh.SceneMesh`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from taichi_lap.core.mesh import pair_lengths
from taichi_lap.preprocess.sheets import spring_pieces


@dataclass
class _Sheet:
    organ: int  # index in the model's organs
    members: np.ndarray  # (S,) bool: its rows of data.spring_pair
    springs: np.ndarray  # the rows of data.spring_pair that may break
    tear_strain: float
    pieces: int  # connected pieces of its unbroken springs


class SpringTearing:
    """Tears the spring sheets of ``model`` whose organ ``materials`` (the scene
    organs' material tables) give a ``tear_strain`` > 0 (module docstring).
    ``separations``: the organs the last :meth:`tear` parted into more connected
    pieces, with their pieces now."""

    def __init__(self, model, materials: list[dict]):
        self.model = model
        data = model.data
        self.separations: list[tuple[str, int]] = []
        self.sheets = []
        pairs = np.asarray(data.spring_pair, dtype=np.int64).reshape(-1, 2)
        for k, organ in enumerate(data.organs):
            tear_strain = float(materials[k].get("tear_strain", 0.0))
            if not organ.row_length or tear_strain <= 0.0:
                continue
            first, end = organ.particles
            inside = (pairs >= first).all(axis=1) & (pairs < end).all(axis=1)
            intestine = (pairs < first + organ.row_length).all(axis=1)  # both on row 0
            springs = np.flatnonzero(inside & ~intestine)
            pieces = spring_pieces(pairs[inside], first, end)
            self.sheets.append(_Sheet(k, inside, springs, tear_strain, pieces))

    def tear(self, x: np.ndarray) -> list[tuple[str, int]]:
        """Break, in each sheet, its mesentery spring stretched most beyond its
        ``tear_strain`` at positions ``x`` (N, 3) [m], if any; returns the organs'
        names and the springs broken (rows of ``data.spring_pair``)."""
        data, out = self.model.data, []
        self.separations = []
        pairs = np.asarray(data.spring_pair, dtype=np.int64).reshape(-1, 2)
        for sheet in self.sheets:
            live = sheet.springs[~self.model.broken_springs[sheet.springs]]
            if not len(live):
                continue
            strain = pair_lengths(x, pairs[live]) / data.spring_rest[live] - 1.0
            worst = int(np.argmax(strain))
            if strain[worst] <= sheet.tear_strain:
                continue
            spring = int(live[worst])
            self.model.break_springs([spring])
            name = data.organs[sheet.organ].name
            out.append((name, spring))
            held = pairs[sheet.members & ~self.model.broken_springs]
            pieces = spring_pieces(held, *data.organs[sheet.organ].particles)
            if pieces > sheet.pieces:
                self.separations.append((name, pieces))
            sheet.pieces = pieces
        return out
