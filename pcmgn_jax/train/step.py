"""Loss, optimiser and the module-level jitted ``train_chunk`` (K optimiser steps per dispatch).

Loss of one graph (normalised units)::

    loss_data = ( sum_i w_i |e_i,xy|^2  +  w_ball |e_ball|^2  +  sum_i w'_i e_i,vm^2 ) / 3
    loss      = loss_data + lambda_pen * L_pen

with e the normalised error of each node's [a_x, a_y, von Mises] (rows of its own node type), e_ball
the rigid ball's, and the weights of :func:`pcmgn_jax.train.setup.loss_weights` (fixed nodes carry no
motion weight). L_pen is the paper's penetration term (section 2.3) of the predicted next positions,
the depth d in units of ``pen_length_scale`` (µm by default, so λ = 10 means what it means in the paper).
"""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import optax

from pcmgn_jax.mgn.normalization import Stats, normalize_target
from pcmgn_jax.mgn.rollout import ball_output, integrate_output, predict
from pcmgn_jax.train.noise import perturb
from pcmgn_jax.train.penetration import penetration_depth, penetration_loss
from pcmgn_jax.train.setup import TrainSpec


def learning_rate(spec: TrainSpec, step):
    """lr0 * rate ** (step / decay_steps) (continuous exponential decay)."""
    return optax.exponential_decay(spec.cfg.learning_rate, transition_steps=spec.decay_steps,
                                   decay_rate=spec.cfg.lr_decay_rate)(step)


def make_optimizer(spec: TrainSpec) -> optax.GradientTransformation:
    return optax.adam(functools.partial(learning_rate, spec))


def init_state(spec: TrainSpec, params) -> dict:
    return dict(step=jnp.zeros((), jnp.int32), params=params, opt_state=make_optimizer(spec).init(params))


def _penetration(spec: TrainSpec, pen_nodes, points, u_next):
    cfg = spec.cfg
    pos = points + u_next
    d, valid = penetration_depth(pos[pen_nodes["ball"]], pos[pen_nodes["panel"]], degree_ball=cfg.poly_ball,
                                 degree_panel=cfg.poly_panel, interval=spec.pen_interval)
    return penetration_loss(d, valid, length_scale=cfg.pen_length_scale)


def loss_fn(params, spec: TrainSpec, stats: Stats, topology, index, sigma, pen_nodes, weights, sample, key):
    """Loss of one graph. sample: points, u, v (N,2), target (N,3), ball (2,) SI (with ``pushforward``
    also u_prev_in, v_prev_in (N,2), has_prev ()). Returns (loss, aux)."""
    sim = spec.sim
    form = sim.formulation
    dev = None
    if spec.cfg.pushforward:
        pf_mask = weights["perturbed"]
        # the model's own one-step prediction of this frame (from the true previous frame) as the input:
        # its deviation from the truth is exactly an input "noise" n with velocity noise n/dt; only on
        # the perturbed parts (noise_parts): for a body that keeps an acceleration target, landing on the
        # true next frame from a wrong position would need an unphysical one-step acceleration
        frozen = jax.lax.stop_gradient(params)
        out0, _ = predict(sim, frozen, stats, topology, index, sample["points"], sample["u_prev_in"],
                          sample["v_prev_in"])
        u_hat, _, _ = integrate_output(sim, stats, topology, sample["points"], sample["u_prev_in"],
                                       sample["v_prev_in"], out0)
        dev = jax.lax.stop_gradient(u_hat - sample["u"]) * (sample["has_prev"] * pf_mask)[:, None]
    sample = perturb(sim, topology, sample, sigma, key, dev)
    out, edges = predict(sim, params, stats, topology, index, sample["points"], sample["u"], sample["v"])
    err = (out[:, :3] - normalize_target(stats, topology.node_type, sample["target"])) ** 2
    loss_data = jnp.sum(weights["motion"] * (err[:, 0] + err[:, 1])) + jnp.sum(weights["stress"] * err[:, 2])
    if form.rigid_ball:
        e_ball = (ball_output(topology, out) - (sample["ball"] - stats.ball_mean) / stats.ball_std) ** 2
        loss_data = loss_data + weights["ball"] * jnp.sum(e_ball)
    loss_data = loss_data / 3.0
    if spec.cfg.lambda_pen > 0:
        u_next, _, _ = integrate_output(sim, stats, topology, sample["points"], sample["u"], sample["v"], out)
        loss_pen = _penetration(spec, pen_nodes, sample["points"], u_next)
    else:
        loss_pen = jnp.zeros((), jnp.float32)
    loss = loss_data + spec.cfg.lambda_pen * loss_pen
    return loss, dict(loss_data=loss_data, loss_pen=loss_pen, overflow=edges.overflow, contact_count=edges.count)


def _batch_loss(params, spec, stats, topology, index, sigma, pen_nodes, weights, batch, key):
    keys = jax.random.split(key, batch["u"].shape[0])
    fn = lambda s, k: loss_fn(params, spec, stats, topology, index, sigma, pen_nodes, weights, s, k)  # noqa
    loss, aux = jax.vmap(fn)(batch, keys)
    return jnp.mean(loss), dict(loss_data=jnp.mean(aux["loss_data"]), loss_pen=jnp.mean(aux["loss_pen"]),
                                overflow=jnp.any(aux["overflow"]), contact_count=jnp.max(aux["contact_count"]))


@functools.partial(jax.jit, static_argnames=("spec",))
def train_chunk(spec: TrainSpec, state, stats, topology, index, sigma, pen_nodes, weights, batches, seed_key):
    """K optimiser steps in one dispatch. batches: dict of (K, B, ...) arrays; returns (state, metrics (K,))."""
    tx = make_optimizer(spec)

    def one(state, batch):
        key = jax.random.fold_in(seed_key, state["step"])
        (loss, aux), grads = jax.value_and_grad(_batch_loss, has_aux=True)(
            state["params"], spec, stats, topology, index, sigma, pen_nodes, weights, batch, key)
        updates, opt_state = tx.update(grads, state["opt_state"], state["params"])
        params = optax.apply_updates(state["params"], updates)
        return dict(step=state["step"] + 1, params=params, opt_state=opt_state), dict(loss=loss, **aux)

    return jax.lax.scan(one, state, batches)
