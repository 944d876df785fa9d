"""Checkpoints of a trained simulator, and the one way to load one for inference.

A run directory holds ``config.json`` (the resolved :class:`~pcmgn_jax.config.TrainConfig`) and orbax
checkpoints under ``checkpoints/{periodic,best}/<step>/`` with three items: ``state`` (step, params,
optimiser state), ``stats`` (the normalisation statistics, stored only here) and ``meta`` (JSON:
config, contact radius and capacity, frame interval, total steps, best validation error).

    sim = load(workdir, ref_traj)            # Loaded(spec, params, stats, topology, index, meta)
    res = rollout(sim.spec, n, sim.params, sim.stats, sim.topology, sim.index, ...)

No pickle anywhere: params and stats are orbax arrays, meta is JSON.

Kills (docs/reliability.md): orbax writes a step into a temporary folder and renames it when complete;
writing managers clean leftover temporary folders. :func:`latest_intact` reads every item of the newest
step and falls back, naming the damaged one (a file missing inside); :func:`drop_after` removes the
checkpoints a killed run wrote after the step it resumes from. Readers never create folders:
:func:`require_run` answers a missing or incomplete run with one line (exit status 2 in the entry points).
"""
from __future__ import annotations

import shutil
import sys
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np
import orbax.checkpoint as ocp

from pcmgn_jax.config import TrainConfig
from pcmgn_jax.mgn import contact as contact_lib
from pcmgn_jax.mgn.graphs import Topology
from pcmgn_jax.mgn.inputs import topology_from_trajectory
from pcmgn_jax.mgn.model import EncodeProcessDecode
from pcmgn_jax.mgn.normalization import Stats
from pcmgn_jax.mgn.rollout import Spec
from pcmgn_jax.scene import Scene

ITEMS = ("state", "stats", "meta")


class Loaded(NamedTuple):
    """A trained simulator ready for :func:`pcmgn_jax.mgn.rollout.rollout`."""

    spec: Spec
    params: Any
    stats: Stats
    topology: Topology
    index: contact_lib.ContactIndex
    meta: dict
    config: TrainConfig


def make_spec(cfg: TrainConfig, dt: float) -> Spec:
    """The static simulator settings (model sizes, formulation, frame interval [s]) of a config (the
    formulation its rollouts scan: :attr:`TrainConfig.scan_formulation`)."""
    form = cfg.scan_formulation
    model = EncodeProcessDecode(output_size=form.output_size, latent_size=cfg.latent_size,
                                mlp_layers=cfg.mlp_layers, message_passing_steps=cfg.message_passing_steps,
                                decoder_condition=form.decoder_condition, reach=form.reach,
                                reach_levels=form.reach_levels, reach_slices=form.reach_slices,
                                reach_heads=form.reach_heads)
    return Spec(model=model, formulation=form, dt=float(dt))


def manager(path: str | Path, max_to_keep: int | None = None, *, create: bool = False) -> ocp.CheckpointManager:
    """The orbax manager of a checkpoint folder. ``create``: a writer's (makes the folder, removes orbax
    temporary folders a killed save left); readers (default) create nothing."""
    return ocp.CheckpointManager(
        Path(path).absolute(), options=ocp.CheckpointManagerOptions(
            max_to_keep=max_to_keep, create=create, cleanup_tmp_directories=create,
            enable_async_checkpointing=False),
        item_names=ITEMS)


class MissingRun(ValueError):
    """A run folder that is missing, not a folder, or holds no config.json or no checkpoint (one line:
    the path and the command that makes what is missing)."""


def require_run(workdir: str | Path, *, checkpoint: bool = True) -> Path:
    """``Path(workdir)`` when it is a training run folder with a config.json and (``checkpoint``) a
    checkpoint; else :class:`MissingRun` naming the path and the training command. Reads only."""
    run = Path(workdir)
    make = f"python -m experiments.train --workdir {run}"
    if not run.exists():
        raise MissingRun(f"{run}: no such run folder; make it with `{make}`")
    if not run.is_dir():
        raise MissingRun(f"{run}: is a file, not a run folder (a training run's --workdir, made by `{make}`)")
    if not (run / "config.json").is_file():
        raise MissingRun(f"{run}: no config.json, not a training run folder; make one with `{make}`")
    if checkpoint and not any(steps(run / "checkpoints" / w) for w in ("best", "periodic")):
        raise MissingRun(f"{run}: holds no checkpoint in {run / 'checkpoints'}; train it with `{make} --resume`")
    return run


def steps(path: str | Path) -> list[int]:
    """The checkpoint steps in ``path`` (ascending; orbax's finished steps), [] when there is no such folder."""
    path = Path(path)
    return sorted(manager(path).all_steps()) if path.is_dir() else []


def damage(path: str | Path, step: int) -> str | None:
    """Why checkpoint ``step`` in ``path`` cannot be read (every item read in full), or None when it can."""
    try:
        manager(path).restore(step, args=ocp.args.Composite(
            state=ocp.args.StandardRestore(), stats=ocp.args.StandardRestore(), meta=ocp.args.JsonRestore()))
    except Exception as err:   # orbax / tensorstore raise many kinds; each means "not readable"
        return f"{type(err).__name__}: {str(err).splitlines()[0][:200] if str(err) else ''}"
    return None


def latest_intact(path: str | Path, *, set_aside: bool = False) -> int | None:
    """The newest checkpoint step in ``path`` that reads back whole, None when there is none. A damaged
    newer one is named on stderr and skipped; ``set_aside`` (a resuming writer) also moves it to
    ``path/../damaged/<which>-<step>`` so the step can be written again (nothing is deleted)."""
    path = Path(path)
    for step in reversed(steps(path)):
        why = damage(path, step)
        if why is None:
            return step
        note = f"note: checkpoint {path / str(step)} is damaged ({why}); using the previous one"
        if set_aside:
            dest = path.parent / "damaged" / f"{path.name}-{step}"
            dest.parent.mkdir(parents=True, exist_ok=True)
            shutil.rmtree(dest, ignore_errors=True)
            (path / str(step)).rename(dest)
            note += f" (moved to {dest})"
        print(note, file=sys.stderr)
    return None


def drop_after(path: str | Path, step: int) -> list[int]:
    """Remove the checkpoints of ``path`` after ``step`` (a run resumed at ``step`` writes them again, the
    same: its data order is a function of the step); returns their steps, said on stderr."""
    path = Path(path)
    gone = [s for s in steps(path) if s > step]
    for s in gone:
        shutil.rmtree(path / str(s))
    if gone:
        print(f"note: {path}: removed checkpoint(s) {gone} written after step {step}, where the run resumes",
              file=sys.stderr)
    return gone


def save(mgr: ocp.CheckpointManager, state: dict, stats: Stats, meta: dict) -> None:
    """Write ``state`` (with an int ``step``), the statistics and the JSON ``meta``; waits until done."""
    step = int(state["step"])
    mgr.save(step, args=ocp.args.Composite(
        state=ocp.args.StandardSave(state), stats=ocp.args.StandardSave(dict(stats._asdict())),
        meta=ocp.args.JsonSave(meta)), force=True)
    mgr.wait_until_finished()


def read_meta(path: str | Path, step: int | None = None) -> tuple[int, dict]:
    """(step, meta) of the latest (or given) checkpoint in ``path``; FileNotFoundError if none."""
    mgr = manager(path)
    step = mgr.latest_step() if step is None else step
    if step is None:
        raise FileNotFoundError(f"no checkpoint in {path}")
    return step, mgr.restore(step, args=ocp.args.Composite(meta=ocp.args.JsonRestore()))["meta"]


def _stats(raw) -> Stats:
    return Stats(**{k: np.asarray(raw[k], np.float32) for k in Stats._fields})


def restore_stats(path: str | Path, step: int | None = None) -> Stats:
    """The normalisation statistics of the latest (or given) checkpoint in ``path``."""
    step, _ = read_meta(path, step)
    return _stats(manager(path).restore(step, args=ocp.args.Composite(stats=ocp.args.StandardRestore()))["stats"])


def restore(path: str | Path, template_state: dict, step: int | None = None) -> tuple[dict, Stats, dict]:
    """(state, stats, meta) from a checkpoint directory (latest step unless ``step``); ``template_state``
    gives the pytree structure (optimiser state included)."""
    step, meta = read_meta(path, step)
    res = manager(path).restore(step, args=ocp.args.Composite(
        state=ocp.args.StandardRestore(template_state), stats=ocp.args.StandardRestore()))
    return res["state"], _stats(res["stats"]), meta


def checkpoint_dir(workdir: str | Path, which: str = "best") -> Path:
    """``workdir/checkpoints/<which>``, falling back from an empty 'best' to 'periodic'."""
    if which not in ("best", "periodic"):
        raise ValueError(f"which must be 'best' or 'periodic', got {which!r}")
    path = Path(workdir) / "checkpoints" / which
    if which == "best" and not steps(path):
        path = Path(workdir) / "checkpoints" / "periodic"
    return path


def contact_index_for(ref, scene, *, radius: float, capacity: int) -> contact_lib.ContactIndex:
    ball_part, panel_part = contact_lib.contact_parts(scene)
    return contact_lib.allocate(points=ref.points, cells=ref.cells, cell_part=ref.cell_part,
                                ball_part=ball_part, panel_part=panel_part, radius=radius, capacity=capacity)


def load(workdir: str | Path, ref, *, which: str = "best", cfg: TrainConfig | None = None) -> Loaded:
    """A trained simulator from a run directory, on the mesh of the trajectory ``ref``.

    ``ref`` supplies the mesh (points, cells, parts) and its scene; the parameters and statistics come
    from the checkpoint (``which``: 'best', or 'periodic' for the latest).
    """
    workdir = require_run(workdir) if cfg is None else Path(workdir)
    cfg = cfg or TrainConfig.load(workdir / "config.json")
    path = checkpoint_dir(workdir, which)
    step = latest_intact(path)
    if step is None:
        raise MissingRun(f"{path}: no readable checkpoint (every one is damaged or missing); train the run again "
                         f"with `python -m experiments.train --workdir {workdir} --overwrite`")
    step, meta = read_meta(path, step)
    spec = make_spec(cfg, meta["dt"])
    topology = topology_from_trajectory(ref, spec.formulation.scene_features, spec.formulation.hierarchy_levels,
                                        spec.formulation.part_identity)
    index = contact_index_for(ref, Scene.from_dict(ref.meta["scene"]), radius=meta["contact_radius"],
                              capacity=meta["contact_capacity"])
    mgr = manager(path)
    raw = mgr.restore(step, args=ocp.args.Composite(state=ocp.args.StandardRestore(),
                                                    stats=ocp.args.StandardRestore()))
    params = jax.tree.map(np.asarray, raw["state"]["params"])
    stats = _stats(raw["stats"])
    return Loaded(spec, params, stats, topology, index, meta, cfg)
