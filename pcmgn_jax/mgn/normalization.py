"""Feature and target normalisation from the training split; wraps the model, not inside it.

Statistics are per-channel totals (float64 sums over every sampled node / edge / frame of the training
split), so they do not depend on the data order. A channel whose standard deviation is zero or below
``1e-8 * (|mean| + tiny)`` gets std = 1 (the "zero-variance guard"): e.g. the velocity of a dataset with
no motion in x. Stats are a pytree of float32 arrays saved with each checkpoint (and as JSON).

Layout (shapes):
    node_mean/std    [4]  world position x, y [m], world velocity x, y [m/s] (one-hot is not scaled)
    mesh_mean/std    [6]  u_ij, |u_ij|, x_ij, |x_ij| [m]
    contact_mean/std [3]  x_ij, |x_ij| [m] (real contact edges only)
    target_mean/std  [k]  model outputs in SI (e.g. velocity [m/s] x, y and von Mises [Pa])
"""
from __future__ import annotations

import json
from pathlib import Path
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

    def to_json(self) -> dict:
        return {k: np.asarray(v, np.float64).tolist() for k, v in self._asdict().items()}

    @classmethod
    def from_json(cls, data: dict) -> "Stats":
        return cls(**{k: np.asarray(data[k], np.float32) for k in cls._fields})

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_json(), indent=1))

    @classmethod
    def load(cls, path: str | Path) -> "Stats":
        return cls.from_json(json.loads(Path(path).read_text()))


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


def guard_std(mean: np.ndarray, std: np.ndarray) -> np.ndarray:
    """Zero-variance guard: std -> 1 where it is not finite or ~0 relative to |mean|."""
    ok = np.isfinite(std) & (std > 1e-8 * (np.abs(mean) + 1e-30))
    return np.where(ok, std, 1.0)


def make_stats(*, node: Accumulator, mesh: Accumulator, contact: Accumulator, target: Accumulator,
               contact_default_std: float = 1.0) -> Stats:
    nm, ns = node.result()
    mm, ms = mesh.result()
    cm, cs = contact.result(default_std=contact_default_std)
    tm, ts = target.result()
    f = lambda a: np.asarray(a, np.float32)  # noqa: E731
    return Stats(f(nm), f(ns), f(mm), f(ms), f(cm), f(cs), f(tm), f(ts))


def normalize_graph(stats: Stats, graph: jraph.GraphsTuple, n_node_types: int) -> jraph.GraphsTuple:
    """Normalised copy of a raw graph from :func:`pcmgn_jax.mgn.graphs.build_graph`."""
    nodes = graph.nodes
    onehot, phys = nodes[..., :n_node_types], nodes[..., n_node_types:]
    nodes = jnp.concatenate([onehot, (phys - stats.node_mean) / stats.node_std], axis=-1)
    edges = {}
    for key, (m, s) in {"mesh": (stats.mesh_mean, stats.mesh_std),
                        "contact": (stats.contact_mean, stats.contact_std)}.items():
        es: EdgeSet = graph.edges[key]
        feats = (es.features - m) / s
        edges[key] = es._replace(features=jnp.where(es.mask[..., None], feats, 0.0))
    return graph._replace(nodes=nodes, edges=edges)


def normalize_target(stats: Stats, target):
    return (target - stats.target_mean) / stats.target_std


def denormalize_output(stats: Stats, output):
    return output * stats.target_std + stats.target_mean
