"""Imported mesh + results -> a validated Trajectory (node parts, node types, fixed nodes, meta)."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from pcmgn_jax.data.importers.errors import InputFileError
from pcmgn_jax.data.importers.parts import ImportedMesh
from pcmgn_jax.data.trajectory_io import SI_UNITS
from pcmgn_jax.geometry import stiffest_adjacent_part
from pcmgn_jax.scene import Scene
from pcmgn_jax.trajectory import Trajectory


def node_part(mesh: ImportedMesh, scene: Scene | None) -> np.ndarray:
    """(N,) part of each node: an interface node takes the part of its stiffest adjacent cell
    (largest Young's modulus in the scene; without a scene, or on ties: the smallest part id).
    The rule is :func:`pcmgn_jax.geometry.stiffest_adjacent_part`, shared with the solver's mesh."""
    if scene is not None:
        stiffness = np.array([scene.ball.youngs] + [layer.youngs for layer in scene.layers], np.float64)
    else:
        stiffness = np.zeros(len(mesh.part_names))
    return stiffest_adjacent_part(mesh.cells, mesh.cell_part, stiffness, n_nodes=len(mesh.points))


def fixed_mask(mesh: ImportedMesh, fixed: Any) -> np.ndarray:
    n = len(mesh.points)
    if fixed is None:
        return np.zeros(n, dtype=bool)
    if isinstance(fixed, str) and fixed == "bottom":
        y = mesh.points[:, 1]
        tol = 1e-9 * max(float(np.ptp(mesh.points)), 1e-30)
        return y <= y.min() + tol
    if isinstance(fixed, str):
        ids = mesh.node_sets.get(fixed.lower())
        if ids is None:
            raise InputFileError(f"{mesh.source}: fixed-node set {fixed!r} not found; have {sorted(mesh.node_sets)}"
                                 " (--fixed bottom | none | a node component name)")
    else:
        ids = np.asarray(list(fixed), dtype=np.int64)
    missing = np.setdiff1d(ids, mesh.node_ids)
    if len(missing) and not isinstance(fixed, str):
        raise InputFileError(f"{mesh.source}: fixed node {int(missing[0])} is not in the mesh")
    return np.isin(mesh.node_ids, ids)


def build_trajectory(mesh: ImportedMesh, scene: Scene | None, fixed: Any, times: np.ndarray, disp: np.ndarray,
                     vel: np.ndarray, vm: np.ndarray, source: str, extra: Mapping[str, Any],
                     design: Mapping[str, float] | None) -> Trajectory:
    part = node_part(mesh, scene)
    node_type = part.copy()
    node_type[fixed_mask(mesh, fixed)] = len(mesh.part_names)
    dt = np.diff(times)
    uniform = len(dt) > 0 and np.allclose(dt, dt[0], rtol=1e-9, atol=0)
    if design is None and scene is not None and scene.design_layers:
        design = dict(zip(scene.design_layers, scene.design))
    extra = dict(extra)
    if mesh.notes:
        extra["notes"] = list(mesh.notes)
    meta = {"units": dict(SI_UNITS), "source": source,
            "analysis": scene.analysis if scene is not None else mesh.analysis,
            "scene": scene.to_dict() if scene is not None else None,
            "design": dict(design) if design is not None else None,
            "output_dt": float(dt[0]) if uniform else None, "solver": None, "energy": None,
            "part_names": list(mesh.part_names), "node_ids": mesh.node_ids.tolist(), "import": extra}
    traj = Trajectory(points=mesh.points, cells=mesh.cells, cell_part=mesh.cell_part, node_part=part,
                      node_type=node_type, times=np.asarray(times, np.float64), displacement=disp,
                      velocity=vel, von_mises=vm, meta=meta)
    try:
        traj.validate(f"import from {extra.get('results', mesh.source)}")
    except ValueError as err:
        raise InputFileError(str(err)) from None
    return traj
