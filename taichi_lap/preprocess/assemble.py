"""Scene -> :class:`ModelData`: builds every organ, applies attachments, joins
organs and concatenates them. Builds that take more than a second show a progress
bar (the model cache, :mod:`taichi_lap.preprocess.cache`, calls this on a miss).
"""

from __future__ import annotations

import numpy as np
from tqdm import tqdm

from taichi_lap.core.errors import InputError
from taichi_lap.preprocess import clusters as clustering
from taichi_lap.preprocess.model_data import PARTICLE_MATERIAL, ModelData, OrganRecord
from taichi_lap.preprocess.organs import (
    OrganParts,
    add_cut_reserve,
    cut_reserve,
    add_long_range_attachments,
    build_organ,
    select_region,
)
from taichi_lap.scene import Scene
from taichi_lap.scene.schema import CLUSTER_MODELS

_MATERIAL_FOR_MODEL = {
    "stiffness": CLUSTER_MODELS,
    "recover_rate": CLUSTER_MODELS,
    "eta_on_contact": CLUSTER_MODELS,
    "haptic_mass_ratio": CLUSTER_MODELS + ("fascia_lra", "truss"),
    "lra_relaxation": ("fascia_lra",),
}


def assemble(scene: Scene, *, progress: bool = True) -> ModelData:
    """Build every organ and concatenate them into one :class:`ModelData`."""
    bar = tqdm(
        total=len(scene.organs),
        desc=f"building {scene.settings['name']}",
        unit="organ",
        delay=1.0,
        disable=None if progress else True,
        leave=False,
    )
    parts: list[OrganParts] = []
    for organ in scene.organs:
        bar.set_postfix_str(organ.name)
        done = len(parts)

        def report(fraction: float, done=done):
            bar.n = done + min(max(fraction, 0.0), 1.0)
            bar.refresh()

        organ_parts = build_organ(organ, scene.source, scene.settings["detail"], report)
        _apply_region_attachments(scene, organ, organ_parts)
        reserve = cut_reserve(organ, organ_parts, scene.tools)
        if reserve:
            add_cut_reserve(organ_parts, reserve)
        parts.append(organ_parts)
        bar.n = len(parts)
        bar.refresh()
    bar.close()
    return _concatenate(scene, parts)


def _apply_region_attachments(scene: Scene, organ, parts: OrganParts):
    anchors = []
    for k, att in enumerate(organ.attachments):
        if att.kind == "join":
            continue
        chosen = select_region(
            parts,
            att.region,
            source=scene.source,
            key=f"{organ.key}.attachments[{k}]",
            organ=organ.name,
        )
        parts.pinned[chosen] = True
        if att.kind == "lra_anchor":
            anchors.append(chosen)
    if organ.model == "fascia_lra" and anchors:
        add_long_range_attachments(organ, parts, np.concatenate(anchors))


def _concatenate(scene: Scene, parts: list[OrganParts]) -> ModelData:
    """One ModelData from the organs' parts: local indices become global."""
    offsets = np.concatenate([[0], np.cumsum([len(p.positions) for p in parts])])
    surface_offsets = np.concatenate([[0], np.cumsum([len(p.surface_index) for p in parts])])
    material = {name: np.zeros(int(offsets[-1])) for name in PARTICLE_MATERIAL}
    cluster_parts, records = [], []
    triangles = tets = 0
    for index, (organ, part) in enumerate(zip(scene.organs, parts)):
        first, last = int(offsets[index]), int(offsets[index + 1])
        for name in PARTICLE_MATERIAL:
            if name in organ.material and organ.model in _MATERIAL_FOR_MODEL.get(
                name, (organ.model,)
            ):
                material[name][first:last] = organ.material[name]
        cluster_start = sum(c.count for c in cluster_parts)
        if part.clusters is not None:
            cluster_parts.append(_shift_clusters(part.clusters, first))
        cluster_parts += [
            _join(scene, parts, offsets, organ, att, index)
            for att in organ.attachments
            if att.kind == "join"
        ]
        records.append(
            OrganRecord(
                name=organ.name,
                model=organ.model,
                particles=(first, last),
                triangles=(triangles, triangles + len(part.surface_triangles)),
                surface_vertices=(int(surface_offsets[index]), int(surface_offsets[index + 1])),
                tets=(tets, tets + len(part.tets)),
                clusters=(cluster_start, sum(c.count for c in cluster_parts)),
                struts=part.struts,
                springs=len(part.spring_pairs),
                row_length=part.row_length,
                reserve=part.reserve,
            )
        )
        triangles += len(part.surface_triangles)
        tets += len(part.tets)
    clusters = clustering.concatenate(cluster_parts)

    def cat(name, width=None, shift=None):
        """Concatenate one array of every part; indices shifted to global."""
        arrays = [
            getattr(p, name) + (0 if shift is None else shift[k]) for k, p in enumerate(parts)
        ]
        out = np.concatenate(arrays)
        return out.reshape(-1, width) if width else out

    def particle_index(name, width=None):
        return cat(name, width, offsets).astype(np.int64)

    return ModelData(
        rest_position=cat("positions", 3),
        mass=cat("mass"),
        pinned=cat("pinned").astype(bool),
        radius=cat("radius"),
        organ=np.repeat(np.arange(len(parts)), np.diff(offsets)),
        material=material,
        cluster_start=clusters.start,
        cluster_member=clusters.members,
        cluster_radius=clusters.radius,
        distance_pair=particle_index("distance_pairs", 2),
        distance_rest=cat("distance_rest"),
        distance_stiffness=cat("distance_stiffness"),
        lra_particle=particle_index("lra_particle"),
        lra_anchor=particle_index("lra_anchor"),
        lra_rest=cat("lra_rest"),
        spring_pair=particle_index("spring_pairs", 2),
        spring_rest=cat("spring_rest"),
        spring_stiffness=cat("spring_stiffness"),
        spring_damping=cat("spring_damping"),
        tets=particle_index("tets", 4),
        surface_index=particle_index("surface_index", 4),
        surface_weight=cat("surface_weight", 4),
        surface_triangles=cat("surface_triangles", 3, surface_offsets).astype(np.int64),
        organs=records,
    )


def _shift_clusters(c: clustering.Clusters, base: int) -> clustering.Clusters:
    return clustering.Clusters(
        start=c.start, members=c.members + base, center=c.center, radius=c.radius
    )


def _join(scene: Scene, parts, offsets, organ, att, index) -> clustering.Clusters:
    """Seed 002 §3.2 clusters tying ``organ`` to ``att.organ``; their reach is the
    attachment's radius, else the organ's typical cluster radius."""
    other = next(k for k, o in enumerate(scene.organs) if o.name == att.organ)
    radius = att.radius or float(np.median(parts[index].clusters.radius))
    positions = np.concatenate([p.positions for p in parts])
    own = np.arange(offsets[index], offsets[index + 1] - parts[index].reserve)
    theirs = np.arange(offsets[other], offsets[other + 1] - parts[other].reserve)
    joined = clustering.joining_clusters(positions, own, theirs, radius)
    if joined.count == 0:
        key = f"{organ.key}.attachments[{organ.attachments.index(att)}]"
        raise InputError(
            scene.source,
            key,
            f"organs {organ.name!r} and {att.organ!r} within "
            f"{radius:g} m of each other were expected, they "
            f"do not touch",
        )
    return joined
