"""Benchmark scripts' outputs from given results (no benchmark runs here)."""

import importlib.util
from pathlib import Path

import imageio.v3 as iio

PERF = Path(__file__).resolve().parent.parent / "perf"


def load_script(name: str):
    spec = importlib.util.spec_from_file_location(f"perf_{name}", PERF / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_circumsphere_box_plot_is_written_as_a_png(tmp_path):
    bench = load_script("bench_circumsphere")
    rows = [
        {
            "case": "cylinder",
            "metric": "rel_error",
            "median": 0.1 * iterations,
            "q1": 0.0,
            "q3": 0.2 * iterations,
            "min": -0.1,
            "max": 0.5 * iterations,
            "params": {"method": method, "iterations": iterations},
        }
        for method in bench.METHODS
        for iterations in (1, 4)
    ]
    bench.box_plot(rows, tmp_path / "plot.png")
    image = iio.imread(tmp_path / "plot.png")
    assert image.shape[:2] == (540, 1200)  # 10 x 4.5 inches at 120 dpi
    assert image.std() > 10  # boxes, axes and labels drawn, not an empty canvas
    assert [p.name for p in tmp_path.iterdir()] == ["plot.png"]  # no temporary file left
