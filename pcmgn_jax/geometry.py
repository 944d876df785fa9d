"""Mesh geometry rules shared by the simulator, the dataset, the graph builder, training and evaluation.

One home for each rule (host-side NumPy only; this module imports nothing else from the package):

- :func:`cell_sides` -- the sides of every cell, as (a, b, owner) with a -> b in the cell's corner order.
- :func:`quad_sides` -- the unique undirected sides of (E, 4) quads (the graph's mesh edges).
- :func:`boundary_sides` -- sides used by exactly one of the given cells (the outline of a part).
- :func:`outward_normals` -- unit outward normals of sides, from the owning cell's signed area
  (clockwise and counter-clockwise cells both work).
- :func:`surface_nodes` -- nodes of a part on boundary sides whose outward normal points up or down.
- :func:`stiffest_adjacent_part` -- an interface node takes the part of its stiffest adjacent cell.
- :func:`roi_crop` -- the region-of-interest crop rule (contact zone, radius, depth, ball height) for any
  quad mesh; :func:`put_back` returns cropped nodal fields to full-size arrays.

Shapes: ``points`` (N, 2) [m], ``cells`` (E, k) node indices (k = 4 for quads; a collapsed quad repeats a
node), ``cell_part`` (E,) part ids.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["cell_sides", "quad_sides", "boundary_sides", "outward_normals", "surface_nodes",
           "stiffest_adjacent_part", "RoiCrop", "RoiCropError", "roi_crop", "put_back"]


def _cells(cells) -> np.ndarray:
    cells = np.asarray(cells, dtype=np.int64)
    if cells.ndim != 2 or cells.shape[1] < 3:
        raise ValueError(f"cells must have shape (E, k >= 3), got {cells.shape}")
    return cells


def cell_sides(cells) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every side of every cell: (a, b, owner), each (E*k,) int64, side i of cell e at index e*k + i.

    a -> b follows the cell's corner order (corner i -> corner i+1, last -> first); owner is the cell.
    """
    cells = _cells(cells)
    a = cells.reshape(-1)
    b = np.roll(cells, -1, axis=1).reshape(-1)
    owner = np.repeat(np.arange(cells.shape[0]), cells.shape[1])
    return a, b, owner


def quad_sides(cells) -> np.ndarray:
    """Unique undirected sides of quads ``cells`` (E, 4): (S, 2) int64 rows (lo, hi), lo < hi, sorted.

    Only the 4 sides of each quad (no diagonals); sides of collapsed quads (a == b) are dropped.
    """
    cells = np.asarray(cells, dtype=np.int64)
    if cells.ndim != 2 or cells.shape[1] != 4:
        raise ValueError(f"cells must have shape (E, 4), got {cells.shape}")
    a, b, _ = cell_sides(cells)
    und = np.unique(np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1), axis=0)
    return und[und[:, 0] != und[:, 1]]


def boundary_sides(cells) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sides used by exactly one of ``cells``: (a, b, owner) as in :func:`cell_sides`, in cell order.

    Pass the cells of one part to get that part's outline (a side shared with another part counts).
    """
    a, b, owner = cell_sides(cells)
    if a.size == 0:
        return a, b, owner
    key = np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    keep = counts[inv.reshape(-1)] == 1
    return a[keep], b[keep], owner[keep]


def outward_normals(points, cells, a, b, owner) -> np.ndarray:
    """Unit outward normals (n, 2) of sides a -> b of cells ``owner`` (zero for a zero-length side).

    The outward side follows from the owning cell's signed area (shoelace), so cell orientation is free.
    """
    points = np.asarray(points, np.float64)
    p = points[_cells(cells)]                                               # (E, k, 2)
    area2 = np.sum(p[:, :, 0] * np.roll(p[:, :, 1], -1, 1) - np.roll(p[:, :, 0], -1, 1) * p[:, :, 1], 1)
    d = points[b] - points[a]
    n = np.stack([d[:, 1], -d[:, 0]], axis=1) * np.sign(area2)[owner][:, None]   # ccw: (dy, -dx)
    length = np.hypot(d[:, 0], d[:, 1])
    return n / np.maximum(length, 1e-300)[:, None]


def surface_nodes(points, cells, cell_part, part: int, *, facing: str, min_normal_y: float = 0.5,
                  visible_only: bool = False) -> np.ndarray:
    """Sorted unique nodes (int32) of ``part`` on boundary sides facing ``facing`` ('up' | 'down').

    A side is on the boundary of the part when only one cell of that part has it; it faces up when its
    unit outward normal has n_y > min_normal_y (down: n_y < -min_normal_y). The default 0.5 keeps sides
    within 60 degrees of horizontal; the symmetry-axis side (n_y = 0) never counts.
    visible_only: keep only nodes seen from outside (from below for 'down', above for 'up'): a facing
      side hidden behind another facing side of the same part (e.g. the staircase a region-of-interest
      crop leaves inside the ball) does not count.
    ``cell_part=None`` means all ``cells`` belong to the part.
    """
    if facing not in ("up", "down"):
        raise ValueError(f"facing must be 'up' or 'down', got {facing!r}")
    points = np.asarray(points, np.float64)
    cells = _cells(cells)
    if cell_part is not None:
        cells = cells[np.asarray(cell_part) == part]
    if cells.size == 0:
        raise ValueError(f"no cells with part id {part}")
    a, b, owner = boundary_sides(cells)
    n_y = outward_normals(points, cells, a, b, owner)[:, 1]
    sel = n_y > min_normal_y if facing == "up" else n_y < -min_normal_y
    a, b = a[sel], b[sel]
    nodes = np.unique(np.concatenate([a, b]))
    if visible_only and nodes.size:
        ea, eb = points[a], points[b]
        swap = (ea[:, 0] > eb[:, 0])[:, None]
        left, right = np.where(swap, eb, ea), np.where(swap, ea, eb)
        width = right[:, 0] - left[:, 0]
        scale = max(float(np.ptp(points[:, 1])), 1e-300)
        keep = np.ones(nodes.size, bool)
        for i, node in enumerate(nodes):
            x, y = points[node]
            over = (left[:, 0] <= x) & (x <= right[:, 0]) & (width > 0)
            y_side = left[over, 1] + (x - left[over, 0]) / width[over] * (right[over, 1] - left[over, 1])
            hidden = y_side < y - 1e-9 * scale if facing == "down" else y_side > y + 1e-9 * scale
            keep[i] = not hidden.any()
        nodes = nodes[keep]
    return nodes.astype(np.int32)


def stiffest_adjacent_part(cells, cell_part, stiffness, *, n_nodes: int) -> np.ndarray:
    """Part id (N,) int32 of every node: the part of its stiffest adjacent cell.

    An interface node (shared by cells of several parts, e.g. bonded layers) takes the part with the
    largest ``stiffness[part]`` (Young's modulus); ties go to the smaller part id. Nodes in no cell: -1.
    stiffness: (n_parts,) one value per part id.
    """
    cells = _cells(cells)
    cell_part = np.asarray(cell_part, np.int64)
    stiffness = np.asarray(stiffness, np.float64)
    rank = np.empty(len(stiffness), np.int64)
    rank[np.argsort(-stiffness, kind="stable")] = np.arange(len(stiffness))   # 0 = stiffest
    best = np.full(int(n_nodes), len(stiffness), np.int64)
    for c in range(cells.shape[1]):
        np.minimum.at(best, cells[:, c], rank[cell_part])
    by_rank = np.append(np.argsort(rank), -1)                              # rank -> part id; none -> -1
    return by_rank[best].astype(np.int32)


# ---------------------------------------------------------------------------------------------------------
# Region-of-interest crop (host side, reference mesh, once): one rule for generated and imported meshes
# ---------------------------------------------------------------------------------------------------------
ROI_REL_TOL = 1e-9   # a node within radius/depth/ball_height x (1 + 1e-9) of the limit counts as inside


@dataclass(frozen=True)
class RoiCrop:
    """Which cells and nodes a region-of-interest crop keeps (see :func:`roi_crop`).

    keep_cell:     (E,) bool   full cells kept
    node_map:      (n,) int64  sorted; cropped node i is full node ``node_map[i]``
    cells:         (e, k) int64 kept cells in the cropped node numbering (same corner order)
    x_contact:     [m] the contact axis (axisymmetric: 0) or contact point x (plane strain) used
    y_panel_top:   [m] the impacted (top) panel surface the depth is measured from (NaN: no panel cells)
    y_ball_bottom: [m] the ball's lowest point the ball height is measured from (NaN: no ball cells)
    """

    keep_cell: np.ndarray
    node_map: np.ndarray
    cells: np.ndarray
    x_contact: float
    y_panel_top: float
    y_ball_bottom: float

    @property
    def n_nodes(self) -> int:
        return int(self.node_map.shape[0])


class RoiCropError(ValueError):
    """A region-of-interest limit that is not > 0, or a crop that leaves nothing of the mesh, the panel or
    the ball. ``param`` names the limit to fix: 'radius', 'depth' or 'ball_height'."""

    def __init__(self, message: str, param: str):
        super().__init__(message)
        self.param = param


def roi_crop(points, cells, cell_part, *, radius: float, depth: float = math.inf,
             ball_height: float = math.inf, analysis: str = "axisymmetric", ball_part: int | None = 0,
             x_contact: float | None = None) -> RoiCrop:
    """The region-of-interest crop rule, for any quad mesh of a ball above a layered panel (NumPy, host side).

    A cell is kept when all its nodes lie
      - within ``radius`` [m] of the contact: axisymmetric ``x <= radius`` (the contact axis is x = 0);
        plane strain ``|x - x_contact| <= radius``, ``x_contact`` [m] given (e.g. from the scene) or the x of
        the ball's lowest node (the mean x of nodes tied for lowest);
      - panel cells (every part but ``ball_part``): within ``depth`` [m] below the impacted panel top,
        ``y >= y_panel_top - depth`` with ``y_panel_top`` the highest panel node within the radius
        (``depth = inf`` keeps the full thickness);
      - ball cells (``cell_part == ball_part``): within ``ball_height`` [m] above the ball's lowest point,
        ``y <= y_ball_bottom + ball_height`` (``inf`` keeps the whole ball).
    Limits are inclusive (relative tolerance 1e-9). Nodes on the cut edges stay ordinary nodes; part and
    type arrays are cropped with ``node_map`` by the caller. ``ball_part=None``: the mesh has no ball.

    points (N, 2) [m] reference coordinates; cells (E, k) node indices; cell_part (E,) part ids.
    Raises :class:`RoiCropError` (a ValueError naming the limit and the mesh extent) for a limit that is not
    > 0, when no cell is kept, or when the mesh has panel (ball) cells and none of them is kept.
    """
    points = np.asarray(points, np.float64)
    cells = _cells(cells)
    cell_part = np.asarray(cell_part)
    if points.ndim != 2 or points.shape[1] != 2 or cell_part.shape != (cells.shape[0],):
        raise ValueError(f"roi_crop: points (N, 2), cells (E, k) and cell_part (E,) expected, got "
                         f"{points.shape}, {cells.shape} and {cell_part.shape}")
    for name, value in (("radius", radius), ("depth", depth), ("ball_height", ball_height)):
        if not value > 0:     # also refuses NaN
            raise RoiCropError(f"roi_crop: {name} must be > 0 [m], got {value}", name)
    if analysis not in ("axisymmetric", "plane_strain"):
        raise ValueError(f"roi_crop: analysis must be 'axisymmetric' or 'plane_strain', got {analysis!r}")
    x, y = points[:, 0], points[:, 1]
    span = max(float(np.ptp(points)) if points.size else 0.0, 1e-300)
    is_ball = cell_part == ball_part if ball_part is not None else np.zeros(len(cells), bool)
    ball_nodes = np.unique(cells[is_ball])
    y_ball_bottom = float(y[ball_nodes].min()) if ball_nodes.size else math.nan
    if analysis == "axisymmetric":
        if x_contact not in (None, 0, 0.0):
            raise ValueError(f"roi_crop: an axisymmetric contact is on the axis x = 0, got x_contact={x_contact}")
        xc = 0.0
        lateral = x <= radius * (1 + ROI_REL_TOL)
    else:
        if x_contact is None:
            if not ball_nodes.size:
                raise ValueError("roi_crop: plane strain without ball cells needs x_contact [m] (the contact point)")
            lowest = ball_nodes[y[ball_nodes] <= y_ball_bottom + ROI_REL_TOL * span]
            x_contact = float(x[lowest].mean())
        xc = float(x_contact)
        lateral = np.abs(x - xc) <= radius * (1 + ROI_REL_TOL) + ROI_REL_TOL * span
    panel_nodes = np.unique(cells[~is_ball])
    near_panel = panel_nodes[lateral[panel_nodes]]
    y_panel_top = float(y[near_panel].max()) if near_panel.size else math.nan
    in_depth = y >= y_panel_top - depth * (1 + ROI_REL_TOL) if math.isfinite(depth) else np.ones(len(x), bool)
    in_height = (y <= y_ball_bottom + ball_height * (1 + ROI_REL_TOL) if math.isfinite(ball_height)
                 else np.ones(len(x), bool))
    inside = lateral[cells].all(axis=1)
    keep_cell = inside & np.where(is_ball, in_height[cells].all(axis=1), in_depth[cells].all(axis=1))

    where = (f"roi_crop (radius={radius} m, depth={depth} m, ball_height={ball_height} m; mesh x in "
             f"[{x.min():.6g}, {x.max():.6g}] m, y in [{y.min():.6g}, {y.max():.6g}] m, contact x={xc:.6g} m)")
    if not inside.any():
        raise RoiCropError(f"{where}: no cell lies within the radius of the contact", "radius")
    for group, name, param in ((~is_ball, "panel", "depth"), (is_ball, "ball", "ball_height")):
        if group.any() and not (keep_cell & group).any():
            culprit = param if (inside & group).any() else "radius"
            raise RoiCropError(f"{where}: keeps no {name} cell; widen {culprit}", culprit)
    kept = cells[keep_cell]
    node_map = np.unique(kept)
    inverse = np.full(len(points), -1, np.int64)
    inverse[node_map] = np.arange(len(node_map))
    return RoiCrop(keep_cell=keep_cell, node_map=node_map, cells=inverse[kept], x_contact=xc,
                   y_panel_top=y_panel_top, y_ball_bottom=y_ball_bottom)


def put_back(values, node_map, *, n_nodes: int, axis: int = 0, fill=math.nan) -> np.ndarray:
    """Cropped nodal ``values`` (size ``len(node_map)`` along ``axis``) in a full-size array.

    Full node ``node_map[i]`` gets cropped value i; nodes outside the crop get ``fill`` (default NaN, so
    float values, or integer/bool values promoted to float64; pass an in-range fill, e.g. -1, to keep an
    integer dtype). ``n_nodes`` is the full mesh's node count, e.g. ``meta['roi']['n_nodes_full']``.
    """
    values = np.asarray(values)
    node_map = np.asarray(node_map, np.int64)
    axis = axis % max(values.ndim, 1)
    if values.ndim == 0 or values.shape[axis] != len(node_map):
        raise ValueError(f"put_back: values have {values.shape} but node_map has {len(node_map)} nodes "
                         f"(axis {axis})")
    if len(node_map) and (node_map.min() < 0 or node_map.max() >= n_nodes):
        raise ValueError(f"put_back: node_map refers to nodes outside 0..{n_nodes - 1}")
    shape = list(values.shape)
    shape[axis] = int(n_nodes)
    out = np.full(shape, fill, dtype=np.result_type(values.dtype, np.min_scalar_type(fill)
                                                    if isinstance(fill, (int, np.integer)) else type(fill)))
    index = [slice(None)] * values.ndim
    index[axis] = node_map
    out[tuple(index)] = values
    return out


# ---------------------------------------------------------------------------------------------------------
# Boundary nodes of a contact pair (host side, reference mesh, once): the penetration fits and metric
# ---------------------------------------------------------------------------------------------------------
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
