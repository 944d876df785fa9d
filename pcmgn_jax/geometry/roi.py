"""Region-of-interest crop (host side, reference mesh, once): one rule for generated and imported meshes.

:func:`roi_crop` picks the cells near the contact; :func:`put_back` returns cropped nodal fields to
full-size arrays. Shapes as in :mod:`pcmgn_jax.geometry.sides`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pcmgn_jax.geometry.sides import as_cells

__all__ = ["ROI_REL_TOL", "RoiCrop", "RoiCropError", "put_back", "roi_crop"]

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
    cells = as_cells(cells)
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
