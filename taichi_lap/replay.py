"""Reading recordings and replaying them (the format is described in
:mod:`taichi_lap.recording`).

:func:`read_recording` reads a file up to its last complete record: a truncated
end (a killed run) is a warning; a foreign file, another version or a damaged
record in the middle raises :class:`~taichi_lap.errors.InputError` naming the file,
the record and what was expected. :class:`ReplayDevice` feeds the recorded poses
back to :meth:`Session.step <taichi_lap.session.Session.step>` in recorded order.
"""

from __future__ import annotations

import json
import logging
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from taichi_lap.core.errors import InputError
from taichi_lap.devices import Pose
from taichi_lap.recording import (
    CRC,
    FRAME_HEAD,
    FRAME_TOOL,
    HEADER,
    MAGIC,
    MAX_PAYLOAD,
    RECORD_HEAD,
    TAG_EVENT,
    TAG_FRAME,
    TAG_STATS,
    TAG_TICK,
    TICK_HEAD,
    FRAME_TOOL_V1,
    READABLE_VERSIONS,
    TICK_TOOL,
    TICK_TOOL_V1,
    run_settings,
    scene_fingerprint,
    state_checksum,
)

log = logging.getLogger("taichi_lap")

STATS_FIELDS = ("time", "frame", "stages", "forces", "contacts")
REQUIRED_FIELDS = {
    "session_start": ("source", "digest", "raw_scene", "arch", "threads", "versions", "tools"),
    "session_end": ("status", "frames", "checksum"),
}


@dataclass
class Frame:
    """One frame record: the poses and buttons per tool name applied before the step
    from ``time`` [s]; ``clock`` [s] is when they were read."""

    time: float
    frame: int
    clock: float
    poses: dict[str, Pose]
    buttons: dict[str, int]


@dataclass
class Tick:
    """One haptic servo tick: ``clock`` [s], per tool name pose, buttons, force [N]."""

    clock: float
    poses: dict[str, Pose]
    buttons: dict[str, int]
    forces: dict[str, np.ndarray]


@dataclass
class Recording:
    """A recording as read: events (``session_start`` first), frames, ticks and
    per-frame statistics in file order; ``truncated_at`` is the byte offset of an
    incomplete last record."""

    path: str
    version: int
    events: list[dict] = field(default_factory=list)
    frames: list[Frame] = field(default_factory=list)
    ticks: list[Tick] = field(default_factory=list)
    stats: list[dict] = field(default_factory=list)
    truncated_at: int | None = None

    @property
    def start(self) -> dict:
        return self.events[0]

    @property
    def end(self) -> dict | None:
        return next((e for e in reversed(self.events) if e["kind"] == "session_end"), None)

    @property
    def tools(self) -> list[str]:
        return self.start["tools"]

    def check_scene(self, scene):
        """Raise :class:`InputError` naming what differs unless ``scene`` is the
        recorded one (values after overrides and mesh files)."""
        digest, raw = scene_fingerprint(scene)
        if digest == self.start["digest"]:
            return
        found = "; ".join(
            f"{key} = {_brief(given)} (recorded: {_brief(recorded)})"
            for key, recorded, given in _differences(self.start["raw_scene"], raw)
        )
        raise InputError(
            self.path,
            "session_start.digest",
            f"the recorded scene {self.start['source']!r} was expected, found "
            f"{scene.source!r} with {found or 'other mesh files'}",
        )

    def compare_final_state(self, state) -> tuple[bool, str]:
        """``(matches, report)`` for a replay's final state against ``session_end``."""
        end = self.end
        if end is None:
            return True, f"{self.path}: no session_end record: final state not compared"
        if state.frame != end["frames"]:
            return True, (
                f"replayed {state.frame} of {end['frames']} recorded frames: final "
                f"state not compared"
            )
        checksum = state_checksum(state)
        if checksum == end["checksum"]:
            return True, (
                f"replay matches {self.path}: final state sha256 {checksum[:16]} "
                f"after {state.frame} frames"
            )
        here = run_settings()
        differ = ", ".join(
            f"{key} {self.start[key]} recorded, {here[key]} here"
            for key in here
            if self.start[key] != here[key]
        )
        return False, (
            f"{self.path}: session_end.checksum: the recorded final state "
            f"{end['checksum'][:16]} was expected after {state.frame} frames, found "
            f"{checksum[:16]} ({differ or 'same backend, threads and versions'})"
        )


def _differences(recorded, given, key: str = "") -> list[tuple[str, object, object]]:
    """Up to three ``(dotted key, recorded, given)`` where two JSON values differ."""
    if isinstance(recorded, dict) and isinstance(given, dict):
        found = []
        for name in sorted(set(recorded) | set(given)):
            found += _differences(
                recorded.get(name, "(not set)"),
                given.get(name, "(not set)"),
                f"{key}.{name}" if key else name,
            )
        return found[:3]
    if isinstance(recorded, list) and isinstance(given, list) and len(recorded) == len(given):
        found = []
        for index, (a, b) in enumerate(zip(recorded, given)):
            found += _differences(a, b, f"{key}[{index}]")
        return found[:3]
    return [] if recorded == given else [(key, recorded, given)]


def _brief(value) -> str:
    text = json.dumps(value)
    return text if len(text) <= 60 else text[:57] + "..."


class ReplayDevice:
    """Feeds a recording's poses and buttons back, frame by frame in recorded order."""

    def __init__(self, recording: Recording):
        self.recording = recording
        self.source = recording.path
        self._next = 0

    def poses(self, time: float) -> dict[str, Pose]:
        frames = self.recording.frames
        if self._next >= len(frames):
            raise InputError(
                self.source,
                "frames",
                f"at most {len(frames)} frames to replay were expected, found a request for more",
            )
        frame = frames[self._next]
        if frame.time != time:
            raise InputError(
                self.source,
                f"frame {frame.frame}",
                f"the session at t = {frame.time!r} s was expected, found t = {time!r} s",
            )
        self._next += 1
        return frame.poses

    def buttons(self, time: float) -> dict[str, int]:
        return self.recording.frames[self._next - 1].buttons


def _decode_frame(payload: bytes, tools: list[str], version: int) -> Frame:
    layout = FRAME_TOOL if version > 1 else FRAME_TOOL_V1
    _expect_size(payload, FRAME_HEAD.size, "a frame header", at_least=True)
    time, number, clock, count = FRAME_HEAD.unpack_from(payload)
    _expect_size(payload, FRAME_HEAD.size + count * layout.size, f"a frame of {count} tools")
    frame = Frame(time, number, clock, {}, {})
    for k in range(count):
        index, *values, buttons = layout.unpack_from(payload, FRAME_HEAD.size + k * layout.size)
        name = _tool_name(tools, index)
        frame.poses[name] = _pose(values, version)
        frame.buttons[name] = buttons
    return frame


def _decode_tick(payload: bytes, tools: list[str], version: int) -> Tick:
    layout = TICK_TOOL if version > 1 else TICK_TOOL_V1
    _expect_size(payload, TICK_HEAD.size, "a tick header", at_least=True)
    clock, count = TICK_HEAD.unpack_from(payload)
    _expect_size(payload, TICK_HEAD.size + count * layout.size, f"a tick of {count} tools")
    tick = Tick(clock, {}, {}, {})
    for k in range(count):
        index, *values = layout.unpack_from(payload, TICK_HEAD.size + k * layout.size)
        name = _tool_name(tools, index)
        tick.poses[name] = _pose(values, version)
        tick.buttons[name], tick.forces[name] = values[-4], np.array(values[-3:])
    return tick


def _pose(values: list, version: int) -> Pose:
    """A recorded tool's pose from its tip, direction and (from version 2) roll."""
    roll = float(values[6]) if version > 1 else 0.0
    return Pose(np.array(values[0:3]), np.array(values[3:6]), roll)


def _decode_json(payload: bytes, expected: str):
    """A JSON payload, or ValueError saying ``expected`` and what was wrong."""
    try:
        return json.loads(payload.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{expected}, found {exc}") from None


def _decode_event(payload: bytes) -> dict:
    event = _decode_json(payload, "an event as UTF-8 JSON was expected")
    if not isinstance(event, dict) or not isinstance(event.get("kind"), str):
        raise ValueError(f"an event object with a kind was expected, found {payload[:60]!r}")
    missing = [name for name in REQUIRED_FIELDS.get(event["kind"], ()) if name not in event]
    if missing:
        raise ValueError(
            f"a {event['kind']} event with {', '.join(missing)} was expected, "
            f"found {', '.join(event)}"
        )
    return event


def _decode_stats(payload: bytes, tools: list[str]) -> dict:
    stats = _decode_json(payload, "statistics as UTF-8 JSON were expected")
    if not isinstance(stats, dict) or not set(STATS_FIELDS) <= set(stats):
        raise ValueError(
            f"statistics with {', '.join(STATS_FIELDS)} were expected, found {payload[:60]!r}"
        )
    unknown = sorted((set(stats["forces"]) | set(stats["contacts"])) - set(tools))
    if unknown:
        raise ValueError(f"the recorded tools were expected, found {unknown}")
    return stats


def _expect_size(payload: bytes, size: int, what: str, *, at_least: bool = False):
    if len(payload) < size or (len(payload) > size and not at_least):
        raise ValueError(f"{size} bytes for {what} were expected, found {len(payload)}")


def _tool_name(tools: list[str], index: int) -> str:
    if index >= len(tools):
        raise ValueError(f"a tool index below {len(tools)} was expected, found {index}")
    return tools[index]


def read_recording(path: str | Path, *, ticks: bool = True) -> Recording:
    """Read a recording up to its last complete record (a truncated end is a warning).
    A foreign file, another version or a damaged record raises :class:`InputError`.
    ``ticks=False`` checks tick records but does not decode them."""
    path = str(path)
    try:
        with open(path, "rb") as file:
            return _read(path, file, ticks)
    except OSError as exc:
        raise InputError(path, "", f"a readable recording was expected: {exc.strerror}") from None


def _read(path: str, file, ticks: bool) -> Recording:
    head = file.read(HEADER.size)
    if not MAGIC.startswith(head[: len(MAGIC)]) or not head:
        found = head[: len(MAGIC)].hex(" ") or "an empty file"
        raise InputError(
            path,
            "header",
            f"a taichi-lap recording (magic {MAGIC.hex(' ')}) was expected, found {found}",
        )
    if len(head) < HEADER.size:
        raise InputError(
            path, "header", f"a {HEADER.size}-byte header was expected, found {len(head)} bytes"
        )
    version = HEADER.unpack(head)[1]
    if version not in READABLE_VERSIONS:
        raise InputError(
            path,
            "header.version",
            f"version {' or '.join(map(str, READABLE_VERSIONS))} was expected, found {version}",
        )
    recording, offset, index = Recording(path, version), HEADER.size, 0
    while head := file.read(RECORD_HEAD.size):
        key = f"record {index} (byte {offset})"
        if head[0] == 0 and not (head + file.read()).strip(b"\0"):
            return _truncated(recording, offset, key, "a tail of zero bytes")
        if len(head) < RECORD_HEAD.size:
            return _truncated(recording, offset, key, "an incomplete record")
        tag, length = RECORD_HEAD.unpack(head)
        if length > MAX_PAYLOAD:
            raise InputError(
                path, key, f"a record length up to {MAX_PAYLOAD} bytes was expected, found {length}"
            )
        body = file.read(length + CRC.size)
        if len(body) < length + CRC.size:
            return _truncated(recording, offset, key, "an incomplete record")
        payload, (crc,) = body[:length], CRC.unpack(body[length:])
        actual = zlib.crc32(payload, zlib.crc32(head))
        if crc != actual:
            raise InputError(
                path, key, f"CRC-32 {crc:08x} was expected, found {actual:08x} (a damaged record)"
            )
        try:
            if tag == TAG_EVENT:
                recording.events.append(_decode_event(payload))
                if index == 0 and recording.start["kind"] != "session_start":
                    raise ValueError(
                        f"a session_start event was expected, found {recording.start['kind']!r}"
                    )
            elif index == 0:
                raise ValueError(
                    f"a session_start event was expected, found a record tagged {chr(tag)!r}"
                )
            elif tag == TAG_FRAME:
                recording.frames.append(_decode_frame(payload, recording.tools, version))
            elif tag == TAG_TICK and ticks:
                recording.ticks.append(_decode_tick(payload, recording.tools, version))
            elif tag == TAG_STATS:
                recording.stats.append(_decode_stats(payload, recording.tools))
        except ValueError as exc:
            raise InputError(path, key, str(exc)) from None
        offset += RECORD_HEAD.size + length + CRC.size
        index += 1
    if not recording.events:
        raise InputError(
            path, "record 0", "a session_start event was expected, found the end of the file"
        )
    return recording


def _truncated(recording: Recording, offset: int, key: str, what: str) -> Recording:
    if not recording.events:
        raise InputError(
            recording.path, key, f"a complete session_start event was expected, found {what}"
        )
    recording.truncated_at = offset
    log.warning(
        "%s: truncated at byte %d (%s): read %d frames and %d events before it",
        recording.path,
        offset,
        what,
        len(recording.frames),
        len(recording.events),
    )
    return recording
