"""Contact edges between the scene's contact pair (ball <-> cover glass), jax-md style.

``allocate`` (host, NumPy) finds the candidate nodes once from the reference mesh -- ball surface
nodes facing down x cover-glass top-surface nodes -- and sizes a fixed-capacity edge buffer from the
frames it is shown. ``update`` (jittable) recomputes the edges from current positions:

    index = allocate(points=..., cells=..., cell_part=..., ball_part=0, panel_part=1,
                     radius=r_w, positions=[(T, N, 2) world frames, ...])
    edges = update(index, positions)      # ContactEdges(senders, receivers, mask, count, overflow)

Edges are within ``radius`` [m] (Euclidean, world space), both directions (ball -> CG and CG -> ball),
never self-loops or mesh edges. When more pairs are in range than the buffer holds, ``overflow`` is
True and ``count`` the number needed; callers must re-allocate (``grow``) outside jit and redo the
computation -- the dropped edges are never silently ignored.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from pcmgn_jax import geometry


@struct.dataclass
class ContactIndex:
    """Contact candidates (arrays) and buffer size (static); a pytree, pass it to jit.

    ball_nodes:  [Nb]      int32  ball surface nodes whose outward normal points down
    panel_nodes: [Np]      int32  contact-layer (CG) top-surface nodes
    allowed:     [Nb, Np]  bool   False for mesh edges / identical nodes
    radius:      float            contact radius r_w [m]
    capacity:    int              directed-edge buffer size C (even)
    """

    ball_nodes: np.ndarray
    panel_nodes: np.ndarray
    allowed: np.ndarray
    radius: float = struct.field(pytree_node=False)
    capacity: int = struct.field(pytree_node=False)


class ContactEdges(NamedTuple):
    senders: jnp.ndarray    # [C] int32 (padding: 0)
    receivers: jnp.ndarray  # [C] int32 (padding: 0)
    mask: jnp.ndarray       # [C] bool
    count: jnp.ndarray      # []  int32 number of directed edges in range (may exceed C)
    overflow: jnp.ndarray   # []  bool  count > C


def surface_nodes(points: np.ndarray, cells: np.ndarray, cell_part: np.ndarray, part: int,
                  *, facing: str) -> np.ndarray:
    """Nodes of ``part`` on boundary sides whose outward normal points ``facing`` ('up'|'down'),
    within 60 degrees of vertical (:func:`pcmgn_jax.geometry.surface_nodes`)."""
    return geometry.surface_nodes(points, cells, cell_part, part, facing=facing, min_normal_y=0.5)


def count_pairs(index_nodes: tuple[np.ndarray, np.ndarray, np.ndarray], positions: np.ndarray,
                radius: float) -> np.ndarray:
    """Host-side number of directed contact edges in each frame of ``positions`` (T, N, 2)."""
    ball, panel, allowed = index_nodes
    positions = np.asarray(positions, np.float64)
    out = np.empty(positions.shape[0], np.int64)
    for t in range(positions.shape[0]):
        d = positions[t, ball][:, None, :] - positions[t, panel][None, :, :]
        out[t] = 2 * int(np.sum((np.einsum("ijk,ijk->ij", d, d) <= radius * radius) & allowed))
    return out


def allocate(*, points: np.ndarray, cells: np.ndarray, cell_part: np.ndarray, ball_part: int = 0,
             panel_part: int = 1, radius: float, positions=(), capacity_factor: float = 2.0,
             min_capacity: int = 64, capacity: int | None = None) -> ContactIndex:
    """Host-side: candidates from the reference mesh and a buffer sized from ``positions``.

    points/cells/cell_part: reference mesh (SI). radius: r_w [m].
    positions: iterable of world-position arrays (T, N, 2) [m] (e.g. every training trajectory);
      capacity = max(min_capacity, ceil(capacity_factor * max pairs seen)), rounded up to a multiple
      of 16, or ``capacity`` if given. Never larger than all candidate pairs (2 * Nb * Np).
    """
    if not (isinstance(radius, (int, float)) and math.isfinite(radius) and radius > 0):
        raise ValueError(f"contact radius must be a finite number > 0 [m], got {radius!r}")
    ball = surface_nodes(points, cells, cell_part, ball_part, facing="down")
    panel = surface_nodes(points, cells, cell_part, panel_part, facing="up")
    allowed = ball[:, None] != panel[None, :]
    cells = np.asarray(cells)
    a, b = cells.reshape(-1), np.roll(cells, -1, axis=1).reshape(-1)
    mesh_pairs = set(zip(a.tolist(), b.tolist())) | set(zip(b.tolist(), a.tolist()))
    pos_b = {int(n): i for i, n in enumerate(ball)}
    pos_p = {int(n): j for j, n in enumerate(panel)}
    for s, r in mesh_pairs:
        if s in pos_b and r in pos_p:
            allowed[pos_b[s], pos_p[r]] = False
    full = 2 * int(allowed.sum())
    if capacity is None:
        seen = 0
        for frames in positions:
            frames = np.asarray(frames)
            if frames.ndim == 2:
                frames = frames[None]
            seen = max(seen, int(count_pairs((ball, panel, allowed), frames, radius).max()))
        capacity = max(int(min_capacity), int(math.ceil(capacity_factor * seen)))
        capacity = int(16 * math.ceil(capacity / 16))
    capacity = max(2, min(int(capacity), max(full, 2)))
    capacity += capacity % 2
    return ContactIndex(ball_nodes=ball, panel_nodes=panel, allowed=allowed, radius=float(radius),
                        capacity=int(capacity))


def full_capacity(index: ContactIndex) -> int:
    """All directed candidate pairs of one graph (of the largest graph for a per-graph index), >= 2."""
    allowed = np.asarray(index.allowed)
    per_graph = allowed.reshape((-1,) + allowed.shape[-2:]).sum(axis=(1, 2))
    return max(2 * int(per_graph.max(initial=0)), 2)


def grow(index: ContactIndex, needed: int, factor: float = 1.5) -> ContactIndex:
    """A larger buffer holding at least ``needed`` directed edges (host-side, after an overflow).
    For a per-graph index (:func:`stack`) the capacity and ``needed`` are per graph."""
    cap = min(full_capacity(index), max(index.capacity * 2, int(16 * math.ceil(factor * needed / 16))))
    cap += cap % 2
    return index.replace(capacity=int(cap))


def update(index: ContactIndex, positions: jnp.ndarray) -> ContactEdges:
    """Jittable: contact edges for world ``positions`` (N, 2) [m]; static shapes (capacity C).

    Edges come in pairs: slot 2k is ball -> panel, slot 2k+1 the reverse, in row-major candidate
    order, so the selection is deterministic.
    """
    ball = jnp.asarray(index.ball_nodes)
    panel = jnp.asarray(index.panel_nodes)
    d = positions[ball][:, None, :] - positions[panel][None, :, :]
    within = (jnp.sum(d * d, axis=-1) <= index.radius ** 2) & jnp.asarray(index.allowed)
    flat = within.reshape(-1)
    n_pairs = index.capacity // 2
    (idx,) = jnp.nonzero(flat, size=n_pairs, fill_value=0)
    count = jnp.sum(flat, dtype=jnp.int32)
    valid = jnp.arange(n_pairs) < count
    bi, pj = idx // panel.shape[0], idx % panel.shape[0]
    bn = jnp.where(valid, ball[bi], 0)
    pn = jnp.where(valid, panel[pj], 0)
    senders = jnp.stack([bn, pn], axis=1).reshape(-1).astype(jnp.int32)
    receivers = jnp.stack([pn, bn], axis=1).reshape(-1).astype(jnp.int32)
    mask = jnp.repeat(valid, 2)
    return ContactEdges(senders=senders, receivers=receivers, mask=mask, count=2 * count,
                        overflow=2 * count > index.capacity)


def empty_edges(capacity: int) -> ContactEdges:
    z = jnp.zeros((capacity,), jnp.int32)
    return ContactEdges(senders=z, receivers=z, mask=jnp.zeros((capacity,), bool),
                        count=jnp.zeros((), jnp.int32), overflow=jnp.zeros((), bool))


def stack(indices, offsets, *, n_slots: int, n_ball: int, n_panel: int, capacity: int) -> ContactIndex:
    """Host-side: one per-graph index for a disjoint union of graphs (see :mod:`pcmgn_jax.mgn.batching`).

    indices: one :class:`ContactIndex` per graph, all of the same radius; offsets: each graph's first
    node in the union. Returns ball_nodes [n_slots, n_ball], panel_nodes [n_slots, n_panel] (union node
    numbers), allowed [n_slots, n_ball, n_panel] (False on padding, and for the slots past the graphs)
    and ``capacity`` directed edges per graph. :func:`update_graphs` searches each graph on its own.
    """
    if not indices:
        raise ValueError("stack needs at least one contact index")
    radii = {float(i.radius) for i in indices}
    if len(radii) != 1:
        raise ValueError(f"graphs of one batch must share the contact radius, got {sorted(radii)} [m]")
    if len(indices) > n_slots:
        raise ValueError(f"{len(indices)} graphs do not fit {n_slots} slots")
    ball = np.zeros((n_slots, n_ball), np.int32)
    panel = np.zeros((n_slots, n_panel), np.int32)
    allowed = np.zeros((n_slots, n_ball, n_panel), bool)
    for g, (index, off) in enumerate(zip(indices, offsets)):
        nb, npn = len(index.ball_nodes), len(index.panel_nodes)
        if nb > n_ball or npn > n_panel:
            raise ValueError(f"graph {g}: {nb} x {npn} contact candidates exceed the {n_ball} x {n_panel} bucket")
        ball[g, :nb] = np.asarray(index.ball_nodes) + off
        panel[g, :npn] = np.asarray(index.panel_nodes) + off
        allowed[g, :nb, :npn] = np.asarray(index.allowed)
    return ContactIndex(ball_nodes=ball, panel_nodes=panel, allowed=allowed, radius=radii.pop(),
                        capacity=int(capacity))


def update_graphs(index: ContactIndex, positions: jnp.ndarray) -> ContactEdges:
    """Jittable: :func:`update` on each graph of a per-graph index (:func:`stack`) over the union's world
    ``positions`` (N, 2) [m]. Edges [G * C] graph-major (each graph's edges in :func:`update`'s order);
    ``count`` and ``overflow`` [G] per graph."""
    edges = jax.vmap(update, in_axes=(0, None))(index, positions)
    flat = lambda a: a.reshape(-1)  # noqa: E731
    return edges._replace(senders=flat(edges.senders), receivers=flat(edges.receivers), mask=flat(edges.mask))


def contact_parts(scene) -> tuple[int, int]:
    """(ball part, contact layer part) of the scene's declared contact pair (a :class:`Scene`)."""
    if not scene.contact_pairs:
        raise ValueError("scene declares no contact pair; contact edges need one (ball, layer)")
    return 0, scene.part_names.index(scene.contact_pairs[0][1])


def auto_radius(points, cells, cell_part, panel_part: int) -> float:
    """Default r_w [m]: 1.5 x the median spacing of the contact layer's top-surface nodes near the axis."""
    nodes = surface_nodes(points, cells, cell_part, panel_part, facing="up")
    xs = np.sort(np.asarray(points)[nodes, 0])
    d = np.diff(xs)[:20]
    return float(1.5 * np.median(d[d > 0]))
