"""Benchmark scripts without their optional extras (no benchmark runs here)."""

import importlib.util
import sys
from pathlib import Path

PERF = Path(__file__).resolve().parent.parent / "perf"


def load_script(name: str):
    spec = importlib.util.spec_from_file_location(f"perf_{name}", PERF / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_circumsphere_plot_without_matplotlib_says_which_extra_gives_it(
    tmp_path, monkeypatch, capsys
):
    bench = load_script("bench_circumsphere")
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib fails
    rows = [
        {
            "case": "cylinder",
            "metric": "rel_error",
            "median": 0.0,
            "q1": 0.0,
            "q3": 0.0,
            "min": 0.0,
            "max": 0.0,
            "params": {"method": "circumsphere", "iterations": 1},
        }
    ]
    assert bench.box_plot(rows, tmp_path / "plot.png") is False
    assert "pip install 'taichi-lap[perf]'" in capsys.readouterr().out
    assert not (tmp_path / "plot.png").exists()
