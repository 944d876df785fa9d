"""``residual_of``: the MGN as a learned correction of a baseline's fields (docs/design.md §5.2).

    base = fit_baseline("rom", train)                         # the run's baseline, fitted on its training split
    train_r = residual_trajectories(train, *out_of_fold_fields("rom", train))   # what training sees
    u, vm = corrected(trajs, res_u, res_vm, *base.predict_trajectories(trajs))  # what a rollout reports

With :attr:`TrainConfig.residual_of <pcmgn_jax.config.TrainConfig>` = ``rom`` the network is trained on,
and rolls out, the part of the fields the baseline gets wrong:

- **targets**: the panel's displacement [m] and every node's von Mises stress [Pa] minus the baseline's at
  the same frame. The ball's displacement stays the truth: the rigid ball is the rollout's one dynamical
  state (its contact with the reference cover glass drives it), not a field the baseline predicts.
- **out of fold**: a baseline reproduces the scenes it was fitted on (a POD of 22 snapshots holds each of
  them), so its residual on its own training scenes is ~0 and teaches nothing. Each training scene's
  baseline fields come from a baseline fitted without it (leave-one-out by default, ``folds``): the
  residuals are the ones the final baseline makes on scenes it has not seen. Validation scenes get the
  baseline fitted on the whole training split, as the test scenes do.
- **normalisation**: the per-part statistics are the residuals' own, so a 0.3 µm correction is O(1).
- **rollout**: the network's panel output plus the baseline's fields at the same frame (the baseline
  fitted on the whole training split). The rigid ball follows the baseline's ball trajectory
  (:func:`ball_path`; ``residual_ball='baseline'``, the default) and the network's panel map is read along
  it, or moves by the network's own acceleration (``residual_ball='network'``). The contact projection, when the formulation has it, acts on that
  sum, not inside the scan (:attr:`TrainConfig.scan_formulation <pcmgn_jax.config.TrainConfig>`).

The network sees what it always sees (geometry, scene features, the ball's state), not the baseline's
field: it learns the baseline's error as a function of the scene. Where the correction has nothing to
say it should output ~0 and the result is the baseline's; how close it stays to that is measured, not
assumed (docs/results/tasks.md).
"""
from __future__ import annotations

import dataclasses
import warnings
from typing import Sequence

import numpy as np

from pcmgn_jax.eval.response_surfaces import ExtrapolationWarning
from pcmgn_jax.mgn.formulation import axial, is_ball


def fit_baseline(kind: str, train_trajs: Sequence):
    """The baseline ``kind`` fitted on ``train_trajs``: an object with ``predict_trajectories(trajs)`` ->
    (u list of (T, N, 2) [m], vm list of (T, N) [Pa]), each on the query's own mesh."""
    if kind == "rom":
        from pcmgn_jax.eval.rom import Rom
        return Rom(train_trajs)
    raise ValueError(f"residual_of={kind!r}: no such baseline (choose rom)")


def out_of_fold_fields(kind: str, trajs: Sequence, *, folds: int = 0) -> tuple[list, list]:
    """Per trajectory, the baseline's fields from a baseline fitted on the other folds: (u, vm) lists as
    :func:`fit_baseline`'s ``predict_trajectories``. ``folds``: 0 = leave one out; else trajectory i is in
    fold i % folds. Deterministic (no shuffling)."""
    trajs = list(trajs)
    k = len(trajs) if folds <= 0 else min(folds, len(trajs))
    if k < 2:
        raise ValueError(f"residual_of={kind!r}: out-of-fold fields need at least 2 training trajectories, got "
                         f"{len(trajs)}")
    us, vms = [None] * len(trajs), [None] * len(trajs)
    outside = 0
    for f in range(k):
        held = [i for i in range(len(trajs)) if i % k == f]
        base = fit_baseline(kind, [t for i, t in enumerate(trajs) if i % k != f])
        with warnings.catch_warnings():  # a held-out corner scene is outside its fold's box by construction
            warnings.simplefilter("ignore", ExtrapolationWarning)
            u, vm = base.predict_trajectories([trajs[i] for i in held])
        outside += len(base.warnings)
        for i, a, b in zip(held, u, vm):
            us[i], vms[i] = a, b
    if outside:
        print(f"residual_of={kind}: {outside} out-of-fold queries fell outside their fold's parameter box "
              "(extrapolated, as the final baseline does outside the training box)", flush=True)
    return us, vms


def residual_splits(kind: str, train: Sequence, val: Sequence, *, folds: int = 0) -> tuple[list, list]:
    """What a ``residual_of`` run trains and validates on: the training trajectories minus their
    out-of-fold baseline fields, the validation ones minus the baseline fitted on all of ``train``."""
    train, val = list(train), list(val)
    print(f"residual_of={kind}: the network learns the {kind} baseline's residual; out-of-fold {kind} fields for "
          f"{len(train)} training trajectories ({'leave one out' if folds <= 0 else f'{folds} folds'})", flush=True)
    train_r = residual_trajectories(train, *out_of_fold_fields(kind, train, folds=folds))
    val_r = residual_trajectories(val, *fit_baseline(kind, train).predict_trajectories(val)) if val else []
    return train_r, val_r


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
    from pcmgn_jax.mgn.checkpoint import contact_index_for
    from pcmgn_jax.mgn.rollout import project_frames
    from pcmgn_jax.scene import Scene
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
