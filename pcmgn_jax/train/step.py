"""Loss, optimiser and the module-level jitted ``train_chunk`` (K optimiser steps per dispatch).

A step's batch is a padded disjoint union of graphs (:func:`pcmgn_jax.train.sampling.union_batch`; the
graphs may have different meshes). Loss of one graph g (normalised units)::

    loss_data_g = ( sum_i w_i |e_i,xy|^2  +  w_ball,g |e_ball,g|^2  +  sum_i w'_i e_i,vm^2 ) / 3
    loss_g      = loss_data_g + lambda(step) * L_pen,g + lambda_obj * L_obj,g     (lambda(step): :func:`penalty_weight`)
    L_obj,g     = ( sum_i o_i e_i,vm )^2      (signed e; o: the objective's section weights, sum 1)

summed over g's own nodes i, with e the normalised error of each node's [a_x, a_y, von Mises] (rows of
its own node type), e_ball,g graph g's rigid ball (its vertical component: the ball moves along the
symmetry axis, :func:`pcmgn_jax.mgn.formulation.axial`), and the weights of
:func:`pcmgn_jax.train.setup.loss_weights` (fixed nodes carry no motion weight; padding nodes none at all).
L_pen,g is the paper's penetration term (section 2.3) of g's predicted next positions, from g's own
boundary nodes, the depth d in units of ``pen_length_scale`` (µm by default, so λ = 10 means what it
means in the paper). L_obj,g (``lambda_obj`` > 0) is the squared error of the OLED's objective-section
mean von Mises of this frame, in the OLED's normalised units (one std per node type: the weighted mean of
the normalised errors is the section mean's error over that std): the node-wise MSE weighs a coherent
bias over the section no more than scatter, and the objective is exactly such a mean
(:func:`pcmgn_jax.train.setup.objective_loss_weights`). With ``stress_target='log'`` the stress output is
s = T(vm) = log1p(vm / 1 MPa) (:mod:`pcmgn_jax.mgn.stress_target`), whose section mean is not the section's mean
stress, so the prediction is read back in Pa (vm^) and L_obj,g = ( (T(sum_i o_i vm^_i) - T(sum_i o_i vm_i)) /
sum_i o_i std_i )^2, std_i the s channel's std of node i's type. The step's loss is the mean of loss_g over the real
graphs of the batch: padding changes neither the loss nor its gradient, and a graph's loss does not depend on the
other graphs.
Noise is drawn per node from the graph's id (:func:`pcmgn_jax.train.noise.sample_noise`), so it does
not depend on the union either.
"""
from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax

from pcmgn_jax.mgn.formulation import axial
from pcmgn_jax.mgn.normalization import Stats, denormalize_output, normalize_target
from pcmgn_jax.mgn.rollout import ball_mask, ball_output, integrate_output, network, predict
from pcmgn_jax.mgn.stress_target import stress_to_target, target_to_stress
from pcmgn_jax.train.noise import perturb
from pcmgn_jax.train.penetration import penetration_depth, penetration_loss
from pcmgn_jax.train.setup import TrainSpec


def learning_rate(spec: TrainSpec, step):
    """lr0 * rate ** (step / decay_steps) (continuous exponential decay)."""
    return optax.exponential_decay(spec.cfg.learning_rate, transition_steps=spec.decay_steps,
                                   decay_rate=spec.cfg.lr_decay_rate)(step)


def penalty_weight(spec: TrainSpec, step):
    """λ at optimiser step ``step``: 0 before ``lambda_start`` x total steps, then a linear ramp to
    ``lambda_pen`` over the next 10 % of training (``lambda_start`` = 0: λ throughout, the paper).

    Why a delayed start: the penetration term is quadratic in µm, so while the model's contact zone is
    still far from the truth a single frame's term can be 10–40x the normalised data loss and its
    gradient wrecks the fit (docs/results/studies.md); once the fields are close, the term
    only has to remove the last µm of overlap."""
    cfg = spec.cfg
    if cfg.lambda_start <= 0:
        return jnp.asarray(cfg.lambda_pen, jnp.float32)
    total = spec.decay_steps
    start, ramp = cfg.lambda_start * total, max(0.1 * total, 1.0)
    return cfg.lambda_pen * jnp.clip((jnp.asarray(step, jnp.float32) - start) / ramp, 0.0, 1.0)


def make_optimizer(spec: TrainSpec) -> optax.GradientTransformation:
    return optax.adam(functools.partial(learning_rate, spec))


class TrainState(NamedTuple):
    """What training carries from one optimiser step to the next (a pytree; checkpoints store
    :meth:`to_dict`, whose keys are these names)."""

    step: Any                # () int32: optimiser steps taken
    params: Any              # the model's parameters (flax variables), float32
    opt_state: Any           # Adam's state (optax; moments shaped like params)
    ema_params: Any = None   # the parameters' moving average (like params) when cfg.ema_decay > 0, else None

    def to_dict(self) -> dict:
        """The checkpoint layout: {step, params, opt_state[, ema_params]} (ema_params only when kept)."""
        return {k: v for k, v in self._asdict().items() if v is not None}

    @classmethod
    def from_dict(cls, d: dict) -> "TrainState":
        return cls(step=d["step"], params=d["params"], opt_state=d["opt_state"], ema_params=d.get("ema_params"))


def init_state(spec: TrainSpec, params) -> TrainState:
    """Fresh optimiser state; with ``ema_decay`` > 0 the moving average starts at ``params``."""
    ema = jax.tree.map(jnp.array, params) if spec.cfg.ema_decay > 0 else None
    return TrainState(step=jnp.zeros((), jnp.int32), params=params, opt_state=make_optimizer(spec).init(params),
                      ema_params=ema)


def eval_params(cfg, state: TrainState):
    """The parameters a run (config ``cfg``) validates, keeps as its best checkpoint and evaluates: the
    moving average when ``cfg.ema_decay`` > 0, else the optimiser's own."""
    return state.ema_params if cfg.ema_decay > 0 else state.params


def _penetration(spec: TrainSpec, batch, points, u_next):
    """(G,) penetration loss of each graph of a union (0 for padding slots: no boundary nodes)."""
    cfg = spec.cfg
    pos = points + u_next

    def one(b, bm, p, pm):
        d, valid = penetration_depth(pos[b], pos[p], degree_ball=cfg.poly_ball, degree_panel=cfg.poly_panel,
                                     interval=spec.pen_interval, ball_mask=bm, panel_mask=pm)
        return penetration_loss(d, valid, length_scale=cfg.pen_length_scale)

    return jax.vmap(one)(batch.pen_ball, batch.pen_ball_mask, batch.pen_panel, batch.pen_panel_mask)


def loss_fn(params, spec: TrainSpec, stats: Stats, batch, key, step=None):
    """Loss of one padded union (:func:`pcmgn_jax.train.sampling.union_batch`): (mean over its real
    graphs, aux with the per-graph ``loss_graph`` (G,) and data / penetration parts). ``step``: the
    optimiser step, for the λ schedule (:func:`penalty_weight`); None = the configured λ."""
    if spec.sim.formulation.processor == "per_design":
        return _loss_per_design(params, spec, stats, batch, key, step)
    sim = spec.sim
    g = batch.graph
    topology, layout, index, points = g.topology, g.layout, g.index, g.points
    sample = dict(points=points, u=batch.u, v=batch.v, target=batch.target, ball=batch.ball)
    sample = perturb(sim, topology, sample, batch.sigma, key, layout=layout, graph_ids=batch.graph_id)
    out, edges = predict(sim, params, stats, topology, index, points, sample["u"], sample["v"], layout)
    loss_data, loss_pen, loss_obj = _frame_losses(spec, stats, batch, sample, out)
    return _total(spec, batch, loss_data, loss_pen, loss_obj, edges, step)


def _frame_losses(spec: TrainSpec, stats: Stats, batch, sample: dict, out):
    """(G,) data, penetration and objective losses of one frame's normalised output ``out`` against
    ``sample``'s targets (the module docstring's loss_data_g, L_pen,g and L_obj,g)."""
    sim, form = spec.sim, spec.sim.formulation
    g = batch.graph
    topology, layout, points = g.topology, g.layout, g.points
    node_graph, n_graph = layout.segments
    signed = out[:, :3] - normalize_target(stats, topology.node_type, sample["target"])
    err = signed ** 2
    if spec.cfg.lambda_obj > 0:
        loss_obj = _objective_error(form, stats, batch, out, sample["target"], signed) ** 2
    else:
        loss_obj = jnp.zeros(n_graph, jnp.float32)
    per_node = batch.w_motion * (err[:, 0] + err[:, 1]) + batch.w_stress * err[:, 2]
    loss_data = jax.ops.segment_sum(per_node, node_graph, num_segments=n_graph)
    if form.rigid_ball:
        e_ball = axial((ball_output(topology, out, layout) - (sample["ball"] - stats.ball_mean) / stats.ball_std) ** 2)
        loss_data = loss_data + batch.w_ball * jnp.sum(e_ball, axis=-1)
    loss_data = loss_data / 3.0
    if spec.cfg.lambda_pen > 0:
        u_next, _, _ = integrate_output(sim, stats, topology, points, sample["u"], sample["v"], out, layout)
        if form.panel_model == "quasi_static":  # the panel's prediction is at the input's time: the ball's too
            u_next = jnp.where(ball_mask(topology)[:, None], sample["u"], u_next)
        loss_pen = _penetration(spec, batch, points, u_next)
    else:
        loss_pen = jnp.zeros(n_graph, jnp.float32)
    return loss_data, loss_pen, loss_obj


def _objective_error(form, stats: Stats, batch, out, target, signed):
    """(G,) each graph's signed objective-section error of the stress output in normalised units (L_obj,g before
    the square, module docstring): sum_i o_i e_i,vm; with ``stress_target='log'`` the log target of the section's
    mean predicted stress [Pa] minus the truth's, over the section's mean std of the s channel."""
    node_graph, n_graph = batch.graph.layout.segments
    section = lambda f: jax.ops.segment_sum(batch.w_obj * f, node_graph, num_segments=n_graph)  # noqa: E731
    if form.stress_target == "linear":
        return section(signed[:, 2])
    kind, node_type = form.stress_target, batch.graph.topology.node_type
    pred = target_to_stress(kind, denormalize_output(stats, node_type, out)[:, 2])
    true = target_to_stress(kind, target[:, 2])
    std = section(jnp.asarray(stats.target_std)[node_type, 2])   # 0 on a padding slot (no section weights)
    return (stress_to_target(kind, section(pred)) - stress_to_target(kind, section(true))) / jnp.where(std > 0, std, 1)


def _total(spec: TrainSpec, batch, loss_data, loss_pen, loss_obj, edges, step):
    """The union's mean loss over its real graphs and the aux dict, from per-graph (G,) parts."""
    lam = spec.cfg.lambda_pen if step is None else penalty_weight(spec, step)
    loss = loss_data + lam * loss_pen + spec.cfg.lambda_obj * loss_obj
    real = batch.graph_mask
    mean = lambda a: jnp.sum(jnp.where(real, a, 0.0)) / jnp.maximum(jnp.sum(real), 1)  # noqa: E731
    return mean(loss), dict(loss_data=mean(loss_data), loss_pen=mean(loss_pen), loss_obj=mean(loss_obj),
                            loss_graph=loss, overflow=jnp.any(edges.overflow), contact_count=jnp.max(edges.count))


def _loss_per_design(params, spec: TrainSpec, stats: Stats, batch, key, step=None):
    """:func:`loss_fn` of a per-design processor: the processor runs once on each design's graph and its
    decoder reads out every frame of the batch (u, v, target, ball with a leading frame axis F when
    ``frames_per_sample`` > 1); the loss is the mean over the F frames of each frame's loss."""
    sim = spec.sim
    g = batch.graph
    multi = batch.u.ndim == 3
    frames = [a if multi else a[None] for a in (batch.u, batch.v, batch.target, batch.ball)]
    net = network(sim, params, stats, g.topology, g.index, g.points, frames[0][0], frames[1][0], g.layout)

    def one(f, u, v, target, ball):
        sample = dict(points=g.points, u=u, v=v, target=target, ball=ball)
        sample = perturb(sim, g.topology, sample, batch.sigma, jax.random.fold_in(key, f), layout=g.layout,
                         graph_ids=batch.graph_id)
        out, edges = net(sample["u"], sample["v"])
        return _frame_losses(spec, stats, batch, sample, out) + (edges,)

    # edges (F, ...): the design's one contact set F times (_total reduces over every axis)
    loss_data, loss_pen, loss_obj, edges = jax.vmap(one)(jnp.arange(frames[0].shape[0]), *frames)
    return _total(spec, batch, jnp.mean(loss_data, axis=0), jnp.mean(loss_pen, axis=0), jnp.mean(loss_obj, axis=0),
                  edges, step)


def batch_loss(params, spec, stats, batch, key, step=None):
    """Mean loss of a step's unions (S, ...) (one per device shard, each of B/S real graphs; the same key:
    noise comes from each graph's global id)."""
    fn = lambda b: loss_fn(params, spec, stats, b, key, step)  # noqa: E731
    loss, aux = jax.vmap(fn)(batch)
    return jnp.mean(loss), dict(loss_data=jnp.mean(aux["loss_data"]), loss_pen=jnp.mean(aux["loss_pen"]),
                                loss_obj=jnp.mean(aux["loss_obj"]),
                                overflow=jnp.any(aux["overflow"]), contact_count=jnp.max(aux["contact_count"]))


@functools.partial(jax.jit, static_argnames=("spec",))
def train_chunk(spec: TrainSpec, state, stats, batches, seed_key):
    """K optimiser steps in one dispatch. batches: a pytree of (K, S, ...) unions
    (:func:`pcmgn_jax.train.sampling.gather_unions`); returns (state, metrics (K,)). One compilation per
    (spec, union size bucket): every batch of a dataset has the same static shapes."""
    tx = make_optimizer(spec)

    def one(state: TrainState, batch):
        key = jax.random.fold_in(seed_key, state.step)
        (loss, aux), grads = jax.value_and_grad(batch_loss, has_aux=True)(state.params, spec, stats, batch, key,
                                                                           state.step)
        updates, opt_state = tx.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        ema = None
        if spec.cfg.ema_decay > 0:  # Polyak average: ema <- d ema + (1 - d) params
            ema = optax.incremental_update(params, state.ema_params, 1.0 - spec.cfg.ema_decay)
        return TrainState(step=state.step + 1, params=params, opt_state=opt_state, ema_params=ema), \
            dict(loss=loss, **aux)

    return jax.lax.scan(one, state, batches)
