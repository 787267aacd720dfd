"""Run a test computation on another Taichi backend in a child process.

``run_on_arch("vulkan", "tests.test_x:compute", n=100)`` starts
``python -m tests.archrun``, which initialises Taichi on the backend, calls
``compute(n=100)`` and returns its ``dict`` of NumPy arrays. A backend that is not
available here makes the calling test skip with the reason.

The tests marked ``vulkan`` compare :data:`COMPARE_ARCH` with the CPU: Vulkan unless
``$TAICHI_LAP_COMPARE_ARCH`` names another backend (``cuda`` on a machine with an
NVIDIA GPU).
"""

from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent

COMPARE_ARCH = os.environ.get("TAICHI_LAP_COMPARE_ARCH", "vulkan")
"""The backend the ``vulkan``-marked tests compare with the CPU run."""


def run_on_arch(arch: str, target: str, **kwargs) -> dict[str, np.ndarray]:
    """Call ``target`` (``module:function``) on backend ``arch``; return its arrays."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "result.npz"
        env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        proc = subprocess.run(
            [sys.executable, "-m", "tests.archrun", arch, target, json.dumps(kwargs), str(out)],
            cwd=ROOT,
            env=env,
            capture_output=True,
            text=True,
            timeout=900,
        )
        if proc.returncode == 3:
            pytest.skip(f"backend {arch} is not available here: {proc.stderr.strip()[-300:]}")
        if proc.returncode != 0:
            raise AssertionError(f"{target} on {arch} failed:\n{proc.stderr[-4000:]}")
        with np.load(out) as data:
            return {key: data[key] for key in data.files}


_cpu_results: dict[tuple[str, str], dict[str, np.ndarray]] = {}


def cpu_result(target: str, **kwargs) -> dict[str, np.ndarray]:
    """``target`` (``module:function``) called here, on the CPU, once per test process
    for each ``kwargs``: a CPU test and the backend comparison of the same computation
    share one run (a file's tests run in one process, ``--dist loadfile``). Callers
    only read the arrays."""
    key = (target, json.dumps(kwargs, sort_keys=True))
    if key not in _cpu_results:
        module_name, func_name = target.split(":")
        _cpu_results[key] = getattr(importlib.import_module(module_name), func_name)(**kwargs)
    return _cpu_results[key]


def assert_backend_matches_cpu(
    target: str, tolerance: float, per_key: dict[str, float] | None = None, **kwargs
) -> dict[str, np.ndarray]:
    """Run ``target`` here (CPU) and on :data:`COMPARE_ARCH`; every array must agree
    within ``tolerance`` (max abs difference), or the tolerance ``per_key`` names for
    it. Returns the CPU arrays."""
    cpu = cpu_result(target, **kwargs)
    other = run_on_arch(COMPARE_ARCH, target, **kwargs)
    for key, value in cpu.items():
        difference = np.abs(np.asarray(value, dtype=np.float64) - other[key]).max()
        assert difference <= (per_key or {}).get(key, tolerance), (
            f"{target} {key}: CPU and {COMPARE_ARCH} differ by {difference}"
        )
    return cpu


def _main(argv: list[str]) -> int:
    arch, target, kwargs_json, out = argv
    from taichi_lap import runtime

    if arch not in runtime.available_backends():
        print(f"{arch} not supported by this Taichi build or driver", file=sys.stderr)
        return 3
    try:
        runtime.init(arch)
    except RuntimeError as exc:
        print(str(exc), file=sys.stderr)
        return 3
    module_name, func_name = target.split(":")
    func = getattr(importlib.import_module(module_name), func_name)
    result = func(**json.loads(kwargs_json))
    np.savez(out, **{key: np.asarray(val) for key, val in result.items()})
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
