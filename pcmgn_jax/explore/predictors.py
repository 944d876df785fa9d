"""The explorer's predictors: each kind fitted through the registry, and its answer at one design.

    model = fit_predictor("kriging", train, reading="area_mean", part=3, shared=True)
    p = predict_one("kriging", model, q, reading="area_mean", part=3)      # a Prediction on q's mesh

Every kind is fitted as the evaluation fits it (:func:`pcmgn_jax.surrogates.registry.fit` on the run's training
split), but for the explorer's reading only; a response surface's field surface is fitted on one shared mesh
for the kind with a posterior std only (kriging: MOP's leave-one-out over a whole field is too slow to wait for).
A field prediction's objective is scored on the query's mesh by :func:`pcmgn_jax.metrics.oled_objective_of`.
"""
from __future__ import annotations

import contextlib
import time
import warnings

import numpy as np

from pcmgn_jax.explore.types import Prediction
from pcmgn_jax.surrogates.kinds import KINDS
from pcmgn_jax.surrogates.objective import objective_of_fields
from pcmgn_jax.surrogates.registry import fit


def fit_predictor(kind: str, train, *, reading: str, part: int, shared: bool):
    """The baseline ``kind`` fitted on ``train`` for objective ``reading`` of part ``part``; ``shared``: the
    training meshes are one (per-node kinds and field surfaces apply). ValueError when it does not apply."""
    spec = KINDS[kind]
    options = {"fields": shared and spec.std} if spec.objective_surface else {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = fit(kind, train, readings=(reading,), part=part, **options)
    if spec.objective_surface and model.objective is None:   # the page's row is the objective: no surface, no row
        raise ValueError(model.objective_not_applicable)
    return model


def has_fields(kind: str, model) -> bool:
    """Whether the fitted ``model`` of ``kind`` draws fields (a response surface only with its field surface)."""
    return not KINDS[kind].objective_surface or model.fields is not None


def predict_one(kind: str, model, q, *, reading: str, part: int, lock=None, spread=None) -> Prediction:
    """``model``'s answer at the query trajectory ``q`` (a design's mesh and initial state): its objective
    [MPa] (a surface's own, else its fields' on q's mesh), std, fields, wall time. ``lock``: held around an
    MGN rollout; ``spread``: the MGN's residual GP (:class:`pcmgn_jax.eval.ensemble.ResidualSpread`)."""
    spec = KINDS[kind]
    t0 = time.perf_counter()
    u = vm = std = obj = None
    note = ""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if spec.objective_surface:   # its own objective, not its fields' (the same call answers every kind)
            got = model.predict_objective([q], reading=reading, part=part, return_std=spec.std)
            obj, std = (float(got[0][0]), float(got[1][0])) if spec.std else (float(got[0]), None)
            note = "± GP posterior std" if spec.std else \
                f"objective surface ({model.objective.model.choice[reading]})" + \
                ("; no fields" if model.fields is None else "")
        if has_fields(kind, model):
            with lock if lock is not None else contextlib.nullcontext():
                pu, pv = model.predict_trajectories([q])
            u, vm = pu[0], pv[0]
        if spread is not None:
            std = float(spread.predict([q])[1][0])
            note = "± GP std of the MGN's training residuals"
    if u is not None:
        u, vm = np.asarray(u, np.float64), np.asarray(vm, np.float64)
    if obj is None and vm is not None:
        obj = float(objective_of_fields([q], [vm], part=part, reading=reading)[0])
    return Prediction(kind, obj, std, u, vm, time.perf_counter() - t0, note)
