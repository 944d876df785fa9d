"""The multi-scale global block (BSMS-GNN, Cao et al., ICML 2023): a V-cycle over the mesh graph's
bi-stride coarse levels (``Formulation.reach='multiscale'``; the levels: :mod:`pcmgn_jax.mgn.hierarchy`,
carried in the graph by :func:`pcmgn_jax.mgn.graphs.level_edges`).

With h^0 the mesh nodes' latents (N, L), P_l the pooling of level l-1 into level l (each node's cluster,
``pool{l}``) and MP_l one message-passing step on level l's edges (``coarse{l}``; the mesh step's edge and
node functions with residuals, its own parameters):

    down  h^l = MP_l(mean_{i in cluster} h^{l-1}_i)                    l = 1 .. L    (skip s^l = h^l)
    up    h^l = MP'_l(s^l + h^{l+1}_{P_{l+1}(.)})                       l = L-1 .. 1  (unpool: copy the cluster's)
    out   v_i = v_i + MLP([v_i, h^1_{P_1(i)}])

Edge latents of level l: an encoder MLP of its normalised edge features (once per forward pass, shared
by the V-cycles), updated by the down step and read by the up step. One V-cycle reaches sum_l 2 * 2^l
mesh hops or more (a level-l edge spans up to 2^l mesh hops), the whole ROI with 4 levels
(experiments/reach.py reports the exact reach). Padding: padding nodes pool only into padding nodes
and padding edges are masked (:func:`pcmgn_jax.mgn.hierarchy.union_levels`), so they never reach a real
node.
"""
from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp

from pcmgn_jax.mgn.layers import MLP, EdgeFunction, aggregate


def level_count(graph, levels: int) -> None:
    """Raise ValueError unless ``graph`` carries (at least) ``levels`` coarse levels."""
    if f"coarse{levels}" not in graph.edges:
        have = sum(k.startswith("coarse") for k in graph.edges)
        raise ValueError(f"reach='multiscale' needs {levels} coarse levels in the graph, it has {have}: build the "
                         "topology with pcmgn_jax.mgn.inputs.design_topology(..., levels=form.hierarchy_levels)")


def pool(h, es, n: int):
    """Mean of the level-(l-1) latents ``h`` over each cluster (``pool{l}`` edge set) -> (n, L)."""
    w = es.mask.astype(h.dtype)[:, None]
    total = jax.ops.segment_sum(h * w, es.receivers, num_segments=n)
    count = jax.ops.segment_sum(w, es.receivers, num_segments=n)
    return total / jnp.maximum(count, 1.0)


class LevelStep(nn.Module):
    """One message-passing step on a coarse level: edge update, sum at the receivers, node update."""

    latent_size: int
    mlp_layers: int = 2

    @nn.compact
    def __call__(self, h, e, es):
        L, H = self.latent_size, self.mlp_layers
        upd = EdgeFunction(L, H, name="edge")(h, e, es.senders, es.receivers)
        agg = aggregate(upd, es.mask, es.receivers, h.shape[0], sorted_receivers=True)
        return h + MLP(L, L, H, name="node")(jnp.concatenate([h, agg], axis=-1)), e + upd


class VCycle(nn.Module):
    """One V-cycle over ``levels`` coarse levels (module docstring). ``edges``: {l: encoded edge latents}."""

    latent_size: int
    levels: int
    mlp_layers: int = 2

    @nn.compact
    def __call__(self, v, graph, edges: dict):
        L, H = self.latent_size, self.mlp_layers
        h, skips, e = v, {}, dict(edges)
        for lv in range(1, self.levels + 1):
            n = graph.edges[f"nodes{lv}"].senders.shape[0]
            h = pool(h, graph.edges[f"pool{lv}"], n)
            h, e[lv] = LevelStep(L, H, name=f"down{lv}")(h, e[lv], graph.edges[f"coarse{lv}"])
            skips[lv] = h
        for lv in range(self.levels - 1, 0, -1):
            h = skips[lv] + h[graph.edges[f"pool{lv + 1}"].receivers]
            h, _ = LevelStep(L, H, name=f"up{lv}")(h, e[lv], graph.edges[f"coarse{lv}"])
        up = h[graph.edges["pool1"].receivers]
        return v + MLP(L, L, H, name="out")(jnp.concatenate([v, up], axis=-1))
