"""The model cache: a built :class:`ModelData` stored on disk, keyed by the scene's
content and by the code that builds it.

A second start with the same scene (same validated organs, same mesh files, same
builder code) loads the cached arrays instead of rebuilding; files are written
atomically.
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

import taichi_lap
from taichi_lap.preprocess.assemble import assemble
from taichi_lap.preprocess.model_data import ModelData, OrganRecord
from taichi_lap.scene import Scene

log = logging.getLogger("taichi_lap")


def cache_dir() -> Path:
    """``$TAICHI_LAP_CACHE``, else ``$XDG_CACHE_HOME/taichi-lap``, else ``~/.cache/taichi-lap``."""
    if os.environ.get("TAICHI_LAP_CACHE"):
        return Path(os.environ["TAICHI_LAP_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "taichi-lap"


BUILD_ROOTS = ("taichi_lap.preprocess.assemble", "taichi_lap.preprocess.cache")
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


def code_digest(roots: tuple[str, ...] = BUILD_ROOTS) -> str:
    """Digest of the package version and of every source file ``roots`` read
    (:func:`build_sources`; by default those of a build), so that a change of any of
    them misses a cache keyed on it."""
    h = hashlib.sha256(taichi_lap.__version__.encode())
    for path in build_sources(roots):
        h.update(path.read_bytes())
    return h.hexdigest()


def scene_digest(scene: Scene) -> str:
    """Content key of a scene's model: the validated organs (defaults filled in), the
    detail, the kinds of instruments (scissors give tet organs reserve rows), the mesh
    files and the code that builds it."""
    content = {
        "detail": scene.settings["detail"],
        "organs": [asdict(o) for o in scene.organs],
        "tool_kinds": sorted({tool["kind"] for tool in scene.tools}),
    }
    h = hashlib.sha256(json.dumps(content, sort_keys=True, default=str).encode())
    for organ in scene.organs:
        if organ.geometry.mesh is not None:
            h.update(Path(organ.geometry.mesh).read_bytes())
    h.update(code_digest().encode())
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


def save_arrays(path: Path, arrays: dict[str, np.ndarray]):
    """Write named arrays to an ``.npz`` atomically (temporary file, then rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".npz.tmp")
    try:
        with os.fdopen(fd, "wb") as handle:
            np.savez(handle, **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load_arrays(path: Path) -> dict[str, np.ndarray]:
    """The arrays of an ``.npz`` written by :func:`save_arrays` (no pickles)."""
    with np.load(path, allow_pickle=False) as archive:
        return {k: archive[k] for k in archive.files}


def save_model(data: ModelData, path: Path):
    """Write the model atomically."""
    arrays = data.arrays()
    arrays["organs_json"] = np.array(json.dumps([asdict(r) for r in data.organs]))
    save_arrays(path, arrays)


def load_model(path: Path) -> ModelData:
    """Read a model written by :func:`save_model`."""
    arrays = load_arrays(path)
    organs = [
        OrganRecord(**{k: tuple(v) if isinstance(v, list) else v for k, v in r.items()})
        for r in json.loads(str(arrays.pop("organs_json")))
    ]
    material = {
        k.split(".", 1)[1]: arrays.pop(k) for k in list(arrays) if k.startswith("material.")
    }
    return ModelData(material=material, organs=organs, **arrays)
