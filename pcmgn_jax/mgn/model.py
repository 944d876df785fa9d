"""Flax (linen) encode-process-decode MeshGraphNet, paper section 2.2.

- Every MLP: ``mlp_layers`` hidden layers of ``latent_size`` with ReLU, then a linear output layer of
  ``latent_size``, then LayerNorm (paper: 2 x 128, LayerNorm). The decoder has no LayerNorm.
- Encoders: one node MLP, one MLP per edge set ("mesh", "contact").
- Processor: ``message_passing_steps`` blocks (paper: 15), each with a separate edge function per edge
  set, sum aggregation at the receivers (padded contact edges masked out), a node function on
  [v_i, sum_mesh, sum_contact], and residuals on nodes and edges. Parameters are not shared between
  steps.
- Aggregation is ``jax.ops.segment_sum``; for the edge sets in ``sorted_receivers`` (default: "mesh")
  it is told the receivers are sorted ascending (``indices_are_sorted=True``), which
  :func:`pcmgn_jax.mgn.graphs.quad_edges` and the disjoint union of :mod:`pcmgn_jax.mgn.batching`
  guarantee (tests/mgn/test_graphs.py). Contact edges come in slot order, not sorted: plain sum. XLA:CPU
  gives the same code either way (benchmarks/README.md §1); accelerators use it for sorted scatters.
- The first layer of each processor edge MLP uses the concat trick: W [v_s, v_r, e] =
  W_s v_s + W_r v_r + W_e e; W_s v and W_r v are computed once per node and gathered by senders /
  receivers instead of projecting the concatenated (E, 3L) matrix.

- ``reach`` (docs/design.md §5.3): ``local``, the processor above; ``multiscale`` / ``attention``, a
  global block (:class:`pcmgn_jax.mgn.multiscale.VCycle` over the graph's bi-stride coarse levels /
  :class:`pcmgn_jax.mgn.attention.PhysicsAttention` over learned slices) after every ``GLOBAL_EVERY``-th
  message-passing step and after the last (:func:`global_block_steps`), its output added to the node
  latents; the mesh and contact edge latents pass the blocks unchanged. ``local`` builds exactly the
  paper's modules (the same parameters, the same outputs).
- ``decoder_condition`` = k > 0 (formulation ``processor='per_design'``): the last k node channels (the
  ball's state) bypass the encoder and the processor and enter the decoder, whose first layer is
  W_v v + W_c c + b. The processor's latents and W_v v + b (:meth:`EncodeProcessDecode.decoder_base`)
  depend on the design only; a rollout computes them once and per frame only
  :meth:`EncodeProcessDecode.decode_from_base` (``model.apply(params, base, cond, method=...)``).
  ``model.apply(params, graph)`` is the same network in one call (training).

The model reads *normalised* graphs (see :mod:`pcmgn_jax.mgn.normalization`) and returns normalised
per-node outputs (N, output_size). Use it as a pure function: ``model.apply(params, graph)``.
"""
from __future__ import annotations

from typing import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp
import jraph

from pcmgn_jax.mgn.attention import PhysicsAttention, node_graph_of
from pcmgn_jax.mgn.layers import MLP, EdgeFunction
from pcmgn_jax.mgn.multiscale import VCycle, level_count

EDGE_SETS = ("mesh", "contact")
GLOBAL_EVERY = 4  # reach != 'local': a global block after every 4th message-passing step and after the last


def global_block_steps(steps: int) -> tuple[int, ...]:
    """The message-passing steps (1-based) after which a global block runs: every ``GLOBAL_EVERY``-th
    and the last (so the decoder always reads latents that saw the whole graph)."""
    return tuple(i for i in range(1, steps + 1) if i % GLOBAL_EVERY == 0 or i == steps)


class ConditionedDecoder(nn.Module):
    """The decoder MLP on [v, c] with its first layer split: ``base(v)`` = W_v v + b (computed once per
    design), ``finish(base, c)`` = the rest (relu(base + W_c c), hidden layers, linear output)."""

    latent_size: int
    output_size: int
    hidden_layers: int = 2

    def setup(self):
        self.first = nn.Dense(self.latent_size, name="latent_proj")
        self.cond = nn.Dense(self.latent_size, use_bias=False, name="condition_proj")
        self.hidden = [nn.Dense(self.latent_size) for _ in range(self.hidden_layers - 1)]
        self.out = nn.Dense(self.output_size)

    def base(self, v):
        return self.first(v)

    def finish(self, base, c):
        x = nn.relu(base + self.cond(c))
        for layer in self.hidden:
            x = nn.relu(layer(x))
        return self.out(x)


class EncodeProcessDecode(nn.Module):
    """MeshGraphNet. ``output_size``: per-node outputs (default 3: velocity x, y and von Mises)."""

    output_size: int = 3
    latent_size: int = 128
    mlp_layers: int = 2
    message_passing_steps: int = 15
    edge_sets: Sequence[str] = EDGE_SETS
    sorted_receivers: Sequence[str] = ("mesh",)
    decoder_condition: int = 0  # last node channels handed to the decoder, not the encoder (module docstring)
    reach: str = "local"        # local | multiscale | attention: the global blocks (module docstring)
    reach_levels: int = 4       # multiscale: coarse levels of each V-cycle
    reach_slices: int = 32      # attention: learned slices
    reach_heads: int = 4        # attention: heads

    def setup(self):
        if self.latent_size < 1 or self.message_passing_steps < 0 or self.mlp_layers < 1:
            raise ValueError(
                f"bad model sizes: latent_size={self.latent_size}, mlp_layers={self.mlp_layers}, "
                f"message_passing_steps={self.message_passing_steps}")
        L, H = self.latent_size, self.mlp_layers
        self.node_encoder = MLP(L, L, H, name="node_encoder")
        self.edge_encoders = {k: MLP(L, L, H, name=f"{k}_edge_encoder") for k in self.edge_sets}
        self.edge_fns = [{k: EdgeFunction(L, H, name=f"step{i}_{k}_edge") for k in self.edge_sets}
                         for i in range(self.message_passing_steps)]
        self.node_fns = [MLP(L, L, H, name=f"step{i}_node") for i in range(self.message_passing_steps)]
        after = global_block_steps(self.message_passing_steps)
        if self.reach == "multiscale":
            self.level_encoders = {str(lv): MLP(L, L, H, name=f"coarse{lv}_edge_encoder")
                                   for lv in range(1, self.reach_levels + 1)}
            self.global_blocks = [VCycle(L, self.reach_levels, H, name=f"vcycle{i}") for i in after]
        elif self.reach == "attention":
            self.global_blocks = [PhysicsAttention(L, self.reach_slices, self.reach_heads, H, name=f"attention{i}")
                                  for i in after]
        elif self.reach != "local":
            raise ValueError(f"reach must be 'local', 'multiscale' or 'attention', got {self.reach!r}")
        if self.reach != "local" and self.message_passing_steps < 1:
            raise ValueError(f"reach={self.reach!r} needs message_passing_steps >= 1 (its blocks follow them)")
        if self.decoder_condition:
            self.decoder = ConditionedDecoder(L, self.output_size, H, name="decoder")
        else:
            self.decoder = MLP(L, self.output_size, H, layer_norm=False, name="decoder")

    def __call__(self, graph: jraph.GraphsTuple) -> jnp.ndarray:
        if self.decoder_condition:
            return self.decode_from_base(self.decoder_base(graph), graph.nodes[:, -self.decoder_condition:])
        return self.decoder(self.latents(graph))

    def latents(self, graph: jraph.GraphsTuple) -> jnp.ndarray:
        """(N, latent) node latents after the processor (the decoder's condition channels excluded)."""
        n = graph.nodes.shape[0]
        nodes = graph.nodes[:, :-self.decoder_condition] if self.decoder_condition else graph.nodes
        v = self.node_encoder(nodes)
        e = {k: self.edge_encoders[k](graph.edges[k].features) for k in self.edge_sets}
        block = self._global_block(graph, n)
        after = global_block_steps(self.message_passing_steps)
        for i in range(self.message_passing_steps):
            v, e = self._process_step(i, v, e, graph, n)
            if block is not None and i + 1 in after:
                v = block(after.index(i + 1), v)
        return v

    def _global_block(self, graph, n):
        """``block(j, v) -> v``: the j-th global block of ``reach`` on this graph, or None (local)."""
        if self.reach == "multiscale":
            level_count(graph, self.reach_levels)
            coarse = {lv: self.level_encoders[str(lv)](graph.edges[f"coarse{lv}"].features)
                      for lv in range(1, self.reach_levels + 1)}
            return lambda j, v: self.global_blocks[j](v, graph, coarse)
        if self.reach == "attention":
            node_graph = node_graph_of(graph.n_node, n)
            return lambda j, v: self.global_blocks[j](v, node_graph, graph.n_node.shape[0])
        return None

    def decoder_base(self, graph: jraph.GraphsTuple) -> jnp.ndarray:
        """(N, latent) the conditioned decoder's design-only part, W_v latents + b."""
        return self.decoder.base(self.latents(graph))

    def decode_from_base(self, base, cond) -> jnp.ndarray:
        """(N, output_size) outputs from :meth:`decoder_base` and the condition channels (N, k) (normalised)."""
        return self.decoder.finish(base, cond)

    def _process_step(self, i, v, e, graph, n):
        new_e, aggregated = {}, []
        for k in self.edge_sets:
            es = graph.edges[k]
            upd = self.edge_fns[i][k](v, e[k], es.senders, es.receivers)
            msg = jnp.where(es.mask[:, None], upd, 0.0)
            aggregated.append(jax.ops.segment_sum(msg, es.receivers, num_segments=n,
                                                  indices_are_sorted=k in self.sorted_receivers))
            new_e[k] = e[k] + upd
        v = v + self.node_fns[i](jnp.concatenate([v] + aggregated, axis=-1))
        return v, new_e
