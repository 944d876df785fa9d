"""Many graphs as one: the disjoint union (``jraph.batch``), padded to static size buckets.

Designs whose meshes differ (node count, topology) roll out together as one graph: node numbers of
graph g are offset by the nodes of graphs 0..g-1, and the union is padded with ``jraph.pad_with_graphs``
to a few static sizes (:func:`bucket_size`), so a jitted rollout compiles once per bucket, not once per
mesh or batch size. Layout of a :class:`GraphBatch` (G graph slots, N nodes, E mesh edges, all bucketed)::

    topology  Topology over the union: node_type [N] (padding nodes typed fixed, so held at 0),
              mesh_senders/receivers [E] (padding edges join the first padding node to itself),
              fixed [N] (True on padding), axis [N]
    layout    Layout: n_node [G], n_edge [G] (jraph: real graphs first, then one graph holding the
              padding nodes and edges, then empty graphs), node_graph [N] (graph slot of each node),
              node_mask [N], edge_mask [E] (False on padding: jraph.get_node/edge_padding_mask)
              hierarchy: the coarse levels of a multi-scale model, or None (pcmgn_jax.mgn.hierarchy)
    index     per-graph ContactIndex (contact.stack): candidates [G-1, Nb] x [G-1, Np], capacity per
              graph; each graph's contact search sees only its own nodes
    points    [N, 2] reference coordinates [m] (0 on padding)
    n_designs []  int32 number of real graphs (read on the host only)

Every per-graph quantity is segment-wise over ``layout.node_graph``: the rigid ball's pooled output and
mean motion (:func:`pcmgn_jax.mgn.rollout.ball_output`, :func:`pcmgn_jax.mgn.formulation.rigid_mean`);
the contact search runs per graph slot (:func:`pcmgn_jax.mgn.contact.update_graphs`); normalisation is
per node / edge. Padding nodes have no contact candidates and no edges to real nodes, so they never
contribute (``jraph.zero_out_padding`` is not used: it calls the removed ``jax.tree_map``; padding is
typed fixed and masked instead). Why a union and not ``vmap`` over a stacked batch: see
``benchmarks/README.md`` (rollout throughput).
"""
from __future__ import annotations

import math
from typing import Sequence

import jraph
import numpy as np
from flax import struct

from pcmgn_jax.mgn import contact as contact_lib
from pcmgn_jax.mgn.graphs import Topology
from pcmgn_jax.mgn.hierarchy import level_sizes, union_levels

BUCKET_STEPS = tuple(range(8, 16))  # sizes m * 2^k, m in 8..15: 8 sizes per octave, < 12.5 % padding
MIN_NODES, MIN_EDGES = 64, 256      # the smallest union (nodes, mesh edges) batch_graphs pads to


def bucket_size(n: int, minimum: int = 16) -> int:
    """The smallest static size >= max(n, minimum) of the form m * 2^k with m in 8..15 (even for >= 16)."""
    n = max(int(n), int(minimum), 8)
    k = max(0, int(math.floor(math.log2(n))) - 3)
    while True:
        for m in BUCKET_STEPS:
            if m << k >= n:
                return m << k
        k += 1


def design_slots(n_designs: int) -> int:
    """Graph slots for real designs: the next power of two (1, 2, 4, 8, ...)."""
    if n_designs < 1:
        raise ValueError(f"a batch needs at least one design, got {n_designs}")
    return 1 << (int(n_designs) - 1).bit_length()


def slot_minimums(topologies: Sequence[Topology], slots: int) -> dict:
    """:func:`batch_graphs` minimums that size a union by its graph ``slots`` and its largest design, not by
    how many designs fill it: nodes ``slots`` x the most nodes of one of ``topologies`` (plus the padding
    node), mesh edges and every coarse level's likewise. A union of k <= ``slots`` designs of these meshes
    then has one shape whatever k is (a GA's population after its cached designs are dropped, a ragged last
    batch), so a rollout compiles once per slot count (a power of two), not once per design count."""
    slots = design_slots(slots)
    most_nodes = max(t.n_node for t in topologies)
    most_edges = max(len(t.mesh_senders) for t in topologies)
    levels = ()
    if topologies[0].hierarchy is not None:
        most = np.max([level_sizes(t.hierarchy) for t in topologies], axis=0)  # (levels, 2)
        levels = tuple((slots * int(n) + 1, slots * int(e)) for n, e in most)
    return dict(min_nodes=max(MIN_NODES, slots * most_nodes + 1), min_edges=max(MIN_EDGES, slots * most_edges),
                min_slots=slots, min_levels=levels)


@struct.dataclass
class Layout:
    """How the padded union splits into graphs (see the module docstring)."""

    n_node: np.ndarray      # [G] int32
    n_edge: np.ndarray      # [G] int32
    node_graph: np.ndarray  # [N] int32
    node_mask: np.ndarray   # [N] bool
    edge_mask: np.ndarray   # [E] bool

    @property
    def segments(self):
        """``(node_graph, n_graph)`` for segment-wise (per-graph) reductions; n_graph is static."""
        return self.node_graph, self.n_node.shape[0]


@struct.dataclass
class GraphBatch:
    """A padded disjoint union of design graphs (a pytree: pass it to jit)."""

    topology: Topology
    layout: Layout
    index: contact_lib.ContactIndex
    points: np.ndarray      # [N, 2] m
    n_designs: np.ndarray   # [] int32

    @property
    def n_node(self) -> np.ndarray:
        """Nodes of each real design (host-side)."""
        return np.asarray(self.layout.n_node)[:int(self.n_designs)]

    def bucket(self) -> tuple:
        """The static shape key of this batch (equal keys share one compilation)."""
        return (self.points.shape[0], self.topology.mesh_senders.shape[0], self.layout.n_node.shape[0],
                self.index.allowed.shape, self.index.capacity, self.topology.n_node_types,
                tuple((lv.n_node, lv.senders.shape[0]) for lv in self.topology.hierarchy or ()))


def batch_graphs(topologies: Sequence[Topology], indices: Sequence[contact_lib.ContactIndex],
                 points: Sequence[np.ndarray], *, min_nodes: int = MIN_NODES, min_edges: int = MIN_EDGES,
                 min_slots: int = 1, min_capacity: int = 16, min_ball: int = 8, min_panel: int = 8,
                 min_levels: Sequence[tuple[int, int]] = ()) -> GraphBatch:
    """Host-side: the padded union of designs (their topology, contact index, reference points [m]).

    Sizes are bucketed: nodes (plus one padding node), mesh edges, contact candidates and capacity by
    :func:`bucket_size`; graph slots by :func:`design_slots` (at least ``min_slots``) plus one padding
    graph. ``min_capacity``: contact edges per graph at least (e.g. a buffer grown by an earlier batch);
    ``min_ball`` / ``min_panel``: contact candidates per graph at least (a fixed training bucket).
    Coarse levels (the topologies' ``hierarchy``, all of one depth or none): each level's nodes (plus
    one padding node) and edges bucketed like the mesh's, at least ``min_levels`` (nodes, edges) per level
    (:func:`pcmgn_jax.mgn.hierarchy.union_levels`).
    Designs must share the node types (the model's one-hot width), the contact radius and whether they
    carry scene features (the topology's ``scene_features``, concatenated like the other node arrays).
    """
    if not (len(topologies) == len(indices) == len(points)) or not topologies:
        raise ValueError(f"need one topology, contact index and points array per design, got "
                         f"{len(topologies)}, {len(indices)}, {len(points)}")
    widths = {t.n_node_types for t in topologies}
    if len(widths) != 1:
        raise ValueError(f"designs of one batch must share the node types, got n_node_types {sorted(widths)}")
    widths_sf = {None if t.scene_features is None else np.shape(t.scene_features)[1] for t in topologies}
    if len(widths_sf) != 1:
        raise ValueError(f"designs of one batch must carry the same scene features, got widths {widths_sf}")
    if len({None if t.hierarchy is None else len(t.hierarchy) for t in topologies}) != 1:
        raise ValueError("designs of one batch must carry the same number of coarse levels (topology.hierarchy), "
                         f"got {sorted({0 if t.hierarchy is None else len(t.hierarchy) for t in topologies})}")
    if len({t.top_nodes is None for t in topologies}) != 1:
        raise ValueError("designs of one batch must all mark their contact layer's top_nodes, or none")
    graphs = []
    for t, p in zip(topologies, points):
        p = np.asarray(p, np.float32)
        if p.shape != (t.n_node, 2):
            raise ValueError(f"points {p.shape} do not match a topology of {t.n_node} nodes")
        nodes = dict(node_type=np.asarray(t.node_type, np.int32), fixed=np.asarray(t.fixed, bool),
                     axis=np.asarray(t.axis, bool), points=p)
        if t.scene_features is not None:
            nodes["scene_features"] = np.asarray(t.scene_features, np.float32)
        if t.top_nodes is not None:
            nodes["top_nodes"] = np.asarray(t.top_nodes, bool)
        e = len(t.mesh_senders)
        graphs.append(jraph.GraphsTuple(nodes=nodes, edges=np.zeros((e, 0), np.float32),
                                        senders=np.asarray(t.mesh_senders, np.int32),
                                        receivers=np.asarray(t.mesh_receivers, np.int32),
                                        n_node=np.array([t.n_node], np.int32), n_edge=np.array([e], np.int32),
                                        globals=None))
    union = jraph.batch(graphs)
    n_real = len(graphs)
    slots = max(design_slots(n_real), design_slots(min_slots))
    padded = jraph.pad_with_graphs(union, n_node=bucket_size(int(union.n_node.sum()) + 1, min_nodes),
                                   n_edge=bucket_size(int(union.n_edge.sum()), min_edges), n_graph=slots + 1)
    node_mask = np.asarray(jraph.get_node_padding_mask(padded))
    edge_mask = np.asarray(jraph.get_edge_padding_mask(padded))
    n_node = np.asarray(padded.n_node, np.int32)
    nodes = padded.nodes
    n_types = widths.pop()
    topology = Topology(node_type=np.where(node_mask, nodes["node_type"], n_types - 1).astype(np.int32),
                        n_node_types=n_types, mesh_senders=np.asarray(padded.senders, np.int32),
                        mesh_receivers=np.asarray(padded.receivers, np.int32),
                        fixed=nodes["fixed"] | ~node_mask, axis=nodes["axis"] & node_mask,
                        scene_features=nodes.get("scene_features"), top_nodes=nodes.get("top_nodes"),
                        hierarchy=_union_hierarchy(topologies, node_mask.shape[0], min_levels))
    layout = Layout(n_node=n_node, n_edge=np.asarray(padded.n_edge, np.int32),
                    node_graph=np.repeat(np.arange(len(n_node), dtype=np.int32), n_node),
                    node_mask=node_mask, edge_mask=edge_mask)
    offsets = np.concatenate([[0], np.cumsum(n_node)[:-1]])
    index = contact_lib.stack(
        indices, offsets[:n_real], n_slots=slots,
        n_ball=bucket_size(max(len(i.ball_nodes) for i in indices), min_ball),
        n_panel=bucket_size(max(len(i.panel_nodes) for i in indices), min_panel),
        capacity=bucket_size(max(max(i.capacity for i in indices), min_capacity), 16))
    return GraphBatch(topology=topology, layout=layout, index=index, points=nodes["points"],
                      n_designs=np.asarray(n_real, np.int32))


def _union_hierarchy(topologies: Sequence[Topology], n_fine: int, min_levels) -> tuple | None:
    """The union's coarse levels, bucketed (see :func:`batch_graphs`), or None."""
    if topologies[0].hierarchy is None:
        return None
    real = np.sum([level_sizes(t.hierarchy) for t in topologies], axis=0)  # (levels, 2)
    mins = list(min_levels) + [(0, 0)] * (len(real) - len(min_levels))
    sizes = [(bucket_size(int(n) + 1, max(m[0], 16)), bucket_size(int(e), max(m[1], 16)))
             for (n, e), m in zip(real, mins)]
    return union_levels([t.hierarchy for t in topologies], [t.n_node for t in topologies], n_fine, sizes)


def to_union(batch: GraphBatch, arrays: Sequence[np.ndarray]) -> np.ndarray:
    """Per-design node arrays (N_g, ...) -> one union array (N, ...), zero on padding nodes."""
    sizes = batch.n_node
    if len(arrays) != len(sizes):
        raise ValueError(f"{len(arrays)} arrays for a batch of {len(sizes)} designs")
    for g, (a, n) in enumerate(zip(arrays, sizes)):
        if np.shape(a)[0] != n:
            raise ValueError(f"design {g}: array of {np.shape(a)[0]} nodes, its mesh has {n}")
    cat = np.concatenate([np.asarray(a, np.float32) for a in arrays])
    out = np.zeros((batch.points.shape[0],) + cat.shape[1:], np.float32)
    out[:len(cat)] = cat
    return out


def split(batch: GraphBatch, array, axis: int = 0) -> list[np.ndarray]:
    """A union array with its node axis at ``axis`` -> one array per real design (padding dropped)."""
    array = np.asarray(array)
    bounds = np.cumsum(batch.n_node)
    return np.split(np.take(array, np.arange(bounds[-1]), axis=axis), bounds[:-1], axis=axis)


def split_graphs(batch: GraphBatch, array, axis: int = 0) -> list[np.ndarray]:
    """A per-graph-slot array (graph axis at ``axis``) -> one array per real design."""
    array = np.asarray(array)
    return [np.take(array, g, axis=axis) for g in range(int(batch.n_designs))]
