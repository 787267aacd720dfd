"""Writing user-facing files atomically: a temporary file in the same folder, then a
rename, so that a crash never leaves half a file under the final name."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def give_ordinary_mode(file: int | str):
    """The permissions of an ordinary new file (0666 less the umask) for a file
    ``mkstemp`` made (0600) that will be renamed to its final name (``file``: its
    descriptor or path)."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(file, 0o666 & ~umask)


def write_atomically(path: str | Path, data: bytes | str) -> Path:
    """Write ``data`` (text as UTF-8) to ``path`` atomically; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        give_ordinary_mode(fd)
        with os.fdopen(fd, "wb") as handle:
            handle.write(data.encode() if isinstance(data, str) else data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path
