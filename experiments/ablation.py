"""The surrogate-accuracy ablation: each formulation change alone and combined, several seeds, same data.

    python -m experiments.ablation --out results/ablation/new --num_steps 1000 --seeds 0,1 \
        --cells quasi_static,quasi_static+ema,quasi_static+thickness,default

Every cell is a training run (``--preset cpu`` plus the cell's flags, ``runs/ablation/<cell>_s<seed>``)
followed by the evaluation on the test split (with the baselines). Resumable: a cell whose
``eval/metrics.json`` exists is not retrained; a killed training resumes from its last checkpoint.
Writes OUT.json (every cell's metrics and training time) and OUT.md (the table: mean and spread over
seeds). Runs one job at a time (the machine has two cores). The cells and their runner:
pcmgn_jax/studies/ablation.py; this module parses flags.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import ClassVar

from pcmgn_jax import cli


@dataclass(frozen=True)
class AblationArgs:
    # cli.check_bounds: {flag: (lowest value, inclusive[, highest])}
    BOUNDS: ClassVar[dict] = {"num_steps": (1, True)}
    out: str = "results/ablation/new"        # output stem: OUT.json and OUT.md
    runs: str = "runs/ablation"             # where the cells' run directories go
    num_steps: int = 1000                   # optimiser steps per cell (the cpu preset trains 4000)
    seeds: str = "0,1"                      # comma-separated training seeds (same data for all)
    cells: str = ""                         # comma-separated subset of the cells ("" = all)


def main(argv=None) -> int:
    args = cli.parse(AblationArgs, argv, description=__doc__, prog="python -m experiments.ablation")
    from pcmgn_jax.studies import ablation
    command = cli.command_line("experiments.ablation", argv)
    seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    md = ablation.run([c for c in args.cells.split(",") if c], seeds=seeds, num_steps=args.num_steps,
                      runs=args.runs, out=args.out, command=command)
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
