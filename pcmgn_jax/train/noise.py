"""Training noise: the one implementation, used by the training step and by the statistics.

Gaussian noise n on the input displacement of the chosen parts' free nodes (MeshGraphNets style), with
the velocity input moved consistently (v~ = v + n/dt, the velocity a rollout would feed back) and the
target corrected so the update from the noisy input lands on the clean next frame
(:func:`pcmgn_jax.mgn.formulation.add_noise`, per target type).

The standard deviation is per node (:func:`noise_sigma`): either one absolute ``noise_std`` [m] (the
paper: 0.3 µm on all parts) or ``noise_rel`` times each part's RMS motion per frame, so the 2.5 µm/frame
ball and the ~1 nm/frame plate are perturbed alike relative to how they move. A rigid ball receives one
shared noise vector (it stays rigid).
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from pcmgn_jax.mgn.formulation import BALL_PART, NOISE_PARTS, add_noise
from pcmgn_jax.mgn.rollout import ball_mask


def noise_parts_mask(node_part, parts: str, *, fixed) -> np.ndarray:
    """(N,) bool: the free nodes of the noised parts ('none' | 'ball' | 'panel' | 'all')."""
    if parts not in NOISE_PARTS:
        raise ValueError(f"noise_parts must be one of {NOISE_PARTS}, got {parts!r}")
    node_part = np.asarray(node_part)
    sel = {"none": np.zeros(node_part.shape, bool), "ball": node_part == BALL_PART,
           "panel": node_part != BALL_PART, "all": np.ones(node_part.shape, bool)}[parts]
    return sel & ~np.asarray(fixed, bool)


def motion_rms(trajs, n_types: int, types=None) -> np.ndarray:
    """(n_types,) RMS per-frame displacement increment |u_{t+1} - u_t| per component [m], per node type,
    pooled over ``trajs`` (each on its own mesh, typed by its own ``node_type``, or by ``types``: one (N,)
    array per trajectory, e.g. role node types)."""
    s = np.zeros(n_types)
    n = np.zeros(n_types)
    for i, tr in enumerate(trajs):
        node_type = np.asarray(tr.node_type if types is None else types[i])
        du = np.diff(np.asarray(tr.displacement, np.float64), axis=0)  # (T-1, N, 2)
        sq = (du ** 2).sum(axis=(0, 2))
        np.add.at(s, node_type, sq)
        np.add.at(n, node_type, du.shape[0] * 2)
    return np.sqrt(s / np.maximum(n, 1))


def noise_sigma(node_type, node_part, fixed, *, parts: str, noise_std: float = 0.0, noise_rel: float = 0.0,
                rms=None) -> np.ndarray:
    """(N,) float32 noise std per node [m]: ``noise_std``, or ``noise_rel * rms[type]``; 0 off the noised parts."""
    mask = noise_parts_mask(node_part, parts, fixed=fixed)
    if noise_std > 0:
        sigma = np.full(mask.shape, float(noise_std))
    elif noise_rel > 0:
        if rms is None:
            raise ValueError("noise_rel needs the per-part motion (motion_rms)")
        sigma = float(noise_rel) * np.asarray(rms, np.float64)[np.asarray(node_type)]
    else:
        sigma = np.zeros(mask.shape)
    return np.where(mask, sigma, 0.0).astype(np.float32)


_BALL_DRAW = 0x7FFFFFFF  # fold_in data of a graph's shared rigid-ball draw (no node has this index)


def sample_noise(key, sigma, ball_mask, *, rigid_ball: bool, segments=None, graph_ids=None):
    """(N, 2) noise [m]: N(0, sigma_i^2) per node and component; one shared draw per rigid ball.

    Every node draws from its own key, fold_in(fold_in(key, graph id), node index within its graph), so
    the noise of a graph does not depend on where it sits in a padded disjoint union, on the padding or on
    the other graphs (nor on how a batch is split over devices). ``segments``: ``(node_graph (N,),
    n_graph)`` of a union (None: one graph); ``graph_ids`` (n_graph,) int: each graph's id (default its
    slot). A rigid ball draws once per graph, with that graph's largest ball sigma.
    """
    sigma = jnp.asarray(sigma)
    n_node = sigma.shape[0]
    node_graph, n_graph = (jnp.zeros(n_node, jnp.int32), 1) if segments is None else segments
    ids = jnp.arange(n_graph) if graph_ids is None else jnp.asarray(graph_ids)
    gkeys = jax.vmap(jax.random.fold_in, in_axes=(None, 0))(key, ids)
    count = jax.ops.segment_sum(jnp.ones(n_node, jnp.int32), node_graph, num_segments=n_graph)
    first = jnp.cumsum(count) - count  # nodes of a graph are contiguous (jraph.batch)
    local = jnp.arange(n_node) - first[node_graph]
    nkeys = jax.vmap(jax.random.fold_in)(gkeys[node_graph], local)
    draw = lambda k: jax.random.normal(k, (2,), sigma.dtype)  # noqa: E731
    n = sigma[:, None] * jax.vmap(draw)(nkeys)
    if rigid_ball:
        ball = jnp.asarray(ball_mask)
        s_ball = jax.ops.segment_max(jnp.where(ball, sigma, 0.0), node_graph, num_segments=n_graph)
        bkeys = jax.vmap(jax.random.fold_in, in_axes=(0, None))(gkeys, _BALL_DRAW)
        n_ball = s_ball[:, None] * jax.vmap(draw)(bkeys)
        n = jnp.where(ball[:, None], n_ball[node_graph], n)
    return n


def perturb(spec, topology, sample: dict, sigma, key, layout=None, graph_ids=None) -> dict:
    """``sample`` as the training loss sees it: drawn noise on the input displacement, with the velocity input
    and targets corrected (:func:`pcmgn_jax.mgn.formulation.add_noise`). One function for the loss and the statistics.
    ``layout``: a padded disjoint union's (the rigid ball is one body per graph), ``graph_ids`` its graphs'
    noise ids (:func:`sample_noise`)."""
    form = spec.formulation
    ball = ball_mask(topology)
    segments = None if layout is None else layout.segments
    n = sample_noise(key, sigma, ball, rigid_ball=form.rigid_ball, segments=segments, graph_ids=graph_ids)
    return add_noise(form, ball, sample, n, spec.dt, segments=segments)
