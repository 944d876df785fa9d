"""The surrogate-accuracy ablation: each formulation change alone and combined, several seeds, same data.

    python -m experiments.ablation --out results/ablation_v3 --num_steps 1000 --seeds 0,1 \
        --cells quasi_static,quasi_static+ema,quasi_static+thickness,default

Every cell is a training run (``--preset cpu`` plus the cell's flags, ``runs/ablation/<cell>_s<seed>``)
followed by the evaluation on the test split (with the baselines). Resumable: a cell whose
``eval/metrics.json`` exists is not retrained; a killed training resumes from its last checkpoint.
Writes OUT.json (every cell's metrics and training time) and OUT.md (the table: mean and spread over
seeds). Runs one job at a time (the machine has two cores).
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

from experiments import cells
from pcmgn_jax import cli

# cell name -> (what it changes, flags on top of --preset cpu). Noise and lambda are fixed across the
# formulation cells so that only the formulation changes; the last cells vary them on the default.
CELLS = {
    "paper": ("the paper's formulation (velocity target, one normaliser, raw features, node-mean loss)",
              ["--formulation=paper"]),
    "paper+per_part": ("+ per-part normalisation and part-mean loss",
                       ["--formulation=paper", "--normalization=per_part", "--loss_weighting=parts"]),
    "paper+strain": ("+ strain-like features", ["--formulation=paper", "--features=strain"]),
    "paper+rigid_ball": ("+ rigid ball (one acceleration, pooled from its nodes)",
                         ["--formulation=paper", "--rigid_ball", "--ball_target=acceleration"]),
    "dynamic": ("all three: the layers as a second dynamical system (velocity target, own state as input)",
                ["--formulation=dynamic"]),
    "quasi_static": ("+ quasi-static panel (layers at their reference, total displacement as a map of the "
                     "ball's state; results/ablation_v2's 'default')",
                     ["--formulation=default", "--no_contact_projection", "--scene_features=none", "--ema_decay=0"]),
    "quasi_static+ema": ("+ the parameters' moving average validated and kept (--ema_decay=0.998)",
                         ["--formulation=default", "--no_contact_projection", "--scene_features=none",
                          "--ema_decay=0.998"]),
    "quasi_static+thickness": ("+ the layer thicknesses as node inputs (--scene_features=layer_thickness)",
                               ["--formulation=default", "--no_contact_projection", "--ema_decay=0"]),
    "default": ("all of them and the rollout's contact projection: the default (--preset cpu)",
                ["--formulation=default", "--ema_decay=0.998"]),
    "default+lambda10": ("default + penetration loss, lambda = 10 from half-way (--lambda_start=0.5)",
                         ["--formulation=default", "--ema_decay=0.998", "--lambda_pen=10", "--lambda_start=0.5"]),
    "default+lambda10_from_0": ("default + penetration loss, lambda = 10 from step 0 (the paper's schedule)",
                                ["--formulation=default", "--ema_decay=0.998", "--lambda_pen=10", "--lambda_start=0"]),
}
# noise 1.0 x each layer's per-frame motion on the layers for every cell: it is what the dynamic cells
# need and a no-op for the quasi-static ones (their layers' state is not an input); no parameter
# average unless a cell asks for it (v1 and v2 were made without one)
COMMON = ["--lambda_pen=0", "--lambda_start=0", "--noise_std=0", "--noise_rel=1.0", "--noise_parts=panel",
          "--ema_decay=0"]
KEYS = ("position_mae_um", "stress_mae_mpa", "oled_objective_rel_error_pct_mean", "penetration_max_um")


@dataclass(frozen=True)
class AblationArgs:
    out: str = "results/ablation_v3"        # output stem: OUT.json and OUT.md
    runs: str = "runs/ablation"             # where the cells' run directories go
    num_steps: int = 1000                   # optimiser steps per cell (the cpu preset trains 4000)
    seeds: str = "0,1"                      # comma-separated training seeds (same data for all)
    cells: str = ""                         # comma-separated subset of the cells ("" = all)


def run_cell(name: str, seed: int, args: AblationArgs) -> dict:
    flags = ["--preset=cpu", f"--num_steps={args.num_steps}", f"--seed={seed}", *COMMON, *CELLS[name][1]]
    return cells.run_cell(Path(args.runs) / f"{name}_s{seed}", flags)


def table(results: dict, baselines: dict) -> str:
    head = ("| cell | what changes | position MAE [µm] | stress MAE [MPa] | OLED objective error [%] | "
            "max penetration [µm] | training time [s] |")
    rows = [head, "|---|---|---|---|---|---|---|"]
    for name, per_seed in results.items():
        cols = [cells.mean_pm(m[k] for m in per_seed.values()) for k in KEYS + ("train_seconds",)]
        rows.append(f"| {name} | {CELLS[name][0]} | " + " | ".join(cols) + " |")
    for name, b in baselines.items():
        rows.append(f"| baseline: {name} | fitted on the 12 training designs | "
                    + " | ".join(f"{b[k]:.3g}" for k in KEYS) + " | – |")
    return "\n".join(rows)


def main(argv=None) -> int:
    args = cli.parse(AblationArgs, argv, description=__doc__, prog="python -m experiments.ablation")
    names = [c for c in args.cells.split(",") if c] or list(CELLS)
    unknown = sorted(set(names) - set(CELLS))
    if unknown:
        raise ValueError(f"unknown cell(s) {unknown}; choose from {list(CELLS)}")
    seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    cells.use_compilation_cache(Path(args.runs) / ".xla_cache")
    results, baselines = {}, {}
    for name in names:
        results[name] = {}
        for seed in seeds:
            m = run_cell(name, seed, args)
            results[name][str(seed)] = {k: m[k] for k in KEYS + ("train_seconds",)}
            baselines = m.get("baselines", baselines)
            print(f"{name} seed {seed}: " + ", ".join(f"{k}={m[k]:.4g}" for k in KEYS), flush=True)
    from pcmgn_jax.atomic import atomic_write_text
    from pcmgn_jax.data.trajectory_io import atomic_write_json
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    command = "python -m experiments.ablation " + " ".join(sys.argv[1:] if argv is None else argv)
    atomic_write_json(out.with_suffix(".json"), dict(command=command, common_flags=COMMON, cells=results,
                                                     baselines={k: {kk: v[kk] for kk in KEYS} for k, v in
                                                                baselines.items() if "not_applicable" not in v}))
    md = table(results, {k: v for k, v in baselines.items() if "not_applicable" not in v})
    atomic_write_text(out.with_suffix(".md"), f"`{command}` (flags common to every cell: `{' '.join(COMMON)}`)\n\n{md}\n")
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
