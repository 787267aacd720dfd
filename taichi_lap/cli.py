"""The ``taichi-lap`` command line: run, render, check, bench, report, list, info.

Exit status 0 on success, 2 on bad input (one line on stderr:
``error: FILE: KEY: what was expected, what was found``), 1 on an internal error
or a simulation fault.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys

# Taichi prints a banner to stdout on import; keep stdout for our output (check --json)
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "false")

from taichi_lap.core.errors import InputError, SimulationFault


def _parser() -> argparse.ArgumentParser:
    from taichi_lap.runtime import ARCH_CHOICES

    parser = argparse.ArgumentParser(
        prog="taichi-lap",
        description="Laparoscopic surgery simulator on Taichi (position-based soft tissue).",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress and backend")
    sub = parser.add_subparsers(dest="command", required=True)

    def scene_args(p):
        p.add_argument("scene", help="built-in scene name (see `taichi-lap list`) or a .toml file")
        p.add_argument(
            "--set",
            action="append",
            default=[],
            metavar="KEY=VALUE",
            help="override a scene value, e.g. scene.detail=0.1 or "
            "organs.liver.material.stiffness=0.5",
        )
        p.add_argument("--no-cache", action="store_true", help="rebuild the model")

    run = sub.add_parser("run", help="simulate a scene in a window or headless")
    scene_args(run)
    run.add_argument("--arch", default="auto", choices=ARCH_CHOICES)
    run.add_argument("--headless", action="store_true", help="never open a window")
    run.add_argument("--frames", type=int, default=None, help="stop after N frames")
    run.add_argument("--out", default=None, help="headless output: .mp4, .gif or a folder of PNGs")
    run.add_argument(
        "--device",
        action="append",
        default=None,
        help="mouse, none, openhaptics[:NAME], script:PATH (or a built-in script's name, "
        "see `taichi-lap list`), replay:RECORDING "
        "(default: mouse in a window, the scene's tool scripts headless); "
        "repeat for several at once: each mouse or openhaptics device "
        "drives the next tool of the scene",
    )
    run.add_argument(
        "--record",
        default=None,
        metavar="PATH",
        help="append every frame's device input and every event to a new session file (.tlap); "
        "a window records to a new file in --sessions unless told --no-record or replaying",
    )
    run.add_argument(
        "--sessions",
        default=None,
        metavar="DIR",
        help="where a window's sessions are recorded (default: $TAICHI_LAP_SESSIONS, "
        "else ~/taichi-lap-sessions), one timestamped file each",
    )
    run.add_argument("--no-record", action="store_true", help="a window records nothing")
    run.add_argument("--size", default="1280x720", help="image size WxH")
    run.add_argument("--threads", type=int, default=None, help="CPU threads (reproducible runs)")
    run.add_argument(
        "--check-topology",
        action="store_true",
        help="debug: run the topology validator at the start and after every frame that "
        "removed tissue (a problem ends the run with status 1)",
    )

    render = sub.add_parser("render", help="write one still image")
    scene_args(render)
    render.add_argument("--out", required=True, help="PNG file")
    render.add_argument("--arch", default="auto", choices=ARCH_CHOICES)
    render.add_argument("--frames", type=int, default=0, help="simulate N frames first")
    render.add_argument("--size", default="1280x720", help="image size WxH")

    check = sub.add_parser("check", help="validate a scene and print model statistics")
    scene_args(check)
    check.add_argument("--json", action="store_true", help="print JSON")

    bench = sub.add_parser("bench", help="run the benchmarks on each backend and compare them")
    bench.add_argument(
        "--arch", default="cpu", help="comma-separated backends: cpu, cuda, vulkan, metal"
    )
    bench.add_argument("--quick", action="store_true", help="small sizes (a smoke run)")
    bench.add_argument("--out", default="bench-results", help="folder for the JSON and summary")
    bench.add_argument(
        "--only", default=None, help="comma-separated benchmarks (default: all of them)"
    )
    bench.add_argument(
        "--jobs",
        type=int,
        default=1,
        help="benchmarks run at a time (default 1, each alone; more shorten a smoke run, "
        "its timings then those of a shared machine)",
    )

    report = sub.add_parser(
        "report", help="score recorded sessions: an HTML page with plots, and the numbers"
    )
    report.add_argument("sessions", nargs="+", metavar="SESSION.tlap", help="recordings, in order")
    report.add_argument("--out", default="report.html", help="the HTML page to write")
    report.add_argument("--json", default=None, metavar="PATH", help="also write the numbers")

    sub.add_parser("list", help="list the built-in scenes")
    sub.add_parser("info", help="versions, backends and devices")
    return parser


def _load_scene(args):
    from taichi_lap import scene as scene_mod

    overrides = dict(scene_mod.parse_override(text) for text in args.set)
    return scene_mod.load(args.scene, overrides)


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
        if w < 16 or h < 16 or w > 8192 or h > 8192:
            raise ValueError
        return w, h
    except ValueError:
        raise InputError("--size", text, "WIDTHxHEIGHT between 16 and 8192 was expected") from None


def cmd_check(args) -> int:
    from taichi_lap.preprocess.cache import build_model
    from taichi_lap.stats import format_table, model_statistics

    scene = _load_scene(args)
    stats = model_statistics(
        build_model(scene, use_cache=not args.no_cache, progress=not args.json)
    )
    print(json.dumps(stats, indent=2) if args.json else format_table(stats))
    return 0


def cmd_list(args) -> int:
    from taichi_lap import scene as scene_mod

    for name in scene_mod.builtin_names():
        description = scene_mod.load(name).settings["description"]
        print(f"{name:<12} {description}")
    scripts = ", ".join(scene_mod.builtin_scripts())
    print(f"built-in scripts (--device script:NAME): {scripts}")
    return 0


def cmd_info(args) -> int:
    import ctypes.util
    import platform

    import numpy
    import taichi
    import trimesh

    import taichi_lap
    from taichi_lap.runtime import available_backends

    print(f"taichi-lap {taichi_lap.__version__}")
    print(f"python {platform.python_version()} ({platform.machine()}, {platform.system()})")
    print(
        f"taichi {'.'.join(map(str, taichi.__version__))}, numpy {numpy.__version__}, "
        f"trimesh {trimesh.__version__}"
    )
    print(f"backends: {', '.join(available_backends())}")
    print(f"display: {'yes' if has_display() else 'no (run falls back to headless)'}")
    print(f"OpenHaptics libHD: {ctypes.util.find_library('HD') or 'not found'}")
    return 0


def has_display() -> bool:
    """Whether a window can be opened (Linux needs X11 or Wayland)."""
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def _device(args, scene, headless: bool):
    """The device of ``--device``, or a :class:`DeviceSet` when it is given more than
    once. A mouse or openhaptics device drives the tool whose ``device`` key names it,
    else the first tool no other device drives."""
    from taichi_lap.devices import DeviceSet

    choices = args.device or ["auto"]
    if len(choices) == 1:
        return _one_device(choices[0], scene, headless, set())
    for choice in choices:
        if choice.startswith("replay:") or choice in ("auto", "none"):
            raise InputError(
                "--device",
                choice,
                "devices that can share the scene (mouse, "
                "openhaptics[:NAME], script:PATH) were expected "
                "when --device is given more than once",
            )
    devices, taken = [], set()
    for choice in choices:
        devices.append(_one_device(choice, scene, headless, taken))
    return DeviceSet(devices)


def _one_device(choice: str, scene, headless: bool, taken: set[int]):
    """One device; a mouse or haptic device drives a tool not in ``taken`` (then added)."""
    from taichi_lap.devices import MouseDevice, ScriptedDevice
    from taichi_lap.replay import ReplayDevice, read_recording
    from taichi_lap.scene import resolve_script
    from taichi_lap.session import scene_script

    if choice == "auto":
        choice = "scene" if headless else "mouse"
    if choice.startswith("script:"):
        return ScriptedDevice.from_file(resolve_script(choice[len("script:") :]), scene.tools)
    if choice.startswith("replay:"):
        recording = read_recording(choice[len("replay:") :], ticks=False)
        recording.check_scene(scene)
        return ReplayDevice(recording)
    if choice == "scene":
        return scene_script(scene)
    if choice == "mouse":
        if headless:
            raise InputError(
                "--device", choice, "a device that works headless (none, script:PATH) was expected"
            )
        return MouseDevice(_tool_for(choice, scene, taken)) if scene.tools else None
    if choice == "openhaptics" or choice.startswith("openhaptics:"):
        from taichi_lap.haptics.bridge import openhaptics_bridge

        return openhaptics_bridge(
            _tool_for(choice, scene, taken),
            choice.partition(":")[2] or None,
            os.environ.get("TAICHI_LAP_LIBHD"),
        )
    if choice == "none":
        return None
    raise InputError(
        "--device",
        choice,
        "mouse, none, openhaptics[:NAME], script:PATH or replay:PATH was expected",
    )


def _tool_for(choice: str, scene, taken: set[int]) -> dict:
    """The tool a mouse or haptic device drives: the one whose ``device`` key is
    ``choice``, else the first one free of both ``taken`` and a ``device`` key."""
    tools = scene.tools
    bound = [k for k, tool in enumerate(tools) if tool["device"] == choice and k not in taken]
    free = [k for k, tool in enumerate(tools) if not tool["device"] and k not in taken]
    if not bound and not free:
        raise InputError(
            scene.source,
            "tools",
            f"a tool for --device {choice} was expected "
            f"(one whose device is {choice!r} or one with no "
            f"device), the scene has {len(tools)} and other "
            f"devices drive {len(taken)}",
        )
    index = (bound or free)[0]
    taken.add(index)
    return tools[index]


def _replay_settings(args, recording):
    """A replay runs the recorded number of frames, on the recorded backend and CPU
    thread count, unless the command line says otherwise."""
    from taichi_lap.runtime import available_backends

    recorded = len(recording.frames)
    if args.frames is None:
        args.frames = recorded
    elif args.frames > recorded:
        raise InputError(
            "--frames",
            str(args.frames),
            f"at most {recorded} (the frames in {recording.path}) was expected",
        )
    if args.arch == "auto" and recording.start["arch"] in available_backends():
        args.arch = recording.start["arch"]
    if args.threads is None:
        args.threads = recording.start["threads"]


HEADLESS_FRAMES = 120
"""Frames a headless run without a scene script writes unless told (--frames)."""
SCRIPT_TAIL = 0.5
"""Seconds a headless run of a scene script goes on after its last keyframe."""


def _headless_frames(device, scene) -> int:
    """Frames of a headless run without --frames: a scene script's run to its end
    (SCRIPT_TAIL after its last keyframe), else HEADLESS_FRAMES."""
    from taichi_lap.devices import ScriptedDevice

    if not isinstance(device, ScriptedDevice):
        return HEADLESS_FRAMES
    return max(HEADLESS_FRAMES, math.ceil((device.duration() + SCRIPT_TAIL) / scene.settings["dt"]))


def new_session_path(folder: str | None, scene: str) -> str:
    """A new file for a window's session: ``<scene>-<local date and time>.tlap`` in
    ``folder`` (default ``$TAICHI_LAP_SESSIONS``, else ``~/taichi-lap-sessions``),
    numbered when that name is taken."""
    import datetime
    from pathlib import Path

    folder = Path(folder or os.environ.get("TAICHI_LAP_SESSIONS") or "~/taichi-lap-sessions")
    stem = f"{scene}-{datetime.datetime.now():%Y%m%d-%H%M%S}"
    path, number = folder.expanduser() / f"{stem}.tlap", 1
    while path.exists():
        number += 1
        path = path.with_name(f"{stem}-{number}.tlap")
    return str(path)


def cmd_run(args) -> int:
    from taichi_lap import app, runtime
    from taichi_lap.recording import existing_file_error
    from taichi_lap.replay import ReplayDevice

    if args.frames is not None and args.frames < 0:
        raise InputError("--frames", str(args.frames), "a non-negative number was expected")
    if args.record is not None and os.path.lexists(args.record):
        raise existing_file_error("--record", args.record)
    headless = args.headless
    if not headless and not has_display():
        print("no display found: running headless", file=sys.stderr)
        headless = True
    scene = _load_scene(args)
    size = _size(args.size)
    device = _device(args, scene, headless)
    replay = device.recording if isinstance(device, ReplayDevice) else None
    if not headless and replay is None and args.record is None and not args.no_record:
        args.record = new_session_path(args.sessions, scene.settings["name"])
        print(f"recording to {args.record}", file=sys.stderr)
    if replay is not None:
        _replay_settings(args, replay)
    if headless and args.frames is None:
        args.frames = _headless_frames(device, scene)
    runtime.init(args.arch, threads=args.threads, random_seed=scene.settings["seed"])
    if headless:
        out = args.out or f"{scene.settings['name']}.mp4"
        session = app.run_headless(
            scene,
            device,
            frames=args.frames,
            out=out,
            size=size,
            use_cache=not args.no_cache,
            record=args.record,
            check_topology=args.check_topology,
        )
        print(f"wrote {out}")
    else:
        session = app.run_window(
            scene,
            device,
            frames=args.frames,
            size=size,
            use_cache=not args.no_cache,
            record=args.record,
            check_topology=args.check_topology,
        )
    if args.record is not None:
        print(f"recorded {args.record}")
    status = 0
    if replay is not None:
        matches, report = replay.compare_final_state(session.state)
        print(report if matches else f"error: {report}", file=sys.stdout if matches else sys.stderr)
        status = 0 if matches else 1
    session.close()  # kept for a next run of the scene in this process (Session.close)
    return status


def cmd_render(args) -> int:
    from taichi_lap import app, runtime

    if not args.out.lower().endswith(".png"):
        raise InputError("--out", args.out, "a .png file was expected")
    scene = _load_scene(args)
    runtime.init(args.arch, random_seed=scene.settings["seed"])
    app.render_still(
        scene, frames=args.frames, out=args.out, size=_size(args.size), use_cache=not args.no_cache
    )
    print(f"wrote {args.out}")
    return 0


def cmd_bench(args) -> int:
    from pathlib import Path

    from taichi_lap import bench
    from taichi_lap.perf import BENCHMARKS

    arches = bench.parse_list("--arch", args.arch, bench.ARCHES)
    chosen = bench.parse_list("--only", args.only, BENCHMARKS) if args.only else BENCHMARKS
    if args.jobs < 1:
        raise InputError("--jobs", str(args.jobs), "a whole number of 1 or more was expected")
    out = Path(args.out)
    status = bench.run_benchmarks(arches, out, quick=args.quick, benchmarks=chosen, jobs=args.jobs)
    print(f"wrote {bench.write_summary(out, arches, status, args.jobs)}")
    failed = [
        f"{arch} {name}: {text}"
        for arch, per_benchmark in status.items()
        for name, text in per_benchmark.items()
        if text.startswith("failed")
    ]
    for line in failed:
        print(f"error: {line}", file=sys.stderr)
    return 1 if failed else 0


def cmd_report(args) -> int:
    from taichi_lap.training.report import write_report

    numbers = write_report(args.sessions, args.out, args.json)
    for session in numbers["sessions"]:
        mark = "" if session["complete"] else f" ({session['status']})"
        print(f"{session['path']}: {session['frames']} frames, {session['duration']:.2f} s{mark}")
    print(f"wrote {args.out}" + (f" and {args.json}" if args.json else ""))
    return 0


COMMANDS = {
    "run": cmd_run,
    "render": cmd_render,
    "check": cmd_check,
    "list": cmd_list,
    "info": cmd_info,
    "bench": cmd_bench,
    "report": cmd_report,
}


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING, format="%(levelname)s: %(message)s"
    )
    try:
        return COMMANDS[args.command](args)
    except InputError as exc:
        print(f"error: {exc.one_line()}", file=sys.stderr)
        return 2
    except SimulationFault as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
