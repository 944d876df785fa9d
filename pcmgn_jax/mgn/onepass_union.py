"""The one-pass model's batches: designs of any meshes as one padded disjoint union of static size.

    sizes = union_sizes(designs, slots=4)          # one static size for every union of <= 4 of these designs
    u = make_union(designs, sizes)                 # Union: GraphBatch + initial state (u0, v0) + real-slot mask
    arrays = node_array(u, [y_0, y_1, ...])        # per-design node arrays (N_b, ...) -> the union's (N, ...)
    out = forward(form, model, params, stats, u)   # (N, 3) normalised outputs over the union
    per_design = split(u, out)                     # back to one (N_b, 3) array per design, padding dropped

Each design's graph is built on its own mesh (:func:`pcmgn_jax.mgn.onepass.design_inputs`: a scene family's or a
stack family's designs each have their own node count and topology; the paper's box designs share one) and the
designs of a batch are joined by :func:`pcmgn_jax.mgn.batching.batch_graphs` (``jraph.batch`` +
``jraph.pad_with_graphs``; padding nodes typed fixed and masked, never ``jraph.zero_out_padding``). The sizes come
from :func:`pcmgn_jax.mgn.batching.slot_minimums` over every design the union may hold (``slots`` x the largest
design's nodes and edges, every design's contact candidates, the largest contact buffer), so any draw of up to
``slots`` of them has one shape: a jitted step or prediction compiles once, never again after warm-up.

The input graph is the rollout MGN's (:func:`pcmgn_jax.mgn.rollout.input_graph` with the union's ``layout``: the
contact search per graph slot, the origin of the positions per graph, e.g. ``contact_top`` of the stack presets),
normalised per node type (:func:`pcmgn_jax.mgn.normalization.normalize_graph`); padding nodes carry zero targets
and zero loss weights, padding graph slots are left out of the objective term by ``real``.
"""
from __future__ import annotations

from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from pcmgn_jax.mgn import batching
from pcmgn_jax.mgn.formulation import Formulation
from pcmgn_jax.mgn.normalization import Stats, denormalize_output, normalize_graph, normalize_target
from pcmgn_jax.mgn.rollout import input_graph


class Sizes(NamedTuple):
    """The static size of a union (:func:`union_sizes`): arguments of :func:`pcmgn_jax.mgn.batching.batch_graphs`."""

    slots: int
    nodes: int
    edges: int
    levels: tuple
    ball: int
    panel: int
    capacity: int


class Union(NamedTuple):
    """A padded union of designs and their initial state (a pytree: pass it to jit)."""

    graph: batching.GraphBatch   # topology, layout, per-graph contact index, reference points [m]
    u0: np.ndarray               # (N, 2) [m] initial displacement (0 on padding)
    v0: np.ndarray               # (N, 2) [m/s] initial velocity (0 on padding)
    real: np.ndarray             # (G,) float32 1 on the graph slots holding a design, 0 on padding slots


def union_sizes(designs: Sequence[dict], slots: int) -> Sizes:
    """One size for every union of at most ``slots`` of ``designs`` (:func:`pcmgn_jax.mgn.onepass.design_inputs`
    dicts, any meshes; they must share the contact radius)."""
    if not designs:
        raise ValueError("one-pass union: no designs")
    topos = [d["topology"] for d in designs]
    widths = sorted({t.n_node_types for t in topos})
    if len(widths) != 1:
        raise ValueError(f"one-pass union: the designs have {widths} node types; designs of different parts batch "
                         "together only with part_identity='role' (the stack presets', read from the manifest)")
    m = batching.slot_minimums(topos, slots)
    idx = [d["index"] for d in designs]
    return Sizes(slots=m["min_slots"], nodes=m["min_nodes"], edges=m["min_edges"], levels=m["min_levels"],
                 ball=batching.bucket_size(max(len(i.ball_nodes) for i in idx), 8),
                 panel=batching.bucket_size(max(len(i.panel_nodes) for i in idx), 8),
                 capacity=batching.bucket_size(max(int(i.capacity) for i in idx), 16))


def make_union(designs: Sequence[dict], sizes: Sizes) -> Union:
    """Host side: the padded union of ``designs`` (at most ``sizes.slots``) with their initial state."""
    if len(designs) > sizes.slots:
        raise ValueError(f"one-pass union: {len(designs)} designs do not fit {sizes.slots} slots")
    gb = batching.batch_graphs([d["topology"] for d in designs], [d["index"] for d in designs],
                               [d["points"] for d in designs], min_nodes=sizes.nodes, min_edges=sizes.edges,
                               min_slots=sizes.slots, min_capacity=sizes.capacity, min_ball=sizes.ball,
                               min_panel=sizes.panel, min_levels=sizes.levels)
    real = (np.arange(gb.layout.n_node.shape[0]) < len(designs)).astype(np.float32)
    return Union(gb, batching.to_union(gb, [d["u0"] for d in designs]),
                 batching.to_union(gb, [d["v0"] for d in designs]), real)


def node_array(u: Union, arrays: Sequence[np.ndarray]) -> np.ndarray:
    """Per-design node arrays (N_b, ...) -> the union's (N, ...) float32, zero on padding nodes."""
    return batching.to_union(u.graph, arrays)


def split(u: Union, array) -> list[np.ndarray]:
    """A union node array (N, ...) -> one array per design (its own node count), padding dropped."""
    return batching.split(u.graph, array)


def chunks(n: int, size: int) -> list[range]:
    """``range(n)`` in consecutive pieces of at most ``size``."""
    return [range(i, min(i + size, n)) for i in range(0, n, size)]


def raw_graph(form: Formulation, u: Union):
    """The raw (SI) input graph of the union at its initial state (padding nodes and edges masked)."""
    g = u.graph
    return input_graph(form, g.topology, g.index, g.points, u.u0, u.v0, g.layout)[0]


def normalized_graph(form: Formulation, stats: Stats, u: Union):
    """The normalised input graph of the union at its initial state: what the network reads."""
    return normalize_graph(stats, raw_graph(form, u), u.graph.topology.node_type)


def init_params(form: Formulation, model, stats: Stats, u: Union, seed: int):
    """The network's initial parameters (jitted: the input graph and ``model.init`` compile together)."""
    return jax.jit(lambda key, x: model.init(key, normalized_graph(form, stats, x)))(jax.random.PRNGKey(seed), u)


def forward(form: Formulation, model, params, stats: Stats, u: Union):
    """Normalised outputs (N, 3) of the union's input graph at its initial state."""
    return model.apply(params, normalized_graph(form, stats, u))


def physical(stats: Stats, u: Union, out):
    """(N, 3) normalised outputs -> physical [Pa, Pa, m] with each node's part row."""
    return denormalize_output(stats, u.graph.topology.node_type, out)


def loss_fn(params, form: Formulation, model, stats: Stats, u: Union, targets, weights, obj_weights, lambda_obj):
    """The step's loss (:mod:`pcmgn_jax.mgn.onepass`): ``targets`` (N, 3) physical, ``weights`` (N,) per node (each
    design's sum 1), ``obj_weights`` (N,) each design's ``area_mean`` section weights (sum 1 per design), all zero
    on padding. Data term: sum_i w_i |e_i|^2 / 3 per design, the objective term the squared relative error of each
    design's section mean of the time-mean field; both averaged over the real designs. Returns
    (loss, (data term, objective term))."""
    out = forward(form, model, params, stats, u)
    node_type = u.graph.topology.node_type
    n_real = jnp.maximum(jnp.sum(u.real), 1.0)
    tn = normalize_target(stats, node_type, targets)
    data = jnp.sum(weights[:, None] * (out[:, :3] - tn) ** 2) / 3.0 / n_real
    node_graph, n_graph = u.graph.layout.segments
    section = lambda f: jax.ops.segment_sum(f * obj_weights, node_graph, num_segments=n_graph)  # noqa: E731
    pred, truth = section(physical(stats, u, out)[:, 0]), section(targets[:, 0])
    rel = (pred - truth) / jnp.maximum(jnp.abs(truth), 1e-12)
    obj = jnp.sum(u.real * rel ** 2) / n_real
    return data + lambda_obj * obj, (data, obj)
