"""The paper's studies (its Tables 3-7 and §4.6), in its formulation and in the project's default.

  python -m experiments.study --name lambda                 # ~1 h on 2 CPU cores (trimmed steps, 2 seeds)
  python -m experiments.study --name extrapolation --formulations default --seeds 0

Studies: lambda (penetration weight), degree (polynomial degrees of the boundary fits), noise_sigma
(noise magnitude, all parts), noise_parts (which bodies get 0.3 µm noise), target (what the model
predicts), extrapolation (λ = 0 vs 10, evaluated on the paper's four designs outside the training box,
data/cpu/extrap, generated on first use). Every cell is a training run of ``--preset cpu`` with the
formulation's base flags, the cell's flags and ``--num_steps`` (trimmed so a study fits in about an
hour: steps, not seeds, are cut), then its evaluation. Resumable: finished cells are never
retrained and a killed training resumes (pcmgn_jax/studies/cells.py). Writes results/studies/<name>.{json,md}
(a table beside the paper's numbers, mean ± std over seeds) and <name>_per_frame.png (per-frame position
MAE per cell, like the paper's Figure 7). A run of some formulations keeps the other formulations' rows
of the study's earlier JSON (with the command that measured them), so ``--formulations default``
re-measures only the default's rows; the earlier JSON's note is dropped with the rows it was about.
The studies and their runner: pcmgn_jax/studies/paper.py; this module parses flags.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import ClassVar

from pcmgn_jax import cli


@dataclass(frozen=True)
class StudyArgs:
    # cli.check_bounds: {flag: (lowest value, inclusive[, highest])}
    BOUNDS: ClassVar[dict] = {"num_steps": (0, True)}
    name: str                                   # lambda | degree | noise_sigma | noise_parts | target | extrapolation
    formulations: str = "paper,default"         # comma-separated: paper, default
    seeds: str = "0,1"                          # training seeds (same data for all)
    num_steps: int = 0                          # 0: the study's trimmed default (see STUDIES)
    runs: str = "runs/studies"                  # cell run directories: RUNS/<name>/<formulation>/<cell>_s<seed>
    out: str = "results/studies"                # tables and plots
    data: str = "data/cpu"                      # the cpu preset's dataset (extrap split added for extrapolation)
    render: bool = False                        # only re-write OUT/<name>.{md,png} from OUT/<name>.json (no cell runs)


def main(argv=None) -> int:
    args = cli.parse(StudyArgs, argv, description=__doc__, prog="python -m experiments.study")
    import matplotlib
    matplotlib.use("Agg")  # files only; set here, in the entry point, not in the library
    from pcmgn_jax.studies import paper
    if args.name not in paper.STUDIES:   # the library names the value; the command line names its flag
        raise ValueError(f"--name must be one of {list(paper.STUDIES)}, got {args.name!r}")
    forms = [f for f in args.formulations.split(",") if f]
    if set(forms) - set(paper.BASE):
        raise ValueError(f"--formulations: unknown {sorted(set(forms) - set(paper.BASE))}; choose from "
                         f"{list(paper.BASE)}")
    if args.render:   # the table of a finished (or cut) study again, e.g. after the table's format changed
        paper.render(args.name, out=args.out)
        return 0
    command = cli.command_line("experiments.study", argv)
    paper.run(args.name, formulations=forms,
              seeds=[int(s) for s in args.seeds.split(",") if s.strip()], num_steps=args.num_steps,
              runs=args.runs, out=args.out, data=args.data, command=command)
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
