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

from pcmgn_jax.mgn.formulation import BALL_PART, NOISE_PARTS


def noise_parts_mask(node_part, parts: str, *, fixed) -> np.ndarray:
    """(N,) bool: the free nodes of the noised parts ('none' | 'ball' | 'panel' | 'all')."""
    if parts not in NOISE_PARTS:
        raise ValueError(f"noise_parts must be one of {NOISE_PARTS}, got {parts!r}")
    node_part = np.asarray(node_part)
    sel = {"none": np.zeros(node_part.shape, bool), "ball": node_part == BALL_PART,
           "panel": node_part != BALL_PART, "all": np.ones(node_part.shape, bool)}[parts]
    return sel & ~np.asarray(fixed, bool)


def motion_rms(trajs, node_type, n_types: int) -> np.ndarray:
    """(n_types,) RMS per-frame displacement increment |u_{t+1} - u_t| per component [m], per node type."""
    s = np.zeros(n_types)
    n = np.zeros(n_types)
    node_type = np.asarray(node_type)
    for tr in trajs:
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


def sample_noise(key, sigma, ball_mask, *, rigid_ball: bool):
    """(N, 2) noise [m]: N(0, sigma_i^2) per node and component; one shared draw on a rigid ball."""
    k1, k2 = jax.random.split(key)
    sigma = jnp.asarray(sigma)
    n = sigma[:, None] * jax.random.normal(k1, sigma.shape + (2,), sigma.dtype)
    if rigid_ball:
        ball = jnp.asarray(ball_mask)
        s_ball = jnp.max(jnp.where(ball, sigma, 0.0))
        n = jnp.where(ball[:, None], s_ball * jax.random.normal(k2, (2,), sigma.dtype)[None], n)
    return n


def perturb(spec, topology, sample: dict, sigma, key, offset=None) -> dict:
    """``sample`` as the training loss sees it: ``offset`` (N, 2) [m] (e.g. the pushforward deviation)
    plus drawn noise on the input displacement, with the velocity input and targets corrected
    (:func:`pcmgn_jax.mgn.formulation.add_noise`). One function for the loss and the statistics."""
    from pcmgn_jax.mgn.formulation import add_noise
    from pcmgn_jax.mgn.rollout import ball_mask

    form = spec.formulation
    ball = ball_mask(topology)
    n = sample_noise(key, sigma, ball, rigid_ball=form.rigid_ball)
    return add_noise(form, ball, sample, n if offset is None else n + offset, spec.dt)
