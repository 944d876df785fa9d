"""Sides, outward normals and surfaces of cells, and the part of interface nodes (host-side NumPy).

Shapes: ``points`` (N, 2) [m], ``cells`` (E, k) node indices (k = 4 for quads; a collapsed quad repeats a
node), ``cell_part`` (E,) part ids.
"""
from __future__ import annotations

import numpy as np

__all__ = [
    "as_cells",
    "boundary_sides",
    "cell_sides",
    "outward_normals",
    "quad_sides",
    "stiffest_adjacent_part",
    "surface_nodes",
]


def as_cells(cells) -> np.ndarray:
    """``cells`` as an (E, k >= 3) int64 array of node indices; raises ValueError for another shape."""
    cells = np.asarray(cells, dtype=np.int64)
    if cells.ndim != 2 or cells.shape[1] < 3:
        raise ValueError(f"cells must have shape (E, k >= 3), got {cells.shape}")
    return cells


def cell_sides(cells) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every side of every cell: (a, b, owner), each (E*k,) int64, side i of cell e at index e*k + i.

    a -> b follows the cell's corner order (corner i -> corner i+1, last -> first); owner is the cell.
    """
    cells = as_cells(cells)
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
    p = points[as_cells(cells)]                                               # (E, k, 2)
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
    cells = as_cells(cells)
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
    cells = as_cells(cells)
    cell_part = np.asarray(cell_part, np.int64)
    stiffness = np.asarray(stiffness, np.float64)
    rank = np.empty(len(stiffness), np.int64)
    rank[np.argsort(-stiffness, kind="stable")] = np.arange(len(stiffness))   # 0 = stiffest
    best = np.full(int(n_nodes), len(stiffness), np.int64)
    for c in range(cells.shape[1]):
        np.minimum.at(best, cells[:, c], rank[cell_part])
    by_rank = np.append(np.argsort(rank), -1)                              # rank -> part id; none -> -1
    return by_rank[best].astype(np.int32)
