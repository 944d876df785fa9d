"""What every ANSYS-format writer shares: :class:`ExportError`, the folder write and the error mapping that
turn a failure into one (the atomic writes themselves: :mod:`pcmgn_jax.atomic`)."""
from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from pcmgn_jax.atomic import atomic_dir

__all__ = ["ExportError"]


class ExportError(ValueError):
    """An export could not be written (one line naming the path and the cause)."""


@contextmanager
def export_errors(path: str | os.PathLike) -> Iterator[None]:
    """An ``OSError`` inside the block (writing ``path``) as :class:`ExportError` naming ``path``."""
    try:
        yield
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
