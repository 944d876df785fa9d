"""Atomic file writes: a reader never sees a half-written file, a kill never leaves one behind.

One place for the rule (temp file in the same folder, fsync, rename); every results, config and
checkpoint-side file the project writes goes through :func:`atomic_write_text` (JSON through
``pcmgn_jax.data.trajectory_io.atomic_write_json``, which adds the project's JSON encoding).
Top-level and dependency-free, so the run config can use it without importing a subpackage.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` to ``path`` atomically (temp file in the same folder, fsync, rename)."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", newline="\n") as f:   # LF on every OS (solver input decks, tables)
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)  # mkstemp creates 0600; a results file should be readable like any other
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
