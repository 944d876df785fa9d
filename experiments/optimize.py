"""Optimise the OCA thicknesses on a surrogate and re-check the optimum with the solver (paper §5).

  python -m experiments.optimize --workdir runs/cpu --surrogate mgn --method ga --pop 20 --gens 10
  python -m experiments.optimize --workdir runs/cpu --surrogate poly2 --method gradient
  python -m experiments.optimize --workdir runs/cpu --surrogate mgn --method slsqp --starts 2
  python -m experiments.optimize --workdir runs/cpu --surrogate rbf --method ga --objective node_mean

Objective (docs/design.md §8, pcmgn_jax.eval.metrics): time-mean over the window of the OLED von Mises stress
at x < 3 mm, the section's area-weighted mean by default (node_mean: the paper's node average;
disc_mean; peak). Bounds 50-150 µm per OCA, 150 <= T1 + T2 <= 250 µm. The baselines (nearest, poly2,
rbf) are fitted on the run's training split; mgn is the run's model. The optimum is re-simulated by the
built-in solver on the training data's mesh preset (cached under RUN/optimize/solver/).
Writes RUN/optimize/<surrogate>_<method>[_<objective>].json and .png. The GA is resumable: its values
go to RUN/optimize/<tag>.resume.json as they come (one surrogate batch at a time), and the same command
after a kill replays them and carries on; the file is removed when the result is written.
"""
from __future__ import annotations

import shlex
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Literal

from pcmgn_jax import cli


@dataclass(frozen=True)
class OptimizeArgs:
    workdir: str                                            # training run (config.json; checkpoints for mgn)
    surrogate: Literal["mgn", "nearest", "poly2", "rbf"] = "mgn"  # what predicts the objective
    method: Literal["ga", "gradient", "slsqp"] = "ga"       # pymoo GA, multi-start projected gradient, or scipy SLSQP
    objective: Literal["area_mean", "node_mean", "disc_mean", "peak"] = "area_mean"  # reading (docs/design.md §8)
    pop: int = 100                                          # GA population (paper: 100)
    gens: int = 50                                          # GA generations (paper: 50)
    starts: int = 4                                         # gradient / slsqp: starting designs (seeded LHS)
    iters: int = 20                                         # gradient: evaluations per start; slsqp: iterations per start
    screen: int = 0                                         # slsqp: screen this many seeded designs (values only), start from the best
    seed: int = 0                                           # GA / starts seed
    grid: int = -1                                          # objective map: n x n surrogate grid; -1: 21 (mgn: 7); 0: none
    which: Literal["best", "periodic"] = "best"             # mgn checkpoint
    check: bool = True                                      # re-run the solver at the optimum (--no_check: off)
    progress: bool = True                                   # progress bars (--no_progress: off)


def main(argv: list[str] | None = None) -> int:
    args = cli.parse(OptimizeArgs, argv, description=__doc__, prog="python -m experiments.optimize")
    import matplotlib
    matplotlib.use("Agg")  # files only; set here, in the entry point, not in the library
    import numpy as np

    from pcmgn_jax.config import TrainConfig
    from pcmgn_jax.data.dataset import load_splits
    from pcmgn_jax.data.trajectory_io import atomic_write_json
    from pcmgn_jax.eval import metrics, plots
    from pcmgn_jax.eval.surrogates import FieldRegression, MGNSurrogate, design_of
    from pcmgn_jax.opt import search
    from pcmgn_jax.opt.check import solver_objectives
    from pcmgn_jax.opt.objectives import FieldObjective, MGNObjective
    from pcmgn_jax.opt.problem import DesignBox
    from pcmgn_jax.scene import Scene
    from pcmgn_jax.sim.design_map import DesignMap

    if args.screen and args.method != "slsqp":
        raise ValueError(f"--screen {args.screen}: only for --method slsqp (got --method {args.method})")
    run = Path(args.workdir)
    if not (run / "config.json").exists():
        raise FileNotFoundError(f"{run}/config.json: not a training run directory")
    cfg = TrainConfig.load(run / "config.json")
    train, val, test = load_splits(cfg.resolved_dataset_dir, n_train=cfg.n_train, n_val=cfg.n_val, n_test=cfg.n_test)
    ref = train[0]
    scene = Scene.from_dict(ref.meta["scene"])
    preset = ref.meta.get("solver", {}).get("preset")
    if preset is None:
        raise ValueError(f"{cfg.resolved_dataset_dir}: the optimiser needs solver-generated data (meta.solver.preset)")
    part = scene.part_names.index("OLED")
    box = DesignBox(dim=len(scene.design_layers))
    dmap = DesignMap.build(scene, preset)
    kw = dict(part=part, reading=args.objective)
    if args.surrogate == "mgn":
        obj = MGNObjective(MGNSurrogate(run, ref, which=args.which), dmap, **kw)
    else:
        obj = FieldObjective(FieldRegression(args.surrogate, train), dmap, **kw)

    tag = f"{args.surrogate}_{args.method}" + ("" if args.objective == "area_mean" else f"_{args.objective}")
    dest = plots.ensure_dir(run / "optimize")
    resume = dest / f"{tag}.resume.json"
    loaded = 0
    if args.method == "ga":
        # the GA's values go to a resume file as they come: a killed GA run again replays them and goes on
        loaded = obj.persist(resume, {"surrogate": args.surrogate, "method": "ga", "pop": args.pop,
                                      "gens": args.gens, "seed": args.seed, "preset": preset, "which": args.which})
        if loaded:
            print(f"{resume}: resuming with {loaded} evaluations done ({obj.prior_seconds:.0f} s of search)")
        res = search.ga(obj, box, pop=args.pop, gens=args.gens, seed=args.seed, progress=args.progress)
        obj.stop_timing()
        res["seconds"] = obj.search_seconds()   # this run's and the killed runs' before it
        budget = {"pop": args.pop, "gens": args.gens}
    else:
        kw = dict(starts=args.starts, iters=args.iters, seed=args.seed, progress=args.progress)
        if args.method == "gradient":
            res = search.gradient(obj, box, **kw)
        else:
            res = search.slsqp(obj, box, screen=args.screen, **kw)
        budget = {"starts": args.starts, "iters": args.iters, **({"screen": args.screen} if args.screen else {})}
    x = res["x"]

    # the dataset's own solver-evaluated designs (every split the run sees), for the "beats the data" check
    data = [(design_of(t), float(metrics.oled_objective_of(t, part=part, reading=args.objective)))
            for t in [*train, *val, *test]]
    feas = [(d, f) for d, f in data if box.violation(d)[0] <= 1e-12]
    best_d, best_f = min(feas, key=lambda p: p[1]) if feas else (None, None)

    out = {"surrogate": args.surrogate, "surrogate_fingerprint": obj.fingerprint(), "method": args.method, "objective": args.objective, "budget": budget,
           "optimum_um": (x * 1e6).tolist(), "predicted_mpa": res["f"], "search_seconds": res["seconds"],
           "n_evals": res["n_evals"], "preset": preset, "units": {"objective": "MPa", "design": "µm"},
           "dataset_best": None if best_d is None else {"design_um": (best_d * 1e6).tolist(), "mpa": best_f},
           "command": "python -m experiments.optimize " + " ".join(shlex.quote(a) for a in (argv or sys.argv[1:])),
           "args": asdict(args), **({"resumed": {"evals_loaded": loaded}} if loaded else {})}
    if args.check:
        chk = solver_objectives(scene, x, preset, cache_dir=run / "optimize" / "solver")
        out.update(solver_mpa=chk[args.objective], solver_all_readings_mpa={k: chk[k] for k in metrics.OBJECTIVES},
                   solver_seconds=chk["solver_seconds"],
                   rel_error_pct=float(metrics.relative_error_pct(res["f"], chk[args.objective])),
                   beats_dataset_best=None if best_f is None else bool(chk[args.objective] <= best_f))
    out["history"] = res.get("history") or res.get("paths")
    if res.get("screened"):
        out["screened"] = res["screened"]

    n = args.grid if args.grid >= 0 else (7 if args.surrogate == "mgn" else 21)
    if n > 1:
        grid, ok = box.grid(n)
        f = np.full(len(grid), np.nan)
        f[ok] = obj(grid[ok])
        out["grid"] = {"designs_um": (grid * 1e6).tolist(), "mpa": [None if np.isnan(v) else v for v in f]}
        pop_um = np.asarray(res["final_population"]) * 1e6 if "final_population" in res else None
        paths = [[p["x_um"] for p in path] for path in res["paths"]] if "paths" in res else None
        plots.objective_map(dest / f"{tag}.png", grid * 1e6, f, ok, title=f"{args.surrogate} {args.method}, "
                            f"{args.objective} [MPa]", points_um=pop_um, points_label="final population",
                            paths_um=paths, optimum_um=x * 1e6, solver_um=x * 1e6 if args.check else None,
                            dataset_um=np.asarray([d for d, _ in data]) * 1e6)
    atomic_write_json(dest / f"{tag}.json", out)
    resume.unlink(missing_ok=True)   # the result is written: a new run of the command searches afresh
    line = (f"{args.surrogate} {args.method}: optimum {np.round(x * 1e6, 1).tolist()} µm, predicted "
            f"{res['f']:.4f} MPa in {res['seconds']:.1f} s ({res['n_evals']} evaluations)")
    if args.check:
        line += (f"; solver {out['solver_mpa']:.4f} MPa (error {out['rel_error_pct']:.2f} %); best dataset "
                 f"design {out['dataset_best']['mpa'] if best_f is not None else float('nan'):.4f} MPa")
    print(line)
    print(f"wrote {dest / tag}.json")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
