"""A haptic device drives the scene's tool through the servo process: the HDAPI
binding against the fake libHD (tests/fake_hd), in the servo's own process."""

import numpy as np
import pytest

from taichi_lap import scene as scene_mod
from taichi_lap.cli import main
from taichi_lap.haptics.bridge import openhaptics_bridge
from taichi_lap.session import Session
from tests import fake_hd

SMALL = {"scene.detail": 0.03}


@pytest.fixture(scope="module")
def fake_library(tmp_path_factory):
    if fake_hd.compiler() is None:
        pytest.skip("no C compiler (cc or gcc) on PATH to build the fake libHD")
    return str(fake_hd.build(tmp_path_factory.mktemp("fake_hd")))


def test_device_origin_puts_the_tool_at_its_scene_tip(fake_library):
    """The fake stylus rests at its origin with the identity rotation: the graphical
    tool sits at the tool's scene tip with its shaft along +z (the stylus axis)."""
    scene = scene_mod.load("rectum", SMALL)
    session = Session(scene, progress=False)
    tool = scene.tools[0]
    bridge = openhaptics_bridge(tool, None, fake_library)
    bridge.attach(session)
    try:
        pose = bridge.poses(0.0)[tool["name"]]
        session.step({tool["name"]: pose})
        feedback = bridge.servo.feedback.read()
    finally:
        bridge.close()
    assert np.allclose(pose.tip, tool["tip"], atol=1e-6)
    assert np.allclose(pose.direction, [0.0, 0.0, 1.0], atol=1e-6)
    assert feedback.tick > 0
    assert np.linalg.norm(feedback.force) <= 0.88 + 1e-9  # the fake Touch's continuous force


def test_run_with_openhaptics_device_completes(fake_library, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("TAICHI_LAP_LIBHD", fake_library)
    status = main(["run", "rectum", "--headless", "--device", "openhaptics", "--frames", "3",
                   "--size", "64x48", "--out", str(tmp_path / "frames"),
                   "--set", "scene.detail=0.03"])
    assert status == 0, capsys.readouterr().err
    assert len(list((tmp_path / "frames").glob("*.png"))) == 3


def test_missing_libhd_is_a_clear_error(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("TAICHI_LAP_LIBHD", str(tmp_path / "no-such-libHD.so"))
    status = main(["run", "rectum", "--headless", "--device", "openhaptics", "--frames", "1",
                   "--size", "64x48", "--out", str(tmp_path / "f"), "--set", "scene.detail=0.03"])
    assert status == 2
    err = capsys.readouterr().err
    assert "error: --device: openhaptics: a working haptic device was expected" in err
    assert "libHD" in err and "Traceback" not in err
