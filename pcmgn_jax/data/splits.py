"""What a training or evaluation run reads from a dataset directory.

:func:`prepare_dataset` makes a directory ready to load (by :func:`pcmgn_jax.data.layout.dataset_source`:
a generated dataset gets its missing trajectories from the solver, an imported one is left as it is);
:func:`load_splits` returns its (train, val, test) trajectories through the memory-mapped cache
(:mod:`pcmgn_jax.data.cache`) and never runs the solver; :func:`load_directory` reads any folder of
trajectory files.
"""
from __future__ import annotations

import os
from pathlib import Path

from pcmgn_jax.data.cache import load_split
from pcmgn_jax.data.dataset import FAMILIES, ensure_dataset
from pcmgn_jax.data.family import Design, Family
from pcmgn_jax.data.layout import GENERATE, IMPORTED, DatasetError, check_element, dataset_source, load_manifest
from pcmgn_jax.data.trajectory_io import TrajectoryFileError, read_sidecar, read_trajectory, write_trajectory
from pcmgn_jax.lock import hold
from pcmgn_jax.trajectory import Trajectory

__all__ = ["load_directory", "load_splits", "pool_datasets", "prepare_dataset", "split_designs"]


def load_directory(path: str | os.PathLike) -> list[Trajectory]:
    """Every trajectory in a directory of trajectory files (``*.json`` sidecars beside their ``.h5``/
    ``.xdmf``, e.g. one split of a dataset or an importer's output), sorted by name, hash-verified. Writes
    nothing. DatasetError naming the directory when it holds none."""
    folder = Path(path)
    if not folder.is_dir():
        raise DatasetError(f"{folder}: not a directory of trajectory files")
    stems = [p.with_suffix("") for p in sorted(folder.glob("*.json")) if p.with_suffix(".h5").exists()]
    if not stems:
        raise DatasetError(f"{folder}: no trajectory files (NAME.json + NAME.h5) here")
    return [read_trajectory(s) for s in stems]


def prepare_dataset(dataset_dir: str | os.PathLike, *, preset: str, n_train: int, n_test: int, seed: int = 0,
                    **generate) -> tuple[Path, str]:
    """``(Path(dataset_dir), source)``: the dataset a training run reads, ready to load.

    By :func:`dataset_source`: a :data:`GENERATE` directory gets its missing trajectories from the solver
    (:func:`pcmgn_jax.data.dataset.ensure_dataset` with ``preset``, ``n_train``, ``n_test``, ``seed`` and
    ``generate``); an :data:`IMPORTED` one is left as it is (the preset's designs and the generation sizes
    play no part); anything else is the DatasetError of :func:`dataset_source`, before anything is written.
    A complete generated dataset of the same preset and LHS seed that holds *more* train / test
    trajectories than asked for is read as it is, its first rows (a random subset of its hypercube,
    :func:`load_splits`): a smaller run, e.g. a learning-curve point, needs no second dataset.
    """
    root = Path(dataset_dir)
    source = dataset_source(root)
    man = load_manifest(root) if source == GENERATE else None
    if man is not None:
        check_element(root, man)
    if source == GENERATE and not _covers(root, preset=preset, n_train=n_train, n_test=n_test, seed=seed):
        ensure_dataset(root, preset=preset, n_train=n_train, n_test=n_test, seed=seed, **generate)
    return root, source


def _covers(root: Path, *, preset: str, n_train: int, n_test: int, seed: int) -> bool:
    """True when ``root``'s manifest is a finished LHS (or stack-family) dataset of ``preset`` and ``seed``
    with at least ``n_train`` train and ``n_test`` test trajectories (every one written: a sha256 recorded)."""
    man = load_manifest(root)
    if not man or man.get("preset") != preset:
        return False
    for split, need in (("train", n_train), ("test", n_test)):
        sp = man["splits"].get(split)
        if need == 0:
            continue
        if sp is None or sp["origin"].get("kind") not in ("lhs", "stack") or sp["origin"].get("seed") != seed:
            return False
        done = [e for e in sp["trajectories"] if e.get("sha256")]
        if len(done) < need or len(done) < len(sp["trajectories"]):
            return False
    return True


def split_designs(dataset_dir: str | os.PathLike, split: str, *, family: Family | None = None) -> list[Design]:
    """The designs of the split ``split`` of a generated dataset, in its order (from its manifest; solves and
    reads no trajectory): a family's rows (``scene_params`` [SI]; ``family`` default the preset's, given for
    a family passed to :func:`ensure_dataset` ``family=``), else the design-layer thicknesses [m].
    DatasetError naming the directory when it has no manifest or no such split, or when the rows are not
    ``family``'s."""
    root = Path(dataset_dir)
    man = load_manifest(root)
    if man is None or split not in man["splits"]:
        raise DatasetError(f"{root}: no generated split {split!r} (splits: {sorted((man or {}).get('splits', {}))})")
    family = family if family is not None else FAMILIES.get(man.get("preset") or "")
    out = []
    for e in man["splits"][split]["trajectories"]:
        if man.get("family") is None:
            out.append(Design.of(None, e["design_m"], man["design_layers"]))
            continue
        if family is None or list(e["scene_params"]) != list(family.names):
            raise DatasetError(f"{root}: split {split!r} holds rows of {list(e['scene_params'])}, not of the "
                               f"family {getattr(family, 'name', None)!r}: pass its family")
        out.append(Design.of(family, list(e["scene_params"].values())))
    return out


def load_splits(dataset_dir: str | os.PathLike, *, n_train: int, n_val: int, n_test: int):
    """(train, val, test) trajectories of a dataset directory (never runs the solver).

    With a manifest (a generated dataset): ``train`` and ``val`` are the first ``n_train`` and next
    ``n_val`` trajectories of the split ``train`` (the Latin-hypercube rows are in random order, so both
    are random subsets).
    Without one (an imported dataset, :func:`dataset_source`; the trajectories sorted by file name):
    ``train`` is the first ``n_train`` and ``val`` the LAST ``n_val`` of the split ``train``, so the
    validation trajectories stay the same whatever ``n_train`` is (and with exactly n_train + n_val
    trajectories, as ``experiments.generate`` writes them, both rules pick the same ones); trajectories
    between the two are not used. Name the runs so that the last ones are the validation runs you want.
    ``test`` is the first ``n_test`` of the split ``test`` either way. Reading builds the memory-mapped
    cache in ``DIR/.cache/`` (:mod:`pcmgn_jax.data.cache`). DatasetError naming the directory (and the
    generating command, or the flags) when the dataset is missing or too small.
    """
    root = Path(dataset_dir)
    if not root.exists():
        raise DatasetError(f"{root}: no dataset here; generate it with `python -m experiments.generate "
                           f"--out {root} ...` (or `python -m experiments.train`, which generates its preset's data)")
    imported = dataset_source(root) == IMPORTED
    train = load_split(root, "train") if n_train + n_val else []
    test = load_split(root, "test") if n_test else []
    need = n_train + n_val
    if len(train) < need or len(test) < n_test:
        hint = " (set --n_train, --n_val and --n_test to fit)" if imported else ""
        raise DatasetError(f"{root}: holds {len(train)} train / {len(test)} test trajectories, the config needs "
                           f"n_train + n_val = {need} and n_test = {n_test}{hint}")
    if imported:
        return train[:n_train], train[len(train) - n_val:], test[:n_test]
    return train[:n_train], train[n_train:need], test[:n_test]


def pool_datasets(sources, out_dir: str | os.PathLike, *, progress=None) -> Path:
    """Pool the ``train`` splits of the dataset directories ``sources`` (in that order, each sorted by
    name) and the ``test`` split of the first into ``out_dir``, renumbered ``train_0000``... and
    ``test_0000``...: a directory of trajectory files without a manifest, which
    :func:`load_splits` reads as an imported dataset (train = the first n_train, validation = the last
    n_val). For a learning curve that needs more training scenes than one Latin hypercube holds, with
    the same test scenes (e.g. ``data/family`` + a second LHS of another seed).

    Resumable: a pooled file whose content hash equals its source's is kept; nothing is half-written
    (:func:`pcmgn_jax.data.trajectory_io.write_trajectory` is atomic). DatasetError naming the source
    when it has no such split, or when ``out_dir`` holds a manifest (a generated dataset is never mixed
    into). ``progress``: optional callable(done, total)."""
    out = Path(out_dir)
    sources = [Path(s) for s in sources]
    if not sources:
        raise DatasetError("pool_datasets: no source datasets given")
    if (out / "manifest.json").exists():
        raise DatasetError(f"{out}: holds a manifest (a generated dataset); pool into a new directory")
    plan = []
    for split, dirs in (("train", sources), ("test", sources[:1])):
        stems = []
        for src in dirs:
            folder = src / split
            found = sorted(p.with_suffix("") for p in folder.glob("*.json")) if folder.is_dir() else []
            if not found:
                raise DatasetError(f"{folder}: no trajectory files to pool (split {split!r} of {src})")
            stems += found
        plan += [(stem, out / split / f"{split}_{i:04d}") for i, stem in enumerate(stems)]
        extra = sorted({p.stem for p in (out / split).glob("*.json")}
                       - {t.name for _, t in plan if t.parent.name == split})
        if extra:
            raise DatasetError(f"{out / split}: holds trajectories the pool would not write ({extra[:3]}...): "
                               "pool into a new directory")
    with hold(out, "generate --pool"):      # one writer per dataset folder
        for done, (stem, target) in enumerate(plan):
            want = read_sidecar(stem)["sha256"]
            try:
                have = read_sidecar(target)["sha256"]
            except TrajectoryFileError:
                have = None
            if have != want:
                target.parent.mkdir(parents=True, exist_ok=True)
                write_trajectory(read_trajectory(stem), target)
            if progress is not None:
                progress(done + 1, len(plan))
    return out
