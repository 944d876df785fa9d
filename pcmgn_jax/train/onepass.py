"""Training of the one-pass model (:mod:`pcmgn_jax.mgn.onepass`): steps, logs, validation, checkpoints, resume.

    summary = train(cfg, workdir, train_trajs=..., val_trajs=..., resume=False)

- The dataset's graph settings (:func:`for_dataset`): the preset its manifest names, and that preset's part
  identity, origin and scene features (the rollout MGN's), so a stack family's 5-, 6- and 7-layer designs share
  one node-type set (the roles) and one input width.
- Each design's graph on its own mesh (one contact radius, the first design's; one contact buffer, the largest any
  training design needs at its initial state), its loss weights and the objective's section weights on it.
- Each step: ``batch_graphs`` training designs drawn without replacement by a pure function of (seed, step)
  (:func:`batch_ids`), so a resumed run takes the same steps as an uninterrupted one, joined into a padded union
  of one static size for the whole dataset (:mod:`pcmgn_jax.mgn.onepass_union`: no recompilation when the draw's
  meshes change); one jitted Adam step
  (the MGN's schedule: lr0 x rate^(step / num_steps)) and the parameters' moving average (``ema_decay``;
  ``optax.incremental_update``), both in :class:`pcmgn_jax.train.step.TrainState`.
- Validation every ``val_every`` steps and at the end: the moving average's ``area_mean`` objective error on the
  validation designs (mean relative error [%], :func:`pcmgn_jax.metrics.relative_error_pct`); the best is kept
  in ``checkpoints/best`` (best on validation, never on test).
- Checkpoints (orbax, atomic renames; :mod:`pcmgn_jax.mgn.checkpoint`): ``checkpoints/periodic`` every
  ``ckpt_every`` steps and at the end, with the statistics and the contact radius and buffer in their meta.
  ``resume``: :func:`pcmgn_jax.train.resume.resume_point` (the newest intact periodic checkpoint; later
  checkpoints and ``metrics.jsonl`` lines dropped), its state, statistics and best validation error.
- ``metrics.jsonl``: a JSON line per log / validation; progress lines on stdout.
"""
from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax

from pcmgn_jax.atomic import atomic_write_json
from pcmgn_jax.errors import SettingError
from pcmgn_jax.metrics import objective_weights, relative_error_pct
from pcmgn_jax.mgn import checkpoint, onepass as op, onepass_union as union
from pcmgn_jax.presets import PRESET_NAMES
from pcmgn_jax.train.resume import resume_point
from pcmgn_jax.train.setup import loss_weights
from pcmgn_jax.train.step import TrainState


def batch_ids(seed: int, step: int, batch: int, n: int) -> np.ndarray:
    """The training designs of optimiser step ``step``: ``batch`` of ``n`` without replacement, from (seed, step)."""
    return np.sort(np.random.default_rng([seed, step]).choice(n, size=batch, replace=False))


def optimizer(cfg: op.OnePassConfig) -> optax.GradientTransformation:
    return optax.adam(optax.exponential_decay(cfg.learning_rate, transition_steps=cfg.num_steps,
                                              decay_rate=cfg.lr_decay_rate))


def _check_config(cfg: op.OnePassConfig, workdir: Path, resume: bool) -> None:
    path = workdir / op.CONFIG_FILE
    if resume and path.exists():
        old = op.OnePassConfig.load(workdir)
        if old != cfg:
            diff = {k: (v, cfg.to_dict()[k]) for k, v in old.to_dict().items() if cfg.to_dict()[k] != v}
            raise SettingError("resume", f"{path} was saved with other settings {diff} (saved, given); resume with the "
                               "saved ones")
    elif not resume and (path.exists() or checkpoint.steps(workdir / "checkpoints" / "periodic")):
        raise SettingError("workdir", f"{workdir} holds a run already: resume it, or give another folder")
    atomic_write_json(path, cfg.to_dict(), parents=True)


class Data:
    """A split's designs as the step reads them: each design's graph inputs on its own mesh
    (:func:`pcmgn_jax.mgn.onepass.design_inputs`), physical targets (N_b, 3), per-node loss weights (N_b,), the
    objective's section weights (N_b,) on its own mesh, and each design's objective [Pa]; ``take`` joins a draw
    into a padded union of the one static size ``sizes`` (:mod:`pcmgn_jax.mgn.onepass_union`)."""

    def __init__(self, cfg, designs, targets, obj_weights, slots: int):
        self.designs, self.targets, self.obj_w = list(designs), list(targets), list(obj_weights)
        self.weights = [loss_weights(cfg.formulation, d["topology"])["stress"] for d in self.designs]
        self.objective = np.array([y[:, 0] @ np.asarray(w, np.float64) for y, w in zip(self.targets, self.obj_w)])
        self.sizes = union.union_sizes(self.designs, slots)

    def take(self, ids):
        """(union, targets (N, 3), weights (N,), obj_w (N,)) of the designs ``ids``, zero on padding."""
        u = union.make_union([self.designs[i] for i in ids], self.sizes)
        arr = lambda xs: jnp.asarray(union.node_array(u, [xs[i] for i in ids]))  # noqa: E731
        return u, arr(self.targets), arr(self.weights), arr(self.obj_w)


def make_step(cfg: op.OnePassConfig, model, tx):
    """The jitted step (state, stats, union, targets, weights, obj_w) -> (state, loss, data, obj)."""
    form = cfg.formulation

    @jax.jit
    def onepass_step(state: TrainState, stats, u, targets, weights, obj_w):
        (loss, (data, obj)), grads = jax.value_and_grad(union.loss_fn, has_aux=True)(
            state.params, form, model, stats, u, targets, weights, obj_w, cfg.lambda_obj)
        updates, opt_state = tx.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        ema = optax.incremental_update(params, state.ema_params, step_size=1.0 - cfg.ema_decay)
        return TrainState(step=state.step + 1, params=params, opt_state=opt_state, ema_params=ema), loss, data, obj

    return onepass_step


def validation_error_pct(cfg, params, stats, val: Data | None) -> float:
    """Mean relative ``area_mean`` objective error [%] of the validation designs (nan without any)."""
    if val is None:
        return float("nan")
    fields = op.predict_fields(cfg, params, stats, val.designs, slots=val.sizes.slots)
    pred = np.array([f[:, 0] @ np.asarray(w, np.float64) for f, w in zip(fields, val.obj_w)])
    return float(relative_error_pct(pred, val.objective).mean())


def _section(cfg, traj) -> np.ndarray:
    """The ``area_mean`` section weights (N,) of the objective's part on the trajectory's own mesh."""
    part = op.part_id(traj, cfg.objective_part)
    return objective_weights(traj.points, traj.cells, traj.cell_part, traj.node_part, part=part)


def for_dataset(cfg: op.OnePassConfig, manifest: dict | None, *, given=()) -> op.OnePassConfig:
    """``cfg`` with the dataset's graph settings, read from its ``manifest`` (None: an imported dataset, unchanged):
    ``preset`` the manifest's, and that preset's ``part_identity``, ``origin`` and (unless ``scene_features`` is in
    ``given``, the flags written) ``scene_features`` -- the rollout MGN's formulation for the preset
    (:meth:`pcmgn_jax.config.TrainConfig.from_preset`: the box's part one-hot and layer thicknesses, the scene
    family's heights from the plate's top with the ball radius, the stacks' role node types, materials and
    depths with heights from the contact layer's top)."""
    from pcmgn_jax.config import TrainConfig
    if manifest is None:
        return cfg
    preset = manifest.get("preset")
    if preset not in PRESET_NAMES:
        raise ValueError(f"one-pass: the dataset's manifest names preset {preset!r}, not one of {PRESET_NAMES}")
    form = TrainConfig.from_preset(preset).formulation
    kw = dict(preset=preset, part_identity=form.part_identity, origin=form.origin)
    if "scene_features" not in given:
        kw["scene_features"] = form.scene_features
    return dataclasses.replace(cfg, **kw)


def train(cfg: op.OnePassConfig, workdir: str | Path, *, train_trajs: Sequence, val_trajs: Sequence = (),
          resume: bool = False, stop_after: int | None = None, progress: Callable[[str], None] | None = print) -> dict:
    """Train (module docstring); returns a summary. ``stop_after``: stop after that many steps of this call
    without a final checkpoint, as a kill would (tests)."""
    workdir = Path(workdir)
    if not train_trajs:
        raise ValueError("one-pass training: no training trajectories")
    _check_config(cfg, workdir, resume)
    say = progress or (lambda s: None)
    t_start = time.perf_counter()
    step0 = resume_point(workdir) if resume else None
    radius = float(op.design_inputs(cfg, train_trajs[0])["index"].radius)   # one radius: the first design's
    best_val, stats, capacity = float("inf"), None, None
    if step0 is not None:
        _, meta = checkpoint.read_meta(workdir / "checkpoints" / "periodic", step0)
        radius, capacity = meta["contact_radius"], meta["contact_capacity"]
        best_val = float("inf") if meta["best_val_error_pct"] is None else meta["best_val_error_pct"]
        stats = checkpoint.restore_stats(workdir / "checkpoints" / "periodic", step0)
    designs = [op.design_inputs(cfg, t, radius=radius, capacity=capacity) for t in train_trajs]
    if capacity is None:   # one buffer: the largest any training design needs at its initial state
        capacity = max(int(d["index"].capacity) for d in designs)
        designs = [{**d, "index": d["index"].replace(capacity=capacity)} for d in designs]
    targets = [op.time_targets(t) for t in train_trajs]
    stats = stats or op.compute_stats(cfg, designs, targets, scene=train_trajs[0].meta.get("scene"))
    batch = min(cfg.batch_graphs, len(train_trajs))
    tr = Data(cfg, designs, targets, [_section(cfg, t) for t in train_trajs], batch)
    val = None
    if val_trajs:
        val = Data(cfg, [op.design_inputs(cfg, t, radius=radius, capacity=capacity) for t in val_trajs],
                   [op.time_targets(t) for t in val_trajs], [_section(cfg, t) for t in val_trajs],
                   min(cfg.batch_graphs, len(val_trajs)))
    model, tx = cfg.model(), optimizer(cfg)
    probe = tr.take(range(batch))[0]
    params = union.init_params(cfg.formulation, model, stats, probe, cfg.seed)
    state = TrainState(step=jnp.zeros((), jnp.int32), params=params, opt_state=tx.init(params),
                       ema_params=jax.tree.map(jnp.array, params))
    if step0 is not None:
        raw, _, _ = checkpoint.restore(workdir / "checkpoints" / "periodic", state.to_dict(), step0)
        state = TrainState.from_dict(raw)
    meta = dict(contact_radius=radius, contact_capacity=capacity, total_steps=cfg.num_steps, targets=list(op.TARGETS))
    root = workdir / "checkpoints"
    periodic = checkpoint.manager(root / "periodic", cfg.max_to_keep, create=True)
    best_mgr = checkpoint.manager(root / "best", 1, create=True)
    step_fn = make_step(cfg, model, tx)
    first = int(state.step)
    n_nodes = sorted({d["topology"].n_node for d in designs})
    say(f"one-pass: {len(train_trajs)} training / {len(val_trajs)} validation designs, {n_nodes[0]}.."
        f"{n_nodes[-1]} nodes ({len(n_nodes)} meshes; unions of {probe.graph.points.shape[0]} nodes), batch {batch}, "
        f"steps {first} -> {cfg.num_steps}" + (" (resumed)" if first else ""))
    log, t_train, timed_steps, t_first = (workdir / "metrics.jsonl").open("a"), 0.0, 0, None
    done = first
    try:
        for s in range(first, cfg.num_steps):
            if stop_after is not None and s - first >= stop_after:
                return {"step": s, "stopped": True}
            t0 = time.perf_counter()
            u, targets, weights, obj_w = tr.take(batch_ids(cfg.seed, s, batch, len(train_trajs)))
            state, loss, data, obj = step_fn(state, stats, u, targets, weights, obj_w)
            loss = float(loss)
            if not np.isfinite(loss):
                raise FloatingPointError(f"one-pass training diverged at step {s + 1} (loss {loss}); the last "
                                         f"periodic checkpoint in {root / 'periodic'} is kept")
            if s > first:  # the first step of this call compiles
                t_train, timed_steps = t_train + time.perf_counter() - t0, timed_steps + 1
            else:
                t_first = time.perf_counter() - t0
            done = s + 1
            rec = None
            if done % cfg.log_every == 0 or done == cfg.num_steps:
                rec = dict(step=done, loss=loss, loss_data=float(data), loss_objective=float(obj),
                           seconds=time.perf_counter() - t_start)
            if done % cfg.val_every == 0 or done == cfg.num_steps:
                err = validation_error_pct(cfg, state.ema_params, stats, val)
                rec = {**(rec or dict(step=done)), "val_objective_error_pct": err}
                if val is None or err < best_val:
                    best_val = err if val is not None else best_val
                    best_state = state._replace(params=state.ema_params, ema_params=None)
                    checkpoint.save(best_mgr, best_state.to_dict(), stats,
                                    {**meta, "best_val_error_pct": err if np.isfinite(err) else None})
            if rec is not None:
                log.write(json.dumps(rec) + "\n")
                log.flush()
                say(f"step {done}/{cfg.num_steps}  loss {loss:.4g} (data {float(data):.4g}, objective "
                    f"{float(obj):.3g})" + (f"  val objective error {rec['val_objective_error_pct']:.3f} % "
                                            f"(best {best_val:.3f} %)" if "val_objective_error_pct" in rec else ""))
            if done % cfg.ckpt_every == 0 or done == cfg.num_steps:
                checkpoint.save(periodic, state.to_dict(), stats,
                                {**meta, "best_val_error_pct": best_val if np.isfinite(best_val) else None})
    finally:
        log.close()
    per_step = t_train / timed_steps if timed_steps else float("nan")
    summary = dict(step=done, seconds=time.perf_counter() - t_start, steps_this_call=done - first,
                   step_seconds=per_step, first_step_seconds=t_first, best_val_objective_error_pct=best_val,
                   batch_graphs=batch, n_train=len(train_trajs), n_val=len(val_trajs))
    if done > first:   # a call that trained (a resume of a finished run keeps the summary of the one that did)
        atomic_write_json(workdir / "train_summary.json", summary)
    return summary
