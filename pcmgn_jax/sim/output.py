"""A solver batch's result (:class:`RunResult`) and its output: contact phases from the force
history, and ROI-cropped :class:`~pcmgn_jax.trajectory.Trajectory` objects with their meta."""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from pcmgn_jax.scene import Scene
from pcmgn_jax.sim.mesh import MeshSpec, mesh_spec, roi
from pcmgn_jax.sim.prepare import DEFAULT_SETTINGS, Prepared, SolverSettings
from pcmgn_jax.trajectory import Trajectory


@dataclass
class RunResult:
    """Full-mesh result of a batch: u, v (B,T,N,2); von_mises (B,T,N) [Pa]; energy (B,T,3)
    [J] (kinetic, internal, contact); force (B,T-1,n_sub) contact force on the ball [N];
    approach (B,T-1,n_sub) mass-weighted mean ball displacement [m]; dt [s]; n_sub."""

    prepared: Prepared
    u: np.ndarray
    v: np.ndarray
    von_mises: np.ndarray
    energy: np.ndarray
    force: np.ndarray
    approach: np.ndarray
    dt: float
    n_sub: int
    wall_time_s: float
    energy_error: np.ndarray  # (B,)


def contact_phases(force: np.ndarray, dt: float, threshold: float = 1e-3) -> dict[str, float]:
    """Contact start (first substep with force above ``threshold`` x peak), peak-force time,
    and separation (last such substep) [s] from a per-substep force history (flattened).
    NaN where a phase does not occur within the history (e.g. still in contact at the end)."""
    f = np.asarray(force).ravel()
    peak = f.max()
    t = (np.arange(f.size) + 1) * dt
    on = f > threshold * max(peak, 1e-30)
    if peak <= 0 or not on.any():
        return {"contact_start_s": math.nan, "peak_force_time_s": math.nan,
                "separation_s": math.nan, "peak_force_N": 0.0}
    first = int(np.argmax(on))
    last = int(f.size - 1 - np.argmax(on[::-1]))
    separated = last < f.size - 1
    return {"contact_start_s": float(t[first]), "peak_force_time_s": float(t[np.argmax(f)]),
            "separation_s": float(t[last]) if separated else math.nan,
            "peak_force_N": float(peak)}


def to_trajectories(result: RunResult, scenes: Sequence[Scene], preset: str | MeshSpec, *,
                    settings: SolverSettings = DEFAULT_SETTINGS, crop: bool = True) -> list[Trajectory]:
    """Turn a batch result into Trajectories (cropped to the preset's region of interest)."""
    prep = result.prepared
    full = prep.mesh
    if crop:
        sub, node_map = roi(full, preset)
    else:
        sub, node_map = full, np.arange(full.n_nodes)
    preset_name = preset if isinstance(preset, str) else "custom"
    t = np.arange(result.u.shape[1]) * scenes[0].output_dt
    out = []
    for i, scene in enumerate(scenes):
        phases = contact_phases(result.force[i], result.dt)
        meta = {
            "units": {"length": "m", "time": "s", "velocity": "m/s", "stress": "Pa"},
            "analysis": scene.analysis,
            "scene": scene.to_dict(),
            "design": {name: val for name, val in zip(scene.design_layers, scene.design)},
            "output_dt": scene.output_dt,
            "source": "solver",
            "part_names": list(scene.part_names),
            "solver": {"preset": preset_name, "mesh_spec": _spec_dict(mesh_spec(preset)),
                       "settings": dataclasses.asdict(settings), "dt_s": result.dt,
                       "n_substeps_per_frame": result.n_sub, "full_mesh_nodes": full.n_nodes,
                       "full_mesh_cells": int(full.cells.shape[0]), "roi_nodes": sub.n_nodes,
                       "omega2_mesh": float(prep.omega2_mesh[i]),
                       "omega2_contact": float(prep.omega2_contact[i]),
                       "omega2_coupled": float(prep.omega2_coupled[i]),
                       "batch_size": len(scenes), "wall_time_s": result.wall_time_s / len(scenes)},
            "energy": {"max_relative_error": float(result.energy_error[i]),
                       "initial_kinetic_J": float(result.energy[i, 0, 0])},
            "phases": phases,
            "wall_time_s": result.wall_time_s / len(scenes),
        }
        out.append(Trajectory(
            points=prep.points[i][node_map], cells=sub.cells, cell_part=sub.cell_part,
            node_part=sub.node_part, node_type=sub.node_type, times=t,
            displacement=result.u[i][:, node_map], velocity=result.v[i][:, node_map],
            von_mises=result.von_mises[i][:, node_map], meta=meta))
    return out


def _spec_dict(spec: MeshSpec) -> dict[str, Any]:
    d = dataclasses.asdict(spec)
    d["layer_elems"] = dict(spec.layer_elems)
    return d
