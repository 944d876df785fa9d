"""The explorer's predictors: each kind fitted through the registry, and its answer at one design.

    model = fit_predictor("kriging", train, reading="area_mean", part=3, shared=True)
    p = predict_one("kriging", model, q, reading="area_mean", part=3)      # a Prediction on q's mesh

Every kind is fitted for its objective (:func:`pcmgn_jax.surrogates.registry.fit_objective` on the run's training
split), for the explorer's reading only; a response surface's field surface is fitted on one shared mesh
for the kind with a posterior std only (kriging: MOP's leave-one-out over a whole field is too slow to wait for).
A response surface (``objective_surface``) answers its own objective; any other kind's objective is that of its
field prediction, scored on the query's mesh (:func:`pcmgn_jax.surrogates.objective.objective_of_fields`).
"""
from __future__ import annotations

import contextlib
import time
import warnings

import numpy as np

from pcmgn_jax.explore.types import Prediction
from pcmgn_jax.surrogates.kinds import KINDS, CannotAnswer
from pcmgn_jax.surrogates.objective import objective_of_fields
from pcmgn_jax.surrogates.registry import fit_objective


def fit_predictor(kind: str, train, *, reading: str, part: int, shared: bool):
    """The baseline ``kind`` fitted on ``train`` for objective ``reading`` of part ``part``; ``shared``: the
    training meshes are one (per-node kinds apply; a response surface's field surface is fitted for the kind with
    a posterior std only). ValueError when it does not apply (a response surface: when its objective does not)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fit_objective(kind, train, readings=(reading,), part=part, fields=shared and KINDS[kind].std)


def predict_one(kind: str, model, q, *, reading: str, part: int, lock=None, spread=None) -> Prediction:
    """``model``'s answer at the query trajectory ``q`` (a design's mesh and initial state): its objective
    [MPa] (a response surface's own, with its posterior std where it has one, else its fields' on q's mesh), std,
    fields (none from a response surface without its field surface), wall time. ``lock``: held around an MGN
    rollout; ``spread``: the MGN's residual GP (:class:`pcmgn_jax.eval.ensemble.ResidualSpread`)."""
    t0 = time.perf_counter()
    u = vm = std = obj = None
    note = ""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if model.objective_surface:   # its own objective, not its fields' (kinds.Surrogate)
            try:
                got = model.predict_objective([q], reading=reading, part=part, return_std=True)
                obj, std, note = float(got[0][0]), float(got[1][0]), "± GP posterior std"
            except CannotAnswer:      # no posterior std: the surface's value alone
                obj = float(model.predict_objective([q], reading=reading, part=part)[0])
                note = f"objective surface ({model.objective_model(reading)})"
        try:
            with lock if lock is not None else contextlib.nullcontext():
                pu, pv = model.predict_trajectories([q])
            u, vm = pu[0], pv[0]
        except CannotAnswer:
            if not model.objective_surface:
                raise
            note += "; no fields" if std is None else ""
        if spread is not None:
            std = float(spread.predict([q])[1][0])
            note = "± GP std of the MGN's training residuals"
    if u is not None:
        u, vm = np.asarray(u, np.float64), np.asarray(vm, np.float64)
    if obj is None and vm is not None:
        obj = float(objective_of_fields([q], [vm], part=part, reading=reading)[0])
    return Prediction(kind, obj, std, u, vm, time.perf_counter() - t0, note)
