"""The jitted explicit integration of a batch of designs of one topology (JAX).

:func:`_run` is one ``lax.scan`` (frames) over a ``lax.scan`` (substeps) of central differences,
no host sync inside; :func:`_device_arrays` turns the host arrays of :mod:`pcmgn_jax.sim.prepare`
into its device arrays and static stencil layout; :func:`contact_energy` is the penalty energy
whose gradient gives the contact forces.
"""
from __future__ import annotations

from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from pcmgn_jax.sim import fem, stencil


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


@partial(jax.jit, static_argnames=("layout", "n_frames", "n_sub", "rigid_x", "remat"))
def _run(arrays: dict[str, Any], u0, v0, dt, *, layout: stencil.SliceLayout, n_frames: int,
         n_sub: int, rigid_x: bool, remat: bool = False):
    """A batch of B designs of one topology (see :func:`_device_arrays`).

    u0, v0 (2,B,N) [m, m/s]; dt (B,) [s]. Returns u, v (B,T,N,2), von Mises (B,T,N) [Pa],
    energies (B,T,3) [J] and per-substep histories (force, approach), each (B,T-1,n_sub).
    ``remat``: for reverse-mode derivatives (:mod:`pcmgn_jax.sim.differentiable`; ``arrays`` then also hold
    "stencil_sym" and "row_scale", :func:`node_arrays`): each frame is a ``jax.checkpoint`` (the backward
    pass keeps the frames' states and re-integrates one frame at a time, so memory grows with frames +
    substeps per frame, not their product), and the stiffness product has a hand-written reverse pass
    (:func:`stencil.apply_symmetric`)."""
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
        if remat:
            a = stencil.apply_symmetric(w, arrays["stencil"], arrays["stencil_sym"], arrays["row_scale"],
                                        layout=layout, rigid_x=rigid_x, extra_rows=contact_rows,
                                        extra=gc * contact_scale)
        else:
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
    carry, (us, vs, es, ws, hist) = jax.lax.scan(jax.checkpoint(frame) if remat else frame, init, None,
                                                 length=n_frames)
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


def node_arrays(*, coefs, mass, free, ball_weight, slaves, masters, points, k_slave, cells, node_slots,
                avg_weight, db, sym_coefs=None):
    """The arrays of :func:`_run` (their layout: (2,B,N) node arrays) from B designs' stencil coefficients
    (:func:`stencil.build` of :func:`scaled_blocks`), masses (B,N) [kg], free-dof mask (N,2), ball weights
    (B,N), contact node ids, points (B,N,2) [m], penalties (B,S) [N/m] and the stress operator (B,E,4,8)
    [Pa/m]; NumPy or jax. ``sym_coefs``: the same layout's coefficients of K itself (unscaled), for
    ``_run(remat=True)``: they and the row scale -free/m (2,B,N) [1/kg] give the reverse pass."""
    xp = fem.array_module(mass)
    rows = np.concatenate([slaves, masters])
    row_scale = -np.moveaxis(free, -1, 0)[:, None] / mass[None]
    out = {"stencil": coefs, "mass": mass[None], "ball_weight": ball_weight, "contact_scale": row_scale[..., rows],
           "points": xp.moveaxis(points, -1, 0), "slaves": slaves, "masters": masters,
           "k_slave": k_slave, "cells": cells, "node_slots": node_slots,
           "avg_weight": avg_weight, "db": db}
    if sym_coefs is not None:
        out.update(stencil_sym=sym_coefs, row_scale=row_scale)
    return out


def scaled_blocks(blocks, free, mass):
    """Stencil blocks (B,W,2,2,N) [N/m] -> rows scaled by -1/m [1/kg] and zeroed on fixed dofs (free (N,2)):
    the stencil then gives accelerations -M^-1 K w. NumPy or jax."""
    return blocks * (-np.moveaxis(free, -1, 0)[None, None, :, None, :] / mass[:, None, None, None, :])


def ball_weights(mass, node_part):
    """(B,N) the ball's nodes' mass fractions (zero off the ball) from masses (B,N) [kg]; NumPy or jax."""
    is_ball = (np.asarray(node_part) == 0).astype(float)
    m = mass * is_ball[None]
    return m / m.sum(axis=1, keepdims=True)


def _device_arrays(*, points, cells, ke, db, mass, free, ball_weight, slaves, masters, k_slave,
                   node_slots, avg_weight, shared_rows, dtype):
    """Host arrays of B designs of one topology (leading axis B, (N,...) node arrays) -> the
    device arrays of :func:`_run` ((2,B,N) node layout) and the static stencil layout.

    ``shared_rows`` (N,) bool marks nodes whose stiffness rows and masses should be the same
    for every design of the batch; checked here, and if any differs all rows are taken per
    design."""
    n = points.shape[1]
    neighbours, blocks = fem.node_stencil(cells, ke, n)            # (N,W), (B,W,2,2,N)
    blocks = scaled_blocks(blocks, free, mass)
    shared = np.asarray(shared_rows, bool)
    scale = np.abs(blocks).max()
    if not np.all(np.abs(blocks[..., shared] - blocks[:1, ..., shared]) <= 1e-9 * scale):
        shared = np.zeros(n, bool)
    layout, coefs = stencil.build(neighbours, blocks, shared)
    host = node_arrays(coefs=coefs, mass=mass, free=free, ball_weight=ball_weight, slaves=slaves, masters=masters,
                       points=points, k_slave=k_slave, cells=cells, node_slots=node_slots, avg_weight=avg_weight,
                       db=db)
    arrays = jax.tree.map(lambda v: jnp.asarray(v, dtype=dtype if np.asarray(v).dtype.kind == "f"
                                                else jnp.int32), host)
    return arrays, layout
