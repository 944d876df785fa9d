"""What every ANSYS-format writer shares: :class:`ExportError` and the atomic file / folder writes that
turn a failure into one (:mod:`pcmgn_jax.atomic` underneath)."""
from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from pcmgn_jax.atomic import atomic_dir, atomic_write_text

__all__ = ["ExportError"]


class ExportError(ValueError):
    """An export could not be written (one line naming the path and the cause)."""


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """:func:`pcmgn_jax.atomic.atomic_write_text`, creating the folder, with a failure as :class:`ExportError`."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, text)
    except OSError as err:
        raise ExportError(f"{path}: cannot write: {err.strerror or err}") from None


@contextmanager
def atomic_folder(final: str | os.PathLike) -> Iterator[Path]:
    """:func:`pcmgn_jax.atomic.atomic_dir` for a folder ``final``: yield a temporary folder beside it that
    replaces it on success (on failure ``final`` is untouched); errors are :class:`ExportError` naming
    ``final`` (never the temporary folder)."""
    final = Path(final)
    if final.exists() and not final.is_dir():
        raise ExportError(f"{final}: exists and is not a folder; remove it or choose another output")
    try:
        with atomic_dir(final) as tmp:
            try:
                yield tmp
            except ExportError as err:   # name the final path, not the temporary folder
                raise ExportError(str(err).replace(str(tmp), str(final))) from None
    except OSError as err:
        raise ExportError(f"{final}: cannot write: {err.strerror or err}") from None
