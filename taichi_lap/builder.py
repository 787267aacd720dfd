"""Scene -> :class:`ModelData`: builds every organ, applies attachments, joins
organs, concatenates, and caches the result on disk keyed by the scene's content.

A second start with the same scene (same values, same mesh files, same builder
code) loads the cached arrays instead of rebuilding. Builds that take more than a
second show a progress bar.
"""

from __future__ import annotations

import ast
import hashlib
import importlib.util
import json
import logging
import os
import tempfile
from dataclasses import asdict
from pathlib import Path

import numpy as np
from tqdm import tqdm

import taichi_lap
from taichi_lap.build import clusters as clustering
from taichi_lap.build.model_data import PARTICLE_MATERIAL, ModelData, OrganRecord
from taichi_lap.build.organs import (
    OrganParts,
    add_long_range_attachments,
    build_organ,
    select_region,
)
from taichi_lap.errors import InputError
from taichi_lap.scene import Scene
from taichi_lap.scene_schema import CLUSTER_MODELS

log = logging.getLogger("taichi_lap")

_MATERIAL_FOR_MODEL = {
    "stiffness": CLUSTER_MODELS,
    "recover_rate": CLUSTER_MODELS,
    "eta_on_contact": CLUSTER_MODELS,
    "lra_relaxation": ("fascia_lra",),
}


def cache_dir() -> Path:
    """``$TAICHI_LAP_CACHE``, else ``$XDG_CACHE_HOME/taichi-lap``, else ``~/.cache/taichi-lap``."""
    if os.environ.get("TAICHI_LAP_CACHE"):
        return Path(os.environ["TAICHI_LAP_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "taichi-lap"


BUILD_ROOTS = ("taichi_lap.builder",)
"""Modules whose code, with everything they import from the package, builds a model."""


def build_sources(roots: tuple[str, ...] = BUILD_ROOTS) -> list[Path]:
    """Source files of ``roots`` and of every package module they import, directly or
    through others, at module level or inside a function (read from the files, so an
    import that has not run yet counts too)."""
    seen: dict[str, Path] = {}
    pending = list(roots)
    while pending:
        name = pending.pop()
        if name in seen:
            continue
        try:
            spec = importlib.util.find_spec(name)
        except ModuleNotFoundError:  # a name imported from a module, not a module
            continue
        if spec is None or not spec.origin or not spec.origin.endswith(".py"):
            continue
        path = Path(spec.origin)
        seen[name] = path
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        pending += [package] + _imported_modules(ast.parse(path.read_bytes()), package)
    return sorted(seen.values())


def _imported_modules(tree: ast.AST, package: str) -> list[str]:
    """Package modules an AST imports: ``import a.b``, ``from a import b`` (b a module
    or a name in a), relative imports resolved against ``package``."""
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                base = f"{parent}.{base}" if base else parent
            names += [base] + [f"{base}.{alias.name}" for alias in node.names]
    return [n for n in names if n == "taichi_lap" or n.startswith("taichi_lap.")]


def _code_digest() -> str:
    """Digest of the package version and of every source file a build reads, so a
    change of any of them misses the cache."""
    h = hashlib.sha256(taichi_lap.__version__.encode())
    for path in build_sources():
        h.update(path.read_bytes())
    return h.hexdigest()


def scene_digest(scene: Scene) -> str:
    """Content key of a scene's model: the validated organs (defaults filled in), the
    detail, the mesh files and the code that builds it."""
    content = {"detail": scene.settings["detail"], "organs": [asdict(o) for o in scene.organs]}
    h = hashlib.sha256(json.dumps(content, sort_keys=True, default=str).encode())
    for organ in scene.organs:
        if organ.geometry.mesh is not None:
            h.update(Path(organ.geometry.mesh).read_bytes())
    h.update(_code_digest().encode())
    return h.hexdigest()[:32]


def build_model(scene: Scene, *, use_cache: bool = True, progress: bool = True) -> ModelData:
    """The scene's model, from the cache when possible."""
    path = cache_dir() / f"{scene_digest(scene)}.npz"
    if use_cache and path.is_file():
        try:
            data = load_model(path)
            log.info("model loaded from cache %s", path)
            return data
        except (OSError, ValueError, KeyError) as exc:
            log.warning("ignoring unreadable model cache %s: %s", path, exc)
    data = assemble(scene, progress=progress)
    if use_cache:
        save_model(data, path)
    return data


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
    own = np.arange(offsets[index], offsets[index + 1])
    theirs = np.arange(offsets[other], offsets[other + 1])
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


def save_model(data: ModelData, path: Path):
    """Write the model atomically (temporary file, then rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = data.arrays()
    arrays["organs_json"] = np.array(json.dumps([asdict(r) for r in data.organs]))
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".npz.tmp")
    try:
        with os.fdopen(fd, "wb") as handle:
            np.savez(handle, **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load_model(path: Path) -> ModelData:
    """Read a model written by :func:`save_model`."""
    with np.load(path, allow_pickle=False) as archive:
        arrays = {k: archive[k] for k in archive.files}
    organs = [
        OrganRecord(**{k: tuple(v) if isinstance(v, list) else v for k, v in r.items()})
        for r in json.loads(str(arrays.pop("organs_json")))
    ]
    material = {
        k.split(".", 1)[1]: arrays.pop(k) for k in list(arrays) if k.startswith("material.")
    }
    return ModelData(material=material, organs=organs, **arrays)
