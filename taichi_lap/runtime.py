"""Backend selection: one ``init`` for the whole process.

``auto`` tries CUDA, then Metal, then the CPU, and logs which one it got. Vulkan
is used only when asked for: on a machine without a GPU it is a software driver,
several times slower than the CPU backend. Physics kernels use f32 and i32; the
rasterizer's depth|triangle keys are i64 (``atomic_min``), which Vulkan supports.
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import time
from pathlib import Path

import taichi as ti
from taichi.lang import impl

from taichi_lap.kernels.scatter import serial_on_cpu

log = logging.getLogger("taichi_lap")

ARCH_CHOICES = ("auto", "cpu", "cuda", "vulkan", "metal")
_AUTO_ORDER = ("cuda", "metal", "cpu")

_current_arch: str | None = None

STALE_LOCK_SECONDS = 600.0
"""Age [s] past which Taichi's offline-cache lock is taken for one a killed process
left behind (Taichi holds it for the seconds a load or save of the cache takes)."""


def clear_stale_cache_lock() -> Path | None:
    """Remove Taichi's offline-cache lock (``ticache.lock`` in the cache folder,
    ``$TI_OFFLINE_CACHE_FILE_PATH`` or Taichi's default) when it is older than
    :data:`STALE_LOCK_SECONDS`, and return its path. A process killed while it held
    the lock leaves the file behind; every later process then neither loads nor saves
    compiled kernels (Taichi only warns), so each start compiles every kernel again (a
    rectum session's start and first frames took 18.1 s instead of 8.7 s)."""
    folder = (
        os.environ.get("TI_OFFLINE_CACHE_FILE_PATH") or impl.default_cfg().offline_cache_file_path
    )
    lock = Path(folder) / "ticache.lock"
    try:
        age = time.time() - lock.stat().st_mtime
    except FileNotFoundError:
        return None
    if age <= STALE_LOCK_SECONDS:
        return None
    lock.unlink(missing_ok=True)
    log.warning("removed a stale Taichi cache lock, %.0f min old: %s", age / 60, lock)
    return lock


def _source_line_position(self, node) -> str:
    """Where ``node`` of a kernel being compiled is: file, line, function and the
    source line (Taichi's own text adds a caret line wrapped to 80 columns)."""
    line = node.lineno + self.lineno_offset
    return (
        f'File "{self.file}", line {line}, in {self.func.func.__name__}:\n'
        f"{self.src[node.lineno - 1]}\n"
    )


def _shorten_source_positions():
    """Taichi's front end formats the position of every statement and expression it
    compiles (for a compile error's message) with ``textwrap`` and a caret line,
    eagerly: a quarter of the front end's time. Outside ``debug`` it gets the file,
    line and source line alone (a liver session's start with warm caches: 8.1 s to
    6.2 s; the rectum's volume-cut test: 48.2 s to 44.5 s with an empty kernel cache)."""
    from taichi.lang.ast import ast_transformer_utils

    ast_transformer_utils.ASTTransformerContext.get_pos_info = _source_line_position


def _is_supported(arch_name: str) -> bool:
    arch = getattr(ti, arch_name, None)
    return arch is not None and bool(ti.lang.misc.is_arch_supported(arch))


def init(
    arch: str = "auto", *, debug: bool = False, threads: int | None = None, random_seed: int = 0
) -> str:
    """Initialise Taichi once and return the backend name actually used.

    ``arch`` is one of ``auto``, ``cpu``, ``cuda``, ``vulkan``, ``metal``.
    ``threads`` fixes the CPU thread count (for bit-identical runs). Calling it
    again with the same arch is a no-op; with another arch it re-initialises.
    """
    global _current_arch
    if arch not in ARCH_CHOICES:
        raise ValueError(f"arch must be one of {', '.join(ARCH_CHOICES)}, got {arch!r}")
    if _current_arch is not None and arch in (_current_arch, "auto"):
        return _current_arch
    kwargs = dict(
        default_fp=ti.f32,
        default_ip=ti.i32,
        debug=debug,
        random_seed=random_seed,
        offline_cache=True,
        log_level=os.environ.get("TAICHI_LAP_TI_LOG", "warn"),
    )
    if threads:
        kwargs["cpu_max_num_threads"] = int(threads)
    if arch == "auto":
        name = next(n for n in _AUTO_ORDER if _is_supported(n))
    elif not _is_supported(arch):
        raise RuntimeError(f"backend {arch!r} is not available on this machine")
    else:
        name = arch
    # Taichi's own IR optimisations (CSE, store forwarding, ...) took most of the
    # compile time and gained nothing at run time: the backend's compiler optimises
    # the kernels after them. The rectum at detail 0.03 compiled in 10 s instead of
    # 34 s on the CPU and stepped as fast (the intestine 15 % faster); on Vulkan (Mesa's
    # software driver) in 17 s instead of 44 s, as fast. Other backends keep them
    # until measured.
    kwargs["advanced_optimization"] = name not in ("cpu", "vulkan")
    # CUDA's fast math (approximate division, square root and transcendentals) put the
    # GGX normalisation integral 0.9 % off at roughness 0.05 and a grasp 2.25 mm from
    # the CPU's on an H100; without it both agreed with the CPU. Its cost is unmeasured.
    if name == "cuda":
        kwargs["fast_math"] = False
    if not debug:
        _shorten_source_positions()
    clear_stale_cache_lock()
    with contextlib.redirect_stdout(io.StringIO()):  # "[Taichi] Starting on arch=..."
        ti.init(arch=getattr(ti, name), **kwargs)
    _current_arch = name
    log.info("taichi backend: %s", name)
    return name


def current_arch() -> str | None:
    """The backend chosen by :func:`init`, or ``None`` before it was called."""
    return _current_arch


SERIAL_BELOW = 100_000
"""Models of fewer particles run their per-step loops on one thread on the CPU backend
(:func:`serial_loops`). Handing a parallel loop to Taichi's CPU thread pool cost 60-100
µs on a 2-core Intel Xeon virtual machine whatever its size (waking the pool's
threads), and a frame launches about 180 such loops: the rectum's physics (7,162
particles) took 37 ms a frame with them and 30 ms serial, the intestine's (400) 23.6
and 9.1 ms, the liver's at detail 0.3 (55,134) 34.4 and 31.4 ms, and the full liver
(172,853) 71 ms parallel against 81 ms serial."""


SWEEP_SERIAL_BELOW = 120_000
"""A serial model's Jacobi sweeps run serially only below this many list entries
(twice the distance constraints, plus the LRAs): each sweep does enough arithmetic
that two threads pay. Fascia-128 (161,796 distance entries) stepped with 10
iterations in 11.4 ms parallel against 12.4 ms serial, the rectum's physics (78,394)
in 33.8 ms against 30.5 ms."""


def serial_loops(count: int) -> bool:
    """Whether a model of ``count`` particles runs its per-step loops serially
    (``ti.loop_config(serialize=...)``): on the CPU backends below
    :data:`SERIAL_BELOW`; never on a GPU (a serial loop runs on one GPU thread)."""
    return serial_on_cpu() and count < SERIAL_BELOW


def available_backends() -> list[str]:
    """Backends this Taichi build can start here (OpenGL is not probed: its probe
    crashes the process on machines without a display)."""
    return [name for name in ("cpu", "cuda", "vulkan", "metal") if _is_supported(name)]


def kernel_compilations() -> int:
    """Kernel instances Taichi has compiled in this process: each kernel once per
    distinct object or field it is given as a template argument."""
    return impl.get_runtime().get_num_compiled_functions()


SNODE_TREE_LIMIT = 512
"""The SNode trees a Taichi program can hold (its LLVM runtime's table of tree roots:
a CPU process that built 560 trees crashed, one of 506 did not)."""


def snode_trees() -> int:
    """The SNode tree ids the Taichi program has handed out: the trees alive and those
    freed (Taichi gives a freed id to the next tree before a new one), and the one its
    root tree (fields made outside groups) will take at the next launch: at the first
    launch, or when fields were made outside groups since the last."""
    program, root = impl.get_runtime(), impl.root
    root_to_come = not program.materialized or not (root.finalized or root.empty)
    return program.prog.get_snode_tree_size() + int(root_to_come)
