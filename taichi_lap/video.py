"""Frame output: an MP4 file (imageio with imageio-ffmpeg), a GIF, or a folder of PNGs.

Files are written atomically: a video goes to a temporary file renamed on close;
each PNG is written to a temporary name and renamed, so a killed run leaves only
complete frames.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import imageio.v2 as imageio
import numpy as np

from taichi_lap.core.errors import InputError
from taichi_lap.core.files import give_ordinary_mode, write_atomically

VIDEO_SUFFIXES = (".mp4", ".gif")


def _publish(tmp: str, path: Path):
    """Give a finished temporary file the usual permissions and move it into place
    (``mkstemp`` creates files readable by their owner only)."""
    give_ordinary_mode(tmp)
    os.replace(tmp, path)


def write_png(path: str | Path, image: np.ndarray):
    """Write one PNG atomically."""
    write_atomically(path, imageio.imwrite("<bytes>", image, format="png"))


class FrameWriter:
    """Writes frames to ``out``: ``*.mp4`` / ``*.gif`` as a video, anything else as a
    folder of ``frame_00000.png``..."""

    def __init__(self, out: str | Path, fps: float):
        self.out = Path(out)
        self.count = 0
        self._writer = None
        self._tmp = None
        if self.out.suffix.lower() in VIDEO_SUFFIXES:
            self.out.parent.mkdir(parents=True, exist_ok=True)
            fd, self._tmp = tempfile.mkstemp(dir=self.out.parent, suffix=self.out.suffix)
            os.close(fd)
            try:
                if self.out.suffix.lower() == ".mp4":
                    self._writer = imageio.get_writer(
                        self._tmp,
                        format="FFMPEG",
                        fps=fps,
                        codec="libx264",
                        quality=7,
                        macro_block_size=8,
                    )
                else:
                    self._writer = imageio.get_writer(self._tmp, format="GIF", duration=1.0 / fps)
            except Exception as exc:  # imageio raises several types when ffmpeg is missing
                Path(self._tmp).unlink(missing_ok=True)
                raise InputError(
                    "--out",
                    str(out),
                    f"an MP4 writer was expected (pip install "
                    f"'taichi-lap[video]'), it failed: {exc}",
                ) from None
        elif self.out.exists() and not self.out.is_dir():
            raise InputError(
                "--out",
                str(out),
                "a folder, or a file ending in .mp4 or .gif, was expected, found an existing file",
            )

    def write(self, image: np.ndarray):
        if self._writer is not None:
            self._writer.append_data(image)
        else:
            write_png(self.out / f"frame_{self.count:05d}.png", image)
        self.count += 1

    def close(self):
        if self._writer is not None:
            self._writer.close()
            _publish(self._tmp, self.out)
            self._writer = None

    def __enter__(self):
        return self

    def __exit__(self, kind, value, traceback):
        if kind is None or kind is KeyboardInterrupt:  # keep what was recorded
            self.close()
        elif self._writer is not None:
            self._writer.close()
            Path(self._tmp).unlink(missing_ok=True)
