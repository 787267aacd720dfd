"""Shared-memory snapshot (simulation → servo) and feedback (servo → simulation)."""

from __future__ import annotations

import multiprocessing
import time
from multiprocessing import shared_memory

import numpy as np
import pytest

from taichi_lap.haptics import (
    SceneSnapshot,
    ServoFeedback,
    ServoState,
    SnapshotCapacityError,
    ToolFeedback,
)

CLUSTERS, PARTICLES, GRASP = 600, 120_000, 32


def uniform_scene(sequence: int, clusters: int, particles: int) -> dict:
    """The scene arrays of a snapshot of ``clusters`` spheres (all ``particles`` in
    the first) whose every element equals ``sequence``."""
    start = np.full(clusters + 1, particles)
    start[0] = 0
    value = float(sequence)
    return {
        "cluster_center": np.full((clusters, 3), value),
        "cluster_radius": np.full(clusters, value),
        "cluster_start": start,
        "particle_position": np.full((particles, 3), value),
        "particle_radius": value,
    }


def pattern(sequence: int) -> dict:
    """A snapshot whose every element equals ``sequence``, with counts that vary by it."""
    g = sequence % GRASP
    value = float(sequence)
    return {
        **uniform_scene(sequence, 300 + sequence % 300, 60_000 + (sequence * 7919) % 60_000),
        "grasp_local": np.full((g, 3), value),
        "grasp_neighbor": np.full((g, 3), value),
        "grasp_rest": np.full(g, value),
        "coupling_tip": np.full(3, value) if sequence % 2 else None,  # coupled: odd ones
        "timestamp": value,
    }


def assert_uniform(scene):
    """Every array of ``scene`` holds its sequence number, with the pattern's shapes."""
    expected = pattern(scene.sequence)
    expected["particle_radius"] = np.full(len(expected["particle_position"]), scene.sequence)
    assert scene.timestamp == scene.sequence
    for name in (
        "cluster_center",
        "cluster_radius",
        "cluster_start",
        "particle_position",
        "particle_radius",
        "grasp_local",
        "grasp_neighbor",
        "grasp_rest",
    ):
        np.testing.assert_array_equal(
            getattr(scene, name), expected[name], err_msg=f"{name} of snapshot {scene.sequence}"
        )
        assert getattr(scene, name).shape == np.shape(expected[name]), name
    if expected["coupling_tip"] is None:
        assert scene.coupling_tip is None, f"a coupling tip in snapshot {scene.sequence}"
    else:
        np.testing.assert_array_equal(scene.coupling_tip, expected["coupling_tip"])


def publish_patterns(name: str, stop):
    """Child process: publish patterns 1, 2, ... as fast as possible until ``stop``."""
    snapshot = SceneSnapshot.attach(name)
    sequence = 0
    while not stop.is_set():
        sequence += 1
        fields = pattern(sequence)
        assert snapshot.publish(**fields) == sequence
    snapshot.close()


def test_seqlock_never_returns_a_torn_read_under_a_concurrent_writer_process():
    snapshot = SceneSnapshot.create(clusters=CLUSTERS, particles=PARTICLES, grasp_edges=GRASP)
    context = multiprocessing.get_context("spawn")
    stop = context.Event()
    writer = context.Process(target=publish_patterns, args=(snapshot.name, stop))
    try:
        writer.start()
        reader = snapshot.reader()
        reads, sequences = 0, set()
        start = time.monotonic()
        while time.monotonic() - start < 20.0 and (reads < 200 or time.monotonic() - start < 1.5):
            if reader.poll():
                assert_uniform(reader.scene)
                reads += 1
                sequences.add(reader.scene.sequence)
        assert writer.is_alive(), "the writer process died"
        assert reads >= 100 and len(sequences) == reads
    finally:
        stop.set()
        writer.join(10)
        snapshot.close()
    assert writer.exitcode == 0


def test_reader_takes_the_newest_complete_slot_while_the_writer_is_mid_copy():
    owner = SceneSnapshot.create(clusters=CLUSTERS, particles=PARTICLES, grasp_edges=GRASP)
    servo_side = SceneSnapshot.attach(owner.name)
    try:
        reader = servo_side.reader()
        assert not reader.poll() and reader.scene is None  # nothing published yet
        owner.publish(**pattern(1))
        owner.publish(**pattern(2))
        assert reader.poll() and reader.scene.sequence == 2
        assert_uniform(reader.scene)
        # a writer preempted half-way through snapshot 3: its slot's version is odd
        slot = owner._region.begin()
        slot["cluster_center"][:5] = 99.0
        assert not reader.poll()  # no new complete snapshot, and no spinning on slot 3
        assert reader.scene.sequence == 2
        assert_uniform(reader.scene)
        owner._region.end()  # the stalled writer resumes; the next snapshot is whole again
        owner.publish(**pattern(4))
        assert reader.poll() and reader.scene.sequence == 4
        assert_uniform(reader.scene)
        assert not reader.poll()  # nothing newer
    finally:
        servo_side.close()
        owner.close()


def test_publish_beyond_capacity_raises_naming_the_capacity():
    snapshot = SceneSnapshot.create(clusters=4, particles=10, grasp_edges=2)
    ok = {
        "cluster_center": np.zeros((2, 3)),
        "cluster_radius": np.ones(2),
        "cluster_start": [0, 5, 10],
        "particle_position": np.zeros((10, 3)),
        "particle_radius": 0.001,
    }
    try:
        assert snapshot.publish(**ok) == 1
        with pytest.raises(
            SnapshotCapacityError, match="cluster_center: 5 rows exceed the capacity of 4"
        ):
            snapshot.publish(
                **dict(
                    ok,
                    cluster_center=np.zeros((5, 3)),
                    cluster_radius=np.ones(5),
                    cluster_start=[0, 2, 4, 6, 8, 10],
                )
            )
        with pytest.raises(
            SnapshotCapacityError, match="particle_position: 11 rows exceed the capacity of 10"
        ):
            snapshot.publish(
                **dict(ok, particle_position=np.zeros((11, 3)), cluster_start=[0, 5, 11])
            )
        with pytest.raises(
            SnapshotCapacityError, match="grasp_local: 3 rows exceed the capacity of 2"
        ):
            snapshot.publish(
                **ok,
                grasp_local=np.zeros((3, 3)),
                grasp_neighbor=np.zeros((3, 3)),
                grasp_rest=np.ones(3),
            )
        with pytest.raises(
            ValueError,
            match=r"cluster_radius: an array of shape \(2,\) was "
            r"expected, found \(3,\)",
        ):
            snapshot.publish(**dict(ok, cluster_radius=np.ones(3)))
        with pytest.raises(
            ValueError, match="cluster_start: non-decreasing offsets from 0 to the 10 particles"
        ):
            snapshot.publish(**dict(ok, cluster_start=[0, 5, 9]))
        with pytest.raises(ValueError, match="clusters: a capacity of at least 1"):
            SceneSnapshot.create(clusters=0, particles=10)
    finally:
        snapshot.close()


def test_a_snapshot_outgrown_moves_and_the_attached_reader_follows():
    """reserve() beyond the capacities moves the snapshot to a larger region; a reader
    in another mapping keeps the old scene until the new region's first snapshot, then
    reads it with the sequence numbers going on, through two moves in a row; close()
    unlinks every region the creator made."""
    owner = SceneSnapshot.create(clusters=4, particles=10, grasp_edges=2)
    servo_side = SceneSnapshot.attach(owner.name)
    reader = servo_side.reader()
    names = [owner.name]
    try:
        assert not owner.reserve(clusters=4, particles=10)  # fits: stays
        owner.publish(**uniform_scene(1, 2, 10))
        assert reader.poll() and reader.scene.sequence == 1
        assert owner.reserve(clusters=3, particles=40)
        names.append(owner.name)
        assert owner.capacity == {"clusters": 4, "particles": 60, "grasp_edges": 2}
        assert not reader.poll() and reader.scene.sequence == 1  # nothing new published
        assert servo_side.capacity["particles"] == 60
        owner.publish(**uniform_scene(2, 3, 40))
        assert owner.reserve(clusters=9, particles=40)  # a second move before the poll
        names.append(owner.name)
        owner.publish(**uniform_scene(3, 9, 50))
        assert reader.poll() and reader.scene.sequence == 3
        assert reader.scene.particle_position.shape == (50, 3)
        assert np.all(reader.scene.particle_position == 3.0)
        assert np.all(reader.scene.cluster_center == 3.0) and len(reader.scene.cluster_start) == 10
        assert servo_side.capacity == {"clusters": 14, "particles": 60, "grasp_edges": 2}
        assert servo_side.name == owner.name
        owner.publish(**uniform_scene(4, 1, 60))
        assert reader.poll() and reader.scene.sequence == 4
    finally:
        servo_side.close()
        owner.close()
    assert len(set(names)) == 3
    for name in names:
        with pytest.raises(FileNotFoundError):
            shared_memory.SharedMemory(name=name)


def test_attach_rejects_a_foreign_region_and_close_unlinks():
    foreign = shared_memory.SharedMemory(create=True, size=4096)
    try:
        with pytest.raises(ValueError, match="a taichi-lap region of layout"):
            SceneSnapshot.attach(foreign.name)
    finally:
        foreign.close()
        foreign.unlink()
    snapshot = SceneSnapshot.create(clusters=4, particles=10)
    name = snapshot.name
    snapshot.close()
    with pytest.raises(FileNotFoundError):
        shared_memory.SharedMemory(name=name)


def test_feedback_round_trips_tool_state_and_the_tick_ring_keeps_the_latest():
    feedback = ServoFeedback.create(ticks=8)
    servo_side = ServoFeedback.attach(feedback.name)
    try:
        assert feedback.read() is None and feedback.state == ServoState.STARTING
        assert feedback.fifo_granted is None
        pose = np.eye(4)
        pose[:3, 3] = [0.01, 0.02, 0.03]
        servo_side.write(
            ToolFeedback(
                tick=7,
                time=1.5,
                haptic_pose=pose,
                graphic_pose=np.eye(4),
                buttons=3,
                force=[0.1, 0.2, 0.3],
                contact_force=[1.0, 2.0, 3.0],
                pull_force=[0.0, 0.0, -0.5],
                contacts=4,
                proxy_status=1,
                snapshot_sequence=11,
                missed_2ms=2,
                qp_fallbacks=1,
                qp_failures=0,
                max_force_sent=0.4,
            )
        )
        tool = feedback.read()
        assert (tool.tick, tool.buttons, tool.contacts, tool.snapshot_sequence) == (7, 3, 4, 11)
        np.testing.assert_array_equal(tool.haptic_pose, pose)
        np.testing.assert_array_equal(tool.force, [0.1, 0.2, 0.3])
        assert tool.time == 1.5 and tool.max_force_sent == 0.4 and tool.missed_2ms == 2
        for i in range(20):
            servo_side.record_tick(
                0.001 * i,
                1e-4,
                1e-5,
                clock=100.0 + i,
                tip=[0.0, i, 0.0],
                direction=[0.0, 0.0, 1.0],
                buttons=i % 2,
                force=[i, 0.0, 0.0],
            )
        history = feedback.tick_history()
        assert history["count"] == 20
        np.testing.assert_allclose(history["period"], 0.001 * np.arange(12, 20))
        ticks, count, lost = feedback.ticks_since(15)
        assert (count, lost) == (20, 0)
        np.testing.assert_array_equal(ticks["clock"], 100.0 + np.arange(15, 20))
        np.testing.assert_array_equal(ticks["tip"][:, 1], np.arange(15, 20))
        np.testing.assert_array_equal(ticks["buttons"], np.arange(15, 20) % 2)
        ticks, count, lost = feedback.ticks_since(5)  # the ring of 8 kept ticks 12-19
        assert (count, lost) == (20, 7)
        np.testing.assert_array_equal(ticks["force"][:, 0], np.arange(12, 20))
        servo_side.fifo_granted = True
        servo_side.set_state(ServoState.FAULTED, "RuntimeError: device unplugged")
        assert feedback.fifo_granted is True and feedback.state == ServoState.FAULTED
        assert feedback.message == "RuntimeError: device unplugged"
    finally:
        servo_side.close()
        feedback.close()
