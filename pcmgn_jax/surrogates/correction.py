"""The arithmetic of a baseline-corrected rollout (``residual_of``, docs/design.md §5.2) and of a rollout's contact.

    train_r = residual_trajectories(train, us, vms)      # the fields minus a baseline's: what a residual run learns
    u, vm = corrected(trajs, res_u, res_vm, us, vms)     # the inverse, for predictions
    bu, bv = ball_path(traj, u, dt)                      # the rigid ball's path in a baseline's displacement
    u = rigid_contact(traj, u)                           # the rollout's hard contact on any prediction

Used by the MGN adapter (:mod:`pcmgn_jax.surrogates.mgn`), the ``rom_contact`` kind (:mod:`rom`) and the
residual targets of training (:mod:`residual`); it fits nothing.
"""
from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np

from pcmgn_jax.mgn.checkpoint import contact_index_for
from pcmgn_jax.mgn.formulation import axial, is_ball
from pcmgn_jax.mgn.rollout import project_frames
from pcmgn_jax.scene import Scene


def _check(trajs, us, vms, what: str):
    if not (len(trajs) == len(us) == len(vms)):
        raise ValueError(f"{what}: {len(trajs)} trajectories but {len(us)} / {len(vms)} baseline fields")
    for t, u, vm in zip(trajs, us, vms):
        if np.shape(u) != t.displacement.shape or np.shape(vm) != t.von_mises.shape:
            raise ValueError(f"{what}: {t.meta.get('name', 'a trajectory')}: baseline fields {np.shape(u)} / "
                             f"{np.shape(vm)} do not match its {t.displacement.shape} / {t.von_mises.shape}")


def residual_trajectories(trajs: Sequence, us: Sequence, vms: Sequence) -> list:
    """``trajs`` with the panel's displacement and every node's von Mises minus the baseline's ``us`` /
    ``vms`` (same shapes): the targets of a ``residual_of`` run. The ball's rows, the velocities and the
    meta are unchanged (module docstring); ``meta['residual_of_baseline']`` marks the copy."""
    _check(trajs, us, vms, "residual_trajectories")
    out = []
    for t, u, vm in zip(trajs, us, vms):
        panel = ~is_ball(t.node_type)[None, :, None]
        d = np.where(panel, t.displacement - np.asarray(u, t.displacement.dtype), t.displacement)
        out.append(dataclasses.replace(t, displacement=d, von_mises=t.von_mises - np.asarray(vm, t.von_mises.dtype),
                                       meta={**t.meta, "residual_of_baseline": True}))
    return out


def _ball_mean(u, ball) -> np.ndarray:
    """The ball nodes' (``ball`` (N,) bool) mean displacement (T, 2) [m] of ``u`` (T, N, 2), x = 0 on the
    symmetry axis (:func:`pcmgn_jax.mgn.formulation.axial`): a field's rigid-ball motion, frame by frame."""
    return axial(np.asarray(u, np.float64)[:, ball].mean(axis=1))


def ball_path(traj, u, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The rigid ball's path in a baseline's displacement ``u`` (T, N, 2) [m] on ``traj``'s mesh: its
    ball nodes' mean vertical displacement at frames 1..T-1 and the frame-averaged velocity
    (u_t - u_{t-1}) / dt [m/s] (the model's velocity input), each (T-1, N, 2) on every node (a rollout
    uses the ball's rows: :func:`pcmgn_jax.mgn.rollout.rollout_designs` ``ball_u`` / ``ball_v``)."""
    ball = is_ball(traj.node_type)
    if not ball.any():
        raise ValueError(f"ball_path: {traj.meta.get('name', 'the trajectory')} has no ball nodes")
    mean = _ball_mean(u, ball)                                              # (T, 2), x = 0 on the axis
    shape = (mean.shape[0] - 1, traj.n_nodes, 2)
    return (np.broadcast_to(mean[1:, None], shape).astype(np.float32),
            np.broadcast_to((np.diff(mean, axis=0) / dt)[:, None], shape).astype(np.float32))


def rigid_contact(traj, u) -> np.ndarray:
    """A displacement prediction ``u`` (T, N, 2) [m] on ``traj``'s mesh made to respect the contact the
    way an MGN rollout does: the ball's rows at their mean vertical motion (one rigid body on the axis)
    and the cover glass's top nodes inside the ball moved down onto its lower surface
    (:func:`pcmgn_jax.mgn.rollout.project_frames`). Used for the baseline-corrected rollouts and for the
    ``rom_contact`` baseline (the rom with the same hard constraint: what the network adds beyond it)."""
    u = np.array(u, np.float64)
    ball = is_ball(traj.node_type)
    if ball.any():
        u[:, ball] = _ball_mean(u, ball)[:, None]
    # the projection reads only which nodes can touch (radius and buffer size do not enter it)
    index = contact_index_for(traj, Scene.from_dict(traj.meta["scene"]), radius=1e-12, capacity=2)
    return project_frames(index, traj.points, u)


def corrected(trajs: Sequence, res_u, res_vm, us: Sequence, vms: Sequence) -> tuple[list, list]:
    """The inverse of :func:`residual_trajectories` for predictions: per trajectory the rolled-out
    residual (T, N, 2) [m] / (T, N) [Pa] plus the baseline's fields, the ball's rows as rolled out."""
    res_u, res_vm = list(res_u), list(res_vm)
    _check(trajs, us, vms, "corrected")
    u_out, vm_out = [], []
    for t, ru, rv, u, vm in zip(trajs, res_u, res_vm, us, vms):
        panel = ~is_ball(t.node_type)[None, :, None]
        u_out.append(np.where(panel, np.asarray(ru, np.float64) + u, ru))
        vm_out.append(np.asarray(rv, np.float64) + vm)
    return u_out, vm_out
