"""Exact design gradients from the explicit solver: the OLED objective and its reverse-mode derivative with
respect to named scene parameters (:mod:`pcmgn_jax.sim.parameters`), for a batch of designs of one topology.

What is differentiated. The same run as :func:`pcmgn_jax.sim.solver.simulate` (the jitted integration of
:mod:`pcmgn_jax.sim.integrate`, the element of :mod:`pcmgn_jax.sim.fem`, the penalty of
:mod:`pcmgn_jax.sim.prepare`), with its preparation written as jax functions of the parameters: reference
coordinates (affine in the thicknesses and the ball radius), element stiffness with the ``q4i`` condensation,
lumped masses, penalty stiffness per slave node, the centroid stress operator, the stencil coefficients
(:func:`pcmgn_jax.sim.stencil.gather`) and the initial velocity. The time step dt and the substeps per frame
are FIXED per batch (the host's stable step of the batch, :func:`setup`, recorded in :class:`GradientSetup`):
the gradient is the derivative of the discrete solution at fixed dt. (The host solver's step changes with
the mesh, so its value as a function of the design has small steps of its own; at fixed dt it is smooth.)

The objective (``metrics.oled_objective`` on the region-of-interest section, as ``opt.check`` reads the
solver, here in Pa): ``area_mean`` (default) and ``disc_mean``, the time mean of the section mean, smooth
in the parameters, with the section weights moving with the mesh (``metrics.section_weights`` of the mapped
coordinates); ``node_mean``, fixed weights; ``peak``, the max over the section's nodes and frames,
differentiated through its argmax (a kink where the argmax switches). The contact energy
0.5 k min(g, 0)^2 is C1 (its second derivative jumps at contact onset) and the von Mises root is guarded at
zero stress.

Memory: each frame of the integration is a ``jax.checkpoint`` (``integrate._run(remat=True)``): the reverse
pass keeps the T frame states and re-integrates one frame at a time, keeping its substeps' states, so
memory grows with frames + substeps per frame (~ the square root of all steps), not their product.
Precision: run under ``jax.enable_x64(True)`` with ``dtype="float64"`` (the default here) where the digits
matter (a finite-difference check); float32 works, with round-off of ~1e-4 of the objective.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from pcmgn_jax import metrics
from pcmgn_jax.scene import Scene
from pcmgn_jax.sim import fem, stencil
from pcmgn_jax.sim.initial import ball_velocity
from pcmgn_jax.sim.integrate import _run, ball_weights, node_arrays, scaled_blocks
from pcmgn_jax.sim.mesh import Mesh, MeshSpec, pinned_spec, roi
from pcmgn_jax.sim.parameters import ParameterMap
from pcmgn_jax.sim.prepare import DEFAULT_SETTINGS, SolverSettings, prepare, slave_penalty, soft_modulus


@dataclass(frozen=True, eq=False)
class GradientSetup:
    """Host side of a differentiable batch (:func:`setup`); the jax functions take it and theta (B, P)."""

    pmap: ParameterMap          # names, the mesh and its maps
    theta: np.ndarray           # (B, P) the batch's parameters [SI]
    analysis: str
    element: str
    penalty_factor: float
    dt: float                   # [s] fixed substep (the batch's stable step at setup)
    n_sub: int                  # substeps per frame (fixed)
    n_frames: int
    output_dt: float            # [s] frame interval
    layout: stencil.SliceLayout
    sources: dict               # stencil.plan's coefficient sources (every row per design)
    index: tuple                # fem.stencil_index of the cells
    slaves: np.ndarray          # (S,) ball surface node ids
    masters: np.ndarray         # (M,) top-surface node ids sorted by x
    node_slots: np.ndarray      # (N, 4)
    avg_weight: np.ndarray      # (N, 4)
    reading: str                # the objective reading (metrics.OBJECTIVES)
    section: np.ndarray         # (E_s, 4) full-mesh cells of the area / disc readings' section
    node_weights: np.ndarray    # (N,) fixed weights of node_mean / the peak's mask (zeros for area / disc)
    dtype: str

    @property
    def mesh(self) -> Mesh:
        return self.pmap.mesh


def setup(scenes: Sequence[Scene], preset: str | MeshSpec, *, names=None, settings: SolverSettings = DEFAULT_SETTINGS,
          reading: str = metrics.DEFAULT_OBJECTIVE, part_name: str = "OLED", dtype: str = "float64",
          n_frames: int | None = None) -> GradientSetup:
    """Prepare a batch of scenes of one topology for :func:`objective` / :func:`value_and_grad`: the host
    solver's preparation (:func:`pcmgn_jax.sim.prepare.prepare`) gives the stable step, held fixed; the
    parameter map of ``names`` (default :func:`pcmgn_jax.sim.parameters.default_names`) is built at
    ``scenes[0]``; the objective's section is the preset's region of interest (as the solver's
    trajectories are read)."""
    if reading not in metrics.OBJECTIVES:
        raise ValueError(f"objective reading must be one of {metrics.OBJECTIVES}, got {reading!r}")
    base = scenes[0]
    preset = pinned_spec(base, preset)   # a family mesh's topology at the first scene (mesh.pinned_spec)
    prep = prepare(scenes, preset, settings)
    pmap = ParameterMap.build(base, preset, names)
    mesh = pmap.mesh
    if not np.array_equal(mesh.cells, prep.mesh.cells):
        raise ValueError("differentiable: the parameter map's mesh differs from the solver's")
    output_dt = base.output_dt
    n_sub = max(1, int(np.ceil(output_dt / prep.dt_stable)))
    neighbours, blocks = fem.node_stencil(mesh.cells, prep.ke[:1], mesh.n_nodes)
    live = (np.abs(blocks) > 0).any(axis=(0, 2, 3)).T
    layout, sources = stencil.plan(neighbours, live, np.zeros(mesh.n_nodes, bool))
    part = mesh.part_names.index(part_name)
    sub, node_map = roi(mesh, preset)
    keep = metrics.section_cells(sub.points, sub.cells, sub.cell_part, part=part)
    section = node_map[sub.cells[keep]]
    node_weights = np.zeros(mesh.n_nodes)
    if reading in ("node_mean", "peak"):
        node_weights[node_map] = metrics.objective_weights(sub.points, sub.cells, sub.cell_part, sub.node_part,
                                                           part=part, reading=reading)
    elif not keep.any():
        raise ValueError(f"objective {reading!r}: no cell of {part_name} in the section")
    return GradientSetup(
        pmap=pmap, theta=np.stack([pmap.theta(s) for s in scenes]), analysis=base.analysis,
        element=settings.element, penalty_factor=settings.penalty_factor, dt=output_dt / n_sub, n_sub=n_sub,
        n_frames=base.n_frames if n_frames is None else n_frames, output_dt=output_dt, layout=layout,
        sources=sources, index=(neighbours, fem.stencil_index(mesh.cells, mesh.n_nodes)[1]), slaves=prep.slaves,
        masters=prep.masters, node_slots=prep.node_slots, avg_weight=prep.avg_weight, reading=reading,
        section=section, node_weights=node_weights, dtype=dtype)


def _operators(gs: GradientSetup, points, materials):
    """One design's element stiffness (E,8,8) [N/m], stress operator (E,4,8) [Pa/m], nodal masses (N,) [kg]
    and slave penalties (S,) [N/m] from its points (N,2) [m] and part materials (n_parts, 3)."""
    mesh = gs.mesh
    mat = materials[mesh.cell_part]
    ke, me, db = fem.element_matrices(points, mesh.cells, mat[:, 0], mat[:, 1], mat[:, 2], analysis=gs.analysis,
                                      element=gs.element)
    mass = jnp.zeros(mesh.n_nodes, me.dtype).at[mesh.cells].add(me)
    e_soft = soft_modulus(materials[1, 0], materials[1, 1], materials[0, 0], materials[0, 1])
    k_s = slave_penalty(points[gs.slaves, 0], points[gs.masters, 0], e_soft, factor=gs.penalty_factor,
                        axisymmetric=gs.analysis == "axisymmetric")
    return ke, db, mass, k_s


def solver_inputs(gs: GradientSetup, theta):
    """The arguments of ``integrate._run`` for theta (B, P) [SI], as jax functions of theta: (arrays, u0,
    v0, dt) with u0, v0 (2,B,N) [m, m/s] and dt (B,) [s] (fixed)."""
    mesh = gs.mesh
    dtype = jnp.dtype(gs.dtype)
    theta = jnp.asarray(theta, dtype)
    points = gs.pmap.points(theta)                                  # (B,N,2)
    ke, db, mass, k_s = jax.vmap(partial(_operators, gs))(points, gs.pmap.materials(theta))
    free = (~mesh.fixed).astype(float)
    _, blocks = fem.node_stencil(mesh.cells, ke, mesh.n_nodes, index=gs.index)
    coefs = stencil.gather(scaled_blocks(blocks, free, mass), gs.layout, gs.sources)
    arrays = node_arrays(coefs=coefs, mass=mass, free=free, ball_weight=ball_weights(mass, mesh.node_part),
                         slaves=gs.slaves, masters=gs.masters, points=points, k_slave=k_s, cells=mesh.cells,
                         node_slots=gs.node_slots, avg_weight=gs.avg_weight, db=db,
                         sym_coefs=stencil.gather(blocks, gs.layout, gs.sources))
    arrays = jax.tree.map(lambda v: jnp.asarray(v, dtype if jnp.asarray(v).dtype.kind == "f" else jnp.int32),
                          arrays)
    v0 = jnp.moveaxis(ball_velocity(gs.pmap.velocity(theta), mesh.node_part), -1, 0).astype(dtype)
    return arrays, jnp.zeros_like(v0), v0, jnp.full(theta.shape[:1], gs.dt, dtype)


def objective(gs: GradientSetup, theta):
    """The OLED objective (B,) [Pa] of theta (B, P) [SI] (module docstring); a jax function of theta."""
    arrays, u0, v0, dt = solver_inputs(gs, theta)
    _, _, vm, _, _ = _run(arrays, u0, v0, dt, layout=gs.layout, n_frames=gs.n_frames, n_sub=gs.n_sub,
                          rigid_x=gs.analysis == "plane_strain", remat=True)
    if gs.reading in ("area_mean", "disc_mean"):
        w = jax.vmap(lambda p: metrics.section_weights(p, gs.section, disc=gs.reading == "disc_mean"))(
            gs.pmap.points(jnp.asarray(theta, vm.dtype)))
    else:
        w = jnp.broadcast_to(jnp.asarray(gs.node_weights, vm.dtype), vm.shape[:1] + vm.shape[2:])
    return metrics.oled_objective(vm, w[:, None, :], reading=gs.reading) * 1e6


def value_fn(gs: GradientSetup):
    """jitted theta (B, P) -> objective (B,) [Pa] (compiles once per setup)."""
    return jax.jit(partial(objective, gs))


def value_and_grad_fn(gs: GradientSetup):
    """jitted theta (B, P) -> (objective (B,) [Pa], gradient (B, P) [Pa per SI unit of each parameter]): one
    reverse pass for every parameter of every design (designs are independent: the gradient of the sum)."""
    def total(theta):
        values = objective(gs, theta)
        return values.sum(), values

    grad = jax.value_and_grad(total, has_aux=True)

    @jax.jit
    def run(theta):
        (_, values), g = grad(theta)
        return values, g

    return run
