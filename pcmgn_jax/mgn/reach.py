"""How far the processor sees: hop distances from the contact and the reach of each processor (host side).

The **contact node** is the contact layer's node at the first contact point: on the symmetry axis
(x = 0), the highest reference point of the layer (the cover glass). Hop distances are breadth-first
(:func:`scipy.sparse.csgraph.shortest_path`, unweighted) on the model's graph at first contact: the mesh
graph (the quad sides, :func:`pcmgn_jax.mgn.graphs.quad_edges`) plus one contact edge joining the contact
node to the ball's lowest axis node (the first contact pair; the ball's mesh is a body of its own).

A processor's **reach** is the set of nodes whose output depends on the contact node after one network
pass, found by running the processor's dependency structure on booleans (:func:`processor_reach`): a
message-passing step adds every neighbour (one hop); a multi-scale V-cycle pools "reached" into the
clusters of the coarse levels, spreads it one coarse hop per level on the way down and on the way up,
and copies it back (:mod:`pcmgn_jax.mgn.multiscale`); an attention block reaches every node of the graph
(:mod:`pcmgn_jax.mgn.attention`). The global blocks run where the model runs them
(:func:`pcmgn_jax.mgn.model.global_block_steps`). Without a global block the reach after k steps is
exactly the nodes within k hops. A formulation that carries the panel's state from frame to frame
(``panel_model='dynamic'``) reaches one pass further per frame; a quasi-static panel (the default) is a
map of the ball's state, so one pass is all it sees.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.sparse import csgraph

from pcmgn_jax import markdown
from pcmgn_jax.mgn.graphs import quad_edges
from pcmgn_jax.mgn.hierarchy import Level, adjacency, build_levels
from pcmgn_jax.mgn.model import global_block_steps

AXIS_TOL = 1e-9  # [m] a node with reference |x| <= this lies on the symmetry axis


def contact_node(points, node_type, panel_part: int, ball_part: int = 0) -> tuple[int, int]:
    """(the contact layer's highest axis node, the ball's lowest axis node): the first contact pair."""
    points, node_type = np.asarray(points, float), np.asarray(node_type)
    axis = np.abs(points[:, 0]) <= AXIS_TOL
    panel = np.flatnonzero(axis & (node_type == panel_part))
    ball = np.flatnonzero(axis & (node_type == ball_part))
    if not len(panel) or not len(ball):
        raise ValueError(f"no axis node (|x| <= {AXIS_TOL} m) of part {panel_part if not len(panel) else ball_part}")
    return int(panel[np.argmax(points[panel, 1])]), int(ball[np.argmin(points[ball, 1])])


def contact_graph(cells, n_node: int, pair: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(senders, receivers) of the mesh graph of ``cells`` plus the contact edge ``pair`` (both ways)."""
    s, r = quad_edges(cells)
    a, b = pair
    return np.concatenate([s, [a, b]]).astype(np.int32), np.concatenate([r, [b, a]]).astype(np.int32)


def hop_distances(senders, receivers, n_node: int, source: int) -> np.ndarray:
    """(N,) hops from ``source`` (float: inf where unreachable)."""
    return csgraph.shortest_path(adjacency(senders, receivers, n_node), unweighted=True, indices=source,
                                 directed=False)


def part_hops(hops, node_part, part_names: Sequence[str]) -> dict:
    """{part: {min, median, max}} of the finite hop distances of each part's nodes."""
    hops, node_part = np.asarray(hops), np.asarray(node_part)
    out = {}
    for k, name in enumerate(part_names):
        h = hops[(node_part == k) & np.isfinite(hops)]
        if len(h):
            out[name] = {"min": int(h.min()), "median": float(np.median(h)), "max": int(h.max())}
    return out


def _spread(adj, mask):
    """``mask`` plus every neighbour of a masked node (one message-passing step)."""
    return mask | (adj @ mask.astype(np.int32) > 0)


def vcycle_reach(mask, levels: Sequence[Level]) -> np.ndarray:
    """The mesh nodes a V-cycle (:class:`pcmgn_jax.mgn.multiscale.VCycle`) reaches from ``mask`` (N,) bool."""
    adjs = [adjacency(lv.senders, lv.receivers, lv.n_node) for lv in levels]
    h, skips = np.asarray(mask, bool), []
    for lv, adj in zip(levels, adjs):
        pooled = np.zeros(lv.n_node, bool)
        np.logical_or.at(pooled, lv.parent, h)
        h = _spread(adj, pooled)
        skips.append(h)
    for k in range(len(levels) - 2, -1, -1):
        h = _spread(adjs[k], skips[k] | h[levels[k + 1].parent])
    return np.asarray(mask, bool) | h[levels[0].parent]


def processor_reach(senders, receivers, n_node: int, source: int, *, steps: int, reach: str = "local",
                    levels: Sequence[Level] = ()) -> list[np.ndarray]:
    """The nodes reached from ``source`` after each of the ``steps`` message-passing steps (and the global
    blocks that follow it): a list of ``steps`` (N,) bool masks; the last is one network pass.
    ``levels``: the coarse levels (``reach='multiscale'``)."""
    adj = adjacency(senders, receivers, n_node)
    mask = np.zeros(n_node, bool)
    mask[source] = True
    after, out = global_block_steps(steps), []
    for i in range(1, steps + 1):
        mask = _spread(adj, mask)
        if i in after and reach == "multiscale":
            mask = vcycle_reach(mask, levels)
        elif i in after and reach == "attention":  # every node of the graph (the whole design)
            mask = np.ones(n_node, bool)
        elif i in after and reach != "local":
            raise ValueError(f"reach must be 'local', 'multiscale' or 'attention', got {reach!r}")
        out.append(mask)
    return out


def level_diameters(senders, receivers, n_node: int, levels: Sequence[Level]) -> list[int]:
    """The diameter (the longest shortest path, in hops, within a connected component) of the mesh
    graph and of every coarse level."""
    out = []
    graphs = [(senders, receivers, n_node)] + [(lv.senders, lv.receivers, lv.n_node) for lv in levels]
    for s, r, n in graphs:
        d = csgraph.shortest_path(adjacency(s, r, n), unweighted=True, directed=False)
        out.append(int(np.max(d[np.isfinite(d)])))
    return out


def reach_report(mesh, part_names: Sequence[str], panel_part: int, variants: dict, *,
                 oled: str = "OLED") -> dict:
    """Hop distances from the contact to every part of ``mesh`` (points [m], cells, node_type) and, for
    every processor of ``variants`` ({name: dict(steps=, reach=, levels=)}), the fraction of the part
    ``oled``'s nodes within its reach after each step (``oled_fraction_by_step``) and after one pass
    (``oled_fraction``), plus the coarse levels' sizes and diameters of the multi-scale variants."""
    points, node_type = np.asarray(mesh.points, float), np.asarray(mesh.node_type)
    n = len(points)
    pair = contact_node(points, node_type, panel_part)
    s, r = contact_graph(mesh.cells, n, pair)
    hops = hop_distances(s, r, n, pair[0])
    node_part = np.asarray(getattr(mesh, "node_part", node_type))
    if oled not in part_names:
        raise ValueError(f"reach report: no part named {oled!r} among {list(part_names)}")
    is_oled = node_part == list(part_names).index(oled)
    report = {"nodes": int(n), "contact_node": pair[0], "ball_node": pair[1],
              "hops": part_hops(hops, node_part, part_names), "variants": {}}
    mesh_s, mesh_r = quad_edges(mesh.cells)
    for name, v in variants.items():
        levels = build_levels(mesh_s, mesh_r, n, v.get("levels", 0)) if v["reach"] == "multiscale" else ()
        masks = processor_reach(s, r, n, pair[0], steps=v["steps"], reach=v["reach"], levels=levels)
        by_step = [float(m[is_oled].mean()) for m in masks]
        entry = {**v, "oled_fraction": by_step[-1], "oled_fraction_by_step": by_step}
        if levels:
            diam = level_diameters(mesh_s, mesh_r, n, levels)
            entry["levels_detail"] = [{"level": k, "nodes": int(nn), "edges": int(e), "diameter": d}
                                      for k, (nn, e, d) in enumerate(zip(
                                          [n] + [lv.n_node for lv in levels],
                                          [len(mesh_s)] + [len(lv.senders) for lv in levels], diam))]
        report["variants"][name] = entry
    return report


def report_table(report: dict) -> list[str]:
    """Markdown lines: hops per part, then every variant's OLED fraction."""
    lines = [f"contact node {report['contact_node']} of {report['nodes']} nodes", ""]
    lines += markdown.table(("part", "min hops", "median", "max"),
                            ((p, h["min"], f"{h['median']:g}", h["max"]) for p, h in report["hops"].items()))
    variants = []
    for name, v in report["variants"].items():
        diam = v["levels_detail"][-1]["diameter"] if "levels_detail" in v else "-"
        full = next((i + 1 for i, f in enumerate(v["oled_fraction_by_step"]) if f >= 1.0), "-")
        levels = v.get("levels", "-") if v["reach"] == "multiscale" else "-"
        variants.append((name, v["steps"], v["reach"], levels, f"{100 * v['oled_fraction']:.1f} %", full, diam))
    return lines + [""] + markdown.table(("processor", "steps", "reach", "levels", "OLED within reach (one pass)",
                                          "all OLED after step", "coarsest diameter"), variants)
