"""Training library: data order, loss, module-level jitted ``train_chunk``, checkpoints, the loop.

    setup = prepare(cfg, train_trajs)                   # topology, contact buffer, stats (host)
    state = init_state(cfg, setup)                      # {'step', 'params', 'opt_state'}
    train(cfg, workdir, train_trajs=..., val_trajs=..., resume=False)

- Data order is a pure function of (seed, step): sample k = step * B + b comes from epoch
  k // n_pairs at position k % n_pairs of ``permutation(default_rng([seed, epoch]))``, so ``--resume``
  replays exactly what an uninterrupted run would have seen.
- ``train_chunk`` runs ``steps_per_dispatch`` optimiser steps in one ``lax.scan``; checkpoints, logs
  and validation happen at chunk boundaries (their intervals are rounded up to whole chunks).
- Loss: MSE of normalised outputs vs normalised targets; velocity/displacement/position channels are
  masked on fixed nodes, stress is on all nodes. ``loss = loss_data + lambda_pen * loss_pen``; the
  penetration term is a hook (``_penetration_loss``) until ``pcmgn_jax.train.penetration`` lands.
- Noise (MeshGraphNets style): Gaussian ``noise_std`` [m] on the input displacement of the chosen parts'
  free nodes; targets corrected so the model learns to undo it (velocity: a -= n / dt; displacement:
  a -= n; position: unchanged).
"""
from __future__ import annotations

import functools
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax
import orbax.checkpoint as ocp

from pcmgn_jax.mgn import contact as contact_lib
from pcmgn_jax.config import TrainConfig
from pcmgn_jax.mgn.graphs import Topology, build_graph, topology_from_trajectory
from pcmgn_jax.mgn.model import EncodeProcessDecode
from pcmgn_jax.train.noise import correct_target
from pcmgn_jax.mgn.normalization import (Accumulator, Stats, denormalize_output, make_stats,
                                     normalize_target)
from pcmgn_jax.mgn.rollout import Spec, input_velocity, integrate, make_target, predict, rollout_checked
from pcmgn_jax.scene import Scene


class TrainingDiverged(RuntimeError):
    """Raised when the loss becomes NaN/inf; the last good checkpoint is kept."""


@dataclass(frozen=True)
class TrainSpec:
    """Static (hashable) training settings: the jit cache key of ``train_chunk``."""

    sim: Spec
    learning_rate: float = 1e-3
    lr_decay_rate: float = 0.1
    lr_decay_steps: int = 1000
    lambda_pen: float = 0.0
    noise_std: float = 0.0
    poly_ball: int = 6
    poly_panel: int = 5
    pen_interval: tuple = (0.0, 1.0)  # [m] fixed fit interval (penetration.BoundaryNodes.interval)
    pen_length_scale: float = 1e-6


class Setup(NamedTuple):
    """Everything derived once from the training split (host side)."""

    spec: TrainSpec
    topology: Topology
    index: contact_lib.ContactIndex
    stats: Stats
    noise_mask: np.ndarray   # [N] bool  free nodes of the noised parts
    pen_nodes: dict          # {"ball": [Mb] int, "panel": [Mp] int} boundary nodes of the fits
    scene: Scene
    n_pairs: int             # (trajectory, frame) training pairs
    total_steps: int


# ---- setup -------------------------------------------------------------------------------------

def penetration_boundary(cfg: TrainConfig, ref, panel_part: int):
    """Ball-bottom / CG-top node sets and fit interval (pcmgn_jax.train.penetration.boundary_nodes)."""
    from pcmgn_jax.train.penetration import boundary_nodes
    # stay inside the region of interest: at its far edge the crop leaves cut edges that are not
    # the ball's or the glass's surface
    x_max = min(cfg.pen_x_max, 0.8 * float(np.max(ref.points[:, 0])))
    return boundary_nodes(ref.points, ref.node_part, ball_part=0, panel_part=panel_part, x_max=x_max,
                          cells=ref.cells, cell_part=ref.cell_part)


def make_model(cfg: TrainConfig) -> EncodeProcessDecode:
    return EncodeProcessDecode(output_size=3, latent_size=cfg.latent_size, mlp_layers=cfg.mlp_layers,
                               message_passing_steps=cfg.message_passing_steps)


def output_dt(traj) -> float:
    return float(traj.meta.get("output_dt") or (traj.times[1] - traj.times[0]))


def scene_of(traj) -> Scene:
    return Scene.from_dict(traj.meta["scene"])


def contact_parts(scene: Scene) -> tuple[int, int]:
    if not scene.contact_pairs:
        raise ValueError("scene declares no contact pair; contact edges need one (ball, layer)")
    return 0, scene.part_names.index(scene.contact_pairs[0][1])


def auto_radius(traj, panel_part: int) -> float:
    """1.5 x the median spacing of the contact layer's top-surface nodes near the axis."""
    nodes = contact_lib.surface_nodes(traj.points, traj.cells, traj.cell_part, panel_part, facing="up")
    xs = np.sort(np.asarray(traj.points)[nodes, 0])
    d = np.diff(xs)[:20]
    return float(1.5 * np.median(d[d > 0]))


def total_steps(cfg: TrainConfig, n_pairs: int) -> int:
    steps = cfg.num_steps or int(math.ceil(cfg.epochs * n_pairs / cfg.batch_graphs))
    k = cfg.steps_per_dispatch
    return int(k * math.ceil(steps / k))


def prepare(cfg: TrainConfig, train_trajs: Sequence, *, stats_max_frames: int = 2000,
            capacity: int | None = None, radius: float | None = None) -> Setup:
    """Topology, contact buffer (sized on all training frames) and normalisation stats."""
    if not train_trajs:
        raise ValueError("no training trajectories")
    ref = train_trajs[0]
    for i, t in enumerate(train_trajs):
        if t.points.shape != ref.points.shape or not np.array_equal(t.cells, ref.cells) or \
                not np.array_equal(t.node_type, ref.node_type):
            raise ValueError(f"training trajectory {i} has a different topology; one topology per dataset")
    scene = scene_of(ref)
    dt = output_dt(ref)
    topology = topology_from_trajectory(ref)
    ball_part, panel_part = contact_parts(scene)
    r_w = radius or cfg.contact_radius or auto_radius(ref, panel_part)
    index = contact_lib.allocate(points=ref.points, cells=ref.cells, cell_part=ref.cell_part,
                                 ball_part=ball_part, panel_part=panel_part, radius=r_w,
                                 positions=[t.positions for t in train_trajs],
                                 capacity_factor=cfg.contact_capacity_factor, capacity=capacity)
    sim = Spec(model=make_model(cfg), target=cfg.target, dt=dt)
    n_pairs = sum(t.n_frames - 1 for t in train_trajs)
    steps = total_steps(cfg, n_pairs)
    spec, pen_nodes = _train_spec(cfg, sim, steps, ref, panel_part)
    stats = compute_stats(train_trajs, topology, index, target=cfg.target, dt=dt,
                          max_frames=stats_max_frames, noise_std=cfg.noise_std)
    parts = {"none": [], "ball": [0], "panel": list(range(1, len(scene.part_names))),
             "all": list(range(len(scene.part_names)))}[cfg.noise_parts]
    noise_mask = np.isin(ref.node_part, parts) & ~np.asarray(topology.fixed)
    return Setup(spec, topology, index, stats, noise_mask, pen_nodes, scene, n_pairs, steps)


def _train_spec(cfg: TrainConfig, sim: Spec, steps: int, ref, panel_part: int):
    kw, pen_nodes = {}, {"ball": np.zeros(0, np.int32), "panel": np.zeros(0, np.int32)}
    if cfg.lambda_pen > 0:
        bn = penetration_boundary(cfg, ref, panel_part)
        kw = dict(pen_interval=tuple(float(v) for v in bn.interval))
        pen_nodes = {"ball": np.asarray(bn.ball, np.int32), "panel": np.asarray(bn.panel, np.int32)}
    spec = TrainSpec(sim=sim, learning_rate=cfg.learning_rate, lr_decay_rate=cfg.lr_decay_rate,
                     lr_decay_steps=cfg.lr_decay_steps or steps, lambda_pen=cfg.lambda_pen,
                     noise_std=cfg.noise_std, poly_ball=cfg.poly_ball, poly_panel=cfg.poly_panel,
                     pen_length_scale=cfg.pen_length_scale, **kw)
    return spec, pen_nodes


@jax.jit
def _raw_features(topology, index, points, u, v):
    edges = contact_lib.update(index, points + u)
    g = build_graph(topology, points=points, displacement=u, velocity=v, contact=edges)
    return g.nodes[:, topology.n_node_types:], g.edges["mesh"].features, g.edges["contact"].features, edges.mask


def compute_stats(trajs, topology, index, *, target: str, dt: float, max_frames: int = 2000,
                  noise_std: float = 0.0) -> Stats:
    """Per-channel mean/std over training frames (every frame when <= max_frames pairs exist)."""
    pairs = [(i, t) for i, tr in enumerate(trajs) for t in range(tr.n_frames - 1)]
    if len(pairs) > max_frames:
        pick = np.linspace(0, len(pairs) - 1, max_frames).round().astype(int)
        pairs = [pairs[k] for k in pick]
    acc = dict(node=Accumulator(4), mesh=Accumulator(6), contact=Accumulator(3), target=Accumulator(3))
    for i, t in pairs:
        tr = trajs[i]
        u = np.asarray(tr.displacement[t], np.float64)
        v = input_velocity(tr.displacement, tr.velocity, t, dt)
        node, mesh, cont, mask = _raw_features(topology, index, np.float32(tr.points),
                                               np.float32(u), np.float32(v))
        acc["node"].add(node)
        acc["mesh"].add(mesh)
        acc["contact"].add(cont, np.asarray(mask))
        tgt = make_target(target, points=np.asarray(tr.points, np.float64), u_t=u,
                          u_next=np.asarray(tr.displacement[t + 1], np.float64),
                          vm_next=np.asarray(tr.von_mises[t + 1], np.float64), dt=dt)
        acc["target"].add(tgt[~np.asarray(topology.fixed)])
    return make_stats(**acc, contact_default_std=index.radius)


# ---- data order (pure function of seed and step) -------------------------------------------------

def sample_ids(seed: int, step0: int, n_steps: int, batch: int, n_pairs: int) -> np.ndarray:
    """(n_steps, batch) indices into the flat list of training pairs for steps step0..step0+n-1."""
    k = np.arange(step0 * batch, (step0 + n_steps) * batch, dtype=np.int64)
    epochs, pos = k // n_pairs, k % n_pairs
    out = np.empty_like(k)
    for e in np.unique(epochs):
        perm = np.random.default_rng([seed, int(e)]).permutation(n_pairs)
        sel = epochs == e
        out[sel] = perm[pos[sel]]
    return out.reshape(n_steps, batch)


def pair_table(trajs) -> np.ndarray:
    return np.array([(i, t) for i, tr in enumerate(trajs) for t in range(tr.n_frames - 1)], np.int64)


def gather(trajs, table, ids: np.ndarray, *, target: str, dt: float) -> dict[str, np.ndarray]:
    """Host batch of shape (K, B, ...) float32: points, u, v (inputs), target (SI)."""
    K, B = ids.shape
    n = trajs[0].n_nodes
    out = {k: np.empty((K, B, n, d), np.float32) for k, d in (("points", 2), ("u", 2), ("v", 2), ("target", 3))}
    for a in range(K):
        for b in range(B):
            i, t = table[ids[a, b]]
            tr = trajs[i]
            u = np.asarray(tr.displacement[t], np.float64)
            out["points"][a, b] = tr.points
            out["u"][a, b] = u
            out["v"][a, b] = input_velocity(tr.displacement, tr.velocity, t, dt)
            out["target"][a, b] = make_target(target, points=np.asarray(tr.points, np.float64), u_t=u,
                                              u_next=np.asarray(tr.displacement[t + 1], np.float64),
                                              vm_next=np.asarray(tr.von_mises[t + 1], np.float64), dt=dt)
    return out


# ---- loss and step -------------------------------------------------------------------------------

def learning_rate(spec: TrainSpec, step):
    """lr0 * rate ** (step / decay_steps) (continuous exponential decay)."""
    return optax.exponential_decay(spec.learning_rate, transition_steps=spec.lr_decay_steps,
                                   decay_rate=spec.lr_decay_rate)(step)


def make_optimizer(spec: TrainSpec) -> optax.GradientTransformation:
    return optax.adam(functools.partial(learning_rate, spec))


def _penetration_loss(spec: TrainSpec, pen_nodes, points, u_next):
    """Physics term (paper 2.3): L_pen of the predicted next world positions (d in pen_length_scale)."""
    if spec.lambda_pen == 0:
        return jnp.zeros((), jnp.float32)
    from pcmgn_jax.train.penetration import penetration_depth, penetration_loss
    pos = points + u_next
    d, valid = penetration_depth(pos[pen_nodes["ball"]], pos[pen_nodes["panel"]], degree_ball=spec.poly_ball,
                                 degree_panel=spec.poly_panel, interval=spec.pen_interval)
    return penetration_loss(d, valid, length_scale=spec.pen_length_scale)


def loss_fn(params, spec: TrainSpec, stats: Stats, topology: Topology, index, noise_mask, pen_nodes,
            sample, key):
    """Loss of one graph. sample: points, u, v (N,2) and target (N,3) SI. Returns (loss, aux)."""
    sim = spec.sim
    u, target = sample["u"], sample["target"]
    if spec.noise_std > 0:
        n = spec.noise_std * jax.random.normal(key, u.shape) * noise_mask[:, None]
        u = u + n
        target = target.at[:, :2].set(correct_target(target[:, :2], n, sim.target, dt=sim.dt))
    out, edges = predict(sim, params, stats, topology, index, sample["points"], u, sample["v"])
    err = (out - normalize_target(stats, target)) ** 2
    free = (~topology.fixed).astype(jnp.float32)
    w = jnp.stack([free, free, jnp.ones_like(free)], axis=-1)
    loss_data = jnp.mean(jnp.sum(w * err, axis=0) / jnp.sum(w, axis=0))
    if spec.lambda_pen > 0:
        u_next, _, _ = integrate(sim, topology, sample["points"], u, denormalize_output(stats, out))
        loss_pen = _penetration_loss(spec, pen_nodes, sample["points"], u_next)
    else:
        loss_pen = jnp.zeros((), jnp.float32)
    loss = loss_data + spec.lambda_pen * loss_pen
    return loss, dict(loss_data=loss_data, loss_pen=loss_pen, overflow=edges.overflow,
                      contact_count=edges.count)


def _batch_loss(params, spec, stats, topology, index, noise_mask, pen_nodes, batch, key):
    keys = jax.random.split(key, batch["u"].shape[0])
    fn = lambda s, k: loss_fn(params, spec, stats, topology, index, noise_mask, pen_nodes, s, k)  # noqa
    loss, aux = jax.vmap(fn)(batch, keys)
    return jnp.mean(loss), dict(loss_data=jnp.mean(aux["loss_data"]), loss_pen=jnp.mean(aux["loss_pen"]),
                                overflow=jnp.any(aux["overflow"]), contact_count=jnp.max(aux["contact_count"]))


@functools.partial(jax.jit, static_argnames=("spec",))
def train_chunk(spec: TrainSpec, state, stats, topology, index, noise_mask, pen_nodes, batches, seed_key):
    """K optimiser steps in one dispatch. batches: dict of (K, B, N, d); returns (state, metrics (K,))."""
    tx = make_optimizer(spec)

    def one(state, batch):
        key = jax.random.fold_in(seed_key, state["step"])
        (loss, aux), grads = jax.value_and_grad(_batch_loss, has_aux=True)(
            state["params"], spec, stats, topology, index, noise_mask, pen_nodes, batch, key)
        updates, opt_state = tx.update(grads, state["opt_state"], state["params"])
        params = optax.apply_updates(state["params"], updates)
        new = dict(step=state["step"] + 1, params=params, opt_state=opt_state)
        return new, dict(loss=loss, **aux)

    return jax.lax.scan(one, state, batches)


def init_state(cfg: TrainConfig, setup: Setup, example_traj) -> dict:
    from pcmgn_jax.mgn.normalization import normalize_graph
    t0 = example_traj
    edges = contact_lib.update(setup.index, jnp.asarray(t0.points + t0.displacement[0], jnp.float32))
    g = build_graph(setup.topology, points=t0.points, displacement=t0.displacement[0],
                    velocity=t0.velocity[0], contact=edges)
    g = normalize_graph(setup.stats, g, setup.topology.n_node_types)
    params = setup.spec.sim.model.init(jax.random.PRNGKey(cfg.seed), g)
    opt_state = make_optimizer(setup.spec).init(params)
    return dict(step=jnp.zeros((), jnp.int32), params=params, opt_state=opt_state)


# ---- checkpoints ---------------------------------------------------------------------------------

def _manager(path: Path, max_to_keep: int | None) -> ocp.CheckpointManager:
    return ocp.CheckpointManager(
        path.absolute(), options=ocp.CheckpointManagerOptions(max_to_keep=max_to_keep, create=True,
                                                              enable_async_checkpointing=False),
        item_names=("state", "stats", "meta"))


def save_checkpoint(mgr: ocp.CheckpointManager, state, stats: Stats, meta: dict) -> None:
    step = int(state["step"])
    mgr.save(step, args=ocp.args.Composite(
        state=ocp.args.StandardSave(state), stats=ocp.args.StandardSave(dict(stats._asdict())),
        meta=ocp.args.JsonSave(meta)), force=True)
    mgr.wait_until_finished()


def restore_checkpoint(path: Path, template_state, step: int | None = None):
    """(state, stats, meta) from a checkpoint directory (latest step unless ``step``)."""
    mgr = _manager(Path(path), None)
    step = mgr.latest_step() if step is None else step
    if step is None:
        raise FileNotFoundError(f"no checkpoint in {path}")
    meta = mgr.restore(step, args=ocp.args.Composite(meta=ocp.args.JsonRestore()))["meta"]
    n = {k: np.zeros(len(v), np.float32) for k, v in meta["stats"].items()}  # shapes from meta
    res = mgr.restore(step, args=ocp.args.Composite(
        state=ocp.args.StandardRestore(template_state), stats=ocp.args.StandardRestore(n)))
    return res["state"], Stats(**{k: np.asarray(res["stats"][k]) for k in Stats._fields}), meta


# ---- validation --------------------------------------------------------------------------------

def rollout_position_mae_um(setup: Setup, params, trajs) -> tuple[float, bool]:
    """Mean |x_pred - x_true| [µm] over frames, nodes, components and trajectories; finite flag."""
    if not trajs:
        return float("nan"), True
    T = trajs[0].n_frames
    pts = np.stack([t.points for t in trajs]).astype(np.float32)
    u0 = np.stack([t.displacement[0] for t in trajs]).astype(np.float32)
    v0 = np.stack([t.velocity[0] for t in trajs]).astype(np.float32)
    s0 = np.stack([t.von_mises[0] for t in trajs]).astype(np.float32)
    res, _ = rollout_checked(setup.spec.sim, T - 1, params, setup.stats, setup.topology, setup.index,
                             pts, u0, v0, s0, batched=True)
    true = np.stack([t.displacement for t in trajs])
    err = np.abs(np.asarray(res.displacement, np.float64) - true)
    mae = float(np.mean(err) * 1e6)
    return mae, bool(np.isfinite(mae))


# ---- the loop ------------------------------------------------------------------------------------

def _meta(cfg: TrainConfig, setup: Setup, **extra) -> dict:
    return dict(config=cfg.to_dict(), contact_radius=setup.index.radius,
                contact_capacity=setup.index.capacity, dt=setup.spec.sim.dt, total_steps=setup.total_steps,
                stats=setup.stats.to_json(), **extra)


def train(cfg: TrainConfig, workdir: str | Path, *, train_trajs: Sequence, val_trajs: Sequence = (),
          resume: bool = False, stop_after: int | None = None) -> dict:
    """Train; returns a summary dict. ``stop_after``: stop (as if killed) after that many steps."""
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    cfg.save_json(workdir / "config.json")
    periodic = _manager(workdir / "checkpoints" / "periodic", cfg.max_to_keep)
    best_mgr = _manager(workdir / "checkpoints" / "best", 1)

    if resume and periodic.latest_step() is not None:
        meta = periodic.restore(periodic.latest_step(), args=ocp.args.Composite(meta=ocp.args.JsonRestore()))["meta"]
        setup = prepare(cfg, train_trajs, capacity=meta["contact_capacity"], radius=meta["contact_radius"])
        setup = setup._replace(stats=Stats.from_json(meta["stats"]))
        template = init_state(cfg, setup, train_trajs[0])
        state, _, meta = restore_checkpoint(workdir / "checkpoints" / "periodic", template)
        best_val = meta.get("best_val", float("inf"))
        mode = "a"
    else:
        if resume:
            print(f"--resume: no checkpoint in {workdir / 'checkpoints' / 'periodic'}; starting fresh")
        setup = prepare(cfg, train_trajs)
        state = init_state(cfg, setup, train_trajs[0])
        best_val = float("inf")
        mode = "w"
    setup.stats.save(workdir / "normalization.json")
    table = pair_table(train_trajs)
    K, B = cfg.steps_per_dispatch, cfg.batch_graphs
    every = lambda n: K * max(1, math.ceil(n / K))  # noqa: E731
    log_every, ckpt_every, val_every = every(cfg.log_every), every(cfg.ckpt_every), every(cfg.val_every)
    seed_key = jax.random.PRNGKey(cfg.seed + 1)
    stats, topo, nmask = setup.stats, setup.topology, setup.noise_mask
    step = int(state["step"])
    total = setup.total_steps
    end = total if stop_after is None else min(total, step + stop_after)
    last_good = periodic.latest_step()

    bar = None
    if cfg.progress:
        from tqdm import tqdm
        bar = tqdm(total=total, initial=step, desc="train", dynamic_ncols=True)
    t_start, rate = time.perf_counter(), float("nan")
    with open(workdir / "metrics.jsonl", mode) as log:
        while step < end:
            t_chunk = time.perf_counter()
            ids = sample_ids(cfg.seed, step, K, B, setup.n_pairs)
            batch = gather(train_trajs, table, ids, target=cfg.target, dt=setup.spec.sim.dt)
            new_state, m = train_chunk(setup.spec, state, stats, topo, setup.index, nmask,
                                       setup.pen_nodes, batch, seed_key)
            m = jax.device_get(m)
            if np.any(m["overflow"]):
                need = int(np.max(m["contact_count"]))
                setup = setup._replace(index=contact_lib.grow(setup.index, need))
                print(f"contact buffer overflow at step {step} (needed {need}); grown to "
                      f"{setup.index.capacity} and the chunk is re-run")
                continue
            if not np.all(np.isfinite(m["loss"])):
                bad = step + int(np.argmin(np.isfinite(m["loss"])))
                msg = (f"loss became non-finite at step {bad}; training stopped. Last good checkpoint: "
                       f"{'step ' + str(last_good) if last_good is not None else 'none'} in "
                       f"{workdir / 'checkpoints' / 'periodic'}")
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
                           lr=float(learning_rate(setup.spec, step)),
                           steps_per_s=rate, contact_edges_max=int(np.max(m["contact_count"])))
                if cfg.lambda_pen > 0:
                    rec["loss_pen"] = float(np.mean(m["loss_pen"]))
                    rec["pen_ratio"] = float(cfg.lambda_pen * rec["loss_pen"] / max(rec["loss_data"], 1e-30))
            if val_trajs and (step % val_every == 0 or step >= total):
                val, finite = rollout_position_mae_um(setup, state["params"], val_trajs)
                rec = rec or dict(step=step)
                rec["val_position_mae_um"] = val
                if finite and val < best_val:
                    best_val = val
                    save_checkpoint(best_mgr, state, stats, _meta(cfg, setup, best_val=best_val))
            if rec is not None:
                log.write(json.dumps(rec) + "\n")
                log.flush()
            if step % ckpt_every == 0 or step >= end:
                save_checkpoint(periodic, state, stats, _meta(cfg, setup, best_val=best_val))
                last_good = step
    if bar is not None:
        bar.close()
    if not val_trajs and step >= total:
        save_checkpoint(best_mgr, state, stats, _meta(cfg, setup, best_val=None))
    return dict(step=step, best_val_position_mae_um=best_val, state=state, setup=setup,
                seconds=time.perf_counter() - t_start)


def load_for_inference(workdir: str | Path, cfg: TrainConfig, train_trajs_or_ref, *, which: str = "best"):
    """(setup, params) from a run directory; ``which``: 'best' or 'periodic' (latest)."""
    workdir = Path(workdir)
    path = workdir / "checkpoints" / which
    mgr = _manager(path, None)
    if mgr.latest_step() is None and which == "best":
        path = workdir / "checkpoints" / "periodic"
        mgr = _manager(path, None)
    step = mgr.latest_step()
    if step is None:
        raise FileNotFoundError(f"no checkpoint under {workdir / 'checkpoints'}")
    meta = mgr.restore(step, args=ocp.args.Composite(meta=ocp.args.JsonRestore()))["meta"]
    ref = train_trajs_or_ref
    setup = prepare_from_meta(cfg, ref, meta)
    template = init_state(cfg, setup, ref)
    state, stats, meta = restore_checkpoint(path, template, step)
    return setup._replace(stats=stats), state["params"], meta


def prepare_from_meta(cfg: TrainConfig, ref, meta: dict) -> Setup:
    """Setup for inference from a checkpoint's meta (no training data needed, only the topology)."""
    scene = scene_of(ref)
    topology = topology_from_trajectory(ref)
    ball_part, panel_part = contact_parts(scene)
    index = contact_lib.allocate(points=ref.points, cells=ref.cells, cell_part=ref.cell_part,
                                 ball_part=ball_part, panel_part=panel_part, radius=meta["contact_radius"],
                                 capacity=meta["contact_capacity"])
    sim = Spec(model=make_model(cfg), target=cfg.target, dt=float(meta["dt"]))
    steps = int(meta["total_steps"])
    spec, pen_nodes = _train_spec(cfg, sim, steps, ref, panel_part)
    return Setup(spec, topology, index, Stats.from_json(meta["stats"]), np.zeros(ref.n_nodes, bool),
                 pen_nodes, scene, 0, steps)


__all__ = ["TrainSpec", "Setup", "TrainingDiverged", "prepare", "init_state", "train_chunk", "train",
           "loss_fn", "make_optimizer", "sample_ids", "save_checkpoint", "restore_checkpoint",
           "load_for_inference", "compute_stats", "rollout_position_mae_um"]

