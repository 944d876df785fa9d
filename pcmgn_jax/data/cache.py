"""Packed, memory-mapped training cache of one dataset split.

``OUT/.cache/SPLIT/`` holds one ``.npy`` file per Trajectory array field, each the flat (1-D)
concatenation of that field over all trajectories of the split (in manifest order), plus
``index.json``: per trajectory its name, source content hash (sha256 from the sidecar), shapes,
element offsets into each ``.npy`` and its meta dict. Loading maps the files with
``np.load(mmap_mode='r')`` and hands out zero-copy reshaped views, so a split loads in milliseconds
regardless of size; pages are read on first touch.

The cache is keyed on the content it was built from: per trajectory its name, its sidecar's sha256 and
the size and sha256 of the bytes of each of its files (``.json``, ``.h5``, ``.xdmf``; hashed at every load,
milliseconds per megabyte). When any of them changes (a file truncated, edited in place with its size and
modification time kept, rewritten or replaced behind an unchanged sidecar), the cache is rebuilt, and the
build reads every trajectory with hash verification and finiteness checks (``read_trajectory(verify=True)``),
so a damaged file is refused with its name (TrajectoryFileError), never trained on from an old cache. With a
manifest, every entry is checked against its trajectory's sidecar first (content hash, design, scene
parameters; :func:`pcmgn_jax.data.layout.check_entry`) at every load. A build writes into a temporary
directory and swaps it in (:func:`pcmgn_jax.atomic.atomic_dir`; index.json last), so a killed build never
leaves a cache that loads; concurrent builds of one split wait for each other (the lock
``OUT/.cache/.lock-SPLIT``, :func:`pcmgn_jax.lock.hold`). Arrays keep their dtypes; if trajectories of one
split have different dtypes for a field, the field is stored in their common (promoted) dtype.
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from pcmgn_jax.atomic import atomic_dir, atomic_write_json
from pcmgn_jax.data.layout import check_entry, load_manifest, manifest_element, split_stems
from pcmgn_jax.data.trajectory_io import (
    ARRAY_FIELDS,
    RESERVED_KEYS,
    TrajectoryFileError,
    read_sidecar,
    read_trajectory,
    trajectory_paths,
)
from pcmgn_jax.lock import hold
from pcmgn_jax.trajectory import Trajectory

__all__ = ["CACHE_DIR", "cache_dir", "ensure_cache", "load_split"]

CACHE_DIR = ".cache"
INDEX = "index.json"
CACHE_FORMAT = "pcmgn_jax.cache"
CACHE_VERSION = 3                      # 3: sources keyed on each file's size and sha256 (2: size, mtime)


def cache_dir(dataset_dir: str | os.PathLike, split: str) -> Path:
    """``dataset_dir/.cache/split``."""
    return Path(dataset_dir) / CACHE_DIR / split


def _stat(stem: Path) -> list[list]:
    """[size, sha256 of the bytes] of a trajectory's .json, .h5 and .xdmf ([-1, ""] for a missing one): a file
    edited in place, whatever its size and modification time, changes the key."""
    out: list[list] = []
    for p in trajectory_paths(stem)[::-1]:
        try:
            with open(p, "rb") as f:
                out.append([os.fstat(f.fileno()).st_size, hashlib.file_digest(f, "sha256").hexdigest()])
        except FileNotFoundError:
            out.append([-1, ""])
    return out


def _sources(dataset_dir: Path, split: str) -> list[dict[str, Any]]:
    man = load_manifest(dataset_dir)
    entries = man["splits"][split]["trajectories"] if man is not None and split in man.get("splits", {}) else None
    out = []
    for i, stem in enumerate(split_stems(dataset_dir, split)):
        side = read_sidecar(stem)
        if entries is not None:
            check_entry(dataset_dir, entries[i], side, man.get("design_layers", ()), manifest_element(man))
        out.append({"name": stem.name, "path": str(stem.relative_to(dataset_dir)), "sha256": side["sha256"],
                    "files": _stat(stem), "n_nodes": side["n_nodes"], "n_cells": side["n_cells"],
                    "n_frames": side["n_frames"], "dtypes": side["dtypes"]})
    if not out:
        raise TrajectoryFileError(f"{dataset_dir}: split {split!r} has no trajectories")
    return out


def _read_index(path: Path) -> dict[str, Any] | None:
    try:
        idx = json.loads((path / INDEX).read_text())
    except (OSError, json.JSONDecodeError):
        return None
    if idx.get("format") != CACHE_FORMAT or idx.get("format_version") != CACHE_VERSION:
        return None
    return idx


def _shapes(n: int, e: int, t: int) -> dict[str, tuple[int, ...]]:
    return {"points": (n, 2), "cells": (e, 4), "cell_part": (e,), "node_part": (n,), "node_type": (n,),
            "times": (t,), "displacement": (t, n, 2), "velocity": (t, n, 2), "von_mises": (t, n)}


def _build(dataset_dir: Path, split: str, sources: list[dict[str, Any]]) -> None:
    with atomic_dir(cache_dir(dataset_dir, split)) as tmp:
        shapes = [_shapes(s["n_nodes"], s["n_cells"], s["n_frames"]) for s in sources]
        entries, outs, fields = [], {}, {}
        for f in ARRAY_FIELDS:
            dtype = np.result_type(*[np.dtype(s["dtypes"][f]) for s in sources])
            sizes = [int(np.prod(sh[f])) for sh in shapes]
            offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
            outs[f] = np.lib.format.open_memmap(tmp / f"{f}.npy", mode="w+", dtype=dtype,
                                                shape=(int(offsets[-1]),))
            fields[f] = {"file": f"{f}.npy", "dtype": dtype.str, "offsets": offsets.tolist()}
        for i, src in enumerate(sources):
            traj = read_trajectory(dataset_dir / src["path"], verify=True)
            for f in ARRAY_FIELDS:
                a, b = fields[f]["offsets"][i], fields[f]["offsets"][i + 1]
                outs[f][a:b] = np.asarray(getattr(traj, f)).reshape(-1)
            entries.append({"name": src["name"], "path": src["path"], "sha256": src["sha256"],
                            "shapes": {f: list(shapes[i][f]) for f in ARRAY_FIELDS},
                            "meta": {k: v for k, v in traj.meta.items() if k not in RESERVED_KEYS}})
        for f in ARRAY_FIELDS:
            outs[f].flush()
            del outs[f]
        atomic_write_json(tmp / INDEX, {
            "format": CACHE_FORMAT, "format_version": CACHE_VERSION, "split": split,
            "sources": _key(sources),
            "fields": fields, "trajectories": entries})


def ensure_cache(dataset_dir: str | os.PathLike, split: str, *, force: bool = False) -> tuple[Path, bool]:
    """Build the cache of ``split`` if missing or stale; return ``(cache path, rebuilt?)``."""
    root = Path(dataset_dir)
    path = cache_dir(root, split)
    sources = _sources(root, split)
    if not force and _fresh(path, sources):
        return path, False
    with hold(root / CACHE_DIR, f"cache build of {split!r}", name=f".lock-{split}", wait=True):
        sources = _sources(root, split)      # another process may have built it while this one waited
        if not force and _fresh(path, sources):
            return path, False
        _build(root, split, sources)
    return path, True


def _key(sources: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{"name": s["name"], "sha256": s["sha256"], "files": s["files"]} for s in sources]


def _fresh(path: Path, sources: list[dict[str, Any]]) -> bool:
    idx = _read_index(path)
    return idx is not None and idx.get("sources") == _key(sources)


def load_split(dataset_dir: str | os.PathLike, split: str) -> list[Trajectory]:
    """All trajectories of ``split`` as Trajectories whose arrays are read-only memmap views.

    Rebuilds the cache first when the split's content hashes changed (see module docstring).
    ``meta`` is the sidecar's plus ``name`` and ``source_sha256``.
    Shapes and units as in :class:`pcmgn_jax.trajectory.Trajectory`.
    """
    path, _ = ensure_cache(dataset_dir, split)
    idx = _read_index(path)
    if idx is None:
        raise TrajectoryFileError(f"{path / INDEX}: cache index missing or unreadable")
    arrays = {f: np.load(path / spec["file"], mmap_mode="r", allow_pickle=False)
              for f, spec in idx["fields"].items()}
    out = []
    for i, entry in enumerate(idx["trajectories"]):
        kw = {}
        for f in ARRAY_FIELDS:
            offs = idx["fields"][f]["offsets"]
            kw[f] = arrays[f][offs[i]:offs[i + 1]].reshape(entry["shapes"][f])
        out.append(Trajectory(**kw, meta=dict(entry["meta"], name=entry["name"], source_sha256=entry["sha256"])))
    return out
