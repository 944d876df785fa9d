"""Bi-stride coarse levels of a mesh graph (BSMS-GNN, Cao et al., ICML 2023), host side (NumPy, SciPy).

The multi-scale processor (:mod:`pcmgn_jax.mgn.multiscale`, ``Formulation.reach='multiscale'``) passes
messages on coarse graphs built from the mesh graph itself, no hand-made coarse mesh. Level 0 is the
mesh graph (its nodes, its undirected quad sides); level l + 1 is built from level l by the rule:

- **bi-stride**: in every connected component (the ball and the panel are separate), a breadth-first
  search from its lowest-numbered node; the nodes at even BFS depth are kept (about every other node);
- **coarse edges**: two kept nodes are joined when they are within 2 hops on level l (A + A^2 restricted
  to the kept nodes, both directions, no self loops); every kept node at depth 2k >= 2 is 2 hops from its
  BFS grandparent (depth 2k - 2), so every level of a connected component stays connected;
- **clusters** (pooling, unpooling): a kept node is its own cluster; an odd-depth node joins the kept
  node one hop up its BFS tree (its lowest-numbered neighbour of depth d - 1), so every node of level l
  belongs to exactly one cluster of level l + 1, one hop away.

A :class:`Level` holds level l (l >= 1) as static-shape integer arrays, like the mesh edges: its nodes'
mesh-node numbers, each level-(l-1) node's cluster, its edges (level-local numbers, receivers sorted)
and padding masks. It depends only on the topology: computed once per mesh
(:func:`pcmgn_jax.mgn.inputs.design_topology` ``levels``), carried in
:attr:`pcmgn_jax.mgn.graphs.Topology.hierarchy`, concatenated with offsets and padded in a disjoint union
(:func:`union_levels`): padding nodes of level l - 1 pool into a padding node of level l, padding edges
join that node to itself and are masked, so padding never reaches a real node.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
import scipy.sparse as sp
from flax import struct
from scipy.sparse import csgraph


@struct.dataclass
class Level:
    """One coarse level of a mesh graph (see the module docstring); all int32 / bool NumPy arrays.

    nodes:     [N_l]      mesh-node number of each level-l node (padding: a padding mesh node)
    node_mask: [N_l]      False on padding
    parent:    [N_{l-1}]  level-l number of each level-(l-1) node's cluster (level 0 = the mesh nodes)
    senders:   [E_l]      level-l numbers, both directions of every coarse edge
    receivers: [E_l]      sorted ascending
    edge_mask: [E_l]      False on padding
    """

    nodes: np.ndarray
    node_mask: np.ndarray
    parent: np.ndarray
    senders: np.ndarray
    receivers: np.ndarray
    edge_mask: np.ndarray

    @property
    def n_node(self) -> int:
        return int(self.nodes.shape[0])


def adjacency(senders, receivers, n: int) -> sp.csr_matrix:
    """(n, n) 0/1 CSR adjacency of a graph given by directed edges (both directions expected)."""
    a = sp.csr_matrix((np.ones(len(senders), np.int8), (np.asarray(receivers), np.asarray(senders))), shape=(n, n))
    a.data[:] = 1
    return a


def bfs_depth(adj: sp.csr_matrix) -> np.ndarray:
    """(n,) int BFS depth of every node from its connected component's lowest-numbered node."""
    n_comp, labels = csgraph.connected_components(adj, directed=False)
    seeds = np.array([np.flatnonzero(labels == c)[0] for c in range(n_comp)])
    dist = csgraph.shortest_path(adj, unweighted=True, indices=seeds, directed=False).reshape(len(seeds), -1)
    return dist[labels, np.arange(adj.shape[0])].astype(np.int64)


def coarsen(adj: sp.csr_matrix):
    """One bi-stride step of a level's adjacency: (kept (n_c,) level numbers of the kept nodes,
    parent (n,) the cluster of every node as a kept-node number, coarse adjacency (n_c, n_c))."""
    depth = bfs_depth(adj)
    keep = depth % 2 == 0
    kept = np.flatnonzero(keep)
    number = np.full(adj.shape[0], -1, np.int64)
    number[kept] = np.arange(len(kept))
    parent = number.copy()
    coo = adj.tocoo()  # rows receive from cols
    up = (depth[coo.col] == depth[coo.row] - 1) & ~keep[coo.row]
    best = np.full(adj.shape[0], np.iinfo(np.int64).max)
    np.minimum.at(best, coo.row[up], coo.col[up])
    odd = ~keep
    parent[odd] = number[best[odd]]
    two = (adj + adj @ adj).tocsr()[kept][:, kept].tolil()
    two.setdiag(0)
    coarse = two.tocsr()
    coarse.eliminate_zeros()
    coarse.data[:] = 1
    return kept, parent, coarse


def build_levels(senders, receivers, n_node: int, levels: int) -> tuple[Level, ...]:
    """The ``levels`` coarse levels of the graph with directed edges (senders, receivers) on ``n_node``
    nodes (a :class:`pcmgn_jax.mgn.graphs.Topology`'s mesh edges), unpadded (masks all True)."""
    if levels < 0:
        raise ValueError(f"levels must be >= 0, got {levels}")
    adj = adjacency(senders, receivers, n_node)
    members = np.arange(n_node)
    out = []
    for _ in range(levels):
        kept, parent, adj = coarsen(adj)
        members = members[kept]
        coo = adj.tocoo()
        order = np.lexsort((coo.col, coo.row))
        s, r = coo.col[order].astype(np.int32), coo.row[order].astype(np.int32)
        out.append(Level(nodes=members.astype(np.int32), node_mask=np.ones(len(members), bool),
                         parent=parent.astype(np.int32), senders=s, receivers=r, edge_mask=np.ones(len(s), bool)))
    return tuple(out)


def shrinking_levels(senders, receivers, n_node: int) -> int:
    """How many bi-stride levels of the graph (directed edges (senders, receivers) on ``n_node`` nodes) still
    shrink it: after them every connected part is one node, and any further level repeats the last."""
    adj, count = adjacency(senders, receivers, n_node), 0
    while True:
        kept, _, coarse = coarsen(adj)
        if len(kept) == adj.shape[0]:
            return count
        adj, count = coarse, count + 1


def level_sizes(hierarchy: Sequence[Level]) -> tuple[tuple[int, int], ...]:
    """((nodes, directed edges) of every level)."""
    return tuple((lv.n_node, int(lv.senders.shape[0])) for lv in hierarchy)


def union_levels(hierarchies: Sequence[Sequence[Level]], fine_sizes: Sequence[int], n_fine: int,
                 sizes: Sequence[tuple[int, int]]) -> tuple[Level, ...]:
    """The levels of a padded disjoint union of graphs (:func:`pcmgn_jax.mgn.batching.batch_graphs`).

    ``hierarchies``: each graph's unpadded levels (all of one depth); ``fine_sizes``: each graph's mesh
    nodes; ``n_fine``: the union's padded node count (> sum of ``fine_sizes``: its first padding node
    exists); ``sizes``: the padded (nodes, edges) of every level (each > its real nodes, >= its real
    edges). Graph g's numbers are offset by graphs 0..g-1 on every level."""
    depth = {len(h) for h in hierarchies}
    if len(depth) != 1:
        raise ValueError(f"graphs of one union must have the same number of coarse levels, got {sorted(depth)}")
    out = []
    prev_real, prev_size = int(sum(fine_sizes)), n_fine
    for k in range(depth.pop()):
        lvs = [h[k] for h in hierarchies]
        counts = [lv.n_node for lv in lvs]
        n_real, e_real = sum(counts), sum(len(lv.senders) for lv in lvs)
        n_pad, e_pad = sizes[k]
        if n_pad <= n_real or e_pad < e_real:
            raise ValueError(f"level {k + 1}: padded sizes {(n_pad, e_pad)} too small for {(n_real, e_real)} "
                             "(one padding node needed)")
        fine_off = np.concatenate([[0], np.cumsum(fine_sizes)[:-1]])
        off = np.concatenate([[0], np.cumsum(counts)[:-1]])
        nodes = np.full(n_pad, sum(fine_sizes), np.int32)  # padding: the union's first padding mesh node
        nodes[:n_real] = np.concatenate([lv.nodes + o for lv, o in zip(lvs, fine_off)])
        parent = np.full(prev_size, n_real, np.int32)      # padding pools into the first padding node
        parent[:prev_real] = np.concatenate([lv.parent + o for lv, o in zip(lvs, off)])
        s = np.full(e_pad, n_real, np.int32)
        r = np.full(e_pad, n_real, np.int32)
        s[:e_real] = np.concatenate([lv.senders + o for lv, o in zip(lvs, off)])
        r[:e_real] = np.concatenate([lv.receivers + o for lv, o in zip(lvs, off)])
        out.append(Level(nodes=nodes, node_mask=np.arange(n_pad) < n_real, parent=parent, senders=s, receivers=r,
                         edge_mask=np.arange(e_pad) < e_real))
        prev_real, prev_size = n_real, n_pad
    return tuple(out)
