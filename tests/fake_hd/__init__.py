"""Build the fake libHD (``fake_hd.c``) and drive its test controls from Python."""

from __future__ import annotations

import ctypes
import shutil
import subprocess
from ctypes import POINTER, c_char_p, c_double, c_int, c_uint, c_ulong
from pathlib import Path

import numpy as np

SOURCE = Path(__file__).with_name("fake_hd.c")


def compiler() -> str | None:
    """The system C compiler (``cc`` or ``gcc``), or None."""
    return shutil.which("cc") or shutil.which("gcc")


def build(out_dir: Path) -> Path:
    """Compile the fake into ``out_dir/libHD.so``; raise naming the compiler's output."""
    out = Path(out_dir) / "libHD.so"
    cmd = [compiler(), "-shared", "-fPIC", "-O2", "-pthread", "-o", str(out), str(SOURCE), "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    if proc.returncode != 0:
        raise RuntimeError(f"building the fake libHD failed: {' '.join(cmd)}\n{proc.stderr}")
    return out


class FakeHD:
    """The fake's test controls (``fakehd_*``), loaded from the same library file."""

    def __init__(self, path: Path):
        self.path = str(path)
        lib = ctypes.CDLL(self.path)
        lib.fakehd_set_pose.argtypes = [c_uint, POINTER(c_double)]
        lib.fakehd_set_buttons.argtypes = [c_uint, c_int]
        lib.fakehd_set_calibration.argtypes = [c_char_p, c_uint]
        lib.fakehd_push_errors.argtypes = [c_uint, POINTER(c_uint), c_int]
        lib.fakehd_forces.argtypes = [c_uint, POINTER(c_double), c_int]
        lib.fakehd_frame_count.argtypes = [c_uint]
        lib.fakehd_frame_count.restype = c_ulong
        lib.fakehd_tick_count.restype = c_ulong
        lib.fakehd_is_enabled.argtypes = [c_uint, c_uint]
        lib.fakehd_calls.argtypes = [ctypes.c_char_p, c_int]
        self.lib = lib

    def reset(self):
        self.lib.fakehd_reset()

    def set_pose(self, handle: int, column_major: np.ndarray):
        """Set the 16 doubles ``HD_CURRENT_TRANSFORM`` returns (column-major, [mm])."""
        values = np.asarray(column_major, dtype=np.float64).ravel()
        assert values.shape == (16,), values.shape
        self.lib.fakehd_set_pose(handle, (c_double * 16)(*values))

    def set_buttons(self, handle: int, buttons: int):
        self.lib.fakehd_set_buttons(handle, buttons)

    def set_calibration(self, name: str | None, status: int):
        assert self.lib.fakehd_set_calibration(name.encode() if name else None, status) == 0

    def push_errors(self, handle: int, *codes: int):
        """Push errors of ``handle`` in one step (the servo thread sees all or none)."""
        self.lib.fakehd_push_errors(handle, (c_uint * len(codes))(*codes), len(codes))

    def error_count(self) -> int:
        return self.lib.fakehd_error_count()

    def forces(self, handle: int, last: int = 4096) -> np.ndarray:
        """The output forces [N] of the latest ``last`` frames, oldest first, (n, 3)."""
        buf = (c_double * (3 * last))()
        n = self.lib.fakehd_forces(handle, buf, last)
        return np.array(buf[: 3 * n]).reshape(n, 3)

    def frame_count(self, handle: int) -> int:
        return self.lib.fakehd_frame_count(handle)

    def tick_count(self) -> int:
        return self.lib.fakehd_tick_count()

    def is_enabled(self, handle: int, capability: int = 0) -> bool:
        return bool(self.lib.fakehd_is_enabled(handle, capability))

    def scheduled_count(self) -> int:
        return self.lib.fakehd_scheduled_count()

    def scheduler_running(self) -> bool:
        return bool(self.lib.fakehd_scheduler_running())

    def calls(self) -> list[str]:
        """The logged lifecycle calls, one string each."""
        buf = ctypes.create_string_buffer(1 << 15)
        n = self.lib.fakehd_calls(buf, len(buf))
        return buf.raw[:n].decode().splitlines()
