"""Scene files: TOML (read with the standard library's ``tomllib``; nothing in a
scene file is ever executed), validated into :class:`Scene`.

The schema is the tables of :mod:`taichi_lap.scene.schema`; the README's
scene-file reference is written from them. Bad input raises :class:`InputError`
(``error: FILE: KEY: what was expected, what was found``).
"""

from __future__ import annotations

import copy
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from taichi_lap.core.errors import InputError
from taichi_lap.core.instruments import MAX_TOOLS
from taichi_lap.core.params import REQUIRED, Param, check_table, check_value, describe
from taichi_lap.core.topology import MAX_ORGANS
from taichi_lap.scene.keyframes import read_keyframes
from taichi_lap.scene.schema import (
    ATTACHMENT_PARAMS,
    CAMERA_PARAMS,
    CLUSTER_MODELS,
    GEOMETRY_COMMON,
    MATERIAL_PARAMS,
    MESH_PARAMS,
    ORGAN_PARAMS,
    ENVIRONMENT_TUBE_PARAMS,
    CAVITY_PARAMS,
    PLANE_PARAMS,
    SCENE_PARAMS,
    TASK_PARAMS,
    TASK_PASS_PARAMS,
    TASK_PHASE_PARAMS,
    TASK_PLANE_PARAMS,
    TASK_VIEW_PARAMS,
    TASK_WAYPOINT,
    TOOL_PARAMS,
    UNITS,
)
from taichi_lap.scenes.anatomy import GENERATORS

_PRODUCES_FOR_MODEL = {
    "tet_clusters": ("solid", "surface"),
    "shape_matching": ("surface",),
    "truss": ("surface",),
    "fascia_lra": ("surface",),
    "mass_spring": ("spring_sheet",),
}


@dataclass
class GeometrySpec:
    """A generator name and its complete params, or a mesh path; plus a transform."""

    generator: str | None
    params: dict[str, Any]
    mesh: Path | None
    units: float
    translate: list[float]
    rotate: list[float]


@dataclass
class AttachmentSpec:
    kind: str
    region: dict[str, Any]
    organ: str | None = None
    radius: float | None = None


@dataclass
class OrganSpec:
    name: str
    model: str
    appearance: str
    color: list[float] | None
    geometry: GeometrySpec
    material: dict[str, Any]
    attachments: list[AttachmentSpec] = field(default_factory=list)
    key: str = ""  # dotted key of the organ in the file, for errors


@dataclass
class Scene:
    """A validated scene. ``source`` names the file (or built-in scene) for errors;
    ``raw`` is the parsed TOML after overrides (hashed for the model cache)."""

    source: str
    directory: Path
    settings: dict[str, Any]
    camera: dict[str, Any]
    planes: list[dict[str, Any]]
    tools: list[dict[str, Any]]
    organs: list[OrganSpec]
    raw: dict[str, Any]
    task: dict[str, Any] | None = None  # the [task] table, if the scene has one
    tubes: list[dict[str, Any]] = field(default_factory=list)  # [[environment.tubes]]
    cavity: dict[str, Any] | None = None  # [environment.cavity]


CAVITY = "cavity"
"""Object name of the drawn cavity wall and planes (the renderer's object-id image)."""


def draws_environment(cavity: dict | None, planes: list[dict]) -> bool:
    """Whether a scene with this ``cavity`` and ``planes`` draws a wall or a plane (the
    object ``cavity``)."""
    return cavity is not None or any(p["extent"] > 0.0 for p in planes)


def builtin_names() -> list[str]:
    """Names of the scenes shipped with the package."""
    return sorted(
        p.name[:-5]
        for p in resources.files("taichi_lap.scenes").iterdir()
        if p.name.endswith(".toml")
    )


def builtin_scripts() -> list[str]:
    """Names of the tool scripts shipped with the scenes (``scenes/scripts``): the
    careless references of the built-in tasks, ``<scene>-careless``, and the liver's
    deep transection (the topology benchmark's workload)."""
    return sorted(
        p.name[:-5]
        for p in resources.files("taichi_lap.scenes.scripts").iterdir()
        if p.name.endswith(".toml")
    )


def resolve_script(name_or_path: str) -> Path:
    """The file of a built-in script name (:func:`builtin_scripts`) or of a path."""
    if name_or_path in builtin_scripts() and not Path(name_or_path).exists():
        return Path(str(resources.files("taichi_lap.scenes.scripts") / f"{name_or_path}.toml"))
    return Path(name_or_path)


def resolve(name_or_path: str) -> Path:
    """The file of a built-in scene name or of a path to a ``.toml`` file."""
    if name_or_path in builtin_names():
        return Path(str(resources.files("taichi_lap.scenes") / f"{name_or_path}.toml"))
    path = Path(name_or_path)
    if path.suffix == ".toml" and path.is_file():
        return path
    if path.suffix == ".toml":
        raise InputError(name_or_path, "", "a readable scene file was expected, it does not exist")
    raise InputError(
        name_or_path,
        "",
        f"a built-in scene ({', '.join(builtin_names())}) or a "
        f"path to a .toml file was expected, found neither",
    )


def load(name_or_path: str, overrides: dict[str, Any] | None = None) -> Scene:
    """Read, override (``{"scene.detail": 0.1, "organs.liver.material.stiffness": 0.5}``)
    and validate a scene."""
    path = resolve(name_or_path)
    source = name_or_path if name_or_path in builtin_names() else str(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(source, "", f"a readable UTF-8 text file was expected: {exc}") from None
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(source, "", f"valid TOML was expected: {exc}") from None
    for key, value in (overrides or {}).items():
        _override(raw, key, value, source)
    return validate(raw, source, path.parent)


def from_tables(
    organs: list[dict],
    *,
    tools: list[dict] | None = None,
    planes: list[dict] | None = None,
    **settings,
) -> Scene:
    """A scene from Python tables (as they would be read from TOML), for scripts,
    benchmarks and tests: ``from_tables([{"name": ..., "model": ...}], substeps=2)``."""
    raw: dict[str, Any] = {
        "scene": {"name": "scripted", **settings},
        "organs": copy.deepcopy(organs),
    }
    if tools:
        raw["tools"] = copy.deepcopy(tools)
    if planes:
        raw["environment"] = {"planes": copy.deepcopy(planes)}
    return validate(raw, "<tables>", Path("."))


def parse_override(text: str) -> tuple[str, Any]:
    """``"scene.detail=0.1"`` -> ``("scene.detail", 0.1)``; the value is read as TOML
    (numbers, booleans, arrays, quoted strings), else kept as a bare string."""
    if "=" not in text:
        raise InputError("--set", text, "KEY=VALUE was expected")
    key, value = text.split("=", 1)
    try:
        return key.strip(), tomllib.loads(f"v = {value}")["v"]
    except tomllib.TOMLDecodeError:
        return key.strip(), value


def _override(raw: dict, dotted: str, value: Any, source: str):
    node: Any = raw
    parts = dotted.split(".")
    for depth, part in enumerate(parts[:-1]):
        if isinstance(node, list):
            named = [item for item in node if isinstance(item, dict) and item.get("name") == part]
            if not named:
                raise InputError(source, ".".join(parts[: depth + 1]), "no entry with that name")
            node = named[0]
        else:
            node = node.setdefault(part, {})
    if not isinstance(node, dict):
        raise InputError(source, dotted, "a table to set the key in was expected")
    node[parts[-1]] = value


def _list_of_tables(source: str, key: str, value: Any) -> list[dict]:
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        raise InputError(
            source, key, f"an array of tables ([[{key}]]) was expected, found {describe(value)}"
        )
    return value


def validate(raw: dict[str, Any], source: str, directory: Path) -> Scene:
    """Check a parsed scene; return the :class:`Scene` with every default filled in."""
    known = {"scene", "camera", "environment", "tools", "organs", "task"}
    for key in raw:
        if key not in known:
            raise InputError(
                source, key, f"unknown top-level key; expected one of: {', '.join(sorted(known))}"
            )
    if "scene" not in raw:
        raise InputError(source, "scene", "a [scene] table was expected, it is missing")
    settings = check_table(source, "scene", raw["scene"], SCENE_PARAMS)
    camera = check_table(source, "camera", raw.get("camera", {}), CAMERA_PARAMS)
    environment = raw.get("environment", {})
    check_table(source, "environment", environment, {}, ignore=("planes", "tubes", "cavity"))
    planes = []
    for k, table in enumerate(
        _list_of_tables(source, "environment.planes", environment.get("planes", []))
    ):
        plane = check_table(source, f"environment.planes[{k}]", table, PLANE_PARAMS)
        if sum(c * c for c in plane["normal"]) < 1e-12:
            raise InputError(
                source,
                f"environment.planes[{k}].normal",
                "a non-zero vector was expected, found [0, 0, 0]",
            )
        planes.append(plane)
    tubes = []
    for k, table in enumerate(
        _list_of_tables(source, "environment.tubes", environment.get("tubes", []))
    ):
        tube = check_table(source, f"environment.tubes[{k}]", table, ENVIRONMENT_TUBE_PARAMS)
        if len(tube["points"]) < 2:
            raise InputError(
                source,
                f"environment.tubes[{k}].points",
                f"at least 2 points were expected, found {len(tube['points'])}",
            )
        tubes.append(tube)
    cavity = None
    if "cavity" in environment:
        cavity = check_table(source, "environment.cavity", environment["cavity"], CAVITY_PARAMS)
    tools = _tools(source, _list_of_tables(source, "tools", raw.get("tools", [])))
    organ_tables = _list_of_tables(source, "organs", raw.get("organs", []))
    if not organ_tables:
        raise InputError(source, "organs", "at least one [[organs]] table was expected, found none")
    if len(organ_tables) > MAX_ORGANS:
        raise InputError(
            source,
            "organs",
            f"at most {MAX_ORGANS} organs were expected, found {len(organ_tables)}",
        )
    organs = [_organ(source, directory, f"organs[{k}]", t) for k, t in enumerate(organ_tables)]
    _check_names(source, organs, tools, tubes, draws_environment(cavity, planes))
    task = (
        check_task(
            source,
            "task",
            raw["task"],
            [o.name for o in organs],
            [t["name"] for t in tools],
            [t["name"] for t in tubes],
        )
        if "task" in raw
        else None
    )
    return Scene(
        source=source,
        directory=directory,
        settings=settings,
        camera=camera,
        planes=planes,
        tools=tools,
        organs=organs,
        raw=copy.deepcopy(raw),
        task=task,
        tubes=tubes,
        cavity=cavity,
    )


def check_task(
    source: str,
    key: str,
    table: Any,
    organ_names: list[str],
    tool_names: list[str],
    tube_names: list[str] = (),
) -> dict[str, Any]:
    """A ``[task]`` table (:data:`TASK_PARAMS`, its ``pass`` thresholds
    :data:`TASK_PASS_PARAMS`, its goal: a planned transection ``plane``
    :data:`TASK_PLANE_PARAMS`, ``phases`` :data:`TASK_PHASE_PARAMS` and a ``view``
    :data:`TASK_VIEW_PARAMS`; ``waypoints``, per tool the points [m] it is to visit in
    order, :data:`TASK_WAYPOINT`; each optional) with defaults filled in; the organs,
    tools and environment tubes it names must be the scene's (``organ_names``,
    ``tool_names``, ``tube_names``)."""
    task = check_table(
        source, key, table, TASK_PARAMS, ignore=("pass", "plane", "phases", "view", "waypoints")
    )
    task["waypoints"] = _waypoints(
        source, f"{key}.waypoints", table.get("waypoints", {}), tool_names
    )
    task["view"] = None
    if "view" in table:
        view = task["view"] = check_table(source, f"{key}.view", table["view"], TASK_VIEW_PARAMS)
        targets = [*organ_names, *tube_names]
        if view["target"] not in targets:
            raise InputError(
                source,
                f"{key}.view.target",
                f"the name of an organ or environment tube in this scene ({', '.join(targets)}) "
                f"was expected, found {view['target']!r}",
            )
    task["pass"] = check_table(source, f"{key}.pass", table.get("pass", {}), TASK_PASS_PARAMS)
    named = [
        (f"{key}.{group}[{k}]", name)
        for group in ("forbidden", "removable")
        for k, name in enumerate(task[group])
    ]
    task["plane"] = None
    if "plane" in table:
        plane = task["plane"] = check_table(
            source, f"{key}.plane", table["plane"], TASK_PLANE_PARAMS
        )
        named.append((f"{key}.plane.organ", plane["organ"]))
        normal = np.asarray(plane["normal"])
        if normal @ normal < 1e-12:
            raise InputError(source, f"{key}.plane.normal", "a non-zero vector was expected")
        line = np.subtract(plane["end"], plane["start"])
        if np.linalg.norm(line - (line @ normal) / (normal @ normal) * normal) < 1e-4:
            raise InputError(
                source,
                f"{key}.plane.end",
                "a point at least 0.1 mm from start along the plane was expected",
            )
    phases = _list_of_tables(source, f"{key}.phases", table.get("phases", []))
    task["phases"] = []
    for k, phase in enumerate(phases):
        phase = check_table(source, f"{key}.phases[{k}]", phase, TASK_PHASE_PARAMS)
        if phase["organ"] is not None:
            named.append((f"{key}.phases[{k}].organ", phase["organ"]))
        if phase["tool"] is not None and phase["tool"] not in tool_names:
            raise InputError(
                source,
                f"{key}.phases[{k}].tool",
                f"the name of a tool in this scene ({', '.join(tool_names)}) was expected, "
                f"found {phase['tool']!r}",
            )
        task["phases"].append(phase)
    for where, name in named:
        if name not in organ_names:
            raise InputError(
                source,
                where,
                f"the name of an organ in this scene ({', '.join(organ_names)}) was expected, "
                f"found {name!r}",
            )
    return task


def _waypoints(source: str, key: str, table: Any, tool_names: list[str]) -> dict[str, list]:
    """A task's ``waypoints``: per tool name of the scene, its points (a
    :data:`TASK_WAYPOINT` value)."""
    if not isinstance(table, dict):
        raise InputError(
            source,
            key,
            f"a table of tool names to point arrays was expected, found {describe(table)}",
        )
    out = {}
    for tool, points in table.items():
        if tool not in tool_names:
            raise InputError(
                source,
                f"{key}.{tool}",
                f"the name of a tool in this scene ({', '.join(tool_names)}) was expected",
            )
        out[tool] = check_value(source, f"{key}.{tool}", points, TASK_WAYPOINT)
    return out


def _tools(source: str, tables: list[dict]) -> list[dict]:
    """Tool tables; an inline ``script`` (keyframes, as in a script file) drives the
    tool in headless runs."""
    if len(tables) > MAX_TOOLS:
        raise InputError(
            source, "tools", f"at most {MAX_TOOLS} tools were expected, found {len(tables)}"
        )
    tools = []
    for k, table in enumerate(tables):
        tool = check_table(source, f"tools[{k}]", table, TOOL_PARAMS, ignore=("script",))
        tool["script"] = _list_of_tables(source, f"tools[{k}].script", table.get("script", []))
        tools.append(tool)
    for k, tool in enumerate(tools):
        frames = [dict(frame, tool=tool["name"]) for frame in tool["script"]]
        if frames:
            read_keyframes(f"{source} (tools[{k}].script)", frames, tools)
    return tools


def _organ(source: str, directory: Path, key: str, table: dict) -> OrganSpec:
    head = check_table(
        source, key, table, ORGAN_PARAMS, ignore=("geometry", "material", "attachments")
    )
    if "geometry" not in table:
        raise InputError(source, f"{key}.geometry", "a geometry table was expected, it is missing")
    geometry = _geometry(source, directory, f"{key}.geometry", table["geometry"], head["model"])
    material = check_table(
        source, f"{key}.material", table.get("material", {}), MATERIAL_PARAMS[head["model"]]
    )
    attachments = [
        _attachment(source, f"{key}.attachments[{k}]", t, head["model"])
        for k, t in enumerate(
            _list_of_tables(source, f"{key}.attachments", table.get("attachments", []))
        )
    ]
    return OrganSpec(
        name=head["name"],
        model=head["model"],
        appearance=head["appearance"],
        color=head["color"],
        geometry=geometry,
        material=material,
        attachments=attachments,
        key=key,
    )


def _geometry(source: str, directory: Path, key: str, table: Any, model: str) -> GeometrySpec:
    if not isinstance(table, dict):
        raise InputError(source, key, f"a table was expected, found {describe(table)}")
    if ("generator" in table) == ("mesh" in table):
        raise InputError(source, key, "exactly one of 'generator' or 'mesh' was expected")
    if "mesh" in table:
        spec = check_table(source, key, table, {**MESH_PARAMS, **GEOMETRY_COMMON})
        if model == "mass_spring":
            raise InputError(
                source,
                f"{key}.mesh",
                "model mass_spring takes the 'intestine' generator, found a mesh file",
            )
        mesh = directory / spec["mesh"]
        if not mesh.is_file():
            raise InputError(
                source, f"{key}.mesh", f"mesh file {mesh} was expected, it does not exist"
            )
        return GeometrySpec(
            generator=None,
            params={},
            mesh=mesh,
            units=UNITS[spec["units"]],
            translate=spec["translate"],
            rotate=spec["rotate"],
        )
    name = check_value(
        source,
        f"{key}.generator",
        table["generator"],
        Param("str", REQUIRED, "generator", choices=tuple(sorted(GENERATORS))),
    )
    generator = GENERATORS[name]
    wanted = _PRODUCES_FOR_MODEL[model]
    if generator.produces not in wanted:
        raise InputError(
            source,
            f"{key}.generator",
            f"a generator making {' or '.join(wanted)} "
            f"was expected for model {model}, found "
            f"{name!r} (makes {generator.produces})",
        )
    spec = check_table(
        source, key, table, {**generator.params, **GEOMETRY_COMMON}, ignore=("generator",)
    )
    params = {k: spec[k] for k in generator.params}
    return GeometrySpec(
        generator=name,
        params=params,
        mesh=None,
        units=1.0,
        translate=spec["translate"],
        rotate=spec["rotate"],
    )


def _attachment(source: str, key: str, table: dict, model: str) -> AttachmentSpec:
    spec = check_table(source, key, table, ATTACHMENT_PARAMS)
    kind = spec["kind"]
    region = {
        k: spec[k]
        for k in ("box_min", "box_max", "center", "radius", "rows")
        if spec[k] is not None
    }
    if kind == "join":
        if model not in CLUSTER_MODELS:
            raise InputError(
                source,
                f"{key}.kind",
                f"join needs a cluster model ({', '.join(CLUSTER_MODELS)}), found {model}",
            )
        if spec["organ"] is None:
            raise InputError(
                source, f"{key}.organ", "the organ to join was expected, it is missing"
            )
        return AttachmentSpec(kind=kind, region={}, organ=spec["organ"], radius=spec["radius"])
    if spec["organ"] is not None:
        raise InputError(
            source, f"{key}.organ", f"'organ' applies to join only, found it on {kind}"
        )
    if kind == "lra_anchor" and model != "fascia_lra":
        raise InputError(source, f"{key}.kind", f"lra_anchor needs model fascia_lra, found {model}")
    has_box = "box_min" in region or "box_max" in region
    has_sphere = "center" in region or "radius" in region
    has_rows = "rows" in region
    if has_box + has_sphere + has_rows != 1:
        raise InputError(
            source, key, "one region was expected: box_min and box_max, center and radius, or rows"
        )
    if has_box and not ("box_min" in region and "box_max" in region):
        raise InputError(source, key, "a box region needs both box_min and box_max")
    if has_sphere and not ("center" in region and "radius" in region):
        raise InputError(source, key, "a sphere region needs both center and radius")
    if has_rows and model != "mass_spring":
        raise InputError(
            source,
            f"{key}.rows",
            f"rows select spring-sheet rows (model mass_spring), found model {model}",
        )
    return AttachmentSpec(kind=kind, region=region)


def _check_names(
    source: str, organs: list[OrganSpec], tools: list[dict], tubes: list[dict], drawn: bool
):
    """Organ names unique, joins naming other cluster organs, tool names unique,
    environment tubes named apart from every organ, tool and other tube (they are
    objects of the drawn scene alike), and, where the scene draws its cavity or planes
    (``drawn``), nothing else named ``cavity`` (their object's name)."""
    seen: dict[str, str] = {}
    for organ in organs:
        if organ.name in seen:
            raise InputError(
                source,
                f"{organ.key}.name",
                f"a unique organ name was expected, {organ.name!r} is also {seen[organ.name]}",
            )
        seen[organ.name] = organ.key
    by_name = {o.name: o for o in organs}
    for organ in organs:
        for k, att in enumerate(organ.attachments):
            if att.kind != "join":
                continue
            other = by_name.get(att.organ)
            key = f"{organ.key}.attachments[{k}].organ"
            if other is None:
                raise InputError(
                    source,
                    key,
                    f"the name of an organ in this scene was expected, found {att.organ!r}",
                )
            if other is organ or other.model not in CLUSTER_MODELS:
                raise InputError(
                    source,
                    key,
                    f"another organ with a cluster model was expected, "
                    f"found {att.organ!r} ({other.model})",
                )
    names = [t["name"] for t in tools]
    if len(set(names)) != len(names):
        raise InputError(source, "tools", "unique tool names were expected")
    taken = set(seen) | set(names)
    for k, tube in enumerate(tubes):
        if tube["name"] in taken:
            raise InputError(
                source,
                f"environment.tubes[{k}].name",
                f"a name no organ, tool or other tube has was expected, found {tube['name']!r}",
            )
        taken.add(tube["name"])
    if drawn and CAVITY in taken:
        raise InputError(
            source,
            "environment",
            f"no organ, tool or tube named {CAVITY!r} was expected: the drawn cavity and "
            f"planes are the object of that name",
        )
