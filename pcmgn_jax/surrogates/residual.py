"""``residual_of``: the MGN as a learned correction of a baseline's fields (docs/design.md §5.2).

    base = fit("rom", train)                                  # the run's baseline (registry.fit), on its training split
    train_r = residual_trajectories(train, *out_of_fold_fields("rom", train))   # what training sees
    u, vm = corrected(trajs, res_u, res_vm, *base.predict_trajectories(trajs))  # what a rollout reports

(:func:`residual_trajectories`, :func:`corrected`, :func:`ball_path` and :func:`rigid_contact` are
:mod:`pcmgn_jax.surrogates.correction`; the bases a run can name are the kinds with ``residual_base``,
:data:`pcmgn_jax.surrogates.kinds.KINDS`.)

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
  it, or moves by the network's own acceleration (``residual_ball='network'``). The contact projection, when the
  formulation has it, acts on that sum, not inside the scan
  (:attr:`TrainConfig.scan_formulation <pcmgn_jax.config.TrainConfig>`).

The network sees what it always sees (geometry, scene features, the ball's state), not the baseline's
field: it learns the baseline's error as a function of the scene. Where the correction has nothing to
say it should output ~0 and the result is the baseline's; how close it stays to that is measured, not
assumed (docs/results/tasks.md).
"""
from __future__ import annotations

import warnings
from typing import Sequence

from pcmgn_jax.surrogates.correction import residual_trajectories
from pcmgn_jax.surrogates.kinds import names
from pcmgn_jax.surrogates.registry import fit
from pcmgn_jax.surrogates.surface_fit import ExtrapolationWarning


def fit_baseline(kind: str, train_trajs: Sequence):
    """The baseline ``kind`` (a kind with ``residual_base``) fitted on ``train_trajs`` (:func:`registry.fit`):
    ``predict_trajectories(trajs)`` -> (u list of (T, N, 2) [m], vm list of (T, N) [Pa]), each on its mesh."""
    if kind not in names(residual_base=True):
        raise ValueError(f"residual_of={kind!r}: no such baseline (choose one of {names(residual_base=True)})")
    return fit(kind, train_trajs)


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
