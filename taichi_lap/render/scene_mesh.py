"""Everything drawn, as one triangle mesh on the device: organ surfaces (skinned
to the particles), generalized-cylinder tubes (the intestine, seed 001 §5), the
instruments and the environment: its fixed tubes, the planes' patches and the cavity
wall. Each triangle carries a material and an object index (organs, then tools, then
environment tubes, then ``cavity``: ``object_names``).

Layout of the vertex fields: ``[surfaces | instruments | tubes | membranes |
environment]``; triangles in the same order; the environment's vertices are written
once. The surfaces are the model's rows, spare ones included, copied again after each
dissection (a dead triangle is degenerate); tubes are re-tessellated every frame into a
fixed capacity, their unused triangles degenerate. A spring sheet (the mesentery) is
drawn as its smooth membrane (:mod:`~taichi_lap.kernels.membrane`), a shell
MEMBRANE_THICKNESS thick, its own grid triangles left degenerate.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import taichi as ti
import trimesh

from taichi_lap.core.fields import FieldGroup
from taichi_lap.core.mesh import faces_out, incident_table
from taichi_lap.kernels.draw_mesh import (
    copy_surface,
    copy_surface_triangles,
    gather_points,
    place_instruments,
    surface_char,
    surface_texcoords,
)
from taichi_lap.kernels.membrane import membrane_vertices
from taichi_lap.kernels.normals import vertex_normals
from taichi_lap.kernels.scatter import RowWrites
from taichi_lap.preprocess.organs import CUT_SURFACES
from taichi_lap.preprocess.sheets import (
    shell_cells,
    shell_triangles,
    shell_vertex_count,
)
from taichi_lap.render.instruments import instrument_arrays
from taichi_lap.render.subsurface import TintGrid, vessel_tint_grid
from taichi_lap.render.tubes import TubeMesh
from taichi_lap.scene.materials import (
    INSTRUMENT,
    PRESETS,
    SCALARS,
    VESSEL_APPEARANCES,
    Material,
    material_table,
)
from taichi_lap.scene import CAVITY
from taichi_lap.scenes.anatomy.cavity import cavity_wall, plane_patch
from taichi_lap.scenes.anatomy.tubes import environment_centreline, tube_mesh

MEMBRANE_ACROSS, MEMBRANE_ALONG = 4, 2
"""Samples of a drawn membrane per span between its rows and between its columns."""
MEMBRANE_THICKNESS = 0.0015
"""[m] how thick a membrane is drawn: the mesentery with its fat and vessels, 1-2 mm
(chosen by eye, not measured)."""


def appearance_material(appearance: str, color) -> Material:
    """An appearance preset, with ``color`` as albedo when given."""
    preset = PRESETS[appearance]
    return replace(preset, albedo=tuple(color)) if color is not None else preset


def organ_material(organ) -> Material:
    """The organ's appearance preset, with its ``color`` as albedo when given."""
    return appearance_material(organ.appearance, organ.color)


def organ_tint(scene, data) -> TintGrid:
    """The tint grid of the vessels (organs of a :data:`VESSEL_APPEARANCES` preset)
    under the organs whose material has ``subsurface``, from the model ``data``'s rest
    positions of their particles as built (:func:`~taichi_lap.render.subsurface.vessel_tint_grid`)."""
    specs = {organ.name: organ for organ in scene.organs}
    tissue, vessels = [], []
    for record in data.organs:
        spec = specs[record.name]
        particles = np.arange(record.particles[0], record.particles[1] - record.reserve)
        material = organ_material(spec)
        if material.subsurface > 0.0:
            tissue.append(particles)
        if spec.appearance in VESSEL_APPEARANCES:
            vessels.append((particles, material))
    return vessel_tint_grid(data.rest_position, tissue, vessels)


def environment_arrays(scene) -> dict:
    """The scene's fixed surroundings as one mesh: ``position``, ``normal`` (V, 3),
    ``triangles`` (F, 3, from 0) and the ``piece`` of each triangle, indexing
    ``materials`` and ``names`` (the object each piece is). The pieces: each
    environment tube, drawn round its
    :func:`~taichi_lap.scenes.anatomy.tubes.environment_centreline` with rounded ends
    as it collides (an object of its name); each plane's disc and the cavity wall
    (:mod:`~taichi_lap.scenes.anatomy.cavity`), together the object ``cavity``."""
    pieces = []  # (vertices, faces, vertex normals or None, material, name)
    for tube in scene.tubes:
        mesh = tube_mesh(environment_centreline(tube["points"]), tube["radius"], 16)
        material = appearance_material(tube["appearance"], tube["color"])
        pieces.append((mesh.vertices, mesh.triangles, None, material, tube["name"]))
    for plane in scene.planes:
        if plane["extent"] > 0.0:
            mesh = plane_patch(plane["point"], plane["normal"], plane["extent"])
            normal = np.tile(np.asarray(plane["normal"], float), (len(mesh.vertices), 1))
            material = appearance_material(plane["appearance"], plane["color"])
            pieces.append((mesh.vertices, mesh.triangles, normal, material, CAVITY))
    if scene.cavity is not None:
        cavity = scene.cavity
        mesh = cavity_wall(cavity["center"], cavity["radii"], cavity["relief"])
        material = appearance_material(cavity["appearance"], cavity["color"])
        pieces.append((mesh.vertices, mesh.triangles, None, material, CAVITY))
    names = list(dict.fromkeys(name for *_, name in pieces))
    positions, normals, triangles, piece, base = [], [], [], [], 0
    for k, (vertices, faces, normal, _, _) in enumerate(pieces):
        if normal is None:
            normal = trimesh.Trimesh(vertices, faces, process=False).vertex_normals
        positions.append(vertices)
        normals.append(normal)
        triangles.append(np.asarray(faces, np.int32) + base)
        piece.append(np.full(len(faces), k, np.int32))
        base += len(vertices)
    return {
        "position": np.concatenate(positions or [np.zeros((0, 3))]).astype(np.float32),
        "normal": np.concatenate(normals or [np.zeros((0, 3))]).astype(np.float32),
        "triangles": np.concatenate(triangles or [np.zeros((0, 3), np.int32)]),
        "piece": np.concatenate(piece or [np.zeros(0, np.int32)]),
        "materials": [material for *_, material, _ in pieces],
        "piece_object": np.array([names.index(name) for *_, name in pieces], np.int32),
        "names": names,
    }


def one_sided_objects(data, tool_count: int, tools: dict, environment: dict) -> np.ndarray:
    """Per object of a session's drawn mesh (the organs of the model ``data``, the
    ``tool_count`` tools of :func:`~taichi_lap.render.instruments.instrument_arrays`, the objects of
    :func:`environment_arrays`), 1 where its back faces are never seen, so that the
    rasterizer skips them (half the pixels a closed surface covers are its back), 0
    where it is seen from both sides (a sheet, the cavity seen from within). One-sided:
    an organ drawn as tubes with their membrane (closed and facing out by
    construction), and every organ, tool and environment object whose triangles
    :func:`~taichi_lap.core.mesh.faces_out` as built, but an organ whose surface a cut
    opens (:data:`~taichi_lap.preprocess.organs.CUT_SURFACES` with a reserve: a cut
    vessel shows its inside; a volume cut closes its wound)."""
    rest = data.rest_surface()
    triangles = np.asarray(data.surface_triangles).reshape(-1, 3)
    flags = []
    for organ in data.organs:
        if organ.row_length:
            flags.append(True)
        elif organ.reserve and organ.model in CUT_SURFACES:
            flags.append(False)
        else:
            flags.append(faces_out(rest, triangles[slice(*organ.triangles)]))
    owner = tools["tool"][tools["triangles"][:, 0]]
    for tool in range(tool_count):
        flags.append(faces_out(tools["position"], tools["triangles"][owner == tool]))
    owner = environment["piece_object"][environment["piece"]]
    for k in range(len(environment["names"])):
        flags.append(faces_out(environment["position"], environment["triangles"][owner == k]))
    return np.array(flags, np.int32)


@ti.data_oriented
class ArrayMesh:
    """A triangle mesh for the renderer. Fields: ``positions``, ``normals`` (vec3
    per vertex), ``texcoord`` (vec3 per vertex [m]: where the surface detail is
    evaluated, its rest position, so that the detail moves with the tissue; default
    ``positions`` as given), ``char`` (per vertex, 0 fresh to 1 charred; zeros unless
    its owner writes it), ``blood`` (per vertex, the thickness of the blood film on it
    [m]; zeros unless a :class:`~taichi_lap.render.blood.BloodFilm` writes it),
    ``triangles`` (flat, 3 per triangle), ``triangle_material`` and ``triangle_object``
    (per triangle), ``one_sided`` (per object: 1 where its back faces are not drawn,
    a closed surface facing out, default none), the material table ``albedo`` and the
    :data:`~taichi_lap.scene.materials.SCALARS`, and the vessels' ``tint`` grid
    (``tint_shape``, ``tint_origin``, ``tint_cell``: a
    :class:`~taichi_lap.render.subsurface.TintGrid`, empty by default). Normals
    of the first ``smooth_count`` vertices are gathered from their triangles (the rows of
    ``incident``, a field of :func:`~taichi_lap.core.mesh.incident_table`, built
    from ``triangles`` when not given) by :meth:`update`; the others are written by
    whoever places them. A mesh of fixed arrays never outgrows its fields
    (:attr:`outgrown`)."""

    outgrown = False

    def __init__(
        self,
        triangles: np.ndarray,
        triangle_material: np.ndarray,
        materials: list[Material],
        *,
        vertex_count: int,
        smooth_count: int,
        triangle_object: np.ndarray | None = None,
        one_sided: np.ndarray | None = None,
        positions: np.ndarray | None = None,
        texcoords: np.ndarray | None = None,
        incident=None,
        tint: TintGrid | None = None,
    ):
        triangles = np.asarray(triangles, np.int32).reshape(-1, 3)
        self.vertex_count, self.smooth_count = vertex_count, smooth_count
        self.triangle_count = len(triangles)
        table = material_table(materials)
        group = FieldGroup()
        self.positions = group.field(ti.f32, vertex_count, vector=3, values=positions)
        self.normals = group.field(ti.f32, vertex_count, vector=3)
        self.texcoord = group.field(
            ti.f32, vertex_count, vector=3, values=positions if texcoords is None else texcoords
        )
        self.char = group.field(ti.f32, vertex_count)
        self.blood = group.field(ti.f32, vertex_count)
        self.triangles = group.field(ti.i32, 3 * self.triangle_count, values=triangles.reshape(-1))
        self.triangle_material = group.field(ti.i32, self.triangle_count, values=triangle_material)
        triangle_object = triangle_material if triangle_object is None else triangle_object
        self.triangle_object = group.field(ti.i32, self.triangle_count, values=triangle_object)
        objects = int(np.max(triangle_object, initial=-1)) + 1
        one_sided = np.zeros(objects, np.int32) if one_sided is None else one_sided
        self.one_sided = group.field(ti.i32, max(objects, len(one_sided)), values=one_sided)
        if incident is None:
            smooth = np.flatnonzero(np.all(triangles < smooth_count, axis=1))
            rows = incident_table(triangles[smooth], smooth_count)
            rows = np.where(rows >= 0, smooth[rows], -1)
            incident = group.field(ti.i32, smooth_count, columns=rows.shape[1], values=rows)
        self.incident = incident
        self.albedo = group.field(ti.f32, len(materials), vector=3, values=table["albedo"])
        for name in SCALARS:
            setattr(self, name, group.field(ti.f32, len(materials), values=table[name]))
        tint = tint or TintGrid.empty()
        self.tint = group.field(ti.f32, len(tint.tint), vector=4, values=tint.tint)
        self.tint_shape = group.field(ti.i32, None, vector=3)
        self.tint_origin = group.field(ti.f32, None, vector=3)
        self.tint_cell = group.field(ti.f32, None)
        group.finalize()
        self.tint_shape[None], self.tint_cell[None] = tint.shape.tolist(), tint.cell
        self.tint_origin[None] = tint.origin.tolist()
        self._mesh_group = group

    @classmethod
    def of_material(cls, triangles, positions, material: Material, texcoords=None) -> "ArrayMesh":
        """A mesh of one ``material``, every vertex smooth, one object, drawn one-sided
        when it is a closed surface facing out at ``positions`` (:func:`faces_out`)."""
        return cls(
            triangles,
            np.zeros(len(triangles), np.int32),
            [material],
            one_sided=[int(faces_out(positions, triangles))],
            vertex_count=len(positions),
            smooth_count=len(positions),
            positions=positions,
            texcoords=texcoords,
        )

    def close(self):
        """Free the mesh's fields (:meth:`FieldGroup.close`)."""
        self._mesh_group.close()

    def update(self, state=None, control=None, peak=None):
        """Gather the normals of the smooth vertices from the current positions. The
        simulation's ``state``, ``control`` and particle temperatures ``peak`` are
        for meshes that follow it (:class:`SceneMesh`)."""
        vertex_normals(
            self.positions,
            self.triangles,
            self.incident,
            self.smooth_count,
            self.normals,
        )


class SceneMesh(ArrayMesh):
    """The drawn mesh of a session: organ surfaces, instruments, then the tubes
    (the centre row of every spring-sheet organ: the intestine) as generalized
    cylinders re-tessellated each frame at ``tube_epsilon`` and ``tube_level``
    (seed 001 §5). The organ surfaces are those of ``model`` (a
    :class:`~taichi_lap.sim.model.Model`), followed through dissection; their
    ``char`` follows the peak temperatures of the particles (the wound's look).
    When the model's rows were reallocated (:meth:`~taichi_lap.sim.model.Model.grow`)
    the mesh is :attr:`outgrown` and its owner makes it again (:meth:`rebuilt`)."""

    def __init__(
        self,
        scene,
        model,
        *,
        tube_sides: int = 12,
        tube_max_level: int = 2,
        tint: TintGrid | None = None,
    ):
        data = model.data
        self.scene, self._tube_options = (
            scene,
            {"tube_sides": tube_sides, "tube_max_level": tube_max_level},
        )
        self._layout = model.layout_version
        specs = {organ.name: organ for organ in scene.organs}
        materials = [organ_material(specs[o.name]) for o in data.organs] + [PRESETS[INSTRUMENT]]
        environment = environment_arrays(scene)
        materials += environment["materials"]
        self.model = model
        self.tint_grid = tint or organ_tint(scene, data)
        self._charred = False  # whether the surfaces' char may be non-zero
        self.surface_count = model.surface_vertex_count
        surface_triangles = model.surface_triangles.to_numpy()
        surface_material = model.surface_triangle_organ.to_numpy()
        tools = instrument_arrays(scene.tools)
        self.instrument_count = len(tools["position"])
        instrument_material = np.full(len(tools["triangles"]), len(data.organs), np.int32)
        instrument_object = tools["tool"][tools["triangles"][:, 0]] + len(data.organs)
        self.object_names = [o.name for o in data.organs] + [t["name"] for t in scene.tools]
        self.object_names += environment["names"]

        tubes = [(index, o) for index, o in enumerate(data.organs) if o.row_length]
        self.tubes = [
            TubeMesh(o.row_length, sides=tube_sides, max_level=tube_max_level) for _, o in tubes
        ]
        self.tube_epsilon, self.tube_level = 0.1, tube_max_level
        base = self.surface_count + self.instrument_count
        first_triangle = len(surface_triangles) + len(tools["triangles"])
        self.tube_offsets = []  # (vertex offset, index offset) of each tube's region
        for mesh in self.tubes:
            self.tube_offsets.append((base, 3 * first_triangle))
            base += mesh.vertex_capacity
            first_triangle += mesh.triangle_capacity
        tube_material = np.concatenate(
            [
                np.full(m.triangle_capacity, index, np.int32)
                for (index, _), m in zip(tubes, self.tubes)
            ]
            or [np.zeros(0, np.int32)]
        )
        self.membranes = []  # per sheet: (first surface vertex, rows, columns, vertex offset)
        # per sheet: (organ, first triangle, its shell's triangles, their cells)
        self._membrane_cells = []
        self._torn_drawn = np.zeros(0, np.int64)  # the broken springs the membranes show
        membrane_triangles, membrane_material = [], []
        for index, organ in tubes:
            cols = organ.row_length
            rows = (organ.surface_vertices[1] - organ.surface_vertices[0]) // cols
            fine = ((rows - 1) * MEMBRANE_ACROSS + 1, (cols - 1) * MEMBRANE_ALONG + 1)
            self.membranes.append((organ.surface_vertices[0], rows, cols, base))
            membrane_triangles.append(shell_triangles(*fine) + base)
            membrane_material.append(np.full(len(membrane_triangles[-1]), index, np.int32))
            self._membrane_cells.append(
                (
                    index,
                    first_triangle,
                    membrane_triangles[-1],
                    shell_cells(*fine, MEMBRANE_ACROSS, MEMBRANE_ALONG),
                )
            )
            first_triangle += len(membrane_triangles[-1])
            base += shell_vertex_count(*fine)
        membrane_triangles = np.concatenate(membrane_triangles or [np.zeros((0, 3), np.int32)])
        membrane_material = np.concatenate(membrane_material or [np.zeros(0, np.int32)])
        environment_object = (
            environment["piece_object"][environment["piece"]] + len(data.organs) + len(scene.tools)
        )
        super().__init__(
            np.concatenate(
                [
                    surface_triangles,
                    tools["triangles"] + self.surface_count,
                    np.zeros((len(tube_material), 3), np.int32),
                    membrane_triangles,
                    environment["triangles"] + base,
                ]
            ),
            np.concatenate(
                [
                    surface_material,
                    instrument_material,
                    tube_material,
                    membrane_material,
                    environment["piece"] + len(data.organs) + 1,
                ]
            ),
            materials,
            triangle_object=np.concatenate(
                [
                    surface_material,
                    instrument_object,
                    tube_material,
                    membrane_material,
                    environment_object,
                ]
            ),
            one_sided=one_sided_objects(data, len(scene.tools), tools, environment),
            vertex_count=base + len(environment["position"]),
            smooth_count=self.surface_count,
            incident=model.surface_incident,
            tint=self.tint_grid,
        )
        if len(environment["position"]):  # written once: nothing else writes these rows
            for target, values in (
                (self.positions, "position"),
                (self.normals, "normal"),
                (self.texcoord, "position"),
            ):
                rows = target.to_numpy()
                rows[base:] = environment[values]
                target.from_numpy(rows)

        group = FieldGroup()
        self.tool_position = group.field(
            ti.f32, self.instrument_count, vector=3, values=tools["position"]
        )
        self.tool_normal = group.field(
            ti.f32, self.instrument_count, vector=3, values=tools["normal"]
        )
        self.vertex_tool = group.field(ti.i32, self.instrument_count, values=tools["tool"])
        membrane_organ = np.array([bool(o.row_length) for o in data.organs], np.int32)
        self.membrane_organ = group.field(ti.i32, len(data.organs), values=membrane_organ)
        # per tube: (source, across, points, reference, radius, range) fields: its
        # surface vertices, those of its mesentery's next row (its material direction)
        self.tube_fields = []
        self.tube_spacing = []  # per tube: its points' mean rest distance [m]
        for _, organ in tubes:
            first, count = organ.surface_vertices[0], organ.row_length
            source = np.arange(first, first + count)
            rows = (organ.surface_vertices[1] - first) // count
            across = source + count if rows > 1 else source  # no mesentery: no direction
            row = slice(organ.particles[0], organ.particles[0] + count)
            radius = data.radius[row]
            steps = np.linalg.norm(np.diff(data.rest_position[row], axis=0), axis=1)
            self.tube_spacing.append(float(steps.mean()) if len(steps) else 0.0)
            self.tube_fields.append(
                (
                    group.field(ti.i32, count, values=source),
                    group.field(ti.i32, count, values=across),
                    group.field(ti.f32, count, vector=3),
                    group.field(ti.f32, count, vector=3),
                    group.field(ti.f32, count, values=radius.astype(np.float32)),
                    group.field(ti.i32, 1, vector=2, values=np.array([[0, count]])),
                )
            )
        group.finalize()
        self._group = group
        self._follow_topology()

    @property
    def outgrown(self) -> bool:
        """Whether the model's rows were reallocated since this mesh was made."""
        return self._layout != self.model.layout_version

    def rebuilt(self) -> SceneMesh:
        """A new mesh of the scene and model as they are now, at this mesh's tube
        settings and with its blood film; this one is closed."""
        mesh = SceneMesh(self.scene, self.model, **self._tube_options, tint=self.tint_grid)
        mesh.tube_epsilon, mesh.tube_level = self.tube_epsilon, self.tube_level
        film = mesh.blood.to_numpy()  # the blood on the surface stays where it was
        film[: self.surface_count] = self.blood.to_numpy()[: self.surface_count]
        mesh.blood.from_numpy(film)
        self.close()
        return mesh

    def close(self):
        """Free the mesh's fields."""
        self._group.close()
        super().close()

    def _follow_topology(self):
        """The model's surface triangles (a sheet's grid left degenerate: it is drawn
        as its membrane) and the texcoords of the surfaces and membranes, as the model's
        topology is now."""
        copy_surface_triangles(
            self.model,
            self.membrane_organ,
            self.triangles,
            self.triangle_material,
            self.triangle_object,
        )
        surface_texcoords(self.model, self.texcoord)
        self._draw_membranes(self.texcoord, self.texcoord)  # through the rest positions
        self._leave_out_torn_cells()
        self._version = self.model.topology_version

    def _leave_out_torn_cells(self):
        """Each membrane without the cells of its sheet that broken springs lay in or
        bordered (:meth:`~taichi_lap.sim.model.Model.torn_cells`; a torn mesentery,
        :mod:`~taichi_lap.dissection.spring_sheets`): their triangles, front, back and
        rim, made degenerate; all drawn again once the springs are mended."""
        broken = np.flatnonzero(self.model.broken_springs)
        if np.array_equal(broken, self._torn_drawn):
            return
        writes = RowWrites()
        for organ, start, triangles, cells in self._membrane_cells:
            torn = self.model.torn_cells(organ).ravel()[cells]
            drawn = np.where(torn[:, None], triangles[:, :1], triangles)
            writes.add(3 * start + np.arange(drawn.size), {self.triangles: drawn.ravel()})
        writes.flush()
        self._torn_drawn = broken

    def _draw_membranes(self, points, positions):
        """Each membrane through its sheet's rows of ``points`` (per surface vertex) into
        its rows of ``positions``, with its normals (:func:`membrane_vertices`)."""
        for first, rows, cols, offset in self.membranes:
            membrane_vertices(
                points,
                first,
                rows,
                cols,
                MEMBRANE_ACROSS,
                MEMBRANE_ALONG,
                0.5 * MEMBRANE_THICKNESS,
                positions,
                self.normals,
                offset,
            )

    def update(self, state, control, peak=None):
        """Deformed surfaces with gathered normals, instruments at their poses,
        tubes re-tessellated; the surfaces' triangles again after a dissection. The
        surfaces' char from ``peak``, the particles' peak temperatures [°C]
        (:func:`~taichi_lap.kernels.draw_mesh.surface_char`), or zero when None."""
        if self._version != self.model.topology_version:
            self._follow_topology()
        copy_surface(state.surface_position, self.surface_count, self.positions)
        if peak is not None:
            surface_char(self.model, peak, self.char)
            self._charred = True
        elif self._charred:
            self.char.fill(0.0)
            self._charred = False
        super().update()
        self._draw_membranes(state.surface_position, self.positions)
        if self.instrument_count:
            place_instruments(
                self.tool_position,
                self.tool_normal,
                self.vertex_tool,
                self.instrument_count,
                control,
                self.positions,
                self.normals,
                self.surface_count,
            )
        for mesh, fields, (vertex_offset, index_offset), spacing in zip(
            self.tubes, self.tube_fields, self.tube_offsets, self.tube_spacing
        ):
            source, across, points, reference, radius, span = fields
            gather_points(state.surface_position, source, across, points, reference)
            mesh.update(
                points,
                radius,
                span,
                1,
                self.positions,
                self.normals,
                self.triangles,
                self.texcoord,
                vertex_offset=vertex_offset,
                index_offset=index_offset,
                epsilon=self.tube_epsilon,
                level=self.tube_level,
                spacing=spacing,
                reference=reference,
            )
