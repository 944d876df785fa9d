"""The baselines of an evaluation, fitted on the run's training trajectories and scored on the test ones.

    out = baseline_metrics(train_trajs, test_trajs, scores)   # {kind: summary metrics | {"not_applicable": why}}

``scores(pred_u, pred_vm) -> dict`` is the evaluation's own scoring of a field prediction (pred_u a list of
(T, N_b, 2) [m], pred_vm of (T, N_b) [Pa], one per test trajectory on its mesh; the same function scores the
MGN), so every predictor is measured by one definition (:mod:`pcmgn_jax.metrics`). Kinds: those of
:data:`pcmgn_jax.surrogates.kinds.KINDS` with ``baseline`` (simplest first), each fitted by
:func:`pcmgn_jax.surrogates.registry.fit`:

- ``none``, ``nearest``: zero fields; the nearest training design or scene with its fields carried over
  (any meshes; :class:`~pcmgn_jax.surrogates.regression.NearestScene` when the meshes differ)
- ``poly2``, ``rbf``: per-node regressions of the fields over the design (one shared mesh only)
- ``kriging``, ``mop``: response surfaces of the OLED objective readings over the scene parameters
  (:class:`~pcmgn_jax.surrogates.surface_kind.ObjectiveSurface`; any meshes), scored directly on the objective; on
  one shared mesh also of the fields (:class:`~pcmgn_jax.surrogates.surface_kind.FieldSurface`), whose objective is kept
  under ``fields_oled_objective*``; ``mop`` adds ``mop`` (the chosen candidate and every candidate's CoP per reading)
- ``rom``: POD of the fields on a reference mesh + a GP on the coefficients (:mod:`pcmgn_jax.surrogates.rom`;
  any meshes of one layer list; training stacks of several: one rom per layer list, refusing a query whose
  layer list no training scene has)
- ``rom_contact``: the rom with the MGN rollout's hard contact (a rigid ball, the cover glass projected out
  of it), so a baseline-corrected MGN (``residual_of=rom``) is measured against what the constraint alone gives

A baseline that cannot answer says why (``not_applicable``); queries outside the training box or changing
what training held fixed are answered and listed under ``warnings`` (strings), never silently.
"""
from __future__ import annotations

import time
import warnings as _warnings
from typing import Callable, Sequence

import numpy as np

from pcmgn_jax import metrics
from pcmgn_jax.surrogates.kinds import names
from pcmgn_jax.surrogates.registry import fit
from pcmgn_jax.surrogates.surface_fit import ExtrapolationWarning

BASELINES = names(baseline=True)   # what evaluate scores beside the model, in the registry's order
SUMMARY_KEYS = ("position_mae_um", "position_rmse_um", "stress_mae_mpa", "stress_rmse_mpa", "penetration_max_um",
                "penetration_mean_um", "oled_objective_rel_error_pct_mean", "oled_objective_rel_error_pct_max",
                "oled_objective_area_rel_error_pct_mean", "oled_objective_area_rel_error_pct_max")
READING_KEYS = {"node_mean": "oled_objective", "area_mean": "oled_objective_area"}  # reading -> metrics key


def objective_scores(test_trajs: Sequence, pred: dict[str, np.ndarray], *, part: int | None = None) -> dict:
    """Truth [MPa], prediction [MPa] and relative errors [%] of predicted objective readings
    {reading: (B,) [MPa]} against the test trajectories' own (``metrics.oled_objective_of``; ``part``: the
    OLED part id, default found by name), under evaluate's keys (:data:`READING_KEYS`). The one scoring of
    an objective prediction: the MGN's and every baseline's."""
    out = {}
    for reading, key in READING_KEYS.items():
        if reading not in pred:
            continue
        truth = np.array([float(metrics.oled_objective_of(t, part=part, reading=reading)) for t in test_trajs])
        p = np.asarray(pred[reading], np.float64)
        rel = metrics.relative_error_pct(p, truth)
        out.update({f"{key}_true_mpa": truth.tolist(), f"{key}_pred_mpa": p.tolist(),
                    f"{key}_rel_error_pct_mean": float(rel.mean()), f"{key}_rel_error_pct_max": float(rel.max())})
    return out


def _summary(m: dict) -> dict:
    return {k: m[k] for k in SUMMARY_KEYS if k in m}


def _fields(kind: str, model, test_trajs, scores: Callable) -> dict:
    """A kind whose objective is its fields' (none / nearest / poly2 / rbf / rom / rom_contact), scored like the
    model."""
    t0 = time.perf_counter()
    pu, ps = model.predict_trajectories(test_trajs)
    seconds = time.perf_counter() - t0
    out = {**_summary(scores(list(pu), list(ps))), "fit_seconds": model.fit_seconds,
           "predict_seconds_per_trajectory": seconds / len(test_trajs)}
    if hasattr(model, "pod_modes"):
        out.update(pod_modes=model.pod_modes, warnings=list(model.warnings))
    return out


def _surface(kind: str, s, test_trajs, scores: Callable) -> dict:
    """An objective surface (kriging / mop) scored on the objective; on a shared mesh its field surface too."""
    out, warns = {}, []
    if s.objective is None:   # e.g. no OLED part: the fields still apply
        out["objective"] = f"not applicable: {s.objective_not_applicable}"
    else:
        t0 = time.perf_counter()
        pred = s.objectives(test_trajs)
        out.update(objective_scores(test_trajs, pred), fit_seconds=s.fit_seconds,
                   predict_seconds_per_trajectory=(time.perf_counter() - t0) / len(test_trajs))
        warns += list(s.objective.warnings)
        if kind == "mop":
            out["mop"] = s.objective.model.report()
    if s.fields is not None:
        pu, ps = s.predict_trajectories(test_trajs)
        m = scores(list(pu), list(ps))
        out.update({k: m[k] for k in SUMMARY_KEYS if k in m and "objective" not in k})
        out.update({f"fields_{k}": m[k] for k in SUMMARY_KEYS if k in m and "objective" in k})
        out["fields_fit_seconds"] = s.fields.fit_seconds
        if kind == "mop":
            out["mop_fields"] = {q: s.fields.model.report()[q]["chosen"] for q in ("u", "vm")}
        warns += [w for w in s.fields.warnings if w not in warns]
    else:
        out["fields"] = "not applicable: per-node field surfaces need one shared mesh (see rom for fields)"
    out["warnings"] = warns
    return out


def baseline_metrics(train_trajs: Sequence, test_trajs: Sequence, scores: Callable,
                     kinds: Sequence[str] = BASELINES) -> dict:
    """Every baseline in ``kinds`` fitted on ``train_trajs`` and scored on ``test_trajs`` (module docstring)."""
    train_trajs, test_trajs = list(train_trajs), list(test_trajs)
    out = {}
    for kind in kinds:
        if kind not in BASELINES:
            raise ValueError(f"baseline must be one of {BASELINES}, got {kind!r}")
        try:
            with _warnings.catch_warnings():
                _warnings.simplefilter("ignore", ExtrapolationWarning)  # recorded under "warnings" instead
                # a surface's field surface is fitted when training and test share one mesh (surface_kind.fit)
                model = fit(kind, train_trajs, queries=test_trajs)
                # an objective of its own is reported apart from its fields' (kinds.Surrogate.objective_surface)
                out[kind] = (_surface if model.objective_surface else _fields)(kind, model, test_trajs, scores)
        except ValueError as err:
            out[kind] = {"not_applicable": str(err)}
    return out
