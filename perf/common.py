"""Shared benchmark plumbing: machine description, timing, the results table and
the JSON file every ``perf/bench_*.py`` writes (format in docs/architecture.md)."""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import time
from pathlib import Path

import numpy as np

from taichi_lap.core.files import write_atomically


def gpu() -> str | None:
    """The NVIDIA GPU and its driver (``nvidia-smi``), or None where there is none."""
    try:
        out = subprocess.run(
            ["nvidia-smi", "--query-gpu=name,driver_version", "--format=csv,noheader"],
            capture_output=True,
            text=True,
            timeout=20,
            check=True,
        ).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    lines = [line.strip() for line in out.splitlines() if line.strip()]
    if not lines:
        return None
    name, _, driver = lines[0].rpartition(",")
    return f"{name.strip()}, driver {driver.strip()}"


def machine(arch: str = "cpu") -> dict:
    """CPU model, core count and, for a GPU backend, the GPU and its driver."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "gpu": gpu() if arch != "cpu" else None}


def arguments(name: str, groups: tuple[str, ...] = ()) -> argparse.Namespace:
    """The options every benchmark takes; with ``groups`` (names of its groups of
    cases) also ``--cases``, a comma-separated choice of them (default: all)."""
    parser = argparse.ArgumentParser(description=f"{name} benchmark")
    if groups:
        parser.add_argument(
            "--cases",
            default=",".join(groups),
            type=lambda text: text.split(","),
            help=f"groups of cases to run, comma-separated, of: {', '.join(groups)}",
        )
    parser.add_argument("--quick", action="store_true", help="small sizes, under a minute")
    parser.add_argument("--arch", default="cpu", choices=("cpu", "cuda", "vulkan", "metal"))
    parser.add_argument("--json", default=f"perf/results/{name}.json", help="output file")
    parser.add_argument("--runs", type=int, default=None, help="timed runs per case")
    args = parser.parse_args()
    unknown = set(getattr(args, "cases", ())) - set(groups)
    if unknown:
        parser.error(f"--cases: unknown {', '.join(sorted(unknown))}; of {', '.join(groups)}")
    return args


def timed(func, runs: int, warmup: int = 2) -> list[float]:
    """Milliseconds of ``runs`` calls of ``func`` after ``warmup`` untimed calls."""
    for _ in range(warmup):
        func()
    samples = []
    for _ in range(runs):
        start = time.perf_counter()
        func()
        samples.append((time.perf_counter() - start) * 1e3)
    return samples


def result(
    case: str, params: dict, metric: str, samples: list[float], *, series: str | None = None
) -> dict:
    """One row of a benchmark's results: the median, p95, min and max of ``samples``.
    ``series`` names the cases that are one computation at several sizes (their
    ``params`` hold ``particles``): ``taichi-lap bench`` plots how their cost grows."""
    row = {
        "case": case,
        "params": params,
        "metric": metric,
        "median": statistics.median(samples),
        "p95": float(np.percentile(samples, 95)),
        "min": min(samples),
        "max": max(samples),
        "runs": len(samples),
    }
    if series is not None:
        row["series"] = series
    return row


def report(benchmark: str, arch: str, results: list[dict], path: str):
    """Print the table and write the JSON (atomically)."""
    import taichi

    width = max(len(r["case"]) for r in results) + 2
    host = machine(arch)
    gpu_text = f", GPU {host['gpu']}" if host["gpu"] else ""
    print(f"\n{benchmark} on {host['cpu']} ({host['cores']} cores{gpu_text}), backend {arch}")
    print(
        f"{'case':<{width}}{'metric':<22}{'median':>12}{'p95':>12}{'min':>12}{'max':>12}"
        f"{'runs':>6}  params"
    )
    for r in results:
        params = ", ".join(f"{k}={v}" for k, v in r["params"].items())
        print(
            f"{r['case']:<{width}}{r['metric']:<22}{r['median']:>12.4g}"
            f"{r.get('p95', r['median']):>12.4g}{r['min']:>12.4g}"
            f"{r['max']:>12.4g}{r['runs']:>6}  {params}"
        )
    out = {
        "benchmark": benchmark,
        "machine": host,
        "taichi": ".".join(map(str, taichi.__version__)),
        "arch": arch,
        "results": results,
    }
    print(f"wrote {write_atomically(path, json.dumps(out, indent=2))}")
