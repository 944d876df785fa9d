"""Re-check a design with the built-in solver: every reading of docs/design.md §8's objective at that design,
on the training data's mesh preset, cached as JSON per design (a rerun never repeats a solver run)."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from pcmgn_jax.data.trajectory_io import atomic_write_json
from pcmgn_jax.eval import metrics
from pcmgn_jax.scene import Scene


def solver_objectives(scene: Scene, design, preset, cache_dir: str | Path | None = None, *,
                      label: str | None = None) -> dict:
    """{reading: objective [MPa] for every reading in metrics.OBJECTIVES, 'design_um', 'solver_seconds',
    'preset', 'n_nodes', 'cached'} of ``design`` (D,) [m] simulated by the built-in solver at ``preset`` (a
    preset name or a MeshSpec; ``label`` names a MeshSpec in the cache file name)."""
    import json

    from pcmgn_jax.sim.solver import solve_designs

    d = np.asarray(design, float).reshape(-1)
    path = None
    if cache_dir is not None:
        path = Path(cache_dir) / ("_".join(f"{v * 1e6:.2f}" for v in d) + f"_{label or preset}.json")
        if path.exists():
            return {**json.loads(path.read_text()), "cached": True}
    t0 = time.perf_counter()
    (traj,) = solve_designs(scene, d[None], preset=preset)
    out = {r: float(metrics.oled_objective_of(traj, reading=r)) for r in metrics.OBJECTIVES}
    out.update(design_um=(d * 1e6).tolist(), solver_seconds=time.perf_counter() - t0, preset=label or preset,
               n_nodes=traj.n_nodes)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_json(path, out)
    return {**out, "cached": False}
