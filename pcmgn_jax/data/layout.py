"""Dataset directories on disk: the layout, the manifest, and what a directory handed to training is.

Layout of a dataset directory ``OUT``::

    OUT/manifest.json                    # written atomically after every solver batch
    OUT/train/train_0000.{xdmf,h5,json}  # one trajectory (see trajectory_io.py)
    OUT/test/test_0000.{xdmf,h5,json}
    OUT/extrap/extrap_0000....           # any extra named split (explicit designs)
    OUT/.cache/SPLIT/                    # packed training cache (cache.py)
    OUT/.shards/PLAN-shard-K-of-N.json   # a --shard K/N run's part, until --merge writes the manifest (shards.py)

manifest.json (written by :func:`pcmgn_jax.data.dataset.ensure_dataset`)::

    {"format": "pcmgn_jax.dataset", "format_version": 1, "preset": "cpu", "scene": {...},
     "family": null | {"parameters": [[name, low, high], ...]},
     "design_layers": ["OCA1", "OCA2"], "units": {"design_m": "m", "design_um": "µm", "wall_time_s": "s"},
     "splits": {"train": {"origin": {"kind": "lhs", "seed": 0, "n_total": 150, "rows": [0, 100],
                                     "low_m": 5e-05, "high_m": 0.00015},
                          "trajectories": [{"name": "train_0000", "path": "train/train_0000",
                                            "design_m": [...], "design_um": [...],
                                            "sha256": "...", "wall_time_s": 1.9}, ...]}, ...}}

Datasets without a manifest (:func:`dataset_source`): ``OUT/train/*.json|.h5|.xdmf`` and
``OUT/test/...`` as ``python -m experiments.import_ansys --exports EXPORTS --out OUT`` writes them (or any
trajectory files in that layout) are read as they are; the solver never writes into such a directory.
Everything here only reads.
"""
from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["DATASET_FORMAT", "GENERATE", "IMPORTED", "LEGACY_ELEMENT", "MANIFEST", "SHARD_PARTS", "SPLITS",
           "DatasetError", "check_element", "check_entry", "check_run_element", "dataset_source", "entry_mismatch",
           "has_shard_parts", "has_trajectory_files", "load_manifest", "manifest_element", "meta_design",
           "read_format_json", "split_stems", "trajectory_element"]

MANIFEST = "manifest.json"
SHARD_PARTS = ".shards"                # folder of the per-shard manifest parts (pcmgn_jax.data.shards)
GENERATE = "generate"                  # dataset_source: absent directory or generator manifest -> the solver
IMPORTED = "imported"                  # dataset_source: trajectory files without a manifest -> read as they are
SPLITS = ("train", "test")             # the splits a directory without a manifest is recognised by
DATASET_FORMAT = "pcmgn_jax.dataset"
#: the element of every solver trajectory and generated manifest written before the element was recorded
#: (full-integration Q4, which locks in bending: pcmgn_jax.sim.fem)
LEGACY_ELEMENT = "q4"


class DatasetError(ValueError):
    """Inconsistent dataset directory / arguments, or designs the solver could not run."""


def load_manifest(dataset_dir: str | os.PathLike) -> dict[str, Any] | None:
    """The dataset manifest, or None when there is none. DatasetError if it is not a manifest."""
    path = Path(dataset_dir) / MANIFEST
    if not path.exists():
        return None
    return read_format_json(path, DATASET_FORMAT, "manifest")


def read_format_json(path: Path, fmt: str, what: str) -> dict[str, Any]:
    """The JSON object in ``path`` whose field 'format' is ``fmt``; DatasetError naming the file (and ``what``
    it should be) otherwise."""
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise DatasetError(f"{path}: cannot parse {what}: {err}") from None
    if not isinstance(data, dict) or data.get("format") != fmt:
        raise DatasetError(f"{path}: field 'format' is not {fmt!r}")
    return data


def has_trajectory_files(root: Path) -> bool:
    """True when ``root/train`` or ``root/test`` holds a trajectory sidecar (``NAME.json``)."""
    return any((root / s).is_dir() and any((root / s).glob("*.json")) for s in SPLITS)


def has_shard_parts(root: Path) -> bool:
    """True when ``root/.shards`` holds a shard part (``experiments.generate --shard K/N``, not merged yet)."""
    return (root / SHARD_PARTS).is_dir() and any((root / SHARD_PARTS).glob("*-shard-*-of-*.json"))


def dataset_source(dataset_dir: str | os.PathLike) -> str:
    """What a dataset directory handed to training is; the one rule for whether the solver may run.

    :data:`GENERATE` -- the directory does not exist, or holds a generator manifest (``manifest.json``):
        :func:`pcmgn_jax.data.dataset.ensure_dataset` generates the missing trajectories with the solver
        (resumable, verified).
    :data:`IMPORTED` -- no manifest, but ``DIR/train/`` or ``DIR/test/`` holds trajectory files
        (``NAME.json`` + ``.h5`` + ``.xdmf``, as ``experiments.import_ansys --exports EXPORTS --out DIR``
        writes them): read as they are, never regenerated or added to.
    Anything else (a directory that exists with neither, e.g. empty, or a folder of ANSYS run folders),
    or shard parts without a manifest (a sharded generation not merged yet): a one-line DatasetError
    naming the directory and what is expected. Reads only; writes nothing.
    """
    root = Path(dataset_dir)
    if not root.exists() or load_manifest(root) is not None:
        return GENERATE
    if not root.is_dir():
        raise DatasetError(f"{root}: not a directory; expected a dataset directory")
    if has_shard_parts(root):
        raise DatasetError(f"{root}: holds shard parts ({SHARD_PARTS}/) but no {MANIFEST}: a sharded generation "
                           f"that is not merged yet; run python -m experiments.generate --merge --out {root} with "
                           "the shards' other flags")
    if has_trajectory_files(root):
        return IMPORTED
    raise DatasetError(f"{root}: no {MANIFEST} and no trajectory files in {root / 'train'} or {root / 'test'}; "
                       f"expected a generated dataset (python -m experiments.generate --out {root}), trajectories "
                       f"in train/ and test/ (python -m experiments.import_ansys --exports EXPORTS --out {root}), "
                       "or a directory that does not exist yet (generated with the solver)")


def split_stems(dataset_dir: str | os.PathLike, split: str) -> list[Path]:
    """Path stems (``OUT/split/name``) of a split's trajectories, in manifest order.

    Without a manifest: the sorted sidecars found in ``OUT/split``. DatasetError if the split is unknown.
    """
    root = Path(dataset_dir)
    man = load_manifest(root)
    if man is not None:
        if split not in man.get("splits", {}):
            raise DatasetError(f"{root / MANIFEST}: no split {split!r}; have {sorted(man.get('splits', {}))}")
        return [root / e["path"] for e in man["splits"][split]["trajectories"]]
    folder = root / split
    if not folder.is_dir():
        raise DatasetError(f"{folder}: split {split!r} not found (and no {MANIFEST})")
    return [p.with_suffix("") for p in sorted(folder.glob("*.json"))]


def meta_design(meta: dict[str, Any], layers: Sequence[str]) -> list[float] | None:
    """The design-layer thicknesses [m] a trajectory's meta (or sidecar) records under 'design' ({layer: m}
    or a list), in ``layers``' order; None when it records none (or not for these layers)."""
    d = meta.get("design")
    if isinstance(d, dict):
        try:
            return [float(d[k]) for k in layers]
        except KeyError:
            return None
    if isinstance(d, (list, tuple)):
        return [float(v) for v in d]
    return None


def manifest_element(man: dict[str, Any]) -> str:
    """The solver element a generated dataset's manifest was made with (:data:`LEGACY_ELEMENT` where it
    records none: it predates the record)."""
    return str(man.get("element", LEGACY_ELEMENT))


def trajectory_element(meta: dict[str, Any]) -> str | None:
    """The solver element a trajectory's meta records (``meta['solver']['settings']['element']``;
    :data:`LEGACY_ELEMENT` for a solver trajectory that predates the record); None for a trajectory that does
    not come from the built-in solver (imported, synthetic)."""
    solver = meta.get("solver")
    if not isinstance(solver, dict) or not isinstance(solver.get("settings"), dict):
        return None
    return str(solver["settings"].get("element", LEGACY_ELEMENT))


def check_element(root: Path, man: dict[str, Any]) -> None:
    """DatasetError when a generated dataset was made with another element than the solver's default: its
    trajectories must not be trained on, scored or extended beside the current solver's."""
    from pcmgn_jax.sim.fem import DEFAULT_ELEMENT

    have = manifest_element(man)
    if have != DEFAULT_ELEMENT:
        raise DatasetError(f"{root / MANIFEST}: generated with the {have!r} element, the solver now makes "
                           f"{DEFAULT_ELEMENT!r}: regenerate into another --out (or delete {root}); the two are "
                           "never mixed (pcmgn_jax.sim.fem)")


def check_run_element(workdir: Path, record: dict[str, Any] | None, trajectories: Sequence[Any] = ()) -> None:
    """DatasetError when a trained run (its ``RUN/data.json`` ``record``) or the solver trajectories it is asked to
    score were made with another element than the solver's default. A record without an ``element`` is the old
    element where its data came from the solver (it predates the record), unknown (accepted) for imported data."""
    from pcmgn_jax.sim.fem import DEFAULT_ELEMENT

    if record is not None:
        trained = record.get("element", LEGACY_ELEMENT if record.get("source") == GENERATE else None)
        if trained is not None and trained != DEFAULT_ELEMENT:
            raise DatasetError(f"{workdir}: trained on {trained!r}-element trajectories, the solver now makes "
                               f"{DEFAULT_ELEMENT!r}: retrain it on a regenerated dataset (its figures are of the old "
                               "ground truth)")
    for t in trajectories:
        made = trajectory_element(t.meta)
        if made is not None and made != DEFAULT_ELEMENT:
            raise DatasetError(f"{t.meta.get('name', 'a trajectory')}: made with the {made!r} element, the solver now "
                               f"makes {DEFAULT_ELEMENT!r}; regenerate it")


def entry_mismatch(entry: dict[str, Any], meta: dict[str, Any], layers: Sequence[str],
                   element: str | None = None) -> str | None:
    """What a manifest entry records that its trajectory's meta (or sidecar) does not (the design [m], the
    scene parameters; the solver element where ``element`` is given and the trajectory records one), or None
    when they agree (relative tolerance 1e-9)."""
    made = trajectory_element(meta)
    if element is not None and made is not None and made != element:
        return f"element {element!r} in the manifest, {made!r} in the trajectory"
    d = meta_design(meta, layers)
    if d is not None and (len(d) != len(entry["design_m"])
                          or not np.allclose(d, entry["design_m"], rtol=1e-9, atol=0)):
        return f"design_m {entry['design_m']} in the manifest, {d} in the trajectory"
    want = entry.get("scene_params")
    if want is not None:
        got = meta.get("scene_params") or {}
        if set(got) != set(want) or not np.allclose([got[k] for k in want], list(want.values()), rtol=1e-9, atol=0):
            return f"scene_params {want} in the manifest, {got} in the trajectory"
    return None


def check_entry(root: Path, entry: dict[str, Any], side: dict[str, Any], layers: Sequence[str],
                element: str | None = None) -> None:
    """DatasetError naming the manifest, the entry and the sidecar when a finished manifest entry disagrees
    with its trajectory's sidecar (content hash, design, scene parameters): one of them was changed."""
    why = None
    if entry.get("sha256") and entry["sha256"] != side.get("sha256"):
        why = f"sha256 {entry['sha256'][:12]}... in the manifest, {str(side.get('sha256'))[:12]}... in the sidecar"
    why = why or entry_mismatch(entry, side, layers, element)
    if why:
        raise DatasetError(f"{root / MANIFEST}: entry {entry.get('name')!r} disagrees with {root / entry['path']}.json "
                           f"({why}): the manifest or the trajectory was changed; regenerate it "
                           f"(python -m experiments.generate --out {root} with its flags) or restore the file")
