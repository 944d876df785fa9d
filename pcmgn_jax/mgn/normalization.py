"""Feature and target normalisation: statistics from the training split, wrapping the model.

Statistics are per channel *and per node type* (rows: node types, the last one the fixed nodes), so a
formulation can normalise each part on its own scale (``per_part``) or all parts on one scale
(``global``, the paper: every row then holds the same all-node statistics). Node channels that are
one number per part (a part's own material) use the all-node statistics in every row either way. Mesh-edge statistics
are indexed by the edge's receiver type; contact edges have one row (they join two parts). A multi-scale
graph's coarse-level edges (:func:`pcmgn_jax.mgn.graphs.level_edges`) are normalised with the mesh-edge
statistics of their receiver's mesh node (a coarse edge spans ~2^l mesh edges: its length channel reads
O(2^l), which its level's own encoder takes in).

Layout (T = node types, shapes of the float32 arrays)::

    node_mean/std     [T, Cn]  physical node channels (after the one-hot), see graphs.node_features
    mesh_mean/std     [T, Cm]  mesh-edge channels, by receiver type
    contact_mean/std  [Cc]     contact-edge channels (real contact edges only)
    target_mean/std   [T, 3]   per-node targets [a_x, a_y, von Mises (its log: stress_target)] in SI
    ball_mean/std     [2]      the rigid ball's target (unused unless the formulation has a rigid ball)

Sums are float64 (shifted by the first batch's mean for a stable variance), so the statistics do not
depend on the data order. Zero-variance guard: a channel whose std is not finite or below
``1e-8 * (|mean| + tiny)`` gets std = 1 (e.g. the x-velocity of nodes that never move in x). A node type
with no samples in a channel set takes the all-node statistics. The statistics are saved once, inside
each checkpoint (:mod:`pcmgn_jax.mgn.checkpoint`).
"""
from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import jraph
import numpy as np

from pcmgn_jax.mgn.graphs import EdgeSet


class Stats(NamedTuple):
    node_mean: jnp.ndarray
    node_std: jnp.ndarray
    mesh_mean: jnp.ndarray
    mesh_std: jnp.ndarray
    contact_mean: jnp.ndarray
    contact_std: jnp.ndarray
    target_mean: jnp.ndarray
    target_std: jnp.ndarray
    ball_mean: jnp.ndarray
    ball_std: jnp.ndarray

    def to_json(self) -> dict:
        return {k: np.asarray(v, np.float64).tolist() for k, v in self._asdict().items()}

    @classmethod
    def from_json(cls, data: dict) -> "Stats":
        return cls(**{k: np.asarray(data[k], np.float32) for k in cls._fields})


def guard_std(mean: np.ndarray, std: np.ndarray) -> np.ndarray:
    """Zero-variance guard: std -> 1 where it is not finite or ~0 relative to |mean|."""
    ok = np.isfinite(std) & (std > 1e-8 * (np.abs(mean) + 1e-30))
    return np.where(ok, std, 1.0)


class Accumulator:
    """Float64 per-channel sums for mean/std over any number of (..., C) batches."""

    def __init__(self, channels: int):
        self.n = 0
        self.s = np.zeros(channels, np.float64)
        self.ss = np.zeros(channels, np.float64)
        self.shift = None  # first batch mean, for a numerically stable variance

    def add(self, x, mask=None) -> None:
        x = np.asarray(x, np.float64).reshape(-1, self.s.shape[0])
        if mask is not None:
            x = x[np.asarray(mask).reshape(-1)]
        if x.shape[0] == 0:
            return
        if self.shift is None:
            self.shift = x.mean(0)
        d = x - self.shift
        self.n += x.shape[0]
        self.s += d.sum(0)
        self.ss += (d * d).sum(0)

    def result(self, default_std=1.0) -> tuple[np.ndarray, np.ndarray]:
        if self.n == 0:
            return np.zeros_like(self.s), np.full_like(self.s, default_std)
        m = self.s / self.n
        var = np.maximum(self.ss / self.n - m * m, 0.0)
        mean = self.shift + m
        return mean, guard_std(mean, np.sqrt(var))


class TypedAccumulator:
    """One :class:`Accumulator` per node type plus one over all samples."""

    def __init__(self, n_types: int, channels: int):
        self.all = Accumulator(channels)
        self.per = [Accumulator(channels) for _ in range(n_types)]

    def add(self, x, types, mask=None) -> None:
        x = np.asarray(x, np.float64)
        types = np.asarray(types)
        keep = np.ones(types.shape, bool) if mask is None else np.asarray(mask, bool)
        self.all.add(x, keep)
        for k, acc in enumerate(self.per):
            acc.add(x, keep & (types == k))

    def result(self, per_part: bool, across=()) -> tuple[np.ndarray, np.ndarray]:
        """(mean, std) of shape [T, C]: per type (types without samples: all-node values) or global;
        the channels ``across`` (indices) take the all-node values in every row either way."""
        gm, gs = self.all.result()
        rows = [(a.result() if (per_part and a.n) else (gm, gs)) for a in self.per]
        mean, std = np.stack([r[0] for r in rows]), np.stack([r[1] for r in rows])
        across = list(across)
        mean[:, across], std[:, across] = gm[across], gs[across]
        return mean, std


def make_stats(*, node: TypedAccumulator, mesh: TypedAccumulator, contact: Accumulator,
               motion: TypedAccumulator, stress: TypedAccumulator, ball: Accumulator, per_part: bool,
               contact_default_std: float = 1.0, node_across=()) -> Stats:
    """Stats from accumulators; the per-node target rows join the motion (a_x, a_y) and stress channels.
    ``node_across``: node channels normalised over all nodes even when ``per_part`` (a part's own
    material, :func:`pcmgn_jax.mgn.scene_features.across_part_channels`)."""
    f = lambda a: np.asarray(a, np.float32)  # noqa: E731
    nm, ns = node.result(per_part, node_across)
    mm, ms = mesh.result(per_part)
    cm, cs = contact.result(default_std=contact_default_std)
    (am, as_), (sm, ss) = motion.result(per_part), stress.result(per_part)
    tm, ts = np.concatenate([am, sm], axis=1), np.concatenate([as_, ss], axis=1)
    bm, bs = ball.result()
    return Stats(f(nm), f(ns), f(mm), f(ms), f(cm), f(cs), f(tm), f(ts), f(bm), f(bs))


def normalize_graph(stats: Stats, graph: jraph.GraphsTuple, node_type) -> jraph.GraphsTuple:
    """Normalised copy of a raw graph from :func:`pcmgn_jax.mgn.graphs.build_graph`.

    ``node_type`` (N,) int: the row of the statistics for each node (mesh edges use the receiver's).
    """
    node_type = jnp.asarray(node_type)
    stats = Stats(*(jnp.asarray(a) for a in stats))  # NumPy statistics index with traced types too
    k = stats.node_mean.shape[-1]
    nodes = graph.nodes
    onehot, phys = nodes[..., :-k], nodes[..., -k:]
    nodes = jnp.concatenate([onehot, normalize_last_node_channels(stats, node_type, phys)], axis=-1)
    mesh: EdgeSet = graph.edges["mesh"]
    rt = node_type[mesh.receivers]
    mesh = mesh._replace(features=(mesh.features - stats.mesh_mean[rt]) / stats.mesh_std[rt])
    cont: EdgeSet = graph.edges["contact"]
    feats = (cont.features - stats.contact_mean) / stats.contact_std
    cont = cont._replace(features=jnp.where(cont.mask[..., None], feats, 0.0))
    edges = {**graph.edges, "mesh": mesh, "contact": cont}
    for key, es in graph.edges.items():  # coarse levels (graphs.level_edges): the mesh-edge statistics
        if key.startswith("coarse"):
            rt = node_type[graph.edges["nodes" + key[len("coarse"):]].senders[es.receivers]]
            feats = (es.features - stats.mesh_mean[rt]) / stats.mesh_std[rt]
            edges[key] = es._replace(features=jnp.where(es.mask[:, None], feats, 0.0))
    return graph._replace(nodes=nodes, edges=edges)


def normalize_last_node_channels(stats: Stats, node_type, x):
    """Physical node channels ``x`` (N, j) -> normalised with the statistics' last j node channels (each
    node's type row): all of them in :func:`normalize_graph`, or only the formulation's trailing state
    channels (a ``per_design`` rollout normalises the ball state per frame without rebuilding the graph)."""
    j = x.shape[-1]
    if j == 0:
        return x
    node_type = jnp.asarray(node_type)
    mean, std = jnp.asarray(stats.node_mean)[:, -j:], jnp.asarray(stats.node_std)[:, -j:]
    return (x - mean[node_type]) / std[node_type]


def normalize_target(stats: Stats, node_type, target):
    """(N, 3) physical per-node target -> normalised, with each node's type row."""
    node_type = jnp.asarray(node_type)
    return (target - jnp.asarray(stats.target_mean)[node_type]) / jnp.asarray(stats.target_std)[node_type]


def denormalize_output(stats: Stats, node_type, output):
    """(N, >=3) normalised model output -> physical [a_x, a_y, von Mises] (N, 3)."""
    node_type = jnp.asarray(node_type)
    return output[:, :3] * jnp.asarray(stats.target_std)[node_type] + jnp.asarray(stats.target_mean)[node_type]
