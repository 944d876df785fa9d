"""The one in-memory trajectory type shared by the solver, the importers and the trainer.

Shapes: N nodes, E quad cells, T frames (including the initial frame at t = 0).
Units: SI everywhere (m, s, m/s, Pa).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

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
                  output_dt, source ('solver'|'ansys-text'|'d3plot'|'meshio'), solver settings,
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
