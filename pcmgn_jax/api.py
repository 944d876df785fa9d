"""A script's front door: a trained run as one object that rolls out, solves and scores any scene.

    from pcmgn_jax.api import load_run

    model = load_run("runs/cpu")                       # the run's best checkpoint, its mesh preset and scene
    scene = model.scene.with_design(80e-6, 120e-6)     # OCA1, OCA2 thicknesses [m]
    pred = model.rollout(scene)                        # Trajectory: the MGN's fields [m, m/s, Pa]
    truth = model.solve(scene)                         # Trajectory: the built-in solver's, same mesh
    model.objective(pred), model.objective(truth)      # the OLED objective [MPa] of each
    f = model.design_objective()                       # design (D,) [m] -> objective [MPa], pure JAX
    jax.grad(f)(jnp.array(scene.design))               # [MPa/m], through the mesh and the rollout

Every rollout runs the jitted :func:`pcmgn_jax.mgn.rollout.rollout`: one compilation per mesh topology and
window, reused by every later design of that topology (the designs of a fixed preset share one). Units SI
(m, s, m/s, Pa) in and out; the objective is in MPa (docs/design.md §8). Walk-through: docs/api.md.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import jax.numpy as jnp
import numpy as np

from pcmgn_jax import metrics
from pcmgn_jax.config import TrainConfig
from pcmgn_jax.data.layout import trajectory_element
from pcmgn_jax.mgn.checkpoint import Loaded, load, require_run
from pcmgn_jax.mgn.inputs import GraphInputs, graph_inputs, with_scene
from pcmgn_jax.mgn.rollout import rollout, rollout_checked
from pcmgn_jax.scene import Scene
from pcmgn_jax.sim.design_map import DesignMap
from pcmgn_jax.sim.initial import initial_velocity
from pcmgn_jax.sim.mesh import build_mesh, roi
from pcmgn_jax.sim.prepare import SolverSettings
from pcmgn_jax.sim.solver import simulate, to_trajectories
from pcmgn_jax.surrogates.mgn import run_splits
from pcmgn_jax.trajectory import Trajectory

__all__ = ["Model", "load_run"]


def load_run(workdir: str | Path, *, which: str = "best", reference: Trajectory | None = None) -> "Model":
    """The trained run in ``workdir`` (a ``python -m experiments.train --workdir`` folder) as a :class:`Model`.

    ``which``: 'best' (the checkpoint of lowest validation error) or 'periodic' (the latest).
    ``reference``: a trajectory of the run's data (mesh preset and scene in its meta); default the first of
    the run's training split, read from its dataset. Raises :class:`pcmgn_jax.mgn.checkpoint.MissingRun`
    for a folder that holds no trained run, ``ValueError`` for a run that predicts a baseline's residual
    (``residual_of``: evaluate those with ``python -m experiments.evaluate``).
    """
    require_run(workdir)
    if reference is None:
        splits = run_splits(workdir)
        reference = next((t for split in splits[1:] for t in split), None)
        if reference is None:
            raise ValueError(f"{workdir}: the run's dataset holds no trajectory to take the mesh and scene from; "
                             "pass reference=")
    return Model(load(workdir, reference, which=which), reference)


class Model:
    """A trained MGN with the mesh preset and scene of its data (made by :func:`load_run`).

    ``scene``: the reference scene (the run's data; vary it with ``scene.with_design`` or
    :func:`pcmgn_jax.scene.with_parameters`); ``preset``: the mesh preset every scene is meshed at
    (None for imported data: then only trajectories can be rolled out); ``dt``: the frame interval the
    model steps by [s]. ``sim``: the checkpoint's :class:`~pcmgn_jax.mgn.checkpoint.Loaded` (spec, params, stats),
    whose contact buffer grows when a rollout needs it; ``reference``: the trajectory the preset and scene are
    read from.
    """

    def __init__(self, sim: Loaded, reference: Trajectory):
        self.sim, self.reference = sim, reference

    @property
    def config(self) -> TrainConfig:
        return self.sim.config

    @property
    def scene(self) -> Scene:
        return Scene.from_dict(self.reference.meta["scene"])

    @property
    def preset(self) -> str | None:
        return (self.reference.meta.get("solver") or {}).get("preset")

    @property
    def dt(self) -> float:
        return self.sim.spec.dt

    # ---- one scene in, fields out --------------------------------------------------------------------

    def mesh(self, scene: Scene):
        """The region-of-interest mesh (:class:`pcmgn_jax.sim.mesh.Mesh`) of ``scene`` at the run's preset."""
        if self.preset is None:
            raise ValueError("this run's data names no mesh preset (imported data): roll out a Trajectory instead "
                             "of a Scene")
        mesh, _ = roi(build_mesh(scene, self.preset), self.preset)
        return mesh

    def _inputs(self, mesh, scene: Scene, capacity: int | None = None) -> GraphInputs:
        """The model's graph inputs of ``mesh`` and ``scene`` (node types, coarse levels, scene features and
        contact radius as the run was trained with; ``capacity`` contact edges, default the run's)."""
        s, form = self.sim, self.sim.spec.formulation
        role = form.part_identity == "role"
        return graph_inputs(mesh, scene, scene_features=form.scene_features, radius=s.index.radius,
                            capacity=capacity or s.index.capacity,
                            n_parts=None if role else s.topology.n_node_types - 1, levels=form.hierarchy_levels,
                            identity=form.part_identity)

    def _whole_fields_only(self) -> None:
        if self.config.residual_of:
            raise ValueError(f"this run predicts the {self.config.residual_of} baseline's residual "
                             f"(residual_of={self.config.residual_of!r}): score it with experiments.evaluate")

    def _steps(self, scene: Scene, n_steps: int | None) -> int:
        if not np.isclose(scene.output_dt, self.dt, rtol=1e-6):
            raise ValueError(f"scene output_dt {scene.output_dt!r} s: the model steps by {self.dt!r} s")
        n = scene.n_frames if n_steps is None else n_steps
        if not isinstance(n, int) or n < 1:
            raise ValueError(f"n_steps must be an integer >= 1, got {n!r}")
        return n

    def rollout(self, scene: Scene | Trajectory, *, n_steps: int | None = None) -> Trajectory:
        """The MGN's rollout of ``scene``: a :class:`~pcmgn_jax.trajectory.Trajectory` of ``n_steps`` + 1 frames
        (default the scene's ``n_frames``), displacement (T, N, 2) [m], velocity (T, N, 2) [m/s], von Mises
        (T, N) [Pa], on the scene's mesh at the run's preset, from the solver's initial state (at rest, the
        ball at its drop speed). A Trajectory instead of a Scene: rolled out on its own mesh from its frame 0
        (imported data; ``n_steps`` default its frames - 1). The contact buffer grows as needed (kept for
        the next call); a run that predicts a baseline's residual is refused (``ValueError``)."""
        self._whole_fields_only()
        if isinstance(scene, Trajectory):
            mesh, sc = scene, Scene.from_dict(scene.meta["scene"])
            n = scene.n_frames - 1 if n_steps is None else n_steps
            u0, v0, vm0 = scene.displacement[0], scene.velocity[0], scene.von_mises[0]
        else:
            mesh, sc, n = self.mesh(scene), scene, self._steps(scene, n_steps)
            u0, v0, vm0 = np.zeros((mesh.n_nodes, 2)), initial_velocity(scene, mesh.node_part), np.zeros(mesh.n_nodes)
        inp = self._inputs(mesh, sc)
        f32 = lambda a: np.asarray(a, np.float32)  # noqa: E731
        res, index = rollout_checked(self.sim.spec, n, self.sim.params, self.sim.stats, inp.topology, inp.index,
                                     inp.points, f32(u0), f32(v0), f32(vm0))
        if index.capacity > self.sim.index.capacity:  # kept: later rollouts start from the grown buffer
            self.sim = self.sim._replace(index=self.sim.index.replace(capacity=index.capacity))
        meta = {"scene": sc.to_dict(), "part_names": list(sc.part_names), "output_dt": self.dt, "source": "mgn",
                "design": dict(zip(sc.design_layers, map(float, sc.design)))}
        return Trajectory(points=np.asarray(mesh.points, np.float64), cells=mesh.cells, cell_part=mesh.cell_part,
                          node_part=mesh.node_part, node_type=mesh.node_type, times=self.dt * np.arange(n + 1),
                          displacement=np.asarray(res.displacement, np.float64),
                          velocity=np.asarray(res.velocity, np.float64),
                          von_mises=np.asarray(res.von_mises, np.float64), meta=meta)

    def solve(self, scene: Scene, *, settings: SolverSettings | None = None) -> Trajectory:
        """The built-in solver's trajectory of ``scene`` on the same mesh as :meth:`rollout` (the run's
        preset, cropped to its region of interest): ``scene.n_frames`` + 1 frames every ``scene.output_dt``
        [s]. ``settings``: default the solver settings' element the run's data was made with. Raises
        :class:`pcmgn_jax.sim.solver.SolverError` when the explicit run is unstable."""
        if settings is None:
            element = trajectory_element(self.reference.meta)
            settings = SolverSettings() if element is None else SolverSettings(element=element)
        preset = self.preset
        self.mesh(scene)  # refuses imported data by name
        (traj,) = to_trajectories(simulate([scene], preset, settings=settings), [scene], preset, settings=settings)
        return traj

    @staticmethod
    def objective(traj: Trajectory, *, reading: str = metrics.DEFAULT_OBJECTIVE) -> float:
        """The design objective [MPa] of a trajectory's von Mises (docs/design.md §8): ``reading`` one of
        :data:`pcmgn_jax.metrics.OBJECTIVES` over the OLED section at x < 3 mm, averaged over every frame
        (``peak``: the max). The same number for a rollout and for the solver's trajectory of one scene."""
        return float(metrics.oled_objective_of(traj, reading=reading))

    # ---- the objective as a differentiable function of the design --------------------------------------

    def design_objective(self, scene: Scene | None = None, *, reading: str = metrics.DEFAULT_OBJECTIVE,
                         n_steps: int | None = None, capacity: int | None = None) -> Callable:
        """``f(design) -> objective`` [MPa]: ``design`` (D,) [m] the thicknesses of ``scene.design_layers``
        (default scene: the run's), through the mesh (:class:`pcmgn_jax.sim.design_map.DesignMap`, affine in
        the design), the scene features and the rollout. A pure JAX function: ``jax.grad``, ``jax.jacfwd``,
        ``jax.jit`` and ``jax.vmap`` compose (``jax.jacfwd`` stores no activations: the cheaper with a few
        design variables and a long window). The objective's section weights are held at ``scene``'s design.
        The contact buffer holds ``capacity`` edges (default: what the scene's own rollout needed, doubled);
        a design that overflows it gives NaN, value and gradient: make ``f`` again with a larger ``capacity``.
        ValueError when the preset's mesh changes topology with the design (a family's thickness rule)."""
        self._whole_fields_only()
        base = self.scene if scene is None else scene
        n = self._steps(base, n_steps)
        dmap = DesignMap.build(base, self.preset)
        mesh = dmap.mesh
        if capacity is None:
            self.rollout(base, n_steps=n)   # sizes the contact buffer at the scene's own design
            capacity = 2 * self.sim.index.capacity
        inp = self._inputs(mesh, base, capacity)
        part = list(base.part_names).index("OLED")
        weights = jnp.asarray(metrics.objective_weights(mesh.points, mesh.cells, mesh.cell_part, mesh.node_part,
                                                        part=part, reading=reading), jnp.float32)
        u0 = jnp.zeros((mesh.n_nodes, 2), jnp.float32)
        v0 = jnp.asarray(initial_velocity(base, mesh.node_part), jnp.float32)
        vm0 = jnp.zeros(mesh.n_nodes, jnp.float32)
        s, names = self.sim, self.sim.spec.formulation.scene_features

        def f(design):
            design = jnp.asarray(design, jnp.float32)
            topology = with_scene(inp.topology, base, names, design=design) if names else inp.topology
            res = rollout(s.spec, n, s.params, s.stats, topology, inp.index, dmap.points(design), u0, v0, vm0)
            value = metrics.oled_objective(res.von_mises, weights, reading=reading)
            return value * jnp.where(jnp.any(res.overflow), jnp.nan, 1.0)

        return f
