"""Explicit central-difference dynamics in JAX: the built-in ground truth.

Small-strain linear elasticity on Q4 elements (plane strain or axisymmetric with the hoop
term), row-sum lumped mass, a node-to-segment penalty contact between the ball's lower
surface (slaves) and the top layer's upper surface (masters), clamped plate bottom and a
symmetry axis (u_x = 0 at x = 0). Units SI.

Numerics (docs/design.md §3):
- the state is the displacement u (not absolute coordinates), so float32 keeps the ~1e-9 m
  per-step increments next to mm coordinates; world positions are formed only in the contact
  gap, relative to reference coordinates of the same magnitude;
- contact forces are minus the gradient (jax.grad) of the penalty energy
  0.5 * k_s * min(g, 0)^2 with the gap g measured in the deformed configuration, so the
  contact is conservative by construction (no radial/vertical mismatch);
- the stable step includes the contact springs: dt = safety * 2 / sqrt(w_mesh^2 + w_c^2),
  w_mesh^2 the largest eigenvalue of M^-1/2 K M^-1/2 (scipy Lanczos), w_c^2 a Gershgorin bound
  of M^-1 K_contact. On the default meshes the 25 / 10 um glass, steel and aluminium elements at
  the contact set w_mesh; the bound adds 60-70 % to w_mesh^2 while the coupled eigenvalue with all
  springs engaged (``Prepared.omega2_coupled``) adds only ~9 %, but a step from the latter
  destabilised a run near separation (see :func:`prepare`), so the bound stays;
- energy (kinetic + internal + contact; no external work: the supports are fixed) is
  checked at every frame; a drift above ``energy_tol`` of the initial kinetic energy, or a
  non-finite value, raises :class:`SolverError` naming the frame, and nothing is returned.

The whole run is one jitted ``lax.scan`` (frames) over a ``lax.scan`` (substeps), no host sync
inside. The stiffness is applied as shifted slices of contiguous node rows
(:mod:`pcmgn_jax.sim.stencil`); node arrays are (2, B, N) with a design axis kept in the arrays
rather than vmapped, so designs of one topology can run in one call
(``SolverSettings.designs_per_call``; on CPU they run one at a time, which is faster).
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from functools import partial
from typing import Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse.linalg as spla

from pcmgn_jax.sim import fem, stencil
from pcmgn_jax.sim.mesh import Mesh, MeshSpec, build_mesh, mesh_spec, roi
from pcmgn_jax.scene import Scene
from pcmgn_jax.trajectory import Trajectory


class SolverError(RuntimeError):
    """The explicit run became unstable (energy drift or non-finite values)."""


@dataclass(frozen=True)
class SolverSettings:
    """safety: fraction of the stable time step; penalty_factor: k_p = factor * E'/h [N/m^3]
    with E' the plane-strain modulus of the softer contact body and h the master element size;
    energy_tol: allowed |E(t) - E(0)| / KE(0); dtype: 'float32' or 'float64' (float64 needs
    ``jax.enable_x64``); designs_per_call: designs of a batch integrated together in one
    compiled call (0 = all of them on an accelerator, one at a time on CPU, where the
    vectorised batch of 8 runs at 0.7-0.8x the per-design throughput of single runs:
    benchmarks/README §3)."""

    safety: float = 0.9
    penalty_factor: float = 1.0
    energy_tol: float = 0.01
    dtype: str = "float32"
    designs_per_call: int = 0


@dataclass
class Prepared:
    """Host-side arrays for a batch of B designs sharing one topology (leading axis B)."""

    mesh: Mesh                # mesh of the first design (topology shared)
    points: np.ndarray        # (B,N,2) reference coordinates [m]
    ke: np.ndarray            # (B,E,8,8) element stiffness [N/m]
    db: np.ndarray            # (B,E,4,8) centroid stress operator [Pa/m]
    mass: np.ndarray          # (B,N) lumped nodal mass [kg]
    k_slave: np.ndarray       # (B,S) penalty stiffness per slave node [N/m]
    slaves: np.ndarray        # (S,) ball surface node ids
    masters: np.ndarray       # (M,) top-surface node ids, sorted by x
    node_slots: np.ndarray    # (N,4) indices into the flattened (E*4 + 1) element-node slots
    avg_weight: np.ndarray    # (N,4) nodal-averaging weights of those slots (own part only)
    free: np.ndarray          # (N,2) 1.0 where the dof is free
    omega2_mesh: np.ndarray   # (B,) largest eigenvalue of M^-1 K [1/s^2]
    omega2_contact: np.ndarray  # (B,) Gershgorin bound of M^-1 K_contact [1/s^2]
    omega2_coupled: np.ndarray  # (B,) largest eigenvalue of M^-1 (K + K_contact) [1/s^2] (reported)
    dt_stable: float          # [s] min over the batch, safety applied


def _node_slots(cells: np.ndarray, n_nodes: int, cell_part: np.ndarray, node_part: np.ndarray):
    """For each node, up to 4 (element, corner) slots; padding points at the zero slot E*4."""
    n_el = cells.shape[0]
    slots = np.full((n_nodes, 4), 4 * n_el, np.int64)
    weight = np.zeros((n_nodes, 4))
    fill = np.zeros(n_nodes, np.int64)
    for e in range(n_el):
        for k in range(4):
            node = cells[e, k]
            if fill[node] >= 4:
                raise ValueError(f"solver: node {node} belongs to more than 4 quads")
            slots[node, fill[node]] = 4 * e + k
            weight[node, fill[node]] = 1.0 if cell_part[e] == node_part[node] else 0.0
            fill[node] += 1
    weight /= np.maximum(weight.sum(axis=1, keepdims=True), 1.0)
    return slots, weight


def _largest_omega2(k, minv_sqrt, free_dofs) -> float:
    """Largest eigenvalue [1/s^2] of M^-1/2 K M^-1/2 on the free dofs (scipy Lanczos, float64)."""
    kff = k[free_dofs][:, free_dofs]
    op = spla.LinearOperator(kff.shape, matvec=lambda x: minv_sqrt * (kff @ (minv_sqrt * x)), dtype=float)
    return float(spla.eigsh(op, k=1, which="LA", return_eigenvectors=False, tol=1e-4)[0])


def _contact_stiffness(slaves, masters, seg, t, k_slave, n_nodes):
    """Penalty springs as a (2N,2N) CSR matrix [N/m]: sum_s k_s g_s g_s^T with g_s the gradient
    of slave s's vertical gap over master segment ``seg[s]`` at coordinate ``t[s]``."""
    import scipy.sparse as sp

    dofs = np.stack([2 * slaves + 1, 2 * masters[seg] + 1, 2 * masters[seg + 1] + 1], axis=1)  # (S,3)
    g = np.stack([np.ones_like(t), -(1.0 - t), -t], axis=1)
    vals = k_slave[:, None, None] * g[:, :, None] * g[:, None, :]
    rows = np.repeat(dofs, 3, axis=1).ravel()
    cols = np.tile(dofs, (1, 3)).ravel()
    return sp.csr_matrix((vals.ravel(), (rows, cols)), shape=(2 * n_nodes, 2 * n_nodes))


def _tributary(x: np.ndarray, axisymmetric: bool) -> np.ndarray:
    """Tributary area [m^2] (axisymmetric ring) or length [m] (plane strain) of sorted x."""
    mid = 0.5 * (x[1:] + x[:-1])
    left = np.concatenate([[max(x[0] - (mid[0] - x[0]), 0.0)], mid])
    right = np.concatenate([mid, [x[-1] + (x[-1] - mid[-1])]])
    left = np.maximum(left, 0.0)
    if axisymmetric:
        return np.pi * (right**2 - left**2)
    return right - left


def _material_arrays(scene: Scene, cell_part: np.ndarray):
    ball = scene.ball
    props = np.array([[ball.youngs, ball.poisson, ball.density]] +
                     [[layer.youngs, layer.poisson, layer.density] for layer in scene.layers])
    return props[cell_part, 0], props[cell_part, 1], props[cell_part, 2]


def prepare(scenes: Sequence[Scene], preset: str | MeshSpec,
            settings: SolverSettings = SolverSettings()) -> Prepared:
    """Mesh, element matrices, masses, penalty and stable step for designs of one topology."""
    spec = mesh_spec(preset)
    meshes = [build_mesh(s, spec) for s in scenes]
    m0 = meshes[0]
    for i, m in enumerate(meshes[1:], 1):
        if m.cells.shape != m0.cells.shape or not np.array_equal(m.cells, m0.cells):
            raise ValueError(f"solver: design {i} has a different mesh topology than design 0")
    axi = scenes[0].analysis == "axisymmetric"
    n = m0.n_nodes
    slots, avg_w = _node_slots(m0.cells, n, m0.cell_part, m0.node_part)
    free = (~m0.fixed).astype(float)
    free_dofs = np.flatnonzero(free.ravel() > 0)
    slaves = m0.ball_surface
    masters = m0.panel_top[np.argsort(m0.points[m0.panel_top, 0])]
    top = scenes[0].layers[0]
    ball = scenes[0].ball
    e_soft = min(top.youngs / (1 - top.poisson**2), ball.youngs / (1 - ball.poisson**2))
    out = {k: [] for k in ("points", "ke", "db", "mass", "k_slave", "w2m", "w2c", "w2t")}
    for scene, m in zip(scenes, meshes):
        youngs, poisson, density = _material_arrays(scene, m.cell_part)
        ke, me, db = fem.element_matrices(m.points, m.cells, youngs, poisson, density,
                                          analysis=scene.analysis)
        mass = np.zeros(n)
        np.add.at(mass, m.cells, me)
        k_glob = fem.assemble_csr(m.cells, ke, n)
        minv = 1.0 / np.sqrt(np.repeat(mass, 2)[free_dofs])
        w2m = _largest_omega2(k_glob, minv, free_dofs)
        xm = m.points[masters, 0]
        h = float(xm[1] - xm[0])
        k_p = settings.penalty_factor * e_soft / h
        k_s = k_p * _tributary(m.points[slaves, 0], axi)
        # contact bound: each slave spring on its own node, and the springs a master can see
        ksum = np.zeros(len(masters))
        xs = m.points[slaves, 0]
        j = np.clip(np.searchsorted(xm, xs) - 1, 0, len(masters) - 2)
        t = np.clip((xs - xm[j]) / (xm[j + 1] - xm[j]), 0.0, 1.0)
        np.add.at(ksum, j, k_s * (1 - t))
        np.add.at(ksum, j + 1, k_s * t)
        # Gershgorin bound of M^-1 K_contact (rows of slaves and of masters); Weyl's inequality
        # then bounds the coupled system by w_mesh^2 + w_c^2, which sets the step.
        w2c = 2.0 * max(float(np.max(k_s / mass[slaves])), float(np.max(ksum / mass[masters])))
        # Reported, not used for the step: the largest eigenvalue of M^-1 (K + K_c) with every
        # spring engaged at the reference slave positions. It is only ~9 % above w_mesh^2 (the
        # Weyl bound is 60-70 % above), but a step from it (safety 0.9) let a batch run of the
        # 150/150 um design gain 1.4 % energy near separation (frame 85, cpu mesh): the sliding,
        # deformed contact is stiffer than this linearisation, and the Weyl bound's margin holds.
        w2t = _largest_omega2(k_glob + _contact_stiffness(slaves, masters, j, t, k_s, n), minv,
                              free_dofs)
        for key, val in (("points", m.points), ("ke", ke), ("db", db), ("mass", mass),
                         ("k_slave", k_s), ("w2m", w2m), ("w2c", w2c), ("w2t", w2t)):
            out[key].append(val)
    w2m, w2c, w2t = (np.asarray(out[k]) for k in ("w2m", "w2c", "w2t"))
    dt = settings.safety * 2.0 / float(np.sqrt(np.max(w2m + w2c)))
    return Prepared(mesh=m0, points=np.stack(out["points"]), ke=np.stack(out["ke"]),
                    db=np.stack(out["db"]), mass=np.stack(out["mass"]),
                    k_slave=np.stack(out["k_slave"]), slaves=slaves, masters=masters,
                    node_slots=slots, avg_weight=avg_w, free=free, omega2_mesh=w2m,
                    omega2_contact=w2c, omega2_coupled=w2t, dt_stable=dt)


# ---------------------------------------------------------------------------------------------
# jittable physics
# ---------------------------------------------------------------------------------------------
# Layout: node arrays are (2, B, N): component, design, node in mesh order (contiguous), so the
# stiffness is applied as shifted slices (pcmgn_jax.sim.stencil) that vectorise over nodes, and
# the coefficients of rows that do not depend on the design (ball, layers away from the design
# layers) are read once for the whole batch. A substep is a handful of fused XLA kernels: on CPU
# each kernel launch costs about a microsecond, as much as the arithmetic of a few hundred nodes.
def contact_energy(us, um, ref_s, ref_m, k_slave):
    """Penalty energy [J] per design, 0.5 * sum_s k_s min(g_s, 0)^2, g_s = vertical gap of slave
    s above the deformed master polyline at the slave's deformed x.

    us (2,B,S), um (2,B,M) [m]: slave / master displacements; ref_s, ref_m their reference
    coordinates [m] (same shapes); k_slave (B,S) [N/m]; masters sorted by x. Returns (B,).
    Differences of reference coordinates are taken before adding displacements, so float32
    keeps sub-um gaps. The master segment of each slave is found by counting the masters to its
    left over all pairs (S x M is ~50 x 50): one fused kernel, where searchsorted is a loop."""
    x_first, y_first = ref_m[0, :, :1], ref_m[1, :, :1]
    # master x positions relative to the first master (monotone in the deformed state)
    xm = (ref_m[0] - x_first) + um[0]                               # (B,M)
    xs = (ref_s[0] - x_first) + us[0]                               # (B,S)
    ym = (ref_m[1] - y_first) + um[1]
    ys = (ref_s[1] - y_first) + us[1]
    j = jnp.clip(jnp.sum(xm[:, None, :] < xs[:, :, None], axis=-1) - 1, 0, xm.shape[-1] - 2)

    def at(a, i):
        return jnp.take_along_axis(a, i, axis=-1)

    x0, x1, y0, y1 = at(xm, j), at(xm, j + 1), at(ym, j), at(ym, j + 1)
    t = (xs - x0) / (x1 - x0)
    pen = jnp.minimum(ys - (y0 + t * (y1 - y0)), 0.0)
    return 0.5 * jnp.sum(k_slave * pen * pen, axis=-1)


def _frame_stress(u, db, cells, node_slots, avg_weight, rigid_x: bool):
    """Nodal von Mises [Pa] (N,) from centroid stresses averaged over the node's own part.
    u (N,2) [m] of one design; the element mean vertical (and horizontal if ``rigid_x``)
    displacement is removed first, for the float32 reason given in :func:`stencil.apply`."""
    ue = u[cells]  # (E,4,2)
    ue = ue - ue.mean(axis=1, keepdims=True) * jnp.asarray([1.0 if rigid_x else 0.0, 1.0], u.dtype)
    sig = jnp.einsum("ekj,ej->ek", db, ue.reshape(cells.shape[0], 8))
    vm = fem.von_mises(sig)
    slots = jnp.concatenate([jnp.repeat(vm, 4), jnp.zeros((1,), vm.dtype)])
    return (slots[node_slots] * avg_weight).sum(axis=1)


@partial(jax.jit, static_argnames=("layout", "n_frames", "n_sub", "rigid_x"))
def _run(arrays: dict[str, Any], u0, v0, dt, *, layout: stencil.SliceLayout, n_frames: int,
         n_sub: int, rigid_x: bool):
    """A batch of B designs of one topology (see :func:`_device_arrays`).

    u0, v0 (2,B,N) [m, m/s]; dt (B,) [s]. Returns u, v (B,T,N,2), von Mises (B,T,N) [Pa],
    energies (B,T,3) [J] and per-substep histories (force, approach), each (B,T-1,n_sub)."""
    mass = arrays["mass"]                                           # (1,B,N) [kg]
    ball_w = arrays["ball_weight"]                                  # (B,N)
    slaves, masters = arrays["slaves"], arrays["masters"]
    ref_s, ref_m = arrays["points"][..., slaves], arrays["points"][..., masters]  # (2,B,S), (2,B,M)
    contact_rows = jnp.concatenate([slaves, masters])
    contact_scale = arrays["contact_scale"]                         # (2,B,S+M) -free/m [1/kg]
    dt_ = dt[:, None]

    def contact(u):
        """Contact energy (B,) [J], its gradient at [slaves, masters] (2,B,S+M) [N], and the
        contact force on the ball (B,) [N]."""
        us, um = u[..., slaves], u[..., masters]
        ec, pullback = jax.vjp(lambda a, b: contact_energy(a, b, ref_s, ref_m, arrays["k_slave"]),
                               us, um)
        gs, gm = pullback(jnp.ones_like(ec))  # designs are independent: per-design gradients
        return ec, jnp.concatenate([gs, gm], axis=-1), -jnp.sum(gs[1], axis=-1)

    # The ball's rigid vertical motion (~1e-5 m) lives in its own scalar state c (velocity vc);
    # the node state w holds everything else. Kept in one float32 array, the rigid drop would
    # round the ball's ~1e-9 m elastic differences away step after step (stress noise ~1 MPa).
    ball_y = jnp.stack([jnp.zeros_like(ball_w[:1]), (ball_w[:1] > 0).astype(ball_w.dtype)])  # (2,1,N)
    ball_mass = jnp.sum(mass[0] * ball_y[1], axis=-1)               # (B,) [kg]
    inv_ball_mass = jnp.where(ball_mass > 0, 1.0 / jnp.where(ball_mass > 0, ball_mass, 1.0), 0.0)

    def accel(w, c):
        """Accelerations of w (ball mean removed) and of c (B,); contact energy (B,) [J] and
        the contact force on the ball (B,) [N]."""
        ec, gc, force = contact(w + c[:, None] * ball_y)
        # -M^-1 (K w + contact gradient): the stencil rows are scaled by -1/m (zero on fixed
        # dofs), the contact gradient is added in the stencil's remainder scatter
        a = stencil.apply(w, arrays["stencil"], layout, rigid_x=rigid_x, extra_rows=contact_rows,
                          extra=gc * contact_scale)
        # the ball's mean acceleration is the contact force over its mass: its internal forces
        # sum to zero (K annihilates a vertical translation of the free ball), so the
        # mass-weighted mean of a[1] over the ball is this, without a reduction over N
        abar = force * inv_ball_mass
        return a - abar[:, None] * ball_y, abar, ec, force

    def substep(carry, _):
        w, vh, c, vch = carry
        a, abar, _, force = accel(w, c)
        # both updates read (w, vh, a) only, so XLA fuses them into one pass
        vh1 = vh + dt_ * a
        w1 = w + dt_ * (vh + dt_ * a)
        vch1 = vch + dt * abar
        # the ball-weighted mean of w_y is zero (removed from the initial state and from every
        # acceleration; up to float32 round-off of the ball's internal-force sum), so c is the
        # mass-weighted ball displacement [m]
        return (w1, vh1, c + dt * vch1, vch1), (force, c)

    def record(w, vh, c, vch):
        a, abar, ec, _ = accel(w, c)
        a_int = stencil.apply(w, arrays["stencil"], layout, rigid_x=rigid_x)  # -M^-1 K w
        v = vh + 0.5 * dt_ * a + (vch + 0.5 * dt * abar)[:, None] * ball_y
        vfull = vh + vch[:, None] * ball_y
        # leapfrog's discrete kinetic energy 0.5 v_{n-1/2} M v_{n+1/2}: with the potential
        # energy at u_n it is conserved exactly for linear forces (the average-velocity
        # kinetic energy is not, by O(w^2 dt^2) of the high-frequency content)
        ke_ = 0.5 * jnp.sum(mass * vfull * (vfull + dt_ * (a + abar[:, None] * ball_y)), axis=(0, 2))
        ie = -0.5 * jnp.sum(mass * w * a_int, axis=(0, 2))         # 0.5 w.K w (w = 0 if fixed)
        return w + c[:, None] * ball_y, v, jnp.stack([ke_, ie, ec], axis=-1)

    def frame(carry, _):
        u, v, energy = record(*carry)
        ws = carry[0]
        carry, hist = jax.lax.scan(substep, carry, None, length=n_sub)
        return carry, (u, v, energy, ws, hist)

    c0 = jnp.sum(ball_w * u0[1], axis=-1)
    vc0 = jnp.sum(ball_w * v0[1], axis=-1)
    w0, vw0 = u0 - c0[:, None] * ball_y, v0 - vc0[:, None] * ball_y
    a0, abar0, _, _ = accel(w0, c0)
    init = (w0, vw0 - 0.5 * dt_ * a0, c0, vc0 - 0.5 * dt * abar0)
    carry, (us, vs, es, ws, hist) = jax.lax.scan(frame, init, None, length=n_frames)
    u_last, v_last, e_last = record(*carry)
    us = jnp.concatenate([us, u_last[None]], axis=0)               # (T,2,B,N)
    vs = jnp.concatenate([vs, v_last[None]], axis=0)
    es = jnp.concatenate([es, e_last[None]], axis=0)               # (T,B,3)
    ws = jnp.concatenate([ws, carry[0][None]], axis=0)
    stress = partial(_frame_stress, cells=arrays["cells"], node_slots=arrays["node_slots"],
                     avg_weight=arrays["avg_weight"], rigid_x=rigid_x)
    vm = jax.vmap(jax.vmap(lambda w, db: stress(w.T, db), in_axes=(0, None)),
                  in_axes=(2, 0))(ws, arrays["db"])                 # (B,T,N)
    force, approach = (jnp.moveaxis(h, -1, 0) for h in hist)        # (B,T-1,n_sub)
    return (jnp.transpose(us, (2, 0, 3, 1)), jnp.transpose(vs, (2, 0, 3, 1)), vm,
            jnp.moveaxis(es, 1, 0), (force, approach))


# the batched entry point (kept as a name: callers and tests check its compilation cache)
_run_batch = _run


def _device_arrays(*, points, cells, ke, db, mass, free, ball_weight, slaves, masters, k_slave,
                   node_slots, avg_weight, shared_rows, dtype):
    """Host arrays of B designs of one topology (leading axis B, (N,...) node arrays) -> the
    device arrays of :func:`_run` ((2,B,N) node layout) and the static stencil layout.

    ``shared_rows`` (N,) bool marks nodes whose stiffness rows and masses should be the same
    for every design of the batch; checked here, and if any differs all rows are taken per
    design."""
    n = points.shape[1]
    neighbours, blocks = fem.node_stencil(cells, ke, n)            # (N,W), (B,W,2,2,N)
    # rows scaled by -1/m and zeroed on fixed dofs: the stencil gives accelerations -M^-1 K w
    blocks = blocks * (-np.moveaxis(free, -1, 0)[None, None, :, None, :] / mass[:, None, None, None, :])
    shared = np.asarray(shared_rows, bool)
    scale = np.abs(blocks).max()
    if not np.all(np.abs(blocks[..., shared] - blocks[:1, ..., shared]) <= 1e-9 * scale):
        shared = np.zeros(n, bool)
    layout, coefs = stencil.build(neighbours, blocks, shared)
    rows = np.concatenate([slaves, masters])
    host = {"stencil": coefs, "mass": mass[None], "ball_weight": ball_weight,
            "contact_scale": -np.moveaxis(free[rows], -1, 0)[:, None] / mass[None][..., rows],
            "points": np.moveaxis(points, -1, 0), "slaves": slaves, "masters": masters,
            "k_slave": k_slave, "cells": cells, "node_slots": node_slots,
            "avg_weight": avg_weight, "db": db}
    arrays = jax.tree.map(lambda v: jnp.asarray(v, dtype=dtype if np.asarray(v).dtype.kind == "f"
                                                else jnp.int32), host)
    return arrays, layout


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


def simulate(scenes: Sequence[Scene], preset: str | MeshSpec = "cpu", *,
             settings: SolverSettings = SolverSettings(), n_frames: int | None = None,
             output_dt: float | None = None) -> RunResult:
    """Run a batch of designs (same topology) and check energy; raises SolverError."""
    if not scenes:
        raise ValueError("simulate: no scenes given")
    base = scenes[0]
    n_frames = base.n_frames if n_frames is None else n_frames
    output_dt = base.output_dt if output_dt is None else output_dt
    prep = prepare(scenes, preset, settings)
    n_sub = max(1, math.ceil(output_dt / prep.dt_stable))
    dt = output_dt / n_sub
    dtype = jnp.dtype(settings.dtype)
    if dtype == jnp.float64 and not jax.config.read("jax_enable_x64"):
        raise ValueError("simulate: dtype float64 needs `with jax.enable_x64(True):`")
    m0 = prep.mesh
    b = len(scenes)
    is_ball = (m0.node_part == 0).astype(float)
    ball_w = prep.mass * is_ball[None] / np.sum(prep.mass * is_ball[None], axis=1, keepdims=True)
    # stiffness rows of nodes touching no design-layer element are the same for every design
    # (the layers above only translate), so the batch reads them once
    design_parts = [m0.part_names.index(name) for name in base.design_layers]
    shared_rows = np.ones(m0.n_nodes, bool)
    shared_rows[m0.cells[np.isin(m0.cell_part, design_parts)].ravel()] = False
    if settings.designs_per_call < 0:
        raise ValueError(f"simulate: designs_per_call must be >= 0, got {settings.designs_per_call}")
    per_call = settings.designs_per_call or (1 if jax.default_backend() == "cpu" else b)
    v0 = np.zeros((2, b, m0.n_nodes))
    v0[1][:, m0.node_part == 0] = -np.array([s.ball.velocity for s in scenes])[:, None]
    outs, wall = [], 0.0
    for lo in range(0, b, per_call):
        part = slice(lo, min(lo + per_call, b))
        arrays, layout = _device_arrays(
            points=prep.points[part], cells=m0.cells, ke=prep.ke[part], db=prep.db[part],
            mass=prep.mass[part], free=prep.free, ball_weight=ball_w[part], slaves=prep.slaves,
            masters=prep.masters, k_slave=prep.k_slave[part], node_slots=prep.node_slots,
            avg_weight=prep.avg_weight, shared_rows=shared_rows, dtype=dtype)
        nb = part.stop - part.start
        t0 = time.perf_counter()
        outs.append(jax.block_until_ready(
            _run(arrays, jnp.zeros((2, nb, m0.n_nodes), dtype), jnp.asarray(v0[:, part], dtype),
                 jnp.full((nb,), dt, dtype), layout=layout, n_frames=n_frames, n_sub=n_sub,
                 rigid_x=base.analysis == "plane_strain")))
        wall += time.perf_counter() - t0
    # each call returns u, v, von Mises, energy, (force, approach) with the designs leading
    us, vs, vm, es, force, approach = (
        np.concatenate([np.asarray(x) for x in per_output])
        for per_output in zip(*[(u, v, m, e, f, a) for u, v, m, e, (f, a) in outs]))
    us, vs, vm, es = (np.asarray(x, np.float64) for x in (us, vs, vm, es))
    ke0 = es[:, 0, 0]
    total = es.sum(axis=2)
    err = np.abs(total - total[:, :1]) / ke0[:, None]
    for i in range(b):
        bad = ~np.isfinite(us[i]).all(axis=(1, 2)) | ~np.isfinite(vs[i]).all(axis=(1, 2)) | \
            ~np.isfinite(err[i])
        if bad.any():
            raise SolverError(f"design {i} {scenes[i].design}: non-finite values at frame "
                              f"{int(np.argmax(bad))} (t = {np.argmax(bad) * output_dt:.3e} s)")
        over = err[i] > settings.energy_tol
        if over.any():
            f = int(np.argmax(over))
            raise SolverError(
                f"design {i} {scenes[i].design}: energy error {err[i, f]:.3%} of the initial "
                f"kinetic energy exceeds {settings.energy_tol:.1%} at frame {f} "
                f"(t = {f * output_dt:.3e} s); dt = {dt:.3e} s")
    return RunResult(prepared=prep, u=us, v=vs, von_mises=vm, energy=es,
                     force=np.asarray(force, np.float64), approach=np.asarray(approach, np.float64),
                     dt=dt, n_sub=n_sub, wall_time_s=wall, energy_error=err.max(axis=1))


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
                    settings: SolverSettings = SolverSettings(), crop: bool = True) -> list[Trajectory]:
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


def solve_designs(scene: Scene, designs: np.ndarray, *, preset: str | MeshSpec = "cpu",
                  settings: SolverSettings = SolverSettings()) -> list[Trajectory]:
    """Simulate designs (B, n_design) [m] of ``scene`` in one batched call; ROI-cropped
    Trajectories with meta (source 'solver', design, solver settings, energy, wall time)."""
    designs = np.atleast_2d(np.asarray(designs, float))
    scenes = [scene.with_design(*d) for d in designs]
    result = simulate(scenes, preset, settings=settings)
    return to_trajectories(result, scenes, preset, settings=settings)
