"""Atomic file and folder writes: a reader never sees a half-written file, a kill never leaves one behind.

One place for the rule (write under a temp name in the same folder, fsync, rename):

* :func:`atomic_write_text`: one file. Every results, config, export and checkpoint-side file the project
  writes goes through it; JSON through :func:`atomic_write_json`, which adds the project's JSON encoding
  (:func:`to_jsonable`: NumPy values, tuples and paths to plain JSON, no NaN).
* :func:`atomic_dir`: several files staged in a temp folder, then swapped into place as one folder
  (training cache, ANSYS run folders) or moved one by one into a shared folder, commit marker last
  (trajectory files, ParaView comparisons).

Top-level and free of the package's subpackages (NumPy only), so the run config can use it.
"""
from __future__ import annotations

import errno
import json
import math
import os
import shutil
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np


def atomic_write_text(path: str | os.PathLike, text: str, *, parents: bool = False) -> None:
    """Write ``text`` to ``path`` atomically (temp file in the same folder, fsync, rename); ``parents``:
    create the missing folders above it first."""
    path = Path(path)
    if parents:
        path.parent.mkdir(parents=True, exist_ok=True)
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


def to_jsonable(obj: Any, where: str = "meta", *, nonfinite: str = "null") -> Any:
    """Convert numpy scalars/arrays, tuples and Paths to plain JSON types; reject other objects.

    Non-finite floats (e.g. a contact phase that did not occur, NaN) become ``null`` with
    ``nonfinite='null'`` (strict JSON has no NaN) or raise ValueError with ``nonfinite='error'``.
    """
    if isinstance(obj, Mapping):
        out = {}
        for k, v in obj.items():
            if not isinstance(k, str):
                raise ValueError(f"{where}: keys must be strings, got {k!r}")  # noqa: TRY004 (callers catch ValueError)
            out[k] = to_jsonable(v, f"{where}.{k}", nonfinite=nonfinite)
        return out
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v, f"{where}[{i}]", nonfinite=nonfinite) for i, v in enumerate(obj)]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist(), where, nonfinite=nonfinite)
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        if not math.isfinite(float(obj)):
            if nonfinite == "null":
                return None
            raise ValueError(f"{where}: non-finite number {obj!r} cannot be stored in JSON")
        return float(obj)
    if obj is None or isinstance(obj, str):
        return obj
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    raise ValueError(f"{where}: value of type {type(obj).__name__} is not JSON-serialisable")


def atomic_write_json(path: str | os.PathLike, data: Any, *, parents: bool = False) -> None:
    """Write ``data`` as JSON (:func:`to_jsonable`) to ``path`` atomically (temp file in the same folder, fsync,
    rename); ``parents``: create the missing folders above it first."""
    atomic_write_text(path, json.dumps(to_jsonable(data, str(path)), indent=1, allow_nan=False), parents=parents)


def _fsync(path: Path, *, strict: bool = True) -> None:
    """fsync a file or folder; folders only where the OS allows it (``strict=False`` ignores OSError)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        if strict:
            raise
        return
    try:
        os.fsync(fd)
    except OSError:
        if strict:
            raise
    finally:
        os.close(fd)


def _fsync_tree(root: Path) -> None:
    """fsync every file under ``root`` (strict) and every folder (where the OS allows it)."""
    for folder, _, files in os.walk(root):
        for name in files:
            _fsync(Path(folder) / name)
        _fsync(Path(folder), strict=False)


@contextmanager
def atomic_dir(path: str | os.PathLike, *, files: Sequence[str] | None = None) -> Iterator[Path]:
    """Yield a fresh temp folder to write into; on a clean exit, fsync its files and commit them.

    ``files=None``: the temp folder is a sibling of ``path`` (``.NAME.tmp-XXXX``) and replaces the folder
    ``path`` as a whole: an old folder of that name is moved aside (``.NAME.old-XXXX``) and deleted after
    the swap, or put back if the swap fails. NotADirectoryError if ``path`` exists and is not a folder.
    ``files=(name, ...)``: ``path`` is a folder shared with other files (created if missing); the temp
    folder is inside it (``.STEM.tmp-XXXX``, STEM = the last name without suffix) and the named files are
    moved from it into ``path`` in that order, the last one being the commit marker: an existing file of
    that name is removed first, so a kill part-way leaves no marker beside new files.
    Either way the folder that receives the result (``path``'s parent, or ``path`` itself with ``files=``) is
    fsynced after the commit, where the OS allows it. On an exception inside the block nothing is committed:
    the temp folder is removed and ``path`` is left as it was; a killed process leaves at most a hidden
    ``.NAME.tmp-XXXX`` folder, never a half-written ``path``.
    """
    path = Path(path)
    if files is None:
        parent, prefix = path.parent, path.name
        if path.exists() and not path.is_dir():
            raise NotADirectoryError(errno.ENOTDIR, "exists and is not a folder", str(path))
    else:
        if not files:
            raise ValueError("atomic_dir: files must name at least one file")
        parent, prefix = path, Path(files[-1]).stem
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{prefix}.tmp-", dir=parent))
    try:
        yield tmp
        _fsync_tree(tmp)
        if files is None:
            _swap_in(tmp, path)
        else:
            marker = path / files[-1]
            if marker.exists():
                marker.unlink()
            for name in files:
                os.replace(tmp / name, path / name)
        _fsync(parent, strict=False)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _swap_in(tmp: Path, path: Path) -> None:
    """Replace the folder ``path`` by ``tmp`` (same parent); the old folder is put back if the swap fails."""
    old = None
    if path.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{path.name}.old-", dir=path.parent))
        os.replace(path, old / path.name)
    try:
        os.replace(tmp, path)
    except BaseException:
        if old is not None:              # put the old folder back (kept on disk if even that fails)
            os.replace(old / path.name, path)
            shutil.rmtree(old, ignore_errors=True)
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
