"""Optimise the OCA thicknesses on a surrogate and re-check the optimum with the solver (paper §5).

  python -m experiments.optimize --workdir runs/cpu                        # kriging (the default), the paper's GA
  python -m experiments.optimize --workdir runs/cpu --surrogate mgn --method ga --pop 20 --gens 10
  python -m experiments.optimize --workdir runs/cpu --surrogate poly2 --method gradient
  python -m experiments.optimize --workdir runs/cpu --surrogate mgn --method slsqp --starts 2
  python -m experiments.optimize --workdir runs/cpu --surrogate rbf --method ga --objective node_mean
  python -m experiments.optimize --workdir runs/cpu --surrogate solver --method slsqp --starts 1 --iters 20
  python -m experiments.optimize --workdir runs/stack_e2 --surrogate kriging --pop 20 --gens 10 \
      --stack CG,OCA1,POL,TSP,OCA2,OLED,PLATE --params OCA1.thickness,OCA2.thickness,TSP.log10_youngs
  python -m experiments.optimize --workdir runs/stack_e2 --surrogate solver --method slsqp --starts 1 --iters 30 \
      --stack CG,OCA1,POL,OCA2,OLED,PLATE

A panel-stack run (the stack presets, issue 40) is searched over its scene parameters instead: a chosen
layer list (--stack, default the paper's six), every layer's thickness and log10 modulus within the
family's ranges (or the --params named), the rest at the stack's nominal values and the ball at the
middle of its ranges; on a surrogate GA only (every candidate has its own mesh); poly2 and rbf are refused
by name (pcmgn_jax/opt/stack_search.py). --surrogate solver searches the stack on the truth with slsqp or
gradient: every evaluation a run of the differentiable solver with its exact gradient, the mesh pinned at the
nominal stack and one time step for the whole box (pcmgn_jax/opt/truth_stack.py). The result's optimum is the
full row of scene parameters (SI).

Objective (docs/design.md §8, pcmgn_jax.metrics): time-mean over the window of the OLED von Mises stress
at x < 3 mm, the section's area-weighted mean by default (node_mean: the paper's node average;
disc_mean; peak). Bounds 50-150 µm per OCA, 150 <= T1 + T2 <= 250 µm. The baselines (nearest, poly2,
rbf) are fitted on the run's training split; mgn is the run's model. The optimum is re-simulated by the
built-in solver on the training data's mesh preset (cached under RUN/optimize/solver/). The pipeline is
pcmgn_jax.opt.run (pcmgn_jax/opt/pipeline.py); this module parses flags and prints.
Writes RUN/optimize/<surrogate>_<method>[_<objective>].json and .png (a stack run: also the layer list, when
not the paper's six, and a hash of --params: one file per search; a file replaced is said). The GA is
resumable: its values go to RUN/optimize/<tag>.resume.json as they come (one surrogate batch at a time), and
the same command after a kill replays them and carries on; the file is removed when the result is written.

--surrogate solver searches on the truth: every evaluation is a run of the built-in solver with its exact design
gradient (float64, one time step for the whole box; pcmgn_jax/opt/truth.py), for --method slsqp or gradient (the
GA is refused: each candidate would be a solver run). It needs no checkpoint, only the run folder's config.json
and its dataset (the box, the scene and the mesh preset). Resumable like the GA; the result holds the trace
(every evaluation's design, value, gradient and wall time) and its check at the optimum is the search's own
value (no second solver run); no objective map unless --grid N (each point a solver run).
"""
from __future__ import annotations

import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import ClassVar, Literal

from pcmgn_jax import cli
from pcmgn_jax.surrogates.kinds import choices


@dataclass(frozen=True)
class OptimizeArgs:
    # cli.check_bounds: {flag: (lowest value, inclusive[, highest])}
    BOUNDS: ClassVar[dict] = {"pop": (2, True), "gens": (1, True), "starts": (1, True), "iters": (1, True),
                              "screen": (0, True), "grid": (-1, True)}
    workdir: str                                            # training run (config.json; checkpoints for mgn)
    # what predicts the objective (kriging/mop: a response surface of the objective itself; auto: mop, its CoP table in
    # the result). Default kriging: the measured winner on the objective in the paper's box (0.037 % against the
    # MGN's 0.60 % at N = 100, docs/results/compute.md) and over stacks (docs/results/stacks.md)
    surrogate: Literal[choices("optimise")] = "kriging"
    method: Literal["ga", "gradient", "slsqp"] = "ga"       # pymoo GA, multi-start projected gradient, or scipy SLSQP
    objective: Literal["area_mean", "node_mean", "disc_mean", "peak"] = "area_mean"  # reading (docs/design.md §8)
    pop: int = 100                                          # GA population (paper: 100)
    gens: int = 50                                          # GA generations (paper: 50)
    starts: int = 4                                         # gradient / slsqp: starting designs (seeded LHS)
    # gradient: evaluations per start; slsqp: iterations per start
    iters: int = 20
    # slsqp: screen this many seeded designs (values only), start from the best
    screen: int = 0
    seed: int = 0                                           # GA / starts seed
    # objective map: n x n surrogate grid; -1: 21 (mgn: 7); 0: none
    grid: int = -1
    which: Literal["best", "periodic"] = "best"             # mgn checkpoint
    check: bool = True                                      # re-run the solver at the optimum (--no_check: off)
    # mgn: other runs (comma-separated) whose models give the optimum's spread
    ensemble: str = ""
    # a panel-stack run: its layer list, top to bottom, comma-separated ('': the paper's six)
    stack: str = ""
    # a panel-stack run: the parameters to search, comma-separated ('': every layer's thickness and modulus)
    params: str = ""
    progress: bool = True                                   # progress bars (--no_progress: off)


def check_args(args: OptimizeArgs, given: set[str]) -> None:
    """ValueError naming a flag that does not apply to the method or surrogate
    (:func:`pcmgn_jax.cli.refuse_inapplicable`), before anything is created (the budgets' ranges: ``BOUNDS``)."""
    ga = None if args.method == "ga" else f"--method {args.method} (only the GA has a population)"
    starts = None if args.method != "ga" else "--method ga (only gradient and slsqp have starts)"
    mgn = None if args.surrogate == "mgn" else f"--surrogate {args.surrogate} (only mgn has a checkpoint and members)"
    truth = None if args.surrogate != "solver" else "--surrogate solver (its optimum is a solver run: its own check)"
    cli.refuse_inapplicable(given, {"pop": ga, "gens": ga, "starts": starts, "iters": starts, "which": mgn,
                                    "ensemble": mgn, "check": truth})


def main(argv: list[str] | None = None) -> int:
    args = cli.parse(OptimizeArgs, argv, description=__doc__, prog="python -m experiments.optimize")
    check_args(args, cli.given_flags(sys.argv[1:] if argv is None else argv))
    import matplotlib
    matplotlib.use("Agg")  # files only; set here, in the entry point, not in the library
    import numpy as np

    from pcmgn_jax.opt import run
    from pcmgn_jax.opt.pipeline import result_tag
    from pcmgn_jax.opt.scenes import parse_names
    command = cli.command_line("experiments.optimize", argv)
    lists = {k: parse_names(getattr(args, k)) for k in ("ensemble", "stack", "params")}   # the comma lists
    out = run(**{**asdict(args), **lists}, command=command)
    tag = result_tag(args.surrogate, args.method, args.objective, lists["stack"], lists["params"])
    written = Path(args.workdir) / "optimize" / f"{tag}.json"
    if "optimum" in out:    # a panel-stack run: the optimum is a row of named scene parameters
        print(f"{args.surrogate} {args.method} on the stack {'/'.join(out['stack'])}: predicted "
              f"{out['predicted_mpa']:.4f} ± {out['predicted_std_mpa']:.4f} MPa ({out['spread']['source']}; "
              f"nominal stack {out['nominal_mpa']:.4f} MPa) in {out['search_seconds']:.1f} s ({out['n_evals']} "
              "evaluations)" + (f"; solver {out['solver_mpa']:.4f} MPa (error {out['rel_error_pct']:.2f} %)"
                                if args.check else ""))
        print("optimum: " + ", ".join(f"{n} = {out['optimum'][n]:.4g}" for n in out["searched"]))
        if "solver_check" in out:   # the solver search: its fixed step and whether the host solver's run is its own
            c = out["solver_check"]
            print(f"solver: {out['solver_runs']} runs at dt {c['dt_s']:.3g} s ({c['n_substeps_per_frame']} substeps "
                  f"per frame); the host solver's own run at the optimum: {'the same' if c['same_run'] else 'another'}"
                  + (f", {c['host_mpa']:.4f} MPa ({c['host_rel_diff_pct']:+.2f} %)" if "host_mpa" in c else ""))
        print(f"wrote {written}")
        return 0
    line = (f"{args.surrogate} {args.method}: optimum {np.round(np.asarray(out['optimum_um']), 1).tolist()} µm, "
            f"predicted {out['predicted_mpa']:.4f} ± {out['predicted_std_mpa']:.4f} MPa ({out['spread']['source']}) "
            f"in {out['search_seconds']:.1f} s ({out['n_evals']} evaluations)")
    if args.check:
        best = out["dataset_best"]
        line += (f"; solver {out['solver_mpa']:.4f} MPa (error {out['rel_error_pct']:.2f} %); best dataset "
                 f"design {best['mpa'] if best is not None else float('nan'):.4f} MPa")
    print(line)
    print(f"wrote {written}")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
