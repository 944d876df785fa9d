"""The training loop: chunks of jitted steps, logs, validation rollouts, checkpoints, resume.

    summary = train(cfg, workdir, train_trajs=..., val_trajs=..., resume=False)

- ``train_chunk`` (:mod:`pcmgn_jax.train.step`) runs ``steps_per_dispatch`` optimiser steps in one
  ``lax.scan``; checkpoints, logs and validation happen at chunk boundaries (their intervals are rounded
  up to whole chunks). A contact-buffer overflow grows the buffer and re-runs the chunk.
- Validation: full rollouts of the validation trajectories, position MAE by
  :func:`pcmgn_jax.metrics.position_mae_um` and, with ``select_on='objective'``, the area-mean OLED objective's
  mean relative error [%] (:func:`pcmgn_jax.metrics.oled_objective`, the evaluation's figure); the best by
  ``select_on`` is kept in ``checkpoints/best`` (its meta: ``best_val``, in that figure's unit). With
  ``ema_decay`` > 0 the moving average of the parameters is what is validated and kept as best. With
  ``lambda_pen`` > 0 only validations after the penetration term has switched on (:func:`penalty_on`)
  compete for best; if none did, the final state is kept as best and its meta says
  ``best_predates_penalty`` (the summary and a printed line too).
- ``--resume`` continues from the latest periodic checkpoint with its statistics and buffer size; the
  data order is a pure function of (seed, step), so the result equals an uninterrupted run. A damaged
  checkpoint, later ones and later log lines are dealt with first (:mod:`pcmgn_jax.train.resume`).
- Batches: each step is one padded disjoint union of ``batch_graphs`` graphs per device
  (:func:`pcmgn_jax.train.sampling.gather_unions`), the meshes may differ; every union of the dataset
  has one static size (:class:`pcmgn_jax.train.setup.UnionSizes`), so ``train_chunk`` compiles once.
- ``devices`` > 1 (or 0: all): data parallelism (:mod:`pcmgn_jax.train.sharding`); the state and the
  statistics are replicated on a 'data' mesh, each chunk's unions (K, S, ...) are split over it along S,
  one union of B/S graphs per device.
"""
from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path
from typing import Sequence

import jax
import numpy as np

from pcmgn_jax import compile_notes
from pcmgn_jax.config import TrainConfig, check_resume
from pcmgn_jax.metrics import objective_weights, oled_objective, position_mae_um, relative_error_pct
from pcmgn_jax.mgn import checkpoint, contact as contact_lib
from pcmgn_jax.mgn.normalization import normalize_graph
from pcmgn_jax.mgn.rollout import input_graph, rollout_designs
from pcmgn_jax.train import startup_cache
from pcmgn_jax.train.resume import resume_point
from pcmgn_jax.train.sampling import gather_unions, pair_table, sample_ids
from pcmgn_jax.train.setup import Setup, graph_for, oled_part, prepare, scene_of
from pcmgn_jax.train.sharding import DataParallel, data_parallel
from pcmgn_jax.train.step import TrainState, eval_params, init_state, learning_rate, penalty_weight, train_chunk


class TrainingDiverged(RuntimeError):
    """Raised when the loss becomes NaN/inf; the last good checkpoint is kept."""


def init_params(setup: Setup, example_traj, seed: int):
    """Fresh model parameters (shapes from one example frame, ``example_traj`` on its own mesh). One jitted
    call, not Flax's op-by-op eager init (which compiles every small operation anew in each process): the
    same parameters bit for bit; a warm start reads them from the start-up cache (train/startup_cache.py)."""
    t0, form, model = example_traj, setup.spec.sim.formulation, setup.spec.sim.model

    def compute():
        d = graph_for(setup, t0)

        def init(key, topology, index, stats, points, u, v):
            g, _ = input_graph(form, topology, index, points, u, v)
            return model.init(key, normalize_graph(stats, g, topology.node_type))

        return jax.jit(init)(jax.random.PRNGKey(seed), d["topology"], d["index"], setup.stats, t0.points,
                             t0.displacement[0], t0.velocity[0])

    extra = dict(seed=seed, radius=setup.radius, capacity=setup.sizes.capacity)
    return startup_cache.params(setup.spec.cfg, [t0], extra, compute)


def rollout_frames(setup: Setup, params, trajs):
    """Rollouts of ``trajs`` from their frame 0, each on its own mesh (padded disjoint unions):
    per trajectory displacement (T, N, 2) [m] and von Mises (T, N) [Pa] (lists)."""
    designs = [dict(graph_for(setup, t), u0=t.displacement[0], v0=t.velocity[0], vm0=t.von_mises[0])
               for t in trajs]
    out = rollout_designs(setup.spec.sim, trajs[0].n_frames - 1, params, setup.stats, designs,
                          note="the validation rollout")
    return ([np.asarray(r.displacement, np.float64) for r in out.rollouts],
            [np.asarray(r.von_mises, np.float64) for r in out.rollouts])


# select_on -> (the validation figure's key in metrics.jsonl, its name, its unit)
VAL_FIGURES = dict(position=("val_position_mae_um", "position MAE", "µm"),
                   objective=("val_objective_error_pct", "objective error", "%"))


def best_line(res: dict) -> str:
    """The summary's best validation figure in words, e.g. 'best validation position MAE 0.220 µm'."""
    _, name, unit = VAL_FIGURES[res.get("select_on", "position")]
    return f"best validation {name} {res['best_val']:.3f} {unit}"


def objective_readings(trajs) -> list[tuple[np.ndarray, float]]:
    """Per validation trajectory, the area-mean OLED objective's section weights (N,) on its own mesh and its true
    objective [MPa]: fixed over training, so computed once. ValueError naming the trajectory without an 'OLED'."""
    out = []
    for t in trajs:
        part = oled_part(scene_of(t), f"select_on='objective' (validation trajectory {t.meta.get('name', '?')})")
        w = objective_weights(t.points, t.cells, t.cell_part, t.node_part, part=part, reading="area_mean")
        out.append((w, float(oled_objective(t.von_mises, w, reading="area_mean"))))
    return out


def validation_scores(setup: Setup, params, trajs, *, objective: list | None = None) -> dict:
    """Full validation rollouts scored as the evaluation scores a test split: {val_position_mae_um [µm]} and, with
    ``objective`` (:func:`objective_readings` of ``trajs``), {val_objective_error_pct}: the mean relative error [%]
    of the area-mean OLED objective (evaluate's ``oled_objective_area_rel_error_pct_mean``)."""
    keys = [VAL_FIGURES["position"][0]] + ([VAL_FIGURES["objective"][0]] if objective is not None else [])
    if not trajs:
        return dict.fromkeys(keys, float("nan"))
    pred_u, pred_vm = rollout_frames(setup, params, trajs)
    out = {keys[0]: position_mae_um(pred_u, [t.displacement for t in trajs])}
    if objective is not None:
        pred = [float(oled_objective(vm, w, reading="area_mean")) for vm, (w, _) in zip(pred_vm, objective)]
        out[keys[1]] = float(np.mean(relative_error_pct(pred, [true for _, true in objective])))
    return out


def chunk_batch(cfg: TrainConfig, setup: Setup, trajs, table, step: int, *, shards: int = 1, rows=None):
    """The host batch of one dispatch: the unions (K, S_local, ...) of the ``steps_per_dispatch`` optimiser steps
    from ``step`` (data order :func:`sample_ids`, a pure function of (seed, step); ``frames_per_sample`` frames
    per sample; ``table``: :func:`pair_table` of ``trajs``), what :func:`train` hands to ``train_chunk``."""
    ids = sample_ids(cfg.seed, step, cfg.steps_per_dispatch, cfg.batch_graphs, setup.n_pairs)
    return gather_unions(setup.spec.sim.formulation, trajs, setup.graphs, table, ids, dt=setup.spec.sim.dt,
                         sizes=setup.sizes, shards=shards, local_shards=rows, frames=cfg.frames)


def replicated(dp: DataParallel, setup: Setup) -> Setup:
    """``setup`` with the jitted step's dataset-wide input (the statistics) replicated on ``dp``'s mesh."""
    return setup._replace(stats=dp.replicate(setup.stats))


def _grown(setup: Setup, needed: int) -> Setup:
    """``setup`` with a contact buffer (per graph) holding ``needed`` directed edges (host side)."""
    cap = max(contact_lib.grow(g.index.replace(capacity=setup.sizes.capacity), needed).capacity
              for g in setup.graphs)
    cap = max(cap, setup.sizes.capacity + 2)
    return setup._replace(sizes=setup.sizes._replace(capacity=cap),
                          graphs=[g._replace(index=g.index.replace(capacity=cap)) for g in setup.graphs])


def _best(cfg: TrainConfig, state: TrainState) -> dict:
    """What the best checkpoint keeps (checkpoint layout): the state with ``params`` the evaluated ones
    (:func:`eval_params`), so every reader of a checkpoint's ``params`` gets the model that was validated
    (and no second copy of the average: only the periodic checkpoint, which ``--resume`` reads, needs both)."""
    return state._replace(params=eval_params(cfg, state), ema_params=None).to_dict()


def penalty_on(setup: Setup, step: int) -> bool:
    """Whether the model at optimiser step ``step`` has trained with the penetration term (λ > 0 in at
    least its last step; always True with ``lambda_pen`` = 0: there is no term to wait for)."""
    return setup.spec.cfg.lambda_pen <= 0 or (step > 0 and float(penalty_weight(setup.spec, step - 1)) > 0)


def _meta(cfg: TrainConfig, setup: Setup, **extra) -> dict:
    return dict(config=cfg.to_dict(), contact_radius=setup.radius, contact_capacity=setup.sizes.capacity,
                dt=setup.spec.sim.dt, total_steps=setup.total_steps, **extra)


def train(cfg: TrainConfig, workdir: str | Path, *, train_trajs: Sequence, val_trajs: Sequence = (),
          resume: bool = False, stop_after: int | None = None) -> dict:
    """Train; returns a summary dict. ``stop_after``: stop (as if killed) after that many steps."""
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    if resume:
        check_resume(cfg, workdir)  # a resumed run keeps its config.json; a changed config is refused
    # the objective's weights and truths once (a validation set without an OLED is refused now, not at step 500)
    readings = objective_readings(val_trajs) if cfg.select_on == "objective" else None
    dp = data_parallel(cfg.devices, cfg.batch_graphs)  # None on one device; checks the batch split first
    periodic_dir = workdir / "checkpoints" / "periodic"
    # damaged checkpoints set aside, later ones and log lines cut (by process 0 on several hosts)
    at = resume_point(workdir, write=jax.process_index() == 0) if resume else None
    periodic = checkpoint.manager(periodic_dir, cfg.max_to_keep, create=True)
    best_mgr = checkpoint.manager(workdir / "checkpoints" / "best", 1, create=True)

    if at is not None:
        _, meta = checkpoint.read_meta(periodic_dir, at)
        setup = prepare(cfg, train_trajs, capacity=meta["contact_capacity"], radius=meta["contact_radius"],
                        stats=checkpoint.restore_stats(periodic_dir, at))
        template = init_state(setup.spec, init_params(setup, train_trajs[0], cfg.seed))
        saved, _, meta = checkpoint.restore(periodic_dir, template.to_dict(), at)
        state = TrainState.from_dict(saved)
        best_val = (meta.get("best_val") or float("inf")) if best_mgr.latest_step() is not None else float("inf")
        mode = "a"
    else:
        if resume:
            print(f"resume: no checkpoint in {periodic_dir}; starting fresh")
        setup = prepare(cfg, train_trajs)
        state = init_state(setup.spec, init_params(setup, train_trajs[0], cfg.seed))
        best_val = float("inf")
        mode = "w"
    if dp is not None:
        state, setup = dp.replicate(state), replicated(dp, setup)
    primary = jax.process_index() == 0  # on several hosts one process writes the files (orbax: checkpoints)
    if primary:
        cfg.save_json(workdir / "config.json")
        compile_notes.log_to(workdir / "compile.jsonl")  # each first compilation's seconds (console + file)
    table = pair_table(train_trajs)
    K = cfg.steps_per_dispatch
    every = lambda n: K * max(1, math.ceil(n / K))  # noqa: E731
    log_every, ckpt_every, val_every = every(cfg.log_every), every(cfg.ckpt_every), every(cfg.val_every)
    seed_key = jax.random.PRNGKey(cfg.seed + 1)
    shards = 1 if dp is None else dp.n_devices  # one union of B / shards graphs per device and step
    rows = None  # the shards this process gathers: all, except on several hosts
    if dp is not None:
        seed_key, rows = dp.replicate(seed_key), dp.local_rows(K, shards)
    step = int(state.step)
    total = setup.total_steps
    end = total if stop_after is None else min(total, step + stop_after)
    last_good = periodic.latest_step()

    bar = None
    if cfg.progress and primary:
        from tqdm import tqdm
        bar = tqdm(total=total, initial=step, desc="train", dynamic_ncols=True)
    t_start, rate = time.perf_counter(), float("nan")
    with open(workdir / "metrics.jsonl" if primary else os.devnull, mode) as log:
        while step < end:
            t_chunk = time.perf_counter()
            batch = chunk_batch(cfg, setup, train_trajs, table, step, shards=shards, rows=rows)
            if dp is not None:
                batch = dp.put_batch(batch, shards)
            with compile_notes.first_call("the training step", (setup.spec, setup.sizes, K)):
                new_state, m = train_chunk(setup.spec, state, setup.stats, batch, seed_key)
                m = jax.device_get(m)
            if np.any(m["overflow"]):
                need = int(np.max(m["contact_count"]))
                setup = _grown(setup, need)  # static size only
                print(f"contact buffer overflow at step {step} (needed {need}); grown to "
                      f"{setup.sizes.capacity} and the chunk is re-run")
                continue
            if not np.all(np.isfinite(m["loss"])):
                bad = step + int(np.argmin(np.isfinite(m["loss"])))
                msg = (f"loss became non-finite at step {bad}; training stopped. Last good checkpoint: "
                       f"{'step ' + str(last_good) if last_good is not None else 'none'} in {periodic_dir}")
                log.write(json.dumps(dict(step=bad, error=msg)) + "\n")
                raise TrainingDiverged(msg)
            state = new_state
            step += K
            chunk_rate = K / (time.perf_counter() - t_chunk)  # first chunk includes compilation
            rate = chunk_rate if not np.isfinite(rate) or step <= K else 0.8 * rate + 0.2 * chunk_rate
            if bar is not None:
                bar.update(K)
                bar.set_postfix(loss=f"{float(m['loss'][-1]):.4g}", steps_s=f"{rate:.1f}")
            rec = None
            if step % log_every == 0 or step >= end:
                rec = dict(step=step, loss=float(np.mean(m["loss"])), loss_data=float(np.mean(m["loss_data"])),
                           lr=float(learning_rate(setup.spec, step)), steps_per_s=rate,
                           contact_edges_max=int(np.max(m["contact_count"])))
                if cfg.lambda_pen > 0:
                    lam = float(penalty_weight(setup.spec, step))
                    rec["loss_pen"], rec["lambda"] = float(np.mean(m["loss_pen"])), lam
                    rec["pen_ratio"] = float(lam * rec["loss_pen"] / max(rec["loss_data"], 1e-30))
                if cfg.lambda_obj > 0:
                    rec["loss_obj"] = float(np.mean(m["loss_obj"]))
            if val_trajs and (step % val_every == 0 or step >= total):
                scores = validation_scores(setup, eval_params(cfg, state), val_trajs, objective=readings)
                rec = rec or dict(step=step)
                rec.update(scores)
                val = scores[VAL_FIGURES[cfg.select_on][0]]
                if np.isfinite(val) and val < best_val and penalty_on(setup, step):
                    best_val = val
                    checkpoint.save(best_mgr, _best(cfg, state), setup.stats,
                                    _meta(cfg, setup, best_val=best_val, best_step=step, best_predates_penalty=False))
            if rec is not None:
                log.write(json.dumps(rec) + "\n")
                log.flush()
            if step % ckpt_every == 0 or step >= end:
                checkpoint.save(periodic, state.to_dict(), setup.stats,
                                _meta(cfg, setup, best_val=best_val if np.isfinite(best_val) else None))
                last_good = step
    if bar is not None:
        bar.close()
    predates = False
    if step >= total and (not val_trajs or (cfg.lambda_pen > 0 and not np.isfinite(best_val))):
        # no validation, or none with the penetration term on: the final state is the kept model
        predates = not penalty_on(setup, step)
        checkpoint.save(best_mgr, _best(cfg, state), setup.stats,
                        _meta(cfg, setup, best_val=None, best_step=step, best_predates_penalty=predates))
        if val_trajs and primary:
            print(f"lambda_pen={cfg.lambda_pen:g}: no finite validation with the penetration term on; the final "
                  f"state (step {step}) is kept as best" + (" and predates the term (it never switched on)"
                                                          if predates else ""))
    return dict(step=step, best_val=best_val, select_on=cfg.select_on, state=state, setup=setup,
                seconds=time.perf_counter() - t_start, best_predates_penalty=predates)

