"""``taichi-lap bench``: every benchmark of :mod:`taichi_lap.perf` for each backend
asked, each in a process of its own (one Taichi backend per process), then one
``summary.md`` over all of them: a table per benchmark, a column of medians per
backend and the ratio of each other backend to the CPU, with a bar chart of the
timings (``summary.png``), and how the cost of
each series of sizes grows with the particles (a table, and ``scaling.png``).

Layout of ``out``: ``<arch>/bench_<name>.json`` (the format every benchmark writes,
docs/architecture.md), ``<arch>/bench_<name>.log`` (what it printed), ``summary.md``,
``summary.png``, ``scaling.png``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from taichi_lap import plots
from taichi_lap.core.errors import InputError
from taichi_lap.core.files import write_atomically
from taichi_lap.perf import BENCHMARKS

ARCHES = ("cpu", "cuda", "vulkan", "metal")


def parse_list(option: str, text: str, choices: tuple[str, ...]) -> list[str]:
    """A comma-separated list of ``choices`` (``option`` names it in errors)."""
    names = [name.strip() for name in text.split(",") if name.strip()]
    unknown = [name for name in names if name not in choices]
    if not names or unknown:
        raise InputError(
            option, text, f"a comma-separated list of {', '.join(choices)} was expected"
        )
    return list(dict.fromkeys(names))


def run_benchmarks(
    arches: list[str], out: Path, *, quick: bool = False, benchmarks=BENCHMARKS, jobs: int = 1
) -> dict[str, dict[str, str]]:
    """Run ``benchmarks`` on each of ``arches`` into ``out``, ``jobs`` processes at a
    time (1: each alone, as timings should be; more shorten a smoke run, whose
    timings are then those of a shared machine); per backend, per benchmark: ``ok``,
    ``failed (exit N, see LOG)`` or ``backend not available``."""
    from concurrent.futures import ThreadPoolExecutor

    from tqdm import tqdm

    from taichi_lap import runtime

    available = runtime.available_backends()
    status: dict[str, dict[str, str]] = {}
    runnable = [arch for arch in arches if arch in available]
    for arch in arches:
        if arch not in available:
            status[arch] = {name: "backend not available" for name in benchmarks}
            print(f"{arch}: not available on this machine, skipped", flush=True)
    bar = tqdm(total=len(runnable) * len(benchmarks), unit="benchmark")

    def run(arch: str, name: str):
        bar.set_description(f"{arch} {name}")
        log = out / arch / f"bench_{name}.log"
        command = [
            sys.executable,
            "-m",
            f"taichi_lap.perf.bench_{name}",
            "--arch",
            arch,
            "--json",
            str(out / arch / f"bench_{name}.json"),
        ]
        with open(log, "w") as stream:
            code = subprocess.run(
                command + (["--quick"] if quick else []),
                stdout=stream,
                stderr=subprocess.STDOUT,
                env=dict(os.environ, ENABLE_TAICHI_HEADER_PRINT="false"),
            ).returncode
        status[arch][name] = "ok" if code == 0 else f"failed (exit {code}, see {log})"
        bar.update()

    for arch in runnable:
        status[arch] = {}
        (out / arch).mkdir(parents=True, exist_ok=True)
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        runs = [pool.submit(run, arch, name) for arch in runnable for name in benchmarks]
        for done in runs:
            done.result()
    bar.close()
    for arch in runnable:  # in the order asked, whichever finished first
        status[arch] = {name: status[arch][name] for name in benchmarks}
    return status


def load_results(out: Path, arches: list[str], benchmarks=BENCHMARKS) -> dict:
    """``{benchmark: {arch: json}}`` of the files in ``out`` (missing ones left out)."""
    found: dict[str, dict[str, dict]] = {}
    for name in benchmarks:
        for arch in arches:
            path = out / arch / f"bench_{name}.json"
            if path.is_file():
                found.setdefault(name, {})[arch] = json.loads(path.read_text())
    return found


def _params_text(params: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in sorted(params.items()))


def comparison(per_arch: dict[str, dict]) -> tuple[list[str], list[tuple]]:
    """The backends of one benchmark and its rows: (case, metric, params, {arch:
    median}); a row is one case, metric and parameter set, in first-seen order."""
    arches = list(per_arch)
    rows: dict[tuple, tuple[dict, dict[str, float]]] = {}
    for arch, data in per_arch.items():
        for result in data["results"]:
            key = result["case"], result["metric"], _params_text(result["params"])
            rows.setdefault(key, (result["params"], {}))[1][arch] = result["median"]
    return arches, [
        (case, metric, params, medians) for (case, metric, _), (params, medians) in rows.items()
    ]


def _labels(rows: list[tuple]) -> list[str]:
    """``case metric`` per row, with the parameters that tell apart rows of the same
    case and metric (solver, iterations, ...)."""
    groups: dict[tuple[str, str], list[dict]] = {}
    for case, metric, params, _ in rows:
        groups.setdefault((case, metric), []).append(params)
    labels = []
    for case, metric, params, _ in rows:
        group = groups[case, metric]
        differ = {k: v for k, v in params.items() if any(p.get(k) != v for p in group)}
        labels.append(f"{case} {metric}" + (f" ({_params_text(differ)})" if differ else ""))
    return labels


def _number(value: float | None) -> str:
    return "—" if value is None else f"{value:.4g}"


def summary_markdown(results: dict, status: dict[str, dict[str, str]], jobs: int = 1) -> str:
    """``summary.md``: the machine, then per benchmark a table of medians per backend
    and each GPU backend's ratio to the CPU's (below 1: faster, for timings); says
    when the benchmarks ran ``jobs`` at a time."""
    lines = ["# Benchmark summary", ""]
    for arch, per_benchmark in status.items():
        notes = sorted({text for text in per_benchmark.values() if text != "ok"})
        lines.append(f"- {arch}: " + ("all ran" if not notes else "; ".join(notes)))
    if jobs > 1:
        lines.append(
            f"- {jobs} benchmarks ran at a time: their timings are those of a shared machine"
        )
    for name, per_arch in results.items():
        arches, rows = comparison(per_arch)
        machine = next(iter(per_arch.values()))["machine"]
        gpus = {arch: data["machine"].get("gpu") for arch, data in per_arch.items()}
        gpu_text = "; ".join(f"{arch}: {gpu}" for arch, gpu in gpus.items() if gpu)
        lines += [
            "",
            f"## {name}",
            "",
            f"{machine['cpu']}, {machine['cores']} cores"
            + (f"; GPU {gpu_text}" if gpu_text else ""),
            "",
        ]
        ratios = [arch for arch in arches if arch != "cpu" and "cpu" in arches]
        header = ["case", "metric", *arches, *(f"{arch}/cpu" for arch in ratios), "params"]
        lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        for case, metric, params, medians in rows:
            cells = [case, metric, *(_number(medians.get(arch)) for arch in arches)]
            for arch in ratios:
                cpu, other = medians.get("cpu"), medians.get(arch)
                cells.append(_number(other / cpu) if cpu and other is not None else "—")
            lines.append("| " + " | ".join([*cells, _params_text(params)]) + " |")
    return "\n".join(lines) + "\n"


def timing_rows(results: dict) -> dict[str, list[tuple[str, dict[str, float]]]]:
    """Per benchmark, the rows whose metric is a time (``ms`` or ``seconds``), as
    (label, {arch: median}): what the bar chart draws."""
    out = {}
    for name, per_arch in results.items():
        _, rows = comparison(per_arch)
        timed = [
            (label, medians)
            for label, (_, metric, _, medians) in zip(_labels(rows), rows)
            if "ms" in metric or metric in ("seconds", "tick_compute_us")
        ]
        if timed:
            out[name] = timed
    return out


def scaling_series(results: dict) -> dict[str, dict[str, list[tuple[int, float]]]]:
    """The rows that belong to a ``series`` (one computation at several sizes), as
    ``{"<benchmark>: <series> <metric>": {arch: [(particles, median), ...]}}``, sorted
    by particles; series of a single size are left out."""
    out: dict[str, dict[str, list[tuple[int, float]]]] = {}
    for name, per_arch in results.items():
        for arch, data in per_arch.items():
            for row in data["results"]:
                if "series" in row and "particles" in row["params"]:
                    key = f"{name}: {row['series']} {row['metric']}"
                    points = out.setdefault(key, {}).setdefault(arch, [])
                    points.append((int(row["params"]["particles"]), float(row["median"])))
    for per_arch in out.values():
        for points in per_arch.values():
            points.sort()
    return {
        key: per_arch
        for key, per_arch in out.items()
        if any(len({n for n, _ in points}) > 1 for points in per_arch.values())
    }


def scaling_markdown(series: dict) -> list[str]:
    """``summary.md``'s section on how cost grows: per series, the median at each size
    and backend, and the growth from the smallest size to the largest against the
    growth of the particle count."""
    if not series:
        return []
    lines = ["", "## How cost grows with size", ""]
    lines += ["| series | backend | particles: median | growth (cost / particles) |"]
    lines += ["|---|---|---|---|"]
    for key, per_arch in series.items():
        for arch, points in per_arch.items():
            sizes = ", ".join(f"{n}: {_number(median)}" for n, median in points)
            (n0, m0), (n1, m1) = points[0], points[-1]
            grew = n1 > n0 > 0 and m0 > 0
            growth = f"{_number(m1 / m0)} / {_number(n1 / n0)}" if grew else "—"
            lines.append(f"| {key} | {arch} | {sizes} | {growth} |")
    return lines


def scaling_chart(series: dict, path: Path) -> bool:
    """Cost against particles (log-log), a panel per series, a line per backend, into
    ``path``; False without a series."""
    if not series:
        return False
    fig, axes = plots.figure(len(series), 1, size=(6, 2.6 * len(series)))
    for ax, (key, per_arch) in zip(axes[:, 0], series.items()):
        for arch, points in per_arch.items():
            ax.loglog(*zip(*points), marker="o", label=arch)
        ax.set_title(key, fontsize=9)
        ax.set_xlabel("particles", fontsize=8)
        ax.set_ylabel("median", fontsize=8)
        ax.legend(fontsize=7)
    plots.save_png(fig, path)
    return True


def bar_chart(results: dict, path: Path) -> bool:
    """Grouped bars of the timings per benchmark, one colour per backend, into
    ``path``; False without a timing."""
    panels = timing_rows(results)
    if not panels:
        return False
    fig, axes = plots.figure(
        len(panels), 1, size=(10, 2.0 + 0.9 * sum(min(len(r), 16) for r in panels.values()))
    )
    for ax, (name, rows) in zip(axes[:, 0], panels.items()):
        rows = rows[:16]  # the first cases of a long benchmark
        arches = sorted({arch for _, medians in rows for arch in medians}, key=ARCHES.index)
        height = 0.8 / len(arches)
        for k, arch in enumerate(arches):
            ax.barh(
                [i + k * height for i in range(len(rows))],
                [medians.get(arch, 0.0) for _, medians in rows],
                height=height,
                label=arch,
            )
        ax.set_yticks([i + 0.4 - height / 2 for i in range(len(rows))])
        ax.set_yticklabels([label for label, _ in rows], fontsize=7)
        ax.set_xscale("log")
        ax.set_title(f"{name} (median; log scale, each row in its own unit)", fontsize=9)
        ax.legend(fontsize=7)
    plots.save_png(fig, path)
    return True


def write_summary(
    out: Path, arches: list[str], status: dict[str, dict[str, str]], jobs: int = 1
) -> Path:
    """``summary.md`` (written atomically), ``summary.png`` and ``scaling.png`` of what
    ``out`` holds (run ``jobs`` benchmarks at a time)."""
    results = load_results(out, arches)
    series = scaling_series(results)
    growth = "".join(line + "\n" for line in scaling_markdown(series))
    text = summary_markdown(results, status, jobs) + growth
    path = write_atomically(out / "summary.md", text)
    bar_chart(results, out / "summary.png")
    scaling_chart(series, out / "scaling.png")
    return path
