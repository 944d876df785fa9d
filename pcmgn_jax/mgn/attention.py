"""Physics attention over learned slices (Transolver, Wu et al., ICML 2024), one global block of the
processor (``Formulation.reach='attention'``; :class:`pcmgn_jax.mgn.model.EncodeProcessDecode` places it
after every 4th message-passing step and the last).

With node latents v_i (N, L) of graph g (the segment ``node_graph``), M slices and H heads:

    x_i   = LayerNorm(v_i)
    w_im  = softmax_m( (W_s x_i + b_s)_m / tau )            soft assignment of node i to slice m (tau > 0 learned)
    z_gm  = sum_{i in g} w_im (W_x x_i) / (sum_{i in g} w_im + eps)      slice tokens, per graph
    z'_g  = z_g + MultiHead(z_g)                             self-attention among the M tokens of graph g
    v_i  <- v_i + W_o sum_m w_im z'_{g(i) m}                 broadcast back by the same weights
    v_i  <- v_i + MLP(v_i)                                   (the per-node MLP with LayerNorm, model.MLP)

O(N M L + G M^2 L). The sums run per graph of a disjoint union (``jax.ops.segment_sum``), so graphs of a
batch never attend to each other; the padding nodes form a graph of their own (jraph's padding graph),
so they never reach a real node. No node order enters anywhere: permuting the nodes permutes the
outputs.
"""
from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp

from pcmgn_jax.mgn.layers import MLP

TOKEN_EPS = 1e-5  # guards the token mean of a graph without nodes (empty padding slots)


def node_graph_of(n_node, n_total: int):
    """(N,) int32 graph number of every node of a union with per-graph node counts ``n_node`` (G,)
    (real graphs, then padding: jraph's layout); ``n_total`` = N, static."""
    n_node = jnp.asarray(n_node)
    return jnp.repeat(jnp.arange(n_node.shape[0], dtype=jnp.int32), n_node, total_repeat_length=n_total)


class PhysicsAttention(nn.Module):
    """One physics-attention block on node latents (N, L) (module docstring)."""

    latent_size: int
    slices: int = 32
    heads: int = 4
    mlp_layers: int = 2

    @nn.compact
    def __call__(self, v, node_graph, n_graph: int):
        L, M, H = self.latent_size, self.slices, self.heads
        if L % H:
            raise ValueError(f"attention: reach_heads={H} must divide latent_size={L}")
        x = nn.LayerNorm(name="norm")(v)
        log_tau = self.param("log_temperature", lambda _: jnp.log(jnp.asarray(0.5, jnp.float32)))
        w = jax.nn.softmax(nn.Dense(M, name="slice_logits")(x) / jnp.exp(log_tau), axis=-1)   # (N, M)
        feats = nn.Dense(L, name="slice_values")(x)                                              # (N, L)
        num = jax.ops.segment_sum(w[:, :, None] * feats[:, None, :], node_graph, num_segments=n_graph)
        den = jax.ops.segment_sum(w, node_graph, num_segments=n_graph)
        z = num / (den[..., None] + TOKEN_EPS)                                                   # (G, M, L)
        split = lambda a: a.reshape(a.shape[0], M, H, L // H)  # noqa: E731
        q, k, val = (split(nn.Dense(L, name=n)(z)) for n in ("query", "key", "value"))
        att = jax.nn.softmax(jnp.einsum("gmhd,gnhd->ghmn", q, k) / jnp.sqrt(L // H), axis=-1)
        z = z + nn.Dense(L, name="heads_out")(jnp.einsum("ghmn,gnhd->gmhd", att, val).reshape(z.shape))
        back = jnp.einsum("nm,nml->nl", w, z[node_graph])
        v = v + nn.Dense(L, name="out")(back)
        return v + MLP(L, L, self.mlp_layers, name="mlp")(v)
