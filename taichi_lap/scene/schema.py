"""The scene-file schema: every key a scene may hold, as typed parameters (kind,
default, range, unit, meaning). The README's scene reference is written from these
tables and a test keeps the two in step."""

import math

from taichi_lap.core.instruments import TOOL_KINDS
from taichi_lap.core.params import REQUIRED, Param
from taichi_lap.scene.materials import PRESETS

MODELS = ("shape_matching", "tet_clusters", "fascia_lra", "truss", "mass_spring")
CLUSTER_MODELS = ("shape_matching", "tet_clusters")
ATTACHMENTS = ("fixed", "lra_anchor", "join")
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}

SCENE_PARAMS = {
    "name": Param("str", REQUIRED, "scene name"),
    "description": Param("str", "", "one line shown by `taichi-lap list`"),
    "dt": Param("float", 1.0 / 60.0, "frame time step", lo=1e-4, hi=0.1, unit="s"),
    "substeps": Param("int", 1, "substeps per frame", lo=1, hi=200),
    "shape_iterations": Param(
        "int", 5, "shape-matching passes per substep (Alg. 1 lines 7-23)", lo=1, hi=100
    ),
    "iterations": Param("int", 10, "distance/LRA constraint iterations per substep", lo=1, hi=500),
    "constraint_solver": Param(
        "str", "jacobi", "distance constraint solver", choices=("jacobi", "gauss_seidel")
    ),
    "over_relaxation": Param(
        "float", 1.5, "Jacobi over-relaxation ω (Macklin et al. 2014)", lo=0.1, hi=2.0
    ),
    "gravity": Param("vec3", [0.0, -9.81, 0.0], "gravity", lo=-1000, hi=1000, unit="m/s²"),
    "seed": Param("int", 0, "seed of every random source", lo=0, hi=2**31 - 1),
    "detail": Param(
        "float", 1.0, "particle-count multiplier (smaller scenes for tests)", lo=1e-3, hi=8.0
    ),
    "settle_time": Param(
        "float",
        0.0,
        "simulated time run from the rest shape, tools at their "
        "scene poses and collision off, before frame 0: the "
        "session starts with the organs at rest under gravity",
        lo=0.0,
        hi=60.0,
        unit="s",
    ),
    "speed_limit": Param(
        "float", 50.0, "particle speed reported as a simulation fault", lo=1e-3, hi=1e6, unit="m/s"
    ),
    "collision": Param(
        "str",
        "off",
        "tissue collision of surface triangles (seed 000 §4)",
        choices=("off", "circumsphere", "bounding_sphere", "polygon"),
    ),
    "collision_scale_phi": Param(
        "float", 3.0, "tissue collision: φ of Eq. 4 (seed 000 §7: 3)", lo=0.0, hi=100.0
    ),
    "self_collision": Param("bool", True, "intestine and mesentery self-collision (seed 001 §4)"),
    "collision_threshold": Param(
        "float",
        0.02,
        "self-collision: pairs are tracked while their gap is below this",
        lo=1e-5,
        hi=1.0,
        unit="m",
    ),
    "collision_random_pairs": Param(
        "int",
        0,
        "self-collision: new random pairs per substep (0: max(64, segments / 2))",
        lo=0,
        hi=1_000_000,
    ),
    "collision_passes": Param(
        "int", 8, "self-collision: response sweeps per substep", lo=1, hi=200
    ),
    "collision_skin": Param(
        "float", 0.001, "self-collision: gap counted as contact", lo=0.0, hi=0.1, unit="m"
    ),
}
_COLOR = Param("vec3", None, "base colour (linear RGB); default: the appearance's", lo=0.0, hi=1.0)
"""The ``color`` of whatever is drawn with an ``appearance``: organs, planes, the
cavity's wall, environment tubes."""
CAMERA_PARAMS = {
    "position": Param("vec3", [0.0, 0.1, 0.35], "endoscope tip", lo=-100, hi=100, unit="m"),
    "target": Param("vec3", [0.0, 0.0, 0.0], "point looked at", lo=-100, hi=100, unit="m"),
    "up": Param("vec3", [0.0, 1.0, 0.0], "up direction", lo=-1, hi=1),
    "fov": Param("float", 60.0, "vertical field of view", lo=5.0, hi=170.0, unit="deg"),
    "near": Param("float", 0.002, "near clipping distance", lo=1e-5, hi=10.0, unit="m"),
    "far": Param("float", 5.0, "far clipping distance", lo=1e-3, hi=1e4, unit="m"),
    "exposure": Param(
        "float", 1.0, "exposure (with auto_exposure: of tissue 30 cm from the tip)", lo=1e-3, hi=1e3
    ),
    "distortion": Param(
        "float",
        0.06,
        "barrel distortion k: radius r (of the half-diagonal) shows r (1 + k r²)",
        lo=0.0,
        hi=0.5,
    ),
    "vignetting": Param("float", 0.35, "the light's fall at the image's corners", lo=0.0, hi=1.0),
    "smoke": Param(
        "float", 1.0, "how fast an energised hook's smoke veils the view (0: none)", lo=0.0, hi=10.0
    ),
    "auto_exposure": Param(
        "bool",
        True,
        "expose for the view's depth (the headlight's inverse-square falloff), adapting over about ten frames",
    ),
    "checkerboard": Param(
        "bool",
        True,
        "shade half the pixels of smooth surfaces and fill the others from their neighbours (false: every pixel)",
    ),
}
PLANE_PARAMS = {
    "point": Param("vec3", REQUIRED, "a point on the plane", lo=-100, hi=100, unit="m"),
    "normal": Param("vec3", REQUIRED, "normal pointing to the free side", lo=-1e3, hi=1e3),
    "friction": Param("float", 0.5, "Coulomb friction coefficient", lo=0.0, hi=10.0),
    "appearance": Param(
        "str", "peritoneum", "render material preset of its drawn patch", choices=tuple(PRESETS)
    ),
    "color": _COLOR,
    "extent": Param(
        "float",
        0.5,
        "radius of the disc drawn around point (0: not drawn)",
        lo=0.0,
        hi=100.0,
        unit="m",
    ),
}
PLANE_LOOK = ("appearance", "color", "extent")
"""Keys of a plane that only change how it is drawn, not how it collides."""
CAVITY_PARAMS = {
    "center": Param("vec3", REQUIRED, "centre of the body cavity", lo=-100, hi=100, unit="m"),
    "radii": Param(
        "vec3", REQUIRED, "semi-axes of its wall along x, y, z", lo=1e-3, hi=100, unit="m"
    ),
    "relief": Param(
        "float", 0.08, "height of the wall's bulges, a fraction of the radii", lo=0.0, hi=0.5
    ),
    "appearance": Param(
        "str", "peritoneum", "render material preset of its wall", choices=tuple(PRESETS)
    ),
    "color": _COLOR,
}
ENVIRONMENT_TUBE_PARAMS = {
    "name": Param("str", REQUIRED, "its name, apart from every organ's and tool's"),
    "points": Param(
        "vec3list",
        REQUIRED,
        "centre line (a spline through these points, at least 2)",
        lo=-100,
        hi=100,
        unit="m",
    ),
    "radius": Param("float", REQUIRED, "tube radius", lo=1e-4, hi=1.0, unit="m"),
    "appearance": Param(
        "str", "serosa", "render material preset (seed 000 §6.1)", choices=tuple(PRESETS)
    ),
    "color": _COLOR,
    "friction": Param("float", 0.5, "Coulomb friction coefficient", lo=0.0, hi=10.0),
}
TOOL_PARAMS = {
    "name": Param("str", REQUIRED, "tool name"),
    "kind": Param("str", "probe", "instrument", choices=TOOL_KINDS),
    "radius": Param("float", 0.0025, "shaft radius", lo=1e-4, hi=0.05, unit="m"),
    "length": Param("float", 0.25, "shaft length inside the body", lo=1e-3, hi=1.0, unit="m"),
    "tip": Param("vec3", [0.0, 0.08, 0.0], "initial tip position", lo=-100, hi=100, unit="m"),
    "direction": Param("vec3", [0.0, 1.0, 0.0], "from the tip towards the handle", lo=-1e3, hi=1e3),
    "workspace_scale": Param(
        "float",
        0.001,
        "haptic device: scene metres per device millimetre; the device origin maps to the tip",
        lo=1e-6,
        hi=1.0,
        unit="m/mm",
    ),
    "device": Param(
        "str",
        "",
        "the device that drives this tool (mouse, openhaptics or "
        "openhaptics:NAME); other tools take the devices left, in order",
    ),
    "power": Param(
        "float",
        30.0,
        "hook: electrical power of the energised electrode (laparoscopic hooks cut at 30-40 W)",
        lo=0.0,
        hi=300.0,
        unit="W",
    ),
    "grasp_stiffness": Param(
        "float",
        0.001,
        "haptic device: k of the grasp pull force, Hooke's "
        "law over the grasped tet edges (seed 002 §3.4)",
        lo=0.0,
        hi=1e4,
        unit="N/m",
    ),
}
ORGAN_PARAMS = {
    "name": Param("str", REQUIRED, "organ name, unique in the scene"),
    "model": Param("str", REQUIRED, "tissue model", choices=MODELS),
    "appearance": Param(
        "str", "serosa", "render material preset (seed 000 §6.1)", choices=tuple(PRESETS)
    ),
    "color": _COLOR,
}
GEOMETRY_COMMON = {
    "translate": Param(
        "vec3", [0.0, 0.0, 0.0], "offset applied after rotation", lo=-100, hi=100, unit="m"
    ),
    "rotate": Param(
        "vec3", [0.0, 0.0, 0.0], "rotation about x, then y, then z", lo=-720, hi=720, unit="deg"
    ),
}
MESH_PARAMS = {
    "mesh": Param("str", REQUIRED, "OBJ/STL/PLY file, relative to the scene file"),
    "units": Param("str", "m", "length unit of the file", choices=tuple(UNITS)),
}

_MASS = Param("float", 0.5, "total mass", lo=1e-6, hi=100.0, unit="kg")
_DAMPING = Param("float", 1.0, "velocity damping rate", lo=0.0, hi=1000.0, unit="1/s")
_HAPTIC_MASS_RATIO = Param(
    "float",
    10.0,
    "the particles' mass in the haptic coupling as a multiple of their mass: how "
    "stiff the tissue feels to a haptic device (seed 002 §3.4)",
    lo=0.0,
    hi=1e4,
)
_SHAPE = {
    "mass": _MASS,
    "damping": _DAMPING,
    "stiffness": Param(
        "float", 0.4, "α, pull towards the goal per substep (Alg. 1)", lo=0.0, hi=1.0
    ),
    "recover_rate": Param("float", 0.01, "R_r, decrease of η per substep (Alg. 1)", lo=0.0, hi=1.0),
    "eta_on_contact": Param(
        "float", 0.7, "η set where a tool touches (seed 000 §7: 0.7; Alg. 1: 1)", lo=0.0, hi=1.0
    ),
    "cluster_radius": Param(
        "float",
        None,
        "cluster radius; default gives ≈50 particles per cluster count (seed 002 Table 1)",
        lo=1e-4,
        hi=1.0,
        unit="m",
    ),
    "haptic_mass_ratio": _HAPTIC_MASS_RATIO,
    "organ_cluster": Param(
        "bool",
        True,
        "add one cluster holding the whole organ, so it keeps its overall shape under gravity",
    ),
}
_HEAT = {
    "thermal_conductivity": Param(
        "float",
        0.52,
        "electrocautery: heat conduction along the tet edges (liver, IT'IS tissue database)",
        lo=0.0,
        hi=100.0,
        unit="W/(m K)",
    ),
    "specific_heat": Param(
        "float",
        3540.0,
        "electrocautery: heat capacity per kilogram (liver, IT'IS tissue database)",
        lo=100.0,
        hi=1e5,
        unit="J/(kg K)",
    ),
    "perfusion_rate": Param(
        "float",
        0.016,
        "electrocautery: cooling towards body temperature by the blood flow (liver "
        "perfusion, about 1 ml per gram per minute)",
        lo=0.0,
        hi=10.0,
        unit="1/s",
    ),
    "ablation_temperature": Param(
        "float",
        100.0,
        "electrocautery: particles whose temperature reaches this are removed (the "
        "tissue water boils: the cut)",
        lo=40.0,
        hi=1000.0,
        unit="°C",
    ),
    "damage_temperature": Param(
        "float",
        None,
        "electrocautery: a vessel's wall is damaged above this (protein coagulation, "
        "about 60 °C): one vessel_damage event per place; none: not a vessel",
        lo=40.0,
        hi=1000.0,
        unit="°C",
    ),
}
_EDGES = {
    "edge_stiffness": Param("float", 1.0, "stiffness of the surface edges", lo=0.0, hi=1.0),
}
MATERIAL_PARAMS = {
    "shape_matching": {
        **_SHAPE,
        "cuttable": Param(
            "bool",
            False,
            "scissors and an energised hook cut its surface, its clusters splitting where "
            "the cut parts them (seed 000 Alg. 3)",
        ),
    },
    "tet_clusters": {
        **_SHAPE,
        **_HEAT,
        "particle_spacing": Param(
            "float",
            0.004,
            "BCC lattice cube edge (seed 002: 2.9 mm gives Table 1)",
            lo=2e-4,
            hi=0.1,
            unit="m",
        ),
    },
    "fascia_lra": {
        "mass": _MASS,
        "damping": _DAMPING,
        **_EDGES,
        "bending_stiffness": Param(
            "float", 0.05, "stiffness across neighbouring triangles", lo=0.0, hi=1.0
        ),
        "lra_relaxation": Param("float", 0.25, "β of Eq. 3 (seed 000 §7: 0.1-0.4)", lo=0.0, hi=1.0),
        "lra_anchors": Param("int", 4, "nearest attached vertices each vertex keeps", lo=1, hi=64),
        "tear_strain": Param(
            "float",
            0.0,
            "the sheet tears across an edge stretched beyond this fraction of its rest length"
            " (Müller et al. 2007); 0: it never tears",
            lo=0.0,
            hi=10.0,
        ),
        "haptic_mass_ratio": _HAPTIC_MASS_RATIO,
    },
    "truss": {
        "mass": _MASS,
        "damping": _DAMPING,
        **_EDGES,
        "cone_angle": Param(
            "float", 0.3, "θ, half-angle of the strut cone (Alg. 2)", lo=0.01, hi=1.5, unit="rad"
        ),
        "bending_threshold": Param(
            "float", math.pi / 3, "θ_threshold (seed 000 §7: π/3)", lo=0.0, hi=math.pi, unit="rad"
        ),
        "min_stiffness": Param("float", 0.05, "k_min (seed 000 §7: 0.05)", lo=0.0, hi=1.0),
        "haptic_mass_ratio": _HAPTIC_MASS_RATIO,
    },
    "mass_spring": {
        "damping": Param("float", 0.2, "velocity damping rate", lo=0.0, hi=1000.0, unit="1/s"),
        "intestine_mass": Param(
            "float", 0.6, "mass of the intestine row", lo=1e-6, hi=100.0, unit="kg"
        ),
        "mesentery_mass": Param(
            "float", 0.3, "mass of the other rows", lo=1e-6, hi=100.0, unit="kg"
        ),
        "intestine_stiffness": Param(
            "float", 60.0, "springs along the intestine", lo=0.0, hi=1e6, unit="N/m"
        ),
        "mesentery_stiffness": Param(
            "float", 15.0, "springs of the mesentery", lo=0.0, hi=1e6, unit="N/m"
        ),
        "bending_stiffness": Param(
            "float", 5.0, "springs skipping one intestine mass", lo=0.0, hi=1e6, unit="N/m"
        ),
        "spring_damping": Param(
            "float", 0.05, "damping of every spring", lo=0.0, hi=1e4, unit="N s/m"
        ),
        "tear_strain": Param(
            "float",
            0.0,
            "the mesentery tears: its spring stretched most beyond this fraction of its rest"
            " length breaks, one a frame (Müller et al. 2007); 0: it never tears",
            lo=0.0,
            hi=10.0,
        ),
    },
}
ATTACHMENT_PARAMS = {
    "kind": Param("str", REQUIRED, "what the attachment does", choices=ATTACHMENTS),
    "box_min": Param("vec3", None, "region: lower corner of a box", lo=-100, hi=100, unit="m"),
    "box_max": Param("vec3", None, "region: upper corner of a box", lo=-100, hi=100, unit="m"),
    "center": Param("vec3", None, "region: centre of a sphere", lo=-100, hi=100, unit="m"),
    "radius": Param("float", None, "region: sphere radius; join: reach", lo=1e-5, hi=100, unit="m"),
    "rows": Param(
        "intlist", None, "region: rows of a spring sheet (0 = intestine)", lo=-1000, hi=1000
    ),
    "organ": Param("str", None, "join: the organ to tie to"),
}
TASK_PARAMS = {
    "name": Param("str", "", "the task's title"),
    "instructions": Param("str", "", "what the trainee is asked to do"),
    "time_limit": Param(
        "float",
        0.0,
        "the goal (without one, the session's end) must come within this time (0: no limit)",
        lo=0.0,
        hi=86400.0,
        unit="s",
    ),
    "forbidden": Param(
        "strlist", [], "organs the instruments must not touch (instrument contacts counted)"
    ),
    "removable": Param(
        "strlist", [], "organs whose removal is the goal (not counted as tissue removed outside it)"
    ),
}
TASK_PLANE_PARAMS = {
    "organ": Param("str", REQUIRED, "the organ transected: its removed tissue is the wound"),
    "point": Param("vec3", REQUIRED, "a point of the planned plane", lo=-100, hi=100, unit="m"),
    "normal": Param("vec3", REQUIRED, "the plane's normal", lo=-1000, hi=1000),
    "start": Param(
        "vec3",
        REQUIRED,
        "the planned line's first end (projected into the plane)",
        lo=-100,
        hi=100,
        unit="m",
    ),
    "end": Param(
        "vec3",
        REQUIRED,
        "the planned line's last end (projected into the plane)",
        lo=-100,
        hi=100,
        unit="m",
    ),
    "tolerance": Param(
        "float",
        0.003,
        "tissue removed this close to the plane is in the goal",
        lo=1e-4,
        hi=1.0,
        unit="m",
    ),
    "coverage": Param(
        "float",
        0.8,
        "fraction of the line the wound must reach to complete the goal",
        lo=0.0,
        hi=1.0,
    ),
}
TASK_VIEW_PARAMS = {
    "target": Param(
        "str", REQUIRED, "the organ or environment tube to expose in the endoscope's view"
    ),
    "visible": Param(
        "float",
        0.6,
        "fraction of the target's image (as if nothing hid it) that must show",
        lo=0.0,
        hi=1.0,
    ),
    "share": Param(
        "float", 0.02, "fraction of the whole image the target must fill", lo=0.0, hi=1.0
    ),
    "hold": Param(
        "float",
        2.0,
        "how long the view must stay so to complete the goal",
        lo=0.0,
        hi=3600.0,
        unit="s",
    ),
}
TASK_WAYPOINT = Param(
    "vec3list",
    REQUIRED,
    "the points a tool is to visit in order; its economy of motion is measured against "
    "the straight path from its start through them to its end",
    lo=-100,
    hi=100,
    unit="m",
)
PHASE_EVENTS = (
    "grasp",
    "cut",
    "tear",
    "separated",
    "dissect",
    "cautery",
    "excised",
    "vessel_damage",
)
TASK_PHASE_PARAMS = {
    "name": Param("str", REQUIRED, "what the phase is, as the trainee reads it"),
    "event": Param("str", REQUIRED, "the event that completes it", choices=PHASE_EVENTS),
    "organ": Param("str", None, "only events on this organ (grasped, cut, torn, removed)"),
    "tool": Param("str", None, "only events of this tool"),
    "count": Param("int", 1, "events needed after the phase before it completed", lo=1, hi=100000),
}
TASK_PASS_PARAMS = {  # upper bounds; a metric without one is reported, not judged
    "path_length": Param(
        "float", None, "instrument path length, all instruments", lo=0.0, hi=1e4, unit="m"
    ),
    "economy": Param(
        "float", None, "economy of motion of the least economical instrument", lo=1.0, hi=1e4
    ),
    "idle_time": Param("float", None, "idle time, all instruments", lo=0.0, hi=86400.0, unit="s"),
    "peak_force": Param("float", None, "peak tool force", lo=0.0, hi=1e4, unit="N"),
    "mean_contact_force": Param(
        "float",
        None,
        "mean tool force in contact, largest of the instruments",
        lo=0.0,
        hi=1e4,
        unit="N",
    ),
    "forbidden_contacts": Param(
        "int", None, "instrument contacts with forbidden organs", lo=0, hi=1_000_000
    ),
    "vessel_damage": Param("int", None, "vessel damage events", lo=0, hi=1_000_000),
    "tears": Param("int", None, "tear events", lo=0, hi=1_000_000),
    "removed_outside": Param(
        "float", None, "tissue removed outside the goal", lo=0.0, hi=1e6, unit="ml"
    ),
    "wound_distance_mean": Param(
        "float", None, "mean distance of the wound from the planned plane", lo=0.0, hi=1.0, unit="m"
    ),
    "wound_distance_max": Param(
        "float",
        None,
        "largest distance of the wound from the planned plane",
        lo=0.0,
        hi=1.0,
        unit="m",
    ),
}
