"""The command line contract: list, info, check --json, run --headless, render."""

import json
import math
import os
import shutil
import subprocess
import sys

import imageio.v2 as imageio
import pytest

from taichi_lap import scene as scene_mod
from taichi_lap.cli import main
from taichi_lap.replay import read_recording
from taichi_lap.runtime import available_backends

SMALL = ["--set", "scene.detail=0.03"]
needs_vulkan = pytest.mark.skipif(
    "vulkan" not in available_backends(), reason="GGUI needs a Vulkan driver (mesa-vulkan-drivers)"
)


def test_list_names_the_three_builtin_scenes(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for name in ("liver", "rectum", "intestine"):
        assert name in out
    scripts = "intestine-careless, liver-careless, liver-deep-transection, rectum-careless"
    assert f"built-in scripts (--device script:NAME): {scripts}" in out


def test_info_reports_versions_and_backends(capsys):
    assert main(["info"]) == 0
    out = capsys.readouterr().out
    assert "taichi 1.7.4" in out and "backends:" in out and "cpu" in out


def test_check_json_follows_the_contract(capsys):
    assert main(["check", "liver", "--json", *SMALL]) == 0
    stats = json.loads(capsys.readouterr().out)
    names = [o["name"] for o in stats["organs"]]
    assert names == ["liver", "portal_vein", "hepatic_vein", "hepatic_artery", "bile_duct"]
    for organ in stats["organs"]:
        for key in (
            "name",
            "model",
            "vertices",
            "triangles",
            "particles",
            "tets",
            "clusters",
            "avg_cluster_radius",
        ):
            assert key in organ
        assert organ["tets"] > 0 and organ["clusters"] > 0
    assert stats["totals"]["particles"] == sum(o["particles"] for o in stats["organs"])


def test_full_liver_matches_table_1():
    """Seed 002 Table 1: 170 854 particles and 3 892 clusters in all; the liver
    146 090 particles in 2 994 clusters of radius 0.84 cm (builds ~170k particles)."""
    from taichi_lap.preprocess.cache import build_model
    from taichi_lap.stats import model_statistics

    stats = model_statistics(build_model(scene_mod.load("liver"), progress=False))
    totals, liver = stats["totals"], stats["organs"][0]
    assert abs(totals["particles"] / 170_854 - 1) < 0.05
    assert abs(totals["clusters"] / 3_892 - 1) < 0.25
    assert abs(liver["particles"] / 146_090 - 1) < 0.05
    assert abs(liver["clusters"] / 2_994 - 1) < 0.1
    assert abs(liver["avg_cluster_radius"] - 0.0084) < 0.0003


def test_run_headless_writes_an_mp4(tmp_path, capsys):
    """A headless run's frames as an MP4 clip, one video frame per simulated frame."""
    pytest.importorskip("imageio_ffmpeg")
    out = tmp_path / "clip.mp4"
    status = main(
        ["run", "rectum", "--headless", "--frames", "4", "--size", "160x120", "--out", str(out)]
        + SMALL
    )
    assert status == 0, capsys.readouterr().err
    frames = imageio.mimread(out, format="FFMPEG")
    assert len(frames) == 4


def test_render_writes_a_still(tmp_path, capsys):
    out = tmp_path / "still.png"
    assert main(["render", "liver", "--out", str(out), "--size", "200x150", *SMALL]) == 0
    image = imageio.imread(out)
    assert image.shape == (150, 200, 3)
    centre = image[50:100, 70:130].reshape(-1, 3).astype(float)
    assert centre[:, 0].mean() > centre[:, 2].mean() + 10  # red-brown liver in the middle


def test_a_run_without_display_or_vulkan_goes_headless_and_draws_on_the_cpu(tmp_path):
    """With no display and the Vulkan loader pointed at no driver (as on a machine
    without either), ``run`` without ``--headless`` says it runs headless and writes
    its frames (readable by others: not private temporaries), and the still is drawn
    too, by the renderer on the CPU backend (one process runs both commands: the still
    takes the run's closed session)."""
    env = dict(
        os.environ,
        VK_ICD_FILENAMES=str(tmp_path / "none.json"),
        VK_DRIVER_FILES=str(tmp_path / "none.json"),
    )
    env.pop("DISPLAY", None)
    env.pop("WAYLAND_DISPLAY", None)
    common = ["--arch", "cpu", *SMALL]
    commands = [
        [
            "run",
            "rectum",
            "--frames",
            "3",
            "--size",
            "160x120",
            "--out",
            str(tmp_path / "f"),
            *common,
        ],
        ["render", "rectum", "--size", "64x48", "--out", str(tmp_path / "still.png"), *common],
    ]
    script = (
        "import sys\n"
        "from taichi_lap.cli import main\n"
        "from taichi_lap.runtime import available_backends\n"
        "print(available_backends())\n"
        f"for command in {commands!r}:\n"
        "    if main(command) != 0:\n"
        "        sys.exit(1)\n"
    )
    proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "vulkan" not in proc.stdout
    assert "running headless" in proc.stderr
    frames = sorted((tmp_path / "f").glob("frame_*.png"))
    assert len(frames) == 3
    umask = os.umask(0)
    os.umask(umask)
    assert frames[0].stat().st_mode & 0o777 == 0o666 & ~umask  # not a private temporary
    assert imageio.imread(frames[-1]).shape == (120, 160, 3)
    assert imageio.imread(tmp_path / "still.png").shape == (48, 64, 3)


@pytest.mark.skipif(shutil.which("xvfb-run") is None, reason="needs xvfb-run (apt: xvfb xauth)")
@needs_vulkan
def test_interactive_window_runs_on_a_virtual_display(tmp_path):
    """The GGUI window loop (camera, mouse device, panel) on Xvfb; the session is
    recorded to a new file in the sessions folder."""
    proc = subprocess.run(
        [
            "xvfb-run",
            "-a",
            "-s",
            "-screen 0 1024x768x24",
            sys.executable,
            "-m",
            "taichi_lap",
            "run",
            "rectum",
            "--frames",
            "6",
            "--size",
            "640x480",
            *SMALL,
        ],
        capture_output=True,
        text=True,
        timeout=600,
        env=dict(os.environ, TAICHI_LAP_SESSIONS=str(tmp_path / "sessions")),
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "running headless" not in proc.stderr
    (recorded,) = (tmp_path / "sessions").glob("rectum-*.tlap")
    recording = read_recording(recorded)
    assert len(recording.frames) == len(recording.stats) == 6
    assert recording.end["status"] == "complete"


def test_simulation_fault_is_reported_not_raised(tmp_path, capsys):
    path = tmp_path / "fast.toml"
    path.write_text(
        "[scene]\nname = 'fault'\ngravity = [0, -900, 0]\nspeed_limit = 0.5\n"
        "[[organs]]\nname = 'ball'\nmodel = 'tet_clusters'\n"
        "geometry = { generator = 'sphere', radius = 0.02 }\n"
        "material = { particle_spacing = 0.006 }\n"
    )
    status = main(["render", str(path), "--out", str(tmp_path / "x.png"), "--frames", "5"])
    err = capsys.readouterr().err
    assert status == 1
    assert "simulation fault" in err and "'ball'" in err
    assert not (tmp_path / "x.png").exists()


def test_a_headless_run_without_frames_plays_the_scene_script_to_its_end():
    from taichi_lap.cli import HEADLESS_FRAMES, SCRIPT_TAIL, _headless_frames
    from taichi_lap.session import scene_script

    scene = scene_mod.load("liver", dict(scene_mod.parse_override(t) for t in SMALL[1::2]))
    device = scene_script(scene)
    expected = math.ceil((device.duration() + SCRIPT_TAIL) / scene.settings["dt"])
    assert device.duration() == 7.4 and _headless_frames(device, scene) == expected
    assert _headless_frames(None, scene) == HEADLESS_FRAMES
