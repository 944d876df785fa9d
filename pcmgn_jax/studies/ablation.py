"""The surrogate-accuracy ablation: each formulation change alone and combined, several seeds, same data.

Every cell (:data:`CELLS`) is a training run of the cpu preset with :data:`COMMON` and the cell's
settings (:meth:`TrainConfig.from_preset` keyword arguments, later ones win) in RUNS/<cell>_s<seed>,
followed by the evaluation on the test split with the baselines (:func:`pcmgn_jax.studies.cells.run_cell`:
a cell whose ``eval/metrics.json`` exists is not retrained; a killed training resumes). :func:`run` writes
OUT.json (every cell's metrics and training time) and OUT.md (the table: mean and spread over seeds), one
job at a time.
"""
from __future__ import annotations

from pathlib import Path

from pcmgn_jax import markdown
from pcmgn_jax.studies import cells

# cell name -> (what it changes, settings on top of the cpu preset). Noise and lambda are fixed across the
# formulation cells so that only the formulation changes; the last cells vary them on the default.
_QUASI_STATIC = {"formulation": "default", "contact_projection": False, "scene_features": ()}
CELLS = {
    "paper": ("the paper's formulation (velocity target, one normaliser, raw features, node-mean loss)",
              {"formulation": "paper"}),
    "paper+per_part": ("+ per-part normalisation and part-mean loss",
                       {"formulation": "paper", "normalization": "per_part", "loss_weighting": "parts"}),
    "paper+strain": ("+ strain-like features", {"formulation": "paper", "features": "strain"}),
    "paper+rigid_ball": ("+ rigid ball (one acceleration, pooled from its nodes)",
                         {"formulation": "paper", "rigid_ball": True, "ball_target": "acceleration"}),
    "dynamic": ("all three: the layers as a second dynamical system (velocity target, own state as input)",
                {"formulation": "dynamic"}),
    "quasi_static": ("+ quasi-static panel (layers at their reference, total displacement as a map of the "
                     "ball's state; results/ablation/panel's 'default')", {**_QUASI_STATIC, "ema_decay": 0.0}),
    "quasi_static+ema": ("+ the parameters' moving average validated and kept (--ema_decay=0.998)",
                         {**_QUASI_STATIC, "ema_decay": 0.998}),
    "quasi_static+thickness": ("+ the layer thicknesses as node inputs (--scene_features=layer_thickness)",
                               {"formulation": "default", "contact_projection": False, "ema_decay": 0.0}),
    "default": ("all of them and the rollout's contact projection: the default (--preset cpu)",
                {"formulation": "default", "ema_decay": 0.998}),
    "default+lambda10": ("default + penetration loss, lambda = 10 from half-way (--lambda_start=0.5)",
                         {"formulation": "default", "ema_decay": 0.998, "lambda_pen": 10.0, "lambda_start": 0.5}),
    "default+lambda10_from_0": ("default + penetration loss, lambda = 10 from step 0 (the paper's schedule)",
                                {"formulation": "default", "ema_decay": 0.998, "lambda_pen": 10.0,
                                 "lambda_start": 0.0}),
}
# noise 1.0 x each layer's per-frame motion on the layers for every cell: it is what the dynamic cells
# need and a no-op for the quasi-static ones (their layers' state is not an input); no parameter
# average unless a cell asks for it (v1 and v2 were made without one)
COMMON = {"lambda_pen": 0.0, "lambda_start": 0.0, "noise_std": 0.0, "noise_rel": 1.0, "noise_parts": "panel",
          "ema_decay": 0.0}
ABLATION_METRICS = ("position_mae_um", "stress_mae_mpa", "oled_objective_rel_error_pct_mean", "penetration_max_um")


def cell_settings(name: str, seed: int, num_steps: int) -> dict:
    """The training settings of cell ``name`` at ``seed``: the cpu preset, ``num_steps`` steps, :data:`COMMON`,
    then the cell's own."""
    return {"preset": "cpu", "num_steps": num_steps, "seed": seed, **COMMON, **CELLS[name][1]}


def table(results: dict, baselines: dict) -> str:
    """The markdown table of ``results`` ({cell: {seed: metrics}}) and the ``baselines`` ({name: metrics})."""
    head = ("cell", "what changes", "position MAE [µm]", "stress MAE [MPa]", "OLED objective error [%]",
            "max penetration [µm]", "training time [s]")
    rows = [(name, CELLS[name][0],
             *(cells.mean_pm(m[k] for m in per_seed.values()) for k in (*ABLATION_METRICS, "train_seconds")))
            for name, per_seed in results.items()]
    rows += [(f"baseline: {name}", "fitted on the 12 training designs", *(f"{b[k]:.3g}" for k in ABLATION_METRICS), "–")
             for name, b in baselines.items()]
    return "\n".join(markdown.table(head, rows))


def run(names=(), *, seeds=(0, 1), num_steps: int = 1000, runs: str | Path = "runs/ablation",
        out: str | Path = "results/ablation/new", command: str = "") -> str:
    """Train and evaluate the cells ``names`` (() = all of :data:`CELLS`) at each training seed, cells under
    RUNS/<cell>_s<seed>; write OUT.json and OUT.md (``command`` recorded in both); return the table."""
    names = list(names) or list(CELLS)
    unknown = sorted(set(names) - set(CELLS))
    if unknown:
        raise ValueError(f"unknown cell(s) {unknown}; choose from {list(CELLS)}")
    cells.use_compilation_cache(Path(runs) / ".xla_cache")
    results, baselines = {}, {}
    for name in names:
        results[name] = {}
        for seed in seeds:
            m = cells.run_cell(Path(runs) / f"{name}_s{seed}", cell_settings(name, seed, num_steps))
            results[name][str(seed)] = {k: m[k] for k in (*ABLATION_METRICS, "train_seconds")}
            baselines = m.get("baselines", baselines)
            print(f"{name} seed {seed}: " + ", ".join(f"{k}={m[k]:.4g}" for k in ABLATION_METRICS), flush=True)
    from pcmgn_jax.atomic import atomic_write_json, atomic_write_text
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    common = cells.as_flags(COMMON)
    fitted = {k: v for k, v in baselines.items() if "not_applicable" not in v}
    atomic_write_json(out.with_suffix(".json"), {
        "command": command, "common_flags": common, "cells": results,
        "baselines": {k: {kk: v[kk] for kk in ABLATION_METRICS} for k, v in fitted.items()}})
    md = table(results, fitted)
    atomic_write_text(out.with_suffix(".md"),
                      f"`{command}` (flags common to every cell: `{' '.join(common)}`)\n\n{md}\n")
    return md
