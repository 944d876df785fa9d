"""The training pipeline as a library call: ``pcmgn_jax.train.run(cfg, workdir)``.

Prepares the dataset (``cfg.resolved_dataset_dir``, generated with the solver when missing,
:func:`pcmgn_jax.data.splits.prepare_dataset`), loads the training and validation splits, writes
``WORKDIR/data.json`` (which trajectories the run trains and validates on) and trains
(:func:`pcmgn_jax.train.loop.train`). ``experiments/train.py`` parses flags and calls :func:`run`.
"""
from __future__ import annotations

import os
import time
from pathlib import Path

from pcmgn_jax.config import TrainConfig
from pcmgn_jax.lock import hold


def run(cfg: TrainConfig, workdir: str | Path, *, resume: bool = False, overwrite: bool = False) -> dict:
    """Train ``cfg`` in ``workdir``; returns :func:`pcmgn_jax.train.loop.train`'s result dict
    (``step``, ``seconds``, ``best_val`` in the unit of ``select_on``, ...). ``resume``: continue from the last
    checkpoint.

    A workdir that holds a run is never replaced silently (:func:`claim`): without ``resume`` it is refused
    unless ``overwrite``, which moves the earlier run aside. The dataset is made (when missing), loaded and
    checked against the model (:func:`check_model_fits`) before the workdir is created; the workdir is then locked
    for the whole run (:func:`pcmgn_jax.lock.hold`: one writer per workdir); nothing is written before every
    check passed."""
    import jax

    from pcmgn_jax.data.layout import dataset_source
    workdir = Path(workdir)
    if jax.process_index() != 0:     # several hosts: process 0 checks, locks and writes the run's files
        return _run_locked(cfg, workdir, _data(cfg), resume=resume)
    claim(workdir, resume=resume, overwrite=overwrite, dry=True)   # refuse before the dataset is made
    dataset_source(cfg.resolved_dataset_dir)                        # a folder that is no dataset: refused here
    data = _data(cfg)                 # the dataset checked (and made when missing) before the run folder exists
    check_model_fits(cfg, data[2] + data[3])
    with hold(workdir, "train"):
        claim(workdir, resume=resume, overwrite=overwrite)
        return _run_locked(cfg, workdir, data, resume=resume)


RUN_FILES = ("config.json", "metrics.jsonl", "checkpoints")   # what makes a folder hold a run worth keeping


class RunFolderError(ValueError):
    """A folder training may not write into, named with the values that refuse it; ``reason`` says which rule
    (``resume_and_overwrite`` | ``not_a_folder`` | ``holds_run``), ``workdir`` the folder and ``found`` the run
    files it holds, so an entry point can say it in its own flags (``experiments/train.py``)."""

    def __init__(self, message: str, *, reason: str, workdir: Path, found: tuple[str, ...] = ()):
        super().__init__(message)
        self.reason, self.workdir, self.found = reason, workdir, found


def claim(workdir: Path, *, resume: bool, overwrite: bool, dry: bool = False) -> None:
    """Check that training may write into ``workdir``: :class:`RunFolderError` naming the folder when it
    holds a run (:data:`RUN_FILES`) and neither ``resume`` nor ``overwrite`` is given, or when both are;
    with ``overwrite`` (and not ``dry``) the earlier run's files are moved to ``WORKDIR.old-<UTC time>``
    (said on stdout); nothing is deleted. A file where the folder should be is refused."""
    if resume and overwrite:
        raise RunFolderError(f"{workdir}: resume=True and overwrite=True exclude each other: continue the run, or "
                             "start it over", reason="resume_and_overwrite", workdir=workdir)
    if workdir.exists() and not workdir.is_dir():
        raise RunFolderError(f"{workdir}: exists and is not a folder", reason="not_a_folder", workdir=workdir)
    found = tuple(n for n in RUN_FILES if (workdir / n).exists())
    if not found or resume:
        return
    if not overwrite:
        raise RunFolderError(f"{workdir}: holds a run ({', '.join(found)}); continue it (resume=True), or start it "
                             f"over (overwrite=True: moves it aside to {workdir.name}.old-<time>)",
                             reason="holds_run", workdir=workdir, found=found)
    if dry:
        return
    old = workdir.with_name(f"{workdir.name}.old-{time.strftime('%Y%m%d-%H%M%S', time.gmtime())}")
    if old.exists():
        old = old.with_name(f"{old.name}-{os.getpid()}")
    old.mkdir()
    for p in sorted(workdir.iterdir()):
        if p.name != ".lock":                  # the lock stays with the folder it guards
            os.replace(p, old / p.name)
    print(f"overwrite: moved the earlier run in {workdir} to {old}")


def _data(cfg: TrainConfig) -> tuple:
    """(dataset root, its source, train, val) of ``cfg``: generated where missing, loaded, checked."""
    from pcmgn_jax.data.splits import load_splits, prepare_dataset
    root, source = prepare_dataset(cfg.resolved_dataset_dir, preset=cfg.data_preset,
                                   n_train=cfg.n_train + cfg.n_val, n_test=cfg.n_test, seed=cfg.data_seed)
    train, val, _ = load_splits(root, n_train=cfg.n_train, n_val=cfg.n_val, n_test=0)
    return root, source, train, val


def check_model_fits(cfg: TrainConfig, trajs) -> None:
    """ValueError naming the graph when the model asks for more than the training graphs hold: coarse levels
    (``reach='multiscale'``) beyond the point where the smallest graph is one node per connected part (more
    levels repeat the last, and only make the compiled program grow), or more attention slices
    (``reach='attention'``) than the smallest graph has nodes."""
    form = cfg.formulation
    if form.reach not in ("multiscale", "attention") or not trajs:
        return
    small = min(trajs, key=lambda t: t.n_nodes)
    what = f"{small.meta.get('name', 'a graph')} ({small.n_nodes} nodes)"
    if form.reach == "attention":
        if form.reach_slices > small.n_nodes:
            raise ValueError(f"reach_slices={form.reach_slices} is more than the graphs hold: {what}; use "
                             f"reach_slices <= {small.n_nodes}")
        return
    from pcmgn_jax.mgn.hierarchy import shrinking_levels
    from pcmgn_jax.mgn.inputs import topology_from_trajectory
    topo = topology_from_trajectory(small)
    most = shrinking_levels(topo.mesh_senders, topo.mesh_receivers, topo.n_node)
    if form.reach_levels > most:
        raise ValueError(f"reach_levels={form.reach_levels} is more than the graphs hold: {what} is one node per "
                         f"connected part after {most} coarse levels; use reach_levels <= {most}")


def _run_locked(cfg: TrainConfig, workdir: Path, data: tuple, *, resume: bool) -> dict:
    from pcmgn_jax.data.layout import IMPORTED, split_stems
    from pcmgn_jax.train import loop as training
    root, source, train, val = data
    if source == IMPORTED:
        have = len(split_stems(root, "train"))
        unused = have - len(train) - len(val)
        print(f"data: {root} (imported, no manifest): training on the first {len(train)} and validating on the "
              f"last {len(val)} of {have} trajectories in {root / 'train'} by name"
              + (f"; {unused} in between unused (raise n_train to use them)" if unused else ""))
    write_data_record(workdir, root, source, train, val)
    train, val = network_trajectories(cfg, train, val)
    return training.train(cfg, str(workdir), train_trajs=train, val_trajs=val, resume=resume)


def network_trajectories(cfg: TrainConfig, train, val) -> tuple:
    """What the network is trained and validated on: the trajectories, or with ``residual_of`` the baseline's error
    on them (pcmgn_jax/surrogates/residual.py)."""
    if not cfg.residual_of:
        return train, val
    from pcmgn_jax.surrogates.residual import residual_splits
    return residual_splits(cfg.residual_of, train, val)


SIZE_FIELDS = ("n_train", "n_val", "n_test", "data_seed")


def fit_to_dataset(cfg: TrainConfig, *, given=()) -> TrainConfig:
    """``cfg`` with the sizes of a generated dataset at ``cfg.dataset_dir`` (one with a manifest), except
    the fields named in ``given`` (flags the user wrote; :data:`SIZE_FIELDS`): the manifest's train split
    (n_train + n_val designs) is used whole: ``n_val`` is the one the manifest records, else ``cfg.n_val``,
    capped so at least one trajectory trains, ``n_train`` the rest; ``n_test`` is the test split's count;
    ``data_seed`` the train split's Latin-hypercube seed. Unchanged without ``dataset_dir``, for a directory
    without a manifest (imported trajectories) or one that does not exist yet (it will be generated)."""
    from pcmgn_jax.data.layout import load_manifest
    if not cfg.dataset_dir or not Path(cfg.dataset_dir).is_dir():
        return cfg
    man = load_manifest(cfg.dataset_dir)
    if man is None or "train" not in man.get("splits", {}):
        return cfg
    train = man["splits"]["train"]
    have = len(train.get("trajectories", []))
    if have < 2 and "n_train" not in given:
        return cfg  # too small to split: load_splits names what is missing
    kw = {}
    n_val = cfg.n_val if "n_val" in given else min(int(train.get("n_val", cfg.n_val)), have - 1)
    kw["n_val"] = n_val
    if "n_train" not in given:
        kw["n_train"] = have - n_val
    if "n_test" not in given:
        kw["n_test"] = len(man["splits"].get("test", {}).get("trajectories", []))
    origin = train.get("origin") or {}
    if "data_seed" not in given and origin.get("kind") == "lhs" and "seed" in origin:
        kw["data_seed"] = int(origin["seed"])
    return cfg.replace(**kw)


def write_data_record(workdir, root, source: str, train, val) -> None:
    """RUN/data.json (atomic; process 0 only): which trajectories this run trains and validates on."""
    import jax

    from pcmgn_jax.atomic import atomic_write_json
    if jax.process_index() != 0:
        return
    from pcmgn_jax.data.layout import trajectory_element
    def item(t):
        return {"name": t.meta.get("name"), "sha256": t.meta.get("source_sha256"),
                "source": t.meta.get("source"), "n_nodes": int(t.n_nodes), "element": trajectory_element(t.meta)}
    elements = {trajectory_element(t.meta) for t in [*train, *val]}
    Path(workdir).mkdir(parents=True, exist_ok=True)
    atomic_write_json(Path(workdir) / "data.json", {
        "format": "pcmgn_jax.run_data", "format_version": 1, "dataset_dir": str(Path(root).resolve()),
        "source": source, "element": elements.pop() if len(elements) == 1 else sorted(map(str, elements)),
        "train": [item(t) for t in train], "val": [item(t) for t in val]})
