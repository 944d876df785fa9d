"""The one in-memory trajectory type shared by the solver, the importers and the trainer.

Shapes: N nodes, E quad cells, T frames (including the initial frame at t = 0).
Units: SI everywhere (m, s, m/s, Pa).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pcmgn_jax import geometry

# node_type: the node's part id (0 = ball, 1..n = layers top to bottom, see scene.py) for free
# nodes, and n_parts (one past the last part id) for fixed (clamped) nodes.


@dataclass
class Trajectory:
    """One explicit-dynamics trajectory on a fixed quad mesh.

    points:       (N, 2) float64  reference coordinates [m] (x = radius or width, y = height)
    cells:        (E, 4) int64    quad connectivity, counter-clockwise
    cell_part:    (E,)   int32    part id of each cell
    node_part:    (N,)   int32    part id of each node (interface nodes: the stiffer layer)
    node_type:    (N,)   int32    node_part, or n_parts for fixed (clamped) nodes
    times:        (T,)   float64  frame times [s]
    displacement: (T, N, 2)       [m]
    velocity:     (T, N, 2)       [m/s]
    von_mises:    (T, N)          nodal von Mises stress [Pa]
    meta:         JSON-able dict: units, analysis, scene (Scene.to_dict()), design (dict name->m),
                  output_dt, source ('solver'|'ansys-text'|'d3plot'|'meshio'|'calculix'), solver settings,
                  energy summary, part_names, ...
    """

    points: np.ndarray
    cells: np.ndarray
    cell_part: np.ndarray
    node_part: np.ndarray
    node_type: np.ndarray
    times: np.ndarray
    displacement: np.ndarray
    velocity: np.ndarray
    von_mises: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def n_nodes(self) -> int:
        return int(self.points.shape[0])

    @property
    def n_frames(self) -> int:
        return int(self.times.shape[0])

    @property
    def positions(self) -> np.ndarray:
        """World positions (T, N, 2) [m] = reference + displacement (float64)."""
        return self.points[None].astype(np.float64) + self.displacement.astype(np.float64)

    def validate(self, where: str = "trajectory") -> None:
        """Raise ValueError naming the field if shapes, ids or values are inconsistent."""
        n, e, t = self.points.shape[0], self.cells.shape[0], self.times.shape[0]
        expect = {
            "points": (self.points, (n, 2)),
            "cells": (self.cells, (e, 4)),
            "cell_part": (self.cell_part, (e,)),
            "node_part": (self.node_part, (n,)),
            "node_type": (self.node_type, (n,)),
            "times": (self.times, (t,)),
            "displacement": (self.displacement, (t, n, 2)),
            "velocity": (self.velocity, (t, n, 2)),
            "von_mises": (self.von_mises, (t, n)),
        }
        for name, (arr, shape) in expect.items():
            if tuple(arr.shape) != shape:
                raise ValueError(f"{where}: field {name!r} has shape {tuple(arr.shape)}, expected {shape}")
            if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
                bad = np.argwhere(~np.isfinite(arr))[0].tolist()
                raise ValueError(f"{where}: field {name!r} has a non-finite value at index {bad}")
        if e and (self.cells.min() < 0 or self.cells.max() >= n):
            raise ValueError(f"{where}: field 'cells' refers to nodes outside 0..{n - 1}")
        if t > 1 and np.any(np.diff(self.times) <= 0):
            raise ValueError(f"{where}: field 'times' must be strictly increasing")


# ---------------------------------------------------------------------------------------------------------
# Region-of-interest crop of a trajectory (the rule itself: pcmgn_jax.geometry.roi_crop)
# ---------------------------------------------------------------------------------------------------------
ROI_META_KEY = "roi"
"""meta[ROI_META_KEY] of a cropped trajectory: radius_m, depth_m, ball_height_m [m] (None = unlimited),
x_contact_m, y_panel_top_m, y_ball_bottom_m, analysis, n_nodes_full, n_cells_full and node_map (cropped
node i = node node_map[i] of the full mesh of n_nodes_full nodes; cropping twice composes the maps)."""


def contact_ball_part(meta: dict[str, Any]) -> int | None:
    """Part id of the ball named by the trajectory's scene (its first contact pair), else the part named
    'ball' in meta['part_names'] (case-insensitive); None when there is none."""
    names = [str(n).lower() for n in (meta.get("part_names") or [])]
    scene = meta.get("scene") or {}
    pairs = scene.get("contact_pairs") or []
    body = str(pairs[0][0]).lower() if pairs else "ball"
    return names.index(body) if body in names else None


def crop_trajectory(traj: Trajectory, *, radius: float, depth: float = float("inf"),
                    ball_height: float = float("inf"), x_contact: float | None = None,
                    ball_part: int | None | str = "scene") -> tuple[Trajectory, np.ndarray]:
    """Crop ``traj`` to the region of interest around the contact (rule: :func:`geometry.roi_crop`).

    radius [m] around the contact axis (axisymmetric) or point (plane strain; ``x_contact`` [m], default
    the ball's lowest node), depth [m] below the panel top (inf: full thickness), ball_height [m] above the
    ball's lowest point (inf: whole ball). The analysis is meta['analysis']; ``ball_part='scene'`` takes the
    ball from the scene's contact pair or the part named 'ball' (:func:`contact_ball_part`).

    Every per-node field (points, node_part, node_type, displacement, velocity, von_mises, meta['node_ids'])
    and per-cell field (cells, cell_part) is cropped; fixed nodes stay fixed (node_type kept); nodes on the
    cut edges are ordinary nodes. meta[ROI_META_KEY] records the crop (see ROI_META_KEY). Returns
    (cropped trajectory, node_map) with cropped node i = node node_map[i] of ``traj``; put fields back with
    :func:`geometry.put_back`. Raises ValueError (:class:`geometry.RoiCropError`) if nothing is kept.
    """
    meta = dict(traj.meta or {})
    analysis = meta.get("analysis")
    if analysis is None:
        raise ValueError("crop_trajectory: meta['analysis'] is missing (axisymmetric | plane_strain)")
    part = contact_ball_part(meta) if isinstance(ball_part, str) and ball_part == "scene" else ball_part
    crop = geometry.roi_crop(traj.points, traj.cells, traj.cell_part, radius=radius, depth=depth,
                             ball_height=ball_height, analysis=analysis, ball_part=part, x_contact=x_contact)
    node_map = crop.node_map
    if meta.get("node_ids") is not None:
        meta["node_ids"] = np.asarray(meta["node_ids"])[node_map].tolist()
    previous = meta.get(ROI_META_KEY)
    full_map = np.asarray(previous["node_map"])[node_map] if previous else node_map
    meta[ROI_META_KEY] = {
        "radius_m": float(radius) if np.isfinite(radius) else None,
        "depth_m": float(depth) if np.isfinite(depth) else None,
        "ball_height_m": float(ball_height) if np.isfinite(ball_height) else None,
        "x_contact_m": crop.x_contact,
        "y_panel_top_m": crop.y_panel_top if np.isfinite(crop.y_panel_top) else None,
        "y_ball_bottom_m": crop.y_ball_bottom if np.isfinite(crop.y_ball_bottom) else None,
        "analysis": analysis,
        "n_nodes_full": int(previous["n_nodes_full"]) if previous else traj.n_nodes,
        "n_cells_full": int(previous["n_cells_full"]) if previous else int(traj.cells.shape[0]),
        "node_map": full_map.astype(int).tolist(),
    }
    if previous:
        meta[ROI_META_KEY]["previous"] = {k: v for k, v in previous.items() if k != "node_map"}
    out = Trajectory(points=traj.points[node_map], cells=crop.cells, cell_part=traj.cell_part[crop.keep_cell],
                     node_part=traj.node_part[node_map], node_type=traj.node_type[node_map], times=traj.times,
                     displacement=traj.displacement[:, node_map], velocity=traj.velocity[:, node_map],
                     von_mises=traj.von_mises[:, node_map], meta=meta)
    return out, node_map
