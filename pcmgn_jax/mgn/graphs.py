"""Pure graph builder: one trajectory frame -> ``jraph.GraphsTuple`` with two edge sets.

Paper section 2.1 (Algorithm 1, Table "graph structure"):

- node features   v_i   = [one_hot(node_type), x_i^w, xdot_i^w]
- mesh edges      e^m_ij = [u_ij, |u_ij|, x^w_ij, |x^w_ij|]   (u = reference/mesh space, both directions)
- contact edges   e^c_ij = [x^w_ij, |x^w_ij|]                 (scene contact pair only, within r_w)

with ``a_ij = a_sender - a_receiver`` (messages flow sender -> receiver; the receiver aggregates).

How the two edge sets ride in the GraphsTuple (graphcast "typed graph" style, keyed by name)::

    GraphsTuple(
        nodes     = (N, n_types + 4) float32   raw (physical, SI) node features
        edges     = {"mesh":    EdgeSet(features (E, 6), senders (E,), receivers (E,), mask (E,)),
                     "contact": EdgeSet(features (C, 3), senders (C,), receivers (C,), mask (C,))},
        senders   = (E,) int32     = edges["mesh"].senders   (mirror, so jraph tools see the mesh graph)
        receivers = (E,) int32     = edges["mesh"].receivers
        n_node    = (1,) int32 [N],  n_edge = (1,) int32 [E],  globals = None)

The contact set has a fixed capacity C with a padding ``mask`` (padded slots point at node 0 and are
ignored by the model); overflow is detected in :mod:`pcmgn_jax.mgn.contact`, never truncated silently.
Features here are raw SI values; normalisation wraps the model (:mod:`pcmgn_jax.mgn.normalization`).
Many designs (any meshes) are one graph: the padded disjoint union of :mod:`pcmgn_jax.mgn.batching`
(``jraph.batch`` + ``jraph.pad_with_graphs``); :func:`build_graph` then takes its ``layout`` (per-graph
``n_node`` / ``n_edge`` and the mesh-edge padding mask). A stacked batch of one topology still vmaps.

Precision: world relative positions are formed as (X_i - X_j) + (u_i - u_j) (reference difference
plus displacement difference), so µm motion is not lost on mm coordinates in float32.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import jraph
import numpy as np
from flax import struct

from pcmgn_jax.geometry import quad_sides

MESH_EDGE_DIM = 6
CONTACT_EDGE_DIM = 3


class EdgeSet(NamedTuple):
    """One typed edge set."""

    features: jnp.ndarray   # [n_edge, d]   float32
    senders: jnp.ndarray    # [n_edge]      int32
    receivers: jnp.ndarray  # [n_edge]      int32
    mask: jnp.ndarray       # [n_edge]      bool (False = padding)


@struct.dataclass
class Topology:
    """Static, per-dataset graph topology (built once on the host; a pytree: pass it to jit).

    node_type:      [N]   int32   part id, or n_parts for fixed nodes
    n_node_types:   int           n_parts + 1 (one-hot width)
    mesh_senders:   [E]   int32   both directions of every quad side
    mesh_receivers: [E]   int32   sorted ascending (quad_edges; kept by the padded union): the model's
                                  mesh segment sum is told so (indices_are_sorted)
    fixed:          [N]   bool    node_type == n_parts: displacement held at 0
    axis:           [N]   bool    nodes on the symmetry axis x = 0: u_x held at 0
    scene_features: [N, k] float32 per-scene node inputs [SI] (Formulation.scene_features; each node
                                  carries its scene's values), or None (k = 0)
    top_nodes:      [N]   bool    the scene's contact layer (:func:`pcmgn_jax.mgn.inputs.design_topology`),
                                  or None: their highest reference point is the origin of
                                  ``Formulation.origin='contact_top'`` (taken from the points, so a
                                  morphed mesh moves it)
    hierarchy:      tuple of :class:`pcmgn_jax.mgn.hierarchy.Level`, the mesh graph's bi-stride coarse
                                  levels (``Formulation.reach='multiscale'``), or None (no levels)
    node_part:      [N]   int32   with role node types (:func:`role_types`): each node's part id (n_parts
                                  for fixed nodes), from which its per-node scene features are read; None
                                  when ``node_type`` is the part id itself (and in a batch's union)
    """

    node_type: np.ndarray
    n_node_types: int = struct.field(pytree_node=False)
    mesh_senders: np.ndarray
    mesh_receivers: np.ndarray
    fixed: np.ndarray
    axis: np.ndarray
    scene_features: np.ndarray | None = None
    top_nodes: np.ndarray | None = None
    hierarchy: tuple | None = None
    node_part: np.ndarray | None = None

    @property
    def n_node(self) -> int:
        return int(self.node_type.shape[0])


def quad_edges(cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique undirected quad sides of ``cells`` (E,4), returned in both directions, sorted.

    Only the 4 sides of each quad (no diagonals), as in Algorithm 1 ("edge pairs from C_quad").
    Returns (senders, receivers) int32 arrays of length 2 * n_unique_sides.
    """
    und = quad_sides(cells)
    senders = np.concatenate([und[:, 0], und[:, 1]])
    receivers = np.concatenate([und[:, 1], und[:, 0]])
    order = np.lexsort((senders, receivers))
    return senders[order].astype(np.int32), receivers[order].astype(np.int32)


def make_topology(*, points: np.ndarray, cells: np.ndarray, node_type: np.ndarray, n_parts: int,
                  axis_tol: float = 1e-9, scene_features=None) -> Topology:
    """Build the static topology. ``points`` (N,2) [m] reference; ``n_parts`` = ball + layers.

    Axis nodes are those with reference x <= ``axis_tol`` [m] (half model, symmetry axis x = 0).
    ``scene_features``: (N, k) rows [SI] (:func:`with_scene_features`), or None.
    """
    node_type = np.asarray(node_type, dtype=np.int32)
    if node_type.min() < 0 or node_type.max() > n_parts:
        raise ValueError(f"node_type must lie in 0..{n_parts} (n_parts = fixed), got range "
                         f"{node_type.min()}..{node_type.max()}")
    s, r = quad_edges(cells)
    points = np.asarray(points, dtype=np.float64)
    topo = Topology(node_type=node_type, n_node_types=int(n_parts) + 1, mesh_senders=s,
                    mesh_receivers=r, fixed=node_type == n_parts,
                    axis=(np.abs(points[:, 0]) <= axis_tol) & (node_type != n_parts))
    return topo if scene_features is None else with_scene_features(topo, scene_features)


ROLES = ("ball", "contact", "film", "objective", "support", "fixed")
"""Role node types (``Formulation.part_identity='role'``): the ball (part 0), the contact layer (part 1, the
top), every other layer between it and the support (a 'film'), the objective's layer (the part named 'OLED'),
the support (the bottom layer) and the fixed nodes: six types for a stack of any layer count."""


def role_types(node_part, part_names) -> np.ndarray:
    """(N,) int32 role ids (:data:`ROLES`) of nodes whose part ids are ``node_part`` (len(part_names) for
    fixed nodes; ``part_names`` indexed by part id, 0 the ball). One layer that is both the contact layer and
    the support is the contact layer."""
    n_parts = len(part_names)
    table = np.full(n_parts + 1, ROLES.index("film"), np.int32)
    table[n_parts - 1] = ROLES.index("support")
    if "OLED" in part_names:
        table[list(part_names).index("OLED")] = ROLES.index("objective")
    table[1] = ROLES.index("contact")
    table[0] = ROLES.index("ball")
    table[n_parts] = ROLES.index("fixed")
    return table[np.asarray(node_part)]


def with_scene_features(topology: Topology, rows) -> Topology:
    """``topology`` whose nodes carry the scene features ``rows`` (N, k) [SI]
    (:func:`pcmgn_jax.mgn.scene_features.scene_feature_rows`; None or k = 0: none)."""
    if rows is None or np.shape(rows)[-1] == 0:
        return topology.replace(scene_features=None)
    rows = np.asarray(rows, np.float32)
    if rows.shape != (topology.n_node, rows.shape[-1]):
        raise ValueError(f"scene features: expected ({topology.n_node}, k) rows, got {rows.shape}")
    return topology.replace(scene_features=rows.copy())


def n_parts_of(traj) -> int:
    names = traj.meta.get("part_names")
    if names is None and "scene" in traj.meta:
        names = ["ball"] + [layer["name"] for layer in traj.meta["scene"]["layers"]]
    if names is None:
        raise ValueError("trajectory meta needs 'part_names' or 'scene' to know the number of parts")
    return len(names)


def _norm(v: jnp.ndarray) -> jnp.ndarray:
    # |v| with a finite gradient at v = 0 (padded / coincident edges).
    sq = jnp.sum(v * v, axis=-1, keepdims=True)
    safe = jnp.where(sq > 0, sq, 1.0)
    return jnp.where(sq > 0, jnp.sqrt(safe), 0.0)


def node_features(topology: Topology, points, displacement, velocity, features: str = "paper",
                  extra=None, identity: str = "type", origin: str = "mesh", node_graph=None) -> jnp.ndarray:
    """(N, n_types + k) node features [m, m/s].

    ``origin``: ``mesh``, positions in the mesh's own coordinates (y from the plate's bottom);
    ``contact_top``, y measured from the contact layer's top surface (the highest reference point of the
    topology's ``top_nodes``, per graph of a union: ``node_graph`` (N,) int32 each node's graph), so a
    layer below that changes thickness does not move the nodes above it in the features;
    ``support_top``, y measured from the top of the bottom layer (the plate: the last part before the
    fixed nodes), so the plate's thickness moves nothing above it (:func:`origin_height`).

    ``identity``: ``type``, the one-hot of every node type; ``material``, only the ball's (type 0) and
    the fixed nodes' (the last type) columns are set: a layer's node is then known by its ``material``
    scene feature and its geometry, not by which layer it is (the width is the same either way); ``role``,
    the one-hot of the topology's role types (:data:`ROLES`, six whatever the layer count).

    'paper':  [one_hot(type), x^w, xdot^w]          (k = 4; x^w = X + u, the paper's Table 1)
    'strain': [one_hot(type), X, u, xdot^w]         (k = 6; reference position and displacement apart,
              so the µm displacement is not a 1e-3 fraction of a mm coordinate)

    followed by the topology's ``scene_features`` (N, k') [SI] when it has them, then ``extra`` (N, k'')
    [SI] when given (the formulation's state channels, :func:`pcmgn_jax.mgn.formulation.model_inputs`).
    """
    one_hot = jnp.eye(topology.n_node_types, dtype=jnp.float32)[jnp.asarray(topology.node_type)]
    if identity == "material":
        keep = np.zeros(topology.n_node_types, np.float32)
        keep[[0, -1]] = 1.0
        one_hot = one_hot * keep
    elif identity not in ("type", "role"):   # role: the topology's node types are already the roles
        raise ValueError(f"identity must be 'type', 'material' or 'role', got {identity!r}")
    points = jnp.asarray(points, jnp.float32)
    if origin != "mesh":
        points = points - jnp.stack([jnp.zeros_like(points[:, 0]),
                                     origin_height(topology, points, origin, node_graph)], -1)
    displacement = jnp.asarray(displacement, jnp.float32)
    velocity = jnp.asarray(velocity, jnp.float32)
    extra = ([] if topology.scene_features is None else [jnp.asarray(topology.scene_features, jnp.float32)]) \
        + ([] if extra is None else [jnp.asarray(extra, jnp.float32)])
    if features == "paper":
        return jnp.concatenate([one_hot, points + displacement, velocity] + extra, axis=-1)
    if features == "strain":
        return jnp.concatenate([one_hot, points, displacement, velocity] + extra, axis=-1)
    raise ValueError(f"features must be 'paper' or 'strain', got {features!r}")


def origin_height(topology: Topology, points, origin: str, node_graph=None) -> jnp.ndarray:
    """(N,) float32 [m]: the height the node features measure y from, per node's graph (``node_graph``
    (N,) int32 of a union, or None: one graph): the highest reference y of the contact layer (the
    topology's ``top_nodes``; ``origin='contact_top'``) or of the bottom layer (node type
    ``n_node_types - 2``; ``'support_top'``); 0 in a graph without any (the union's padding graph)."""
    if origin == "contact_top":
        if topology.top_nodes is None:
            raise ValueError("origin='contact_top' needs the topology's top_nodes (built by "
                             "pcmgn_jax.mgn.inputs.design_topology from a mesh and its scene)")
        mask = jnp.asarray(topology.top_nodes)
    elif origin == "support_top":
        mask = jnp.asarray(topology.node_type) == topology.n_node_types - 2
    else:
        raise ValueError(f"origin must be 'mesh', 'contact_top' or 'support_top', got {origin!r}")
    y = jnp.where(mask, points[:, 1], -jnp.inf)
    if node_graph is None:
        top = jnp.broadcast_to(jnp.max(y), y.shape)
    else:
        node_graph = jnp.asarray(node_graph)
        top = jax.ops.segment_max(y, node_graph, num_segments=topology.n_node)[node_graph]
    return jnp.where(jnp.isfinite(top), top, 0.0)


def mesh_edge_features(topology: Topology, points, displacement, features: str = "paper") -> jnp.ndarray:
    """(E, 6) mesh-edge features, ij = sender - receiver.

    'paper':  [u_ij, |u_ij|, x_ij, |x_ij|] [m]  (u_ij reference, x_ij = u_ij + (u_s - u_r) world)
    'strain': [u_ij / L, L, (u_s - u_r) / L, (|x_ij| - L) / L] with L = |u_ij| [m]: direction, length,
              relative displacement and stretch (dimensionless, ~1e-4..1e-2), the deformation on its own
              scale. The stretch is formed as (2 u_ij.d + |d|^2) / (L (|x_ij| + L)), free of cancellation.
    """
    return edge_features(topology.mesh_senders, topology.mesh_receivers, points, displacement, features)


def edge_features(senders, receivers, points, displacement, features: str = "paper") -> jnp.ndarray:
    """(E, 6) :func:`mesh_edge_features` of the edges (senders, receivers) (node numbers of ``points``):
    the mesh's, or a coarse level's (:func:`level_edges`)."""
    s, r = jnp.asarray(senders), jnp.asarray(receivers)
    points = jnp.asarray(points, jnp.float32)
    displacement = jnp.asarray(displacement, jnp.float32)
    u_ij = points[s] - points[r]
    d_ij = displacement[s] - displacement[r]
    x_ij = u_ij + d_ij
    if features == "paper":
        return jnp.concatenate([u_ij, _norm(u_ij), x_ij, _norm(x_ij)], axis=-1)
    if features != "strain":
        raise ValueError(f"features must be 'paper' or 'strain', got {features!r}")
    length = _norm(u_ij)
    safe = jnp.where(length > 0, length, 1.0)  # coincident reference nodes (degenerate quads)
    stretch = (2 * jnp.sum(u_ij * d_ij, -1, keepdims=True) + jnp.sum(d_ij * d_ij, -1, keepdims=True)) \
        / (safe * (_norm(x_ij) + safe))
    return jnp.concatenate([u_ij / safe, length, d_ij / safe, stretch], axis=-1)


def contact_edge_features(points, displacement, senders, receivers, mask) -> jnp.ndarray:
    """[x_ij, |x_ij|] -> (C, 3) [m]; padded slots (mask False) are zero."""
    points = jnp.asarray(points, jnp.float32)
    displacement = jnp.asarray(displacement, jnp.float32)
    x_ij = (points[senders] - points[receivers]) + (displacement[senders] - displacement[receivers])
    feats = jnp.concatenate([x_ij, _norm(x_ij)], axis=-1)
    return jnp.where(mask[:, None], feats, 0.0)


def build_graph(topology: Topology, *, points, displacement, velocity, contact,
                features: str = "paper", layout=None, node_extra=None, identity: str = "type",
                origin: str = "mesh") -> jraph.GraphsTuple:
    """Pure graph builder (jittable, vmappable).

    points:       (N, 2) reference coordinates [m]
    displacement: (N, 2) [m]   (world position = points + displacement)
    velocity:     (N, 2) [m/s] world velocity
    contact:      a :class:`pcmgn_jax.mgn.contact.ContactEdges` (senders, receivers, mask) of capacity C
    features:     'paper' | 'strain' (see :func:`node_features`, :func:`mesh_edge_features`)
    layout:       None (one graph), or a padded disjoint union's :class:`pcmgn_jax.mgn.batching.Layout`
    node_extra:   None, or (N, k) extra node channels [SI] appended last (:func:`node_features`)
    identity:     'type' | 'material': the one-hot columns set (:func:`node_features`)
    origin:       'mesh' | 'contact_top' | 'support_top': where node heights are measured from (:func:`node_features`)
    """
    n = topology.n_node
    mesh_mask = jnp.ones(topology.mesh_senders.shape, bool) if layout is None else jnp.asarray(layout.edge_mask)
    mesh = EdgeSet(features=mesh_edge_features(topology, points, displacement, features),
                   senders=jnp.asarray(topology.mesh_senders), receivers=jnp.asarray(topology.mesh_receivers),
                   mask=mesh_mask)
    cont = EdgeSet(features=contact_edge_features(points, displacement, contact.senders,
                                                  contact.receivers, contact.mask),
                   senders=contact.senders, receivers=contact.receivers, mask=contact.mask)
    edges = {"mesh": mesh, "contact": cont}
    if topology.hierarchy is not None:
        edges.update(level_edges(topology.hierarchy, points, displacement, features))
    return jraph.GraphsTuple(
        nodes=node_features(topology, points, displacement, velocity, features, node_extra, identity, origin,
                            None if layout is None else layout.node_graph),
        edges=edges,
        senders=mesh.senders, receivers=mesh.receivers,
        n_node=jnp.array([n], jnp.int32) if layout is None else jnp.asarray(layout.n_node),
        n_edge=jnp.array([mesh.senders.shape[0]], jnp.int32) if layout is None else jnp.asarray(layout.n_edge),
        globals=None)


def level_edges(hierarchy, points, displacement, features: str = "paper") -> dict:
    """The coarse levels (:mod:`pcmgn_jax.mgn.hierarchy`) as edge sets of the graph, for l = 1..L:

    ``coarse{l}``  the level's edges (level-local numbers), features :func:`edge_features` of their
                   mesh nodes (raw SI, normalised with the mesh-edge statistics)
    ``pool{l}``    one featureless edge per level-(l-1) node: sender its number, receiver its cluster
    ``nodes{l}``   one featureless self edge per level-l node, sender = receiver = its mesh node number
    """
    out = {}
    for k, lv in enumerate(hierarchy, start=1):
        nodes, s, r = jnp.asarray(lv.nodes), jnp.asarray(lv.senders), jnp.asarray(lv.receivers)
        mask = jnp.asarray(lv.edge_mask)
        feats = edge_features(nodes[s], nodes[r], points, displacement, features)
        out[f"coarse{k}"] = EdgeSet(jnp.where(mask[:, None], feats, 0.0), s, r, mask)
        parent = jnp.asarray(lv.parent)
        prev_mask = jnp.ones(parent.shape, bool) if k == 1 else jnp.asarray(hierarchy[k - 2].node_mask)
        out[f"pool{k}"] = EdgeSet(jnp.zeros(parent.shape + (0,), jnp.float32),
                                  jnp.arange(parent.shape[0], dtype=jnp.int32), parent, prev_mask)
        out[f"nodes{k}"] = EdgeSet(jnp.zeros(nodes.shape + (0,), jnp.float32), nodes, nodes,
                                   jnp.asarray(lv.node_mask))
    return out
