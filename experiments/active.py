"""Active learning: the solver in the loop of a surrogate and an acquisition, resumable (issue 26).

  python -m experiments.active --workdir runs/cpu --surrogate kriging --acquisition ei --budget 16
  python -m experiments.active --workdir runs/cpu --surrogate auto --budget 16      # MOP mean, kriging spread
  python -m experiments.active --workdir runs/cpu --surrogate mgn --budget 16       # the run's MGN + residual GP
  python -m experiments.active --workdir runs/cpu --compare --budgets 8,12,16,24 --seeds 0,1 --out results/active
  python -m experiments.active --workdir runs/family --task robust --budget 24 --n_init 2

Round 0 runs --n_init seeded LHS designs with the built-in solver; each later round fits the surrogate on
every solver value so far, scores the candidate designs with the acquisition (ei: expected improvement;
lcb: mean - 2 std; mean: the surrogate's optimum) and runs the --batch best. The log (every round's
designs, solver values, prediction ± spread, surrogate error on the run's test split, best so far) is
written atomically after each round to --out (default RUN/active/<surrogate>_<acquisition>_s<seed>.json);
the same command after a kill replays it and goes on, and a larger --budget continues a finished log.
--task robust: OCA1, OCA2 and POL minimising the mean objective over three drop cases on a scene-family
run, its training scenes as prior data. --compare: LHS + MOP, GP-EI, auto-EI and MGN-EI at each budget
(pcmgn_jax/opt/active_tasks.py), writing OUT/active_table.{json,md}. Solver runs are cached under
RUN/active/solver/.
"""
from __future__ import annotations

import sys
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar, Literal

from pcmgn_jax import cli
from pcmgn_jax.surrogates.kinds import choices


@dataclass(frozen=True)
class ActiveArgs:
    # cli.check_bounds: {flag: (lowest value, inclusive[, highest])}
    BOUNDS: ClassVar[dict] = {"budget": (1, True), "n_init": (1, True), "batch": (1, True)}
    # training run (its data, mesh preset, test split; mgn: its model)
    workdir: str
    # box: the paper's two OCAs; robust: OCA1, OCA2, POL over drop cases
    task: Literal["box", "robust"] = "box"
    surrogate: Literal[choices("active")] = "kriging"           # what predicts the objective and its spread
    acquisition: Literal["ei", "lcb", "mean"] = "ei"            # how the next design is picked
    budget: int = 16                                            # solver runs in the loop (designs x drop cases)
    n_init: int = 4                                             # LHS designs of round 0
    batch: int = 1                                              # designs per later round
    seed: int = 0                                               # LHS seed
    objective: Literal["area_mean", "node_mean", "disc_mean", "peak"] = "area_mean"  # reading (docs/design.md §8)
    out: str = ""                                               # log file (--compare: output folder)
    compare: bool = False                                       # run the strategy comparison of the box task
    budgets: str = "8,12,16,24"                                 # --compare: budgets
    seeds: str = "0,1"                                          # --compare: seeds
    # --compare: strategies (pcmgn_jax.opt.active_tasks.STRATEGIES)
    strategies: str = "lhs+mop,gp-ei,auto-ei,mgn-ei"
    progress: bool = True                                       # progress bars (--no_progress: off)


def _ints(text: str, flag: str) -> tuple[int, ...]:
    try:
        return tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise ValueError(f"--{flag}: expected comma-separated integers, got {text!r}") from None


def main(argv: list[str] | None = None) -> int:
    args = cli.parse(ActiveArgs, argv, description=__doc__, prog="python -m experiments.active")
    from pcmgn_jax.lock import hold
    from pcmgn_jax.mgn.checkpoint import require_run
    require_run(args.workdir, checkpoint=args.surrogate == "mgn" or (args.compare and "mgn" in args.strategies))
    if not args.compare:              # the loop's settings checked before any folder or solver run
        from pcmgn_jax.opt.active import LoopConfig
        from pcmgn_jax.opt.active_tasks import ROBUST_CASES
        LoopConfig(surrogate=args.surrogate, acquisition=args.acquisition, budget=args.budget, n_init=args.n_init,
                   batch=args.batch, seed=args.seed).check(len(ROBUST_CASES) if args.task == "robust" else 1)
    command = cli.command_line("experiments.active", argv)
    run = Path(args.workdir)
    folder = Path(args.out or run / "active") if args.compare else \
        Path(args.out).parent if args.out else run / "active"
    with ExitStack() as locks:   # one writer per folder: the log's (or table's) and the solver cache's
        for f in dict.fromkeys([folder, run / "active"]):
            locks.enter_context(hold(f, "active"))
        return _main(args, command)


def _main(args: ActiveArgs, command: str) -> int:
    from pcmgn_jax.atomic import atomic_write_json, atomic_write_text
    from pcmgn_jax.opt import active_tasks as tasks
    from pcmgn_jax.opt.active import LoopConfig, run_loop

    if args.compare:
        out = Path(args.out or Path(args.workdir) / "active")
        result = tasks.compare(args.workdir, budgets=_ints(args.budgets, "budgets"), seeds=_ints(args.seeds, "seeds"),
                               strategies=tuple(s for s in args.strategies.split(",") if s), out_dir=out,
                               reading=args.objective, progress=args.progress)
        result["command"] = command
        atomic_write_json(out / "active_table.json", result)
        md = tasks.table_markdown(result, command)
        atomic_write_text(out / "active_table.md", md)
        print(md)
        print(f"wrote {out / 'active_table.json'} and .md")
        return 0
    if args.task == "robust":
        problem, ctx = tasks.robust_problem(args.workdir, reading=args.objective)
    else:
        problem, ctx = tasks.box_problem(args.workdir, reading=args.objective)
    base = None
    run = Path(args.workdir)
    if args.surrogate == "mgn":
        base = tasks.mgn_base(run, problem, run / "active" / "mgn_predictions.json", reading=args.objective)
    cfg = LoopConfig(surrogate=args.surrogate, acquisition=args.acquisition, budget=args.budget,
                     n_init=args.n_init, batch=args.batch, seed=args.seed)
    path = Path(args.out or run / "active" / f"{args.task}_{args.surrogate}_{args.acquisition}_s{args.seed}.json")
    log = run_loop(problem, cfg, path, base=base, progress=args.progress,
                   meta={"command": command, **ctx})
    best = log["rounds"][-1]["best"]
    line = (f"best solver value {best['mpa']:.4f} MPa at {best['design_um']} µm "
            f"after {log['rounds'][-1]['solver_runs']} runs")
    if "gap_pct" in best:
        line += f" ({best['gap_pct']:+.2f} % from the reference {problem.reference['mpa']:.4f} MPa)"
    print(line)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
