"""Figures off screen with matplotlib (benchmark charts, the session report): pyplot
on the Agg backend, written atomically to a PNG file or returned as PNG bytes."""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # after the backend is chosen

from taichi_lap.core.files import write_atomically


def figure(rows: int = 1, columns: int = 1, *, size: tuple[float, float] = (8.0, 3.0)):
    """``(fig, axes)``: a new figure of ``size`` inches; ``axes`` a 2-D array."""
    return plt.subplots(rows, columns, figsize=size, squeeze=False)


def save_png(fig, path: Path, *, dpi: int = 100):
    """Write ``fig`` to the PNG ``path`` atomically and close it."""
    write_atomically(path, png_bytes(fig, dpi=dpi))


def png_bytes(fig, *, dpi: int = 90) -> bytes:
    """``fig`` as PNG bytes (for a page that embeds its images); closes it."""
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi)
    plt.close(fig)
    return buffer.getvalue()
