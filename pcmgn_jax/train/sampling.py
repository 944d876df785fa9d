"""Data order and host batches: which (trajectory, frame) pairs a training step sees.

Training batches are padded disjoint unions of graphs (:func:`gather_unions`): the meshes of one step
may differ. :func:`gather` stacks samples of one topology (K, B, N, ...) (benchmarks, tests).

Data order is a pure function of (seed, step): sample k = step * B + b comes from epoch k // n_pairs at
position k % n_pairs of ``permutation(default_rng([seed, epoch]))``, so ``--resume`` replays exactly what
an uninterrupted run would have seen.
"""
from __future__ import annotations

from typing import Any, NamedTuple

import jax
import numpy as np

from pcmgn_jax.mgn.batching import batch_graphs, design_slots, to_union
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
                          vm_next=traj.von_mises[t + 1], vm=traj.von_mises[t], dt=dt)
    return dict(out, points=np.asarray(traj.points, np.float64))


SAMPLE_ARRAYS = (("points", (2,)), ("u", (2,)), ("v", (2,)), ("target", (3,)))


def gather(form: Formulation, trajs, table, ids: np.ndarray, *, dt: float) -> dict[str, np.ndarray]:
    """Host batch (K, B, ...) float32: points, u, v (N, 2) inputs, target (N, 3), ball (2,) targets."""
    K, B = ids.shape
    n = trajs[0].n_nodes
    out = {k: np.empty((K, B, n) + d, np.float32) for k, d in SAMPLE_ARRAYS}
    out["ball"] = np.empty((K, B, 2), np.float32)
    for a in range(K):
        for b in range(B):
            i, t = table[ids[a, b]]
            s = sample(form, trajs[i], int(t), dt)
            for k in ("points", "u", "v", "target", "ball"):
                out[k][a, b] = s[k]
    return out


class TrainBatch(NamedTuple):
    """One padded training union (:func:`union_batch`): N union nodes (padding rows zero), G graph slots
    (the last a padding slot), Mb / Mp boundary-node budgets. :func:`gather_unions` stacks it (K, S, ...)."""

    graph: Any            # GraphBatch: union topology (+ scene features), layout, contact index, points (N, 2) [m]
    u: Any                # (N, 2) float32 input displacement [m]
    v: Any                # (N, 2) float32 input velocity [m/s]
    target: Any           # (N, 3) float32 physical target of each node [SI] (motion target, von Mises [Pa])
    ball: Any             # (G, 2) float32 each graph's rigid-ball target [SI]
    sigma: Any            # (N,) float32 input noise std [m] (0: not noised)
    w_motion: Any         # (N,) float32 loss weight of the motion channels
    w_stress: Any         # (N,) float32 loss weight of the von Mises channel
    perturbed: Any        # (N,) float32 1 on the noised (or pushed-forward) nodes
    w_ball: Any           # (G,) float32 loss weight of the rigid-ball target
    graph_id: Any         # (G,) int32 each graph's noise id (its global batch column; padding: >= 2**30)
    graph_mask: Any       # (G,) bool: a real graph (False on padding slots)
    pen_ball: Any         # (G, Mb) int32 ball boundary nodes (union node numbers) of the penetration term
    pen_ball_mask: Any    # (G, Mb) bool: a real entry of pen_ball
    pen_panel: Any        # (G, Mp) int32 cover-glass boundary nodes (union node numbers)
    pen_panel_mask: Any   # (G, Mp) bool: a real entry of pen_panel
    w_obj: Any = None      # (N,) float32 the objective's section weights (sum 1 per graph; lambda_obj > 0 only)


def _pad_rows(rows, width: int, fill=0, dtype=np.int32):
    """A list of 1-D arrays -> (len(rows), width) array and mask (False on padding)."""
    out = np.full((len(rows), width), fill, dtype)
    mask = np.zeros((len(rows), width), bool)
    for g, r in enumerate(rows):
        out[g, :len(r)] = r
        mask[g, :len(r)] = True
    return out, mask


def sample_frames(t: int, n_steps: int, frames: int) -> list[int]:
    """The ``frames`` steps a sample of step ``t`` decodes (``frames_per_sample``): t and frames-1 more,
    evenly spread over the trajectory's ``n_steps`` steps (wrapping round), a pure function of t."""
    stride = max(n_steps // frames, 1)
    return [(t + k * stride) % n_steps for k in range(frames)]


def union_batch(form: Formulation, trajs, graphs, pairs, *, dt: float, sizes, graph_ids,
                frames: int = 1) -> TrainBatch:
    """One training union: the graphs of the (trajectory, frame) ``pairs`` as a padded disjoint union of
    the static ``sizes`` (:class:`pcmgn_jax.train.setup.UnionSizes`), with everything the loss reads.

    Returns a :class:`TrainBatch`: ``graph`` (:class:`pcmgn_jax.mgn.batching.GraphBatch`: union topology with the
    scene features, layout, per-graph contact index, reference points [m]); node arrays [N] / [N, k]
    zero on padding: u, v [m, m/s] inputs, target (N, 3) [SI], sigma [m], w_motion, w_stress, perturbed;
    per-graph-slot arrays [G] (G = slots + 1; padding slots zero / False): ball (G, 2) rigid-ball target,
    w_ball, graph_id (the graph's noise id: its column in the global batch), graph_mask; penetration
    boundary nodes pen_ball (G, Mb), pen_panel (G, Mp) as union node numbers, with masks. ``frames`` > 1 (a
    per-design processor): u, v, target and ball carry a leading frame axis (F, ...), the frames of
    :func:`sample_frames` of each pair's trajectory (one graph per design, F readouts of it).
    """
    parts = [graphs[i] for i, _ in pairs]
    gb = batch_graphs([p.topology for p in parts], [p.index for p in parts], [trajs[i].points for i, _ in pairs],
                      min_nodes=sizes.nodes, min_edges=sizes.edges, min_slots=sizes.slots,
                      min_capacity=sizes.capacity, min_ball=sizes.ball, min_panel=sizes.panel, min_levels=sizes.levels)
    got = (gb.points.shape[0], gb.topology.mesh_senders.shape[0], gb.layout.n_node.shape[0] - 1,
           gb.index.capacity, tuple((lv.n_node, lv.senders.shape[0]) for lv in gb.topology.hierarchy or ()))
    if got != (sizes.nodes, sizes.edges, design_slots(sizes.slots), sizes.capacity, tuple(sizes.levels)):
        raise ValueError(f"union of trajectories {[int(i) for i, _ in pairs]} does not fit the dataset's size "
                         f"bucket {sizes} (got nodes, edges, slots, capacity {got})")
    G = gb.layout.n_node.shape[0]
    node = lambda vals: to_union(gb, vals)  # noqa: E731
    if frames > 1:
        per_frame = [[sample(form, trajs[i], f, dt) for f in sample_frames(int(t), trajs[i].n_frames - 1, frames)]
                     for i, t in pairs]
        smp = [s[0] for s in per_frame]
    else:
        smp = [sample(form, trajs[i], int(t), dt) for i, t in pairs]
    n_real = len(pairs)
    per_graph = lambda vals, dtype=np.float32: np.concatenate(  # noqa: E731
        [np.asarray(vals, dtype), np.zeros((G - n_real,) + np.shape(vals)[1:], dtype)])
    offsets = np.concatenate([[0], np.cumsum(gb.layout.n_node)[:-1]])[:n_real]
    pen_ball, pen_ball_mask = _pad_rows([p.pen_ball + o for p, o in zip(parts, offsets)] + [[]] * (G - n_real),
                                        sizes.pen_ball)
    pen_panel, pen_panel_mask = _pad_rows([p.pen_panel + o for p, o in zip(parts, offsets)] + [[]] * (G - n_real),
                                          sizes.pen_panel)
    if frames > 1:  # (F, ...) per frame of the pairs' trajectories
        state = {k: np.stack([node([s[f][k] for s in per_frame]) for f in range(frames)]) for k in ("u", "v", "target")}
        state["ball"] = np.stack([per_graph([s[f]["ball"] for s in per_frame]) for f in range(frames)])
    else:
        state = dict(u=node([s["u"] for s in smp]), v=node([s["v"] for s in smp]),
                     target=node([s["target"] for s in smp]), ball=per_graph([s["ball"] for s in smp]))
    out = dict(graph=gb, **state,
               sigma=node([p.sigma for p in parts]), w_motion=node([p.motion for p in parts]),
               w_stress=node([p.stress for p in parts]), perturbed=node([p.perturbed for p in parts]),
               w_ball=per_graph([p.ball for p in parts]),
               graph_id=np.concatenate([np.asarray(graph_ids, np.int32),
                                        (1 << 30) + np.arange(G - n_real, dtype=np.int32)]),
               graph_mask=per_graph([True] * n_real, bool),
               pen_ball=pen_ball, pen_ball_mask=pen_ball_mask, pen_panel=pen_panel, pen_panel_mask=pen_panel_mask)
    if parts[0].objective is not None:
        out["w_obj"] = node([p.objective for p in parts])
    return TrainBatch(**out)


def gather_unions(form: Formulation, trajs, graphs, table, ids: np.ndarray, *, dt: float, sizes,
                  shards: int = 1, local_shards=None, frames: int = 1):
    """Host batch of K steps: ``ids`` (K, B) global batch columns -> a pytree of (K, S_local, ...) arrays,
    one padded union (:func:`union_batch`) per step and shard; shard s holds columns
    [s B/S, (s+1) B/S) of the global batch (``local_shards``: the shards this process feeds, default all).
    Each graph's noise id is its global column, so the losses do not depend on the shard count.
    Returns a :class:`TrainBatch` of (K, S_local, ...) leaves."""
    K, B = ids.shape
    per = B // shards
    local = range(shards) if local_shards is None else local_shards
    unions = [[union_batch(form, trajs, graphs, [table[ids[k, c]] for c in range(s * per, (s + 1) * per)],
                           dt=dt, sizes=sizes, graph_ids=np.arange(s * per, (s + 1) * per),
                           frames=frames)
               for s in local] for k in range(K)]
    return jax.tree.map(lambda *xs: np.stack(xs).reshape((K, len(local)) + np.shape(xs[0])),
                        *[u for row in unions for u in row])
