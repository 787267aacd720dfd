"""``taichi-lap bench``: the summary across backends, the skipping of backends that
are not available, and one real (quick) benchmark run through the command line."""

import json

import imageio.v3 as iio

from taichi_lap import bench, runtime
from taichi_lap.cli import main


def write_result(folder, arch: str, name: str, rows: list[tuple], gpu=None):
    """A benchmark's JSON of ``rows`` (case, metric, params, median[, series])."""
    (folder / arch).mkdir(parents=True, exist_ok=True)
    results = [
        {"case": row[0], "metric": row[1], "params": row[2], "median": row[3]}
        | ({"series": row[4]} if len(row) > 4 else {})
        for row in rows
    ]
    data = {
        "benchmark": name,
        "machine": {"cpu": "Test CPU", "cores": 2, "gpu": gpu},
        "taichi": "1.7.4",
        "arch": arch,
        "results": results,
    }
    (folder / arch / f"bench_{name}.json").write_text(json.dumps(data))


def test_summary_has_a_column_per_backend_and_the_ratio_to_the_cpu(tmp_path):
    jacobi, gauss = {"solver": "jacobi"}, {"solver": "gauss_seidel"}
    write_result(
        tmp_path,
        "cpu",
        "deform",
        [("sheet", "ms_per_step", jacobi, 10.0), ("sheet", "ms_per_step", gauss, 20.0)],
    )
    write_result(
        tmp_path,
        "cuda",
        "deform",
        [("sheet", "ms_per_step", gauss, 5.0), ("big", "ms_per_step", {}, 1.0)],
        gpu="Test GPU, driver 1",
    )
    status = {
        "cpu": {"deform": "ok"},
        "cuda": {"deform": "ok"},
        "metal": {"deform": "backend not available"},
    }
    text = bench.write_summary(tmp_path, ["cpu", "cuda", "metal"], status).read_text()
    assert "at a time" not in text
    assert "- metal: backend not available" in text
    assert "GPU cuda: Test GPU, driver 1" in text
    assert "| case | metric | cpu | cuda | cuda/cpu | params |" in text
    assert "| sheet | ms_per_step | 20 | 5 | 0.25 | solver=gauss_seidel |" in text
    assert "| sheet | ms_per_step | 10 | — | — | solver=jacobi |" in text  # cpu only
    assert "| big | ms_per_step | — | 1 | — |  |" in text
    shared = bench.write_summary(tmp_path, ["cpu", "cuda"], status, jobs=2).read_text()
    assert "- 2 benchmarks ran at a time: their timings are those of a shared machine" in shared
    labels = [
        label for label, _ in bench.timing_rows(bench.load_results(tmp_path, ["cpu"]))["deform"]
    ]
    assert labels == [
        "sheet ms_per_step (solver=jacobi)",
        "sheet ms_per_step (solver=gauss_seidel)",
    ]


def test_summary_says_how_the_cost_of_a_series_grows_with_the_particles(tmp_path):
    """The sizes of one series are gathered per backend in order of particles; a
    series of one size, and rows of no series, are not a growth."""
    big, small = {"particles": 200_000}, {"particles": 10_000}
    rows = [
        ("full", "ms_per_step", big, 40.0, "liver"),
        ("10k", "ms_per_step", small, 5.0, "liver"),
        ("10k", "numpy_ms_per_step", small, 30.0, "liver (NumPy)"),
        ("sheet", "ms_per_step", small, 3.0),
    ]
    write_result(tmp_path, "cpu", "deform", rows)
    write_result(tmp_path, "cuda", "deform", [("full", "ms_per_step", big, 4.0, "liver")])
    results = bench.load_results(tmp_path, ["cpu", "cuda"])
    assert bench.scaling_series(results) == {
        "deform: liver ms_per_step": {
            "cpu": [(10_000, 5.0), (200_000, 40.0)],
            "cuda": [(200_000, 4.0)],
        }
    }
    text = bench.write_summary(tmp_path, ["cpu", "cuda"], {"cpu": {}, "cuda": {}}).read_text()
    assert "| deform: liver ms_per_step | cpu | 10000: 5, 200000: 40 | 8 / 20 |" in text
    assert "| deform: liver ms_per_step | cuda | 200000: 4 | — |" in text


def test_the_bar_chart_has_a_panel_per_benchmark(tmp_path):
    write_result(tmp_path, "cpu", "render", [("blob", "ms_per_frame", {}, 3.0)])
    write_result(tmp_path, "cpu", "deform", [("10k", "ms_per_step", {}, 5.0)])
    write_result(tmp_path, "cuda", "render", [("blob", "ms_per_frame", {}, 0.5)])
    results = bench.load_results(tmp_path, ["cpu", "cuda"])
    assert bench.bar_chart(results, tmp_path / "s.png")
    image = iio.imread(tmp_path / "s.png")
    # 10 inches wide at 100 dpi; 2 + 0.9 inches per row of the two panels
    assert image.shape[:2] == (380, 1000)
    assert bench.bar_chart({}, tmp_path / "none.png") is False
    assert not (tmp_path / "none.png").exists()


def test_unknown_backend_or_benchmark_is_a_clear_error(tmp_path, capsys):
    assert main(["bench", "--arch", "cpu,gpu", "--out", str(tmp_path)]) == 2
    assert "error: --arch: cpu,gpu: a comma-separated list of cpu, cuda" in capsys.readouterr().err
    assert main(["bench", "--only", "render,speed", "--out", str(tmp_path)]) == 2
    assert (
        "error: --only: render,speed: a comma-separated list of deform" in capsys.readouterr().err
    )
    assert main(["bench", "--jobs", "0", "--out", str(tmp_path)]) == 2
    assert "error: --jobs: 0: a whole number of 1 or more" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


def test_quick_render_benchmark_runs_and_a_missing_backend_is_skipped(tmp_path, capsys):
    missing = [arch for arch in bench.ARCHES if arch not in runtime.available_backends()]
    arches = ",".join(["cpu", *missing[:1]])
    status = main(
        ["bench", "--arch", arches, "--quick", "--only", "render", "--out", str(tmp_path)]
    )
    assert status == 0, capsys.readouterr().err
    data = json.loads((tmp_path / "cpu" / "bench_render.json").read_text())
    assert data["arch"] == "cpu" and data["results"]
    summary = (tmp_path / "summary.md").read_text()
    assert "## render" in summary and "- cpu: all ran" in summary
    if missing:
        assert f"- {missing[0]}: backend not available" in summary
        assert f"{missing[0]}: not available on this machine, skipped" in capsys.readouterr().out
