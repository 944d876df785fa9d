"""The MeshGraphNet's building blocks (paper section 2.2), shared by the processors
(:mod:`pcmgn_jax.mgn.model`, :mod:`pcmgn_jax.mgn.multiscale`, :mod:`pcmgn_jax.mgn.attention`)."""
from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp


class MLP(nn.Module):
    """``hidden_layers`` x Dense(latent)+ReLU, Dense(out), optional LayerNorm."""

    latent_size: int
    output_size: int
    hidden_layers: int = 2
    layer_norm: bool = True

    @nn.compact
    def __call__(self, x):
        for _ in range(self.hidden_layers):
            x = nn.relu(nn.Dense(self.latent_size)(x))
        x = nn.Dense(self.output_size)(x)
        return nn.LayerNorm()(x) if self.layer_norm else x


class EdgeFunction(nn.Module):
    """Edge update MLP on [v_sender, v_receiver, e] with the concat trick in the first layer."""

    latent_size: int
    hidden_layers: int = 2

    @nn.compact
    def __call__(self, nodes, edges, senders, receivers):
        if self.hidden_layers < 1:
            raise ValueError(f"hidden_layers must be >= 1 for the concat trick, got {self.hidden_layers}")
        proj_s = nn.Dense(self.latent_size, use_bias=False, name="sender_proj")(nodes)
        proj_r = nn.Dense(self.latent_size, use_bias=False, name="receiver_proj")(nodes)
        x = nn.Dense(self.latent_size, name="edge_proj")(edges) + proj_s[senders] + proj_r[receivers]
        x = nn.relu(x)
        for _ in range(self.hidden_layers - 1):
            x = nn.relu(nn.Dense(self.latent_size)(x))
        x = nn.Dense(self.latent_size)(x)
        return nn.LayerNorm()(x)


def aggregate(upd, mask, receivers, n: int, *, sorted_receivers: bool = False):
    """Sum at the receivers of the edge updates ``upd`` (E, L), padded edges (mask False) left out: (n, L)."""
    msg = jnp.where(mask[:, None], upd, 0.0)
    return jax.ops.segment_sum(msg, receivers, num_segments=n, indices_are_sorted=sorted_receivers)
