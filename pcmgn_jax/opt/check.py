"""Re-check a design with the built-in solver: every reading of docs/design.md §8's objective at that design,
on the training data's mesh preset, cached as JSON per design (a rerun never repeats a solver run)."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from pcmgn_jax import metrics
from pcmgn_jax.atomic import atomic_write_json
from pcmgn_jax.data.family import Design
from pcmgn_jax.scene import Scene


def solver_preset(traj, where) -> str:
    """The mesh preset the built-in solver made ``traj`` with (meta.solver.preset); ValueError naming
    ``where`` (the dataset) when the data are not solver-generated: a re-check needs the same mesh."""
    preset = traj.meta.get("solver", {}).get("preset")
    if preset is None:
        raise ValueError(f"{where}: the optimiser needs solver-generated data (meta.solver.preset)")
    return preset


def _cache_path(cache_dir, d, label) -> Path:
    return Path(cache_dir) / ("_".join(f"{v * 1e6:.2f}" for v in d) + f"_{label}.json")


def solver_objectives(scene: Scene, design: Design, preset, cache_dir: str | Path | None = None, *,
                      label: str | None = None) -> dict:
    """{reading: objective [MPa] for every reading in metrics.OBJECTIVES, 'design_um', 'solver_seconds',
    'preset', 'n_nodes', 'cached'} of ``design`` (a :class:`~pcmgn_jax.data.family.Design` of ``scene``'s design
    layers [m]) simulated by the built-in solver at ``preset`` (a preset name or a MeshSpec; ``label`` names a
    MeshSpec in the cache file name). ValueError naming a design layer the design lacks."""
    row = design.row
    missing = [n for n in scene.design_layers if n not in row]
    if design.family is not None or missing:
        raise ValueError(f"solver_objectives: a design of the design layers {list(scene.design_layers)} (no family) "
                         f"is checked here, got {design.label()}")
    x = np.array([[row[n] for n in scene.design_layers]], float)
    return solver_objectives_many(scene, x, preset, cache_dir, label=label)[0]


# arrays here: the active loop's GP numerics hand their (B, D) rows straight to the batched solver (solve_designs)
def solver_objectives_many(scene: Scene, designs, preset, cache_dir: str | Path | None = None, *,
                           label: str | None = None) -> list[dict]:
    """:func:`solver_objectives` of designs (B, D) [m]: the designs not in the cache run as one batched
    solver call (cheaper per design than one call each); each result is cached on its own.
    'solver_seconds' of a batched run is its share of the batch's wall time."""
    import json

    from pcmgn_jax.sim.solver import solve_designs

    d = np.atleast_2d(np.asarray(designs, float))
    label = label or preset
    out: list[dict | None] = [None] * len(d)
    for i, x in enumerate(d):
        if cache_dir is not None and (path := _cache_path(cache_dir, x, label)).exists():
            out[i] = {**json.loads(path.read_text()), "cached": True}
    todo = [i for i, o in enumerate(out) if o is None]
    if todo:
        t0 = time.perf_counter()
        try:
            trajs = solve_designs(scene, d[todo], preset=preset)
        except ValueError as e:   # meshes of other topologies (e.g. a layer with more elements): one call each
            if "topology" not in str(e) or len(todo) == 1:
                raise
            trajs = [solve_designs(scene, d[i:i + 1], preset=preset)[0] for i in todo]
        share = (time.perf_counter() - t0) / len(todo)
        for i, traj in zip(todo, trajs):
            rec = {r: float(metrics.oled_objective_of(traj, reading=r)) for r in metrics.OBJECTIVES}
            rec.update(design_um=(d[i] * 1e6).tolist(), solver_seconds=share, preset=label, n_nodes=traj.n_nodes)
            if cache_dir is not None:
                path = _cache_path(cache_dir, d[i], label)
                path.parent.mkdir(parents=True, exist_ok=True)
                atomic_write_json(path, rec)
            out[i] = {**rec, "cached": False}
    return out
