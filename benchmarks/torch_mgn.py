"""Plain-PyTorch reference of pcmgn_jax.mgn.model.EncodeProcessDecode (for benchmarks only).

Same architecture, written the way a PyTorch/PyG MeshGraphNet author writes it:

- MLP: (Linear(L) + ReLU) x mlp_layers, Linear(out), LayerNorm(out, eps=1e-6) (none on the decoder).
- Encoders: node MLP and one MLP per edge set ("mesh", "contact").
- Processor: ``steps`` blocks, separate edge MLP per edge set, messages masked (padded contact slots),
  sum aggregation with ``index_add_`` at the receivers, node MLP on [v, agg_mesh, agg_contact],
  residuals on nodes and edges, no weight sharing between blocks.
- Edge MLP first layer: ``concat_trick=False`` (default, what MeshGraphNets/PyG code does):
  Linear(3L -> L) on torch.cat([v[s], v[r], e]); ``concat_trick=True``: W_s v and W_r v per node, gathered,
  plus W_e e (what pcmgn_jax.mgn.model does). Both are benchmarked; the faster one is the reference.

Inputs are plain tensors (a dict), so the model can be torch.compile-d.
"""
from __future__ import annotations

from typing import Sequence

import torch
from torch import nn

EDGE_SETS = ("mesh", "contact")


def mlp(d_in: int, latent: int, d_out: int, layers: int = 2, layer_norm: bool = True) -> nn.Sequential:
    mods: list[nn.Module] = []
    d = d_in
    for _ in range(layers):
        mods += [nn.Linear(d, latent), nn.ReLU()]
        d = latent
    mods.append(nn.Linear(d, d_out))
    if layer_norm:
        mods.append(nn.LayerNorm(d_out, eps=1e-6))
    return nn.Sequential(*mods)


class EdgeBlock(nn.Module):
    def __init__(self, latent: int, layers: int, concat_trick: bool):
        super().__init__()
        self.concat_trick = concat_trick
        if concat_trick:
            self.sender_proj = nn.Linear(latent, latent, bias=False)
            self.receiver_proj = nn.Linear(latent, latent, bias=False)
            self.edge_proj = nn.Linear(latent, latent)
            self.rest = mlp(latent, latent, latent, layers - 1)
            # mlp(...) with layers-1 hidden layers applied after the first (already projected) layer
            self.rest = nn.Sequential(nn.ReLU(), *list(self.rest))
        else:
            self.net = mlp(3 * latent, latent, latent, layers)

    def forward(self, v, e, senders, receivers):
        if self.concat_trick:
            x = self.edge_proj(e) + self.sender_proj(v)[senders] + self.receiver_proj(v)[receivers]
            return self.rest(x)
        return self.net(torch.cat([v[senders], v[receivers], e], dim=-1))


class TorchMGN(nn.Module):
    def __init__(self, node_dim: int, edge_dims: dict[str, int], *, latent: int = 128, mlp_layers: int = 2,
                 steps: int = 15, out: int = 3, edge_sets: Sequence[str] = EDGE_SETS,
                 concat_trick: bool = False):
        super().__init__()
        L, H = latent, mlp_layers
        self.edge_sets = tuple(edge_sets)
        self.node_encoder = mlp(node_dim, L, L, H)
        self.edge_encoders = nn.ModuleDict({k: mlp(edge_dims[k], L, L, H) for k in self.edge_sets})
        self.edge_fns = nn.ModuleList(
            [nn.ModuleDict({k: EdgeBlock(L, H, concat_trick) for k in self.edge_sets}) for _ in range(steps)])
        self.node_fns = nn.ModuleList([mlp(L * (1 + len(self.edge_sets)), L, L, H) for _ in range(steps)])
        self.decoder = mlp(L, L, out, H, layer_norm=False)

    def forward(self, g: dict[str, torch.Tensor]) -> torch.Tensor:
        v = self.node_encoder(g["nodes"])
        n = v.shape[0]
        e = {k: self.edge_encoders[k](g[f"{k}_features"]) for k in self.edge_sets}
        for edge_fn, node_fn in zip(self.edge_fns, self.node_fns):
            aggs = []
            new_e = {}
            for k in self.edge_sets:
                upd = edge_fn[k](v, e[k], g[f"{k}_senders"], g[f"{k}_receivers"])
                msg = upd * g[f"{k}_maskf"]
                aggs.append(torch.zeros(n, upd.shape[1], dtype=upd.dtype).index_add_(0, g[f"{k}_receivers"], msg))
                new_e[k] = e[k] + upd
            v = v + node_fn(torch.cat([v] + aggs, dim=-1))
            e = new_e
        return self.decoder(v)


def torch_graph(g: dict) -> dict[str, torch.Tensor]:
    """Benchmark graph (numpy dict from pcmgn_jax.eval.bench.bench_graph) -> tensors."""
    out = {"nodes": torch.from_numpy(g["nodes"])}
    for k in EDGE_SETS:
        out[f"{k}_features"] = torch.from_numpy(g[f"{k}_features"])
        out[f"{k}_senders"] = torch.from_numpy(g[f"{k}_senders"].astype("int64"))
        out[f"{k}_receivers"] = torch.from_numpy(g[f"{k}_receivers"].astype("int64"))
        mask = g.get(f"{k}_mask")
        m = torch.ones(g[f"{k}_senders"].shape[0]) if mask is None else torch.from_numpy(mask.astype("float32"))
        out[f"{k}_maskf"] = m[:, None].contiguous()
    return out


def make_train_step(model: nn.Module, lr: float = 1e-3, forward=None):
    """Adam + MSE train step (forward, backward, optimizer step); returns step(g, target) -> loss."""
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    fwd = model if forward is None else forward

    def step(g, target):
        opt.zero_grad(set_to_none=True)
        loss = torch.mean((fwd(g) - target) ** 2)
        loss.backward()
        opt.step()
        return loss
    return step
