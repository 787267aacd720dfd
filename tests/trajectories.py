"""Reference trajectories: the state-regression guard for restructuring.

Each built-in scene runs at a small detail with its own tool scripts (settled start,
its collision settings); the particle positions at chosen frames are stored,
compressed, in ``tests/reference/<scene>.npz``. :mod:`tests.test_trajectories`
replays the same runs and compares position by position with a per-scene tolerance,
on the CPU backend and, in a child process, on Vulkan.

Regenerate them deliberately, after a change that is meant to change the simulation
(and say so in the commit message):

    python -m tests.trajectories            # rewrite every scene's reference
    python -m tests.trajectories rectum     # only one scene
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REFERENCE_DIR = Path(__file__).resolve().parent / "reference"


@dataclass(frozen=True)
class Run:
    """How one scene is run for its reference: ``overrides`` (``--set`` values), the
    ``frames`` at which positions are kept (the last one ends the run) and the largest
    position difference [m] tolerated at them, on the CPU backend (``tolerance``) and on
    Vulkan (``vulkan_tolerance``, default the same).

    Runs are bit-identical on one backend whatever the thread count, but contact and
    collision decisions amplify differences of rounding: a start perturbed by 1e-9 m
    (about one ulp) ends 5 cm away in the liver after the tool pressed for 0.2 s, 1.5
    mm away in the rectum from frame 14 on (tissue-tissue contacts), and 7 mm away in
    the intestine after one frame of its stochastic self-collision. Each run stops
    before that: at its last frame the perturbed run stays within a tenth of the
    tolerance, so another machine's rounding (or Vulkan's) passes and a change of the
    simulation does not. Vulkan, and another CPU, round differently in every
    operation, not once: the rectum's settled start differs by 4e-6 m and frame 13 by
    0.9 mm there, so the rectum is held to 2 mm.

    ``vulkan_frames`` (default all of ``frames``): the stored frames the Vulkan run
    compares, ending it; on Mesa's software driver a liver frame takes 2 to 8 s (the broad phase
    relists its pairs every substep while the liver settles), 50 to 300 times a CPU
    frame."""

    overrides: tuple[str, ...]
    frames: tuple[int, ...]
    tolerance: float = 1e-4
    vulkan_tolerance: float | None = None
    vulkan_frames: tuple[int, ...] | None = None


RUNS = {
    # the hook (not energised) touches the liver's top at frame 28 (the scene's own
    # script would cut); the perturbed run is 1.1e-5 m away there (its thin wire
    # makes contact more sensitive than the probe's shaft did: 4.6e-5 m at frame 33).
    # Vulkan stops at frame 1, the settled start and its first frame of tissue collision
    # (the rectum's grasper covers tool contact there; each further frame on Mesa's
    # software driver cost seconds)
    "liver": Run(
        (
            "scene.detail=0.1",
            "scene.settle_time=0.5",
            "tools.hook.script=[{time = 0.0, tip = [0.03, 0.06, 0.03]}, "
            "{time = 0.6, tip = [0.03, 0.021, 0.03]}]",
        ),
        (1, 16, 28),
        vulkan_frames=(1,),
    ),
    # wall, polyp, fascia, gland and vessel settle and touch; the grasper descends.
    # Another CPU's rounding moves it as far as Vulkan's: a reference made on an AMD
    # EPYC and a run on an Intel Xeon differed by 4e-6 m at frame 1 (the settled start),
    # 0.58 mm at frame 7 and 0.86 mm at frame 13, so one tolerance serves both (the
    # reference now is an Intel Xeon's, made when the vessel and gland got reserve rows)
    # Vulkan stops at frame 7 (each further frame on Mesa's software driver costs
    # seconds of CI; frames 8-13, more of the grasper's descent, the CPU run covers)
    "rectum": Run(
        ("scene.detail=0.3", "scene.settle_time=0.25"),
        (1, 7, 13),
        tolerance=2e-3,
        vulkan_frames=(1, 7),
    ),
    # springs, tool and planes without the stochastic self-collision (its tests compare
    # it with the exact detector); the perturbed run is 1e-5 m away at frame 20.
    # Vulkan stops at frame 10 (frames 11-20 on Mesa's software driver cost CI seconds
    # each; the CPU run covers them)
    "intestine": Run(("scene.self_collision=false",), (1, 10, 20), vulkan_frames=(1, 10)),
}


def run_scene(name: str, frames: tuple[int, ...] | None = None) -> dict[str, np.ndarray]:
    """Positions ``x`` (N, 3) [m] of scene ``name`` at each of ``frames`` (default:
    those of its :data:`RUNS` entry), keyed ``frame_<k>``; Taichi must already be
    initialised."""
    from taichi_lap import scene as scenes
    from taichi_lap.session import Session, scene_script

    run = RUNS[name]
    frames = frames or run.frames
    scene = scenes.load(name, dict(scenes.parse_override(text) for text in run.overrides))
    session = Session(scene, use_cache=False, progress=False)
    device = scene_script(scene)
    out = {}
    for frame in range(1, frames[-1] + 1):
        time = session.state.time
        session.step(device.poses(time), device.buttons(time))
        if frame in frames:
            out[f"frame_{frame}"] = session.state.positions()
    return out


def reference_path(name: str) -> Path:
    return REFERENCE_DIR / f"{name}.npz"


def load_reference(name: str) -> dict[str, np.ndarray]:
    with np.load(reference_path(name)) as data:
        return {key: data[key] for key in data.files}


def max_difference(reference: dict[str, np.ndarray], result: dict[str, np.ndarray]) -> dict:
    """Largest position difference [m] per frame of ``result`` (each one stored in
    ``reference``, of the same shape)."""
    out = {}
    for key, got in result.items():
        expected = reference[key]
        if got.shape != expected.shape:
            raise AssertionError(
                f"{key}: {got.shape[0]} particles, the reference has {expected.shape[0]}"
            )
        out[key] = float(np.abs(got.astype(np.float64) - expected).max())
    return out


def write(names: list[str]):
    """Run each scene on the CPU backend and store its reference."""
    from taichi_lap import runtime

    runtime.init("cpu", threads=2)
    REFERENCE_DIR.mkdir(exist_ok=True)
    for name in names:
        result = run_scene(name)
        np.savez_compressed(reference_path(name), **result)
        print(
            f"wrote {reference_path(name).relative_to(Path.cwd())}: "
            f"{len(result)} frames of {next(iter(result.values())).shape[0]} particles"
        )


if __name__ == "__main__":
    chosen = sys.argv[1:] or list(RUNS)
    unknown = [name for name in chosen if name not in RUNS]
    if unknown:
        sys.exit(f"unknown scene {', '.join(unknown)}; expected some of {', '.join(RUNS)}")
    write(chosen)
