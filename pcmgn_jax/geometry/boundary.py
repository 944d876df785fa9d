"""Boundary nodes of a contact pair (host side, reference mesh, once): the ball's lower surface and the
cover glass's upper surface, for the penetration fits and metric (docs/design.md §6)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pcmgn_jax.geometry.sides import surface_nodes

__all__ = ["BoundaryNodes", "boundary_nodes", "roi_boundary_nodes"]


@dataclass(frozen=True)
class BoundaryNodes:
    """Boundary node sets of the declared contact pair, from the reference mesh.

    ball:      (Mb,) int64  node indices of the ball's lower surface, sorted by reference x
    panel:     (Mp,) int64  node indices of the cover glass top surface, sorted by reference x
    interval:  (x_lo, x_hi) [m] fixed fit interval mapped to t in [-1, 1]; covers both sets' reference x
               with a margin for the expected motion (radial displacements are O(µm))
    ball_rule, panel_rule: how each set was found ('columns' | 'edges' | 'bins'), see boundary_nodes.
    """

    ball: np.ndarray
    panel: np.ndarray
    interval: tuple[float, float]
    ball_rule: str = "columns"
    panel_rule: str = "columns"


def _x_clusters(x: np.ndarray, tol: float) -> np.ndarray:
    """Column label of every entry of x: single-linkage clusters of sorted x with gaps <= tol."""
    order = np.argsort(x, kind="stable")
    xs = x[order]
    new = np.concatenate([[True], np.diff(xs) > tol])
    labels_sorted = np.cumsum(new) - 1
    labels = np.empty_like(labels_sorted)
    labels[order] = labels_sorted
    return labels


def _extreme_per_label(idx: np.ndarray, labels: np.ndarray, y: np.ndarray, side: str) -> np.ndarray:
    """For each label, the index (from idx) of the lowest ('bottom') or highest ('top') y."""
    key = y if side == "bottom" else -y
    # sort by (label, key); first of each label is the extreme
    order = np.lexsort((key, labels))
    first = np.concatenate([[True], labels[order][1:] != labels[order][:-1]])
    return idx[order[first]]


def _surface_nodes(points, idx, side, *, tol, cells, rule, normal_tol):
    """Lower ('bottom') or upper ('top') surface nodes of one part; returns (indices, rule used)."""
    x, y = points[idx, 0], points[idx, 1]
    labels = _x_clusters(x, tol)
    n_cols = int(labels.max()) + 1 if len(idx) else 0
    columnar = n_cols <= 0.5 * len(idx)  # a columnar mesh has >= 2 nodes per column on average
    if rule == "auto":
        rule = "columns" if columnar else ("edges" if cells is not None else "bins")
    if rule == "columns":
        out = _extreme_per_label(idx, labels, y, side)
    elif rule == "edges":
        if cells is None:
            raise ValueError("boundary_nodes: rule 'edges' needs the part's cells")
        out = surface_nodes(points, cells, None, 0, facing="down" if side == "bottom" else "up",
                            min_normal_y=normal_tol, visible_only=True)
        out = out[np.isin(out, idx)]
    elif rule == "bins":
        # bin x at the mesh spacing h (median nearest-neighbour distance of the part's nodes)
        from scipy.spatial import cKDTree

        dist, _ = cKDTree(points[idx]).query(points[idx], k=2)
        h = float(np.median(dist[:, 1]))
        out = _extreme_per_label(idx, np.floor((x - x.min()) / h).astype(np.int64), y, side)
    else:
        raise ValueError(f"boundary_nodes: unknown rule {rule!r} (auto | columns | edges | bins)")
    return out[np.argsort(points[out, 0], kind="stable")].astype(np.int64), rule


def boundary_nodes(
    points,
    node_part,
    *,
    ball_part: int = 0,
    panel_part: int = 1,
    x_max: float | None = None,
    tol: float | None = None,
    cells=None,
    cell_part=None,
    rule: str = "auto",
    margin: float | None = None,
    normal_tol: float = 1e-6,
) -> BoundaryNodes:
    """Ball bottom and cover-glass top nodes of the reference mesh (host-side NumPy, call once).

    points:    (N, 2) reference coordinates [m]; node_part: (N,) part ids (0 = ball, 1 = CG, ...).
    x_max:     [m] keep only nodes with reference x <= x_max (the window where contact can happen; both
               boundaries use it). None keeps all. Recommended: a few contact radii (0.5-1 mm for the
               paper's scene), because a degree-5/6 polynomial over the whole 5 mm ball or the whole panel
               cannot resolve a ~0.25 mm contact patch.
    tol:       [m] x-column tolerance; default 1e-6 x the mesh's x extent (5 nm on 5 mm).
    cells, cell_part: optional quad connectivity (E, 4) and per-cell part ids, used by rule 'edges'.
    rule:      how the surface of each part is found:
               'columns' (the paper's definition): nodes sharing a reference x within ``tol`` form a
                   column; ball bottom = lowest ball node per column, CG top = highest CG node per column.
               'edges': nodes of boundary edges of the part's cells whose outward normal points down
                   (ball) / up (CG), |n_y| > normal_tol. Exact for any (unstructured) mesh; excludes the
                   symmetry-axis edge (n_y = 0).
               'bins': x binned at the mesh spacing (median nearest-neighbour distance), extreme node per
                   bin. Fallback for unstructured meshes without cells; can pick a node one layer inside
                   the surface where a bin holds no surface node.
               'auto' (default): 'columns' if the part is columnar (>= 2 nodes per column on average),
                   else 'edges' if cells are given, else 'bins'. Decided per part.
    margin:    [m] added on both sides of the fit interval; default 2 % of the x span (>> the O(µm)
               radial motion, so predicted x stays inside [-1, 1] after mapping).

    Returns BoundaryNodes(ball, panel, interval, ball_rule, panel_rule).
    """
    points = np.asarray(points, dtype=np.float64)
    node_part = np.asarray(node_part)
    if points.ndim != 2 or points.shape[1] != 2 or node_part.shape != (points.shape[0],):
        raise ValueError(f"boundary_nodes: points (N, 2) and node_part (N,) expected, got "
                         f"{points.shape} and {node_part.shape}")
    span = float(np.ptp(points[:, 0])) if len(points) else 0.0
    tol = 1e-6 * max(span, 1e-12) if tol is None else float(tol)

    def part_nodes(pid):
        idx = np.flatnonzero(node_part == pid)
        if x_max is not None:
            idx = idx[points[idx, 0] <= x_max + tol]
        if len(idx) == 0:
            raise ValueError(f"boundary_nodes: no nodes of part {pid} (x_max={x_max})")
        return idx

    def part_cells(pid):
        if cells is None:
            return None
        c = np.asarray(cells)
        if cell_part is not None:
            return c[np.asarray(cell_part) == pid]
        return c[np.all(node_part[c] == pid, axis=1)]

    ball, ball_rule = _surface_nodes(points, part_nodes(ball_part), "bottom", tol=tol,
                                     cells=part_cells(ball_part), rule=rule, normal_tol=normal_tol)
    panel, panel_rule = _surface_nodes(points, part_nodes(panel_part), "top", tol=tol,
                                       cells=part_cells(panel_part), rule=rule, normal_tol=normal_tol)
    if x_max is not None:
        ball = ball[points[ball, 0] <= x_max + tol]
        panel = panel[points[panel, 0] <= x_max + tol]
    allx = np.concatenate([points[ball, 0], points[panel, 0]])
    lo, hi = float(allx.min()), float(allx.max())
    m = 0.02 * max(hi - lo, 1e-12) if margin is None else float(margin)
    return BoundaryNodes(ball=ball, panel=panel, interval=(lo - m, hi + m),
                         ball_rule=ball_rule, panel_rule=panel_rule)


def roi_boundary_nodes(mesh, panel_part: int, *, x_max: float | None = None, ball_part: int = 0) -> BoundaryNodes:
    """:func:`boundary_nodes` of a region-of-interest mesh (anything with points, node_part, cells,
    cell_part), kept within 0.8 of its x extent (and ``x_max`` [m] if smaller): at the crop's far edge
    the cut sides are not the ball's or the glass's surface."""
    limit = 0.8 * float(np.max(np.asarray(mesh.points)[:, 0]))
    return boundary_nodes(mesh.points, mesh.node_part, ball_part=ball_part, panel_part=panel_part,
                          x_max=limit if x_max is None else min(x_max, limit), cells=mesh.cells,
                          cell_part=mesh.cell_part)
