"""Data order and host batches: which (trajectory, frame) pairs a training step sees.

Data order is a pure function of (seed, step): sample k = step * B + b comes from epoch k // n_pairs at
position k % n_pairs of ``permutation(default_rng([seed, epoch]))``, so ``--resume`` replays exactly what
an uninterrupted run would have seen.
"""
from __future__ import annotations

import numpy as np

from pcmgn_jax.mgn.formulation import Formulation, is_ball, previous_displacement, training_sample


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
    """(P, 2) int64 (trajectory index, frame t) of every training step t -> t + 1."""
    return np.array([(i, t) for i, tr in enumerate(trajs) for t in range(tr.n_frames - 1)], np.int64)


def sample(form: Formulation, traj, t: int, dt: float) -> dict:
    """Inputs and physical targets of the step t -> t + 1 of ``traj`` (float64 NumPy)."""
    u_prev = previous_displacement(traj.displacement, traj.velocity, t, dt)
    out = training_sample(form, is_ball(traj.node_type), points=traj.points, u_prev=u_prev,
                          u=traj.displacement[t], u_next=traj.displacement[t + 1],
                          vm_next=traj.von_mises[t + 1], dt=dt)
    return dict(out, points=np.asarray(traj.points, np.float64))


FIELDS = (("points", (2,)), ("u", (2,)), ("v", (2,)), ("target", (3,)))


def gather(form: Formulation, trajs, table, ids: np.ndarray, *, dt: float,
           previous: bool = False) -> dict[str, np.ndarray]:
    """Host batch (K, B, ...) float32: points, u, v (N, 2) inputs, target (N, 3), ball (2,) targets.

    ``previous``: also the inputs of the frame before (u_prev_in, v_prev_in; the same frame when t = 0)
    and ``has_prev`` (K, B), for pushforward training.
    """
    K, B = ids.shape
    n = trajs[0].n_nodes
    out = {k: np.empty((K, B, n) + d, np.float32) for k, d in FIELDS}
    out["ball"] = np.empty((K, B, 2), np.float32)
    if previous:
        out.update(u_prev_in=np.empty((K, B, n, 2), np.float32), v_prev_in=np.empty((K, B, n, 2), np.float32),
                   has_prev=np.empty((K, B), np.float32))
    for a in range(K):
        for b in range(B):
            i, t = table[ids[a, b]]
            s = sample(form, trajs[i], int(t), dt)
            for k in ("points", "u", "v", "target", "ball"):
                out[k][a, b] = s[k]
            if previous:
                p = sample(form, trajs[i], int(t) - 1, dt) if t > 0 else s
                out["u_prev_in"][a, b], out["v_prev_in"][a, b] = p["u"], p["v"]
                out["has_prev"][a, b] = float(t > 0)
    return out
