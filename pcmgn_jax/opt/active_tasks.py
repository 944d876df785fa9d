"""The solver-in-the-loop tasks on a run's data, and the comparison at equal solver budgets.

    problem, ctx = box_problem("runs/cpu")                 # the paper's box on the run's mesh preset
    problem, ctx = robust_problem("runs/family", CASES)    # OCA1, OCA2, POL over three drop cases
    table = compare("runs/cpu", budgets=(8, 12, 16, 24), seeds=(0, 1), out_dir="results/active")

Strategies (:data:`STRATEGIES`), each a :class:`~pcmgn_jax.opt.active.LoopConfig` run by
:func:`~pcmgn_jax.opt.active.run_loop`; all of them count every solver run they make:

- ``lhs+mop``  budget - 1 LHS designs, MOP (the best regression by CoP) fitted on them, its optimum over the
               candidates run once: the DOE workflow (one log per budget)
- ``gp-ei``    GP Bayesian optimisation: 4 LHS designs, then expected improvement on kriging, one at a time
- ``gp-lcb``   the same with the lower confidence bound (mean - 2 std)
- ``auto-ei``  expected improvement with MOP's mean and the kriging spread (``--surrogate auto``)
- ``mgn-ei``   expected improvement on the run's MGN corrected by a GP on the solver's residuals; the MGN's own
               training runs are reported beside the loop's (``offline_solver_runs``)

The sequential strategies are one loop to the largest budget, read at each budget (:func:`best_at`): a loop
stopped at 12 runs is the first 12 runs of the loop to 24.
"""
from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import Sequence

import numpy as np

from pcmgn_jax import markdown
from pcmgn_jax.atomic import atomic_write_json
from pcmgn_jax.data.designs import FAMILIES
from pcmgn_jax.opt.active import LoopConfig, Problem, SolverOracle, best_at, run_loop
from pcmgn_jax.opt.check import solver_preset
from pcmgn_jax.opt.objectives import MGNObjective
from pcmgn_jax.opt.problem import DesignBox
from pcmgn_jax.scene import Scene
from pcmgn_jax.sim.design_map import DesignMap
from pcmgn_jax.surrogates.inputs import TrainingScenes, design_of
from pcmgn_jax.surrogates.mgn import run_splits
from pcmgn_jax.surrogates.registry import fit
from pcmgn_jax.surrogates.surface_fit import objective_table

# the best solver-checked design known in the paper's box on the cpu mesh, re-solved by box_problem
REFERENCE_UM = (150.0, 100.0)
HIT_PCT = 0.3   # "reached the best design": within this gap [%] of the reference
STRATEGIES = {
    "lhs+mop": dict(surrogate="auto", acquisition="mean"),
    "gp-ei": dict(surrogate="kriging", acquisition="ei", n_init=4),
    "gp-lcb": dict(surrogate="kriging", acquisition="lcb", n_init=4),
    "auto-ei": dict(surrogate="auto", acquisition="ei", n_init=4),
    "mgn-ei": dict(surrogate="mgn", acquisition="ei", n_init=4),
}
# three drop cases inside the family's box (ball radius [m], drop speed [m/s]): small-fast, the paper's, large-slow
ROBUST_CASES = ({"ball.radius": 4.5e-3, "ball.velocity": 0.70}, {"ball.radius": 5.0e-3, "ball.velocity": 0.626},
                {"ball.radius": 5.5e-3, "ball.velocity": 0.55})


@functools.lru_cache(maxsize=2)
def _read_run(workdir: str):
    return run_splits(workdir)


def _splits(workdir):
    """(cfg, (train, val, test)) of a run (:func:`pcmgn_jax.surrogates.mgn.run_splits`), read once per run
    directory: a task's problem and its MGN base prediction share them (read-only)."""
    cfg, *splits = _read_run(str(Path(workdir).resolve()))
    return cfg, splits


def box_problem(workdir, *, reading: str = "area_mean", cache_dir=None) -> tuple[Problem, dict]:
    """The paper's design box (50-150 µm per OCA, 150-250 µm sum) on the run's scene and mesh preset; the
    holdout is the run's test split, the reference the solver at :data:`REFERENCE_UM`. ``cache_dir``:
    solver runs (default RUN/active/solver)."""

    cfg, (train, val, test) = _splits(workdir)
    scene = Scene.from_dict(train[0].meta["scene"])
    preset = solver_preset(train[0], cfg.resolved_dataset_dir)
    box = DesignBox(dim=len(scene.design_layers))
    oracle = SolverOracle(scene, preset, reading=reading, cache_dir=cache_dir or Path(workdir) / "active" / "solver")
    ref = np.asarray(REFERENCE_UM) * 1e-6
    holdout = (np.stack([design_of(t) for t in test]), objective_table(test, (reading,))[reading])
    problem = Problem(names=tuple(scene.design_layers), low=(box.low,) * box.dim, high=(box.high,) * box.dim,
                      oracle=oracle, band=box, holdout=holdout,
                      reference={"design_um": list(REFERENCE_UM), "mpa": float(oracle(ref)[0])})
    return problem, {"preset": preset, "reading": reading, "offline_solver_runs": len(train) + len(val),
                     "n_holdout": len(test)}


def robust_problem(workdir, cases: Sequence[dict] = ROBUST_CASES, *, reading: str = "area_mean",
                   cache_dir=None) -> tuple[Problem, dict]:
    """OCA1, OCA2 (50-150 µm, sum 150-250 µm) and POL (30-70 µm) minimising the objective's mean over
    ``cases`` on a scene-family run's data: prior = its training scenes, holdout = its test scenes."""

    cfg, (train, val, test) = _splits(workdir)
    if "scene_params" not in train[0].meta:
        raise ValueError(f"{cfg.resolved_dataset_dir}: the robust design needs scene-family data (meta.scene_params)")
    preset = solver_preset(train[0], cfg.resolved_dataset_dir)
    scenes = TrainingScenes(train)
    names = ("OCA1", "OCA2", "POL")
    bounds = {p: (lo, hi) for p, lo, hi in FAMILIES["family"].parameters}
    need = set(names) | {k for c in cases for k in c}
    if missing := sorted(need - set(scenes.names)):
        raise ValueError(f"{cfg.resolved_dataset_dir}: the family does not vary {missing} (it varies {scenes.names})")
    scene = Scene.from_dict(train[0].meta["scene"])
    if tuple(scene.design_layers) != names:
        raise ValueError(f"robust design: the scene's design layers are {scene.design_layers}, expected {names}")
    oracle = SolverOracle(scene, preset, reading=reading, cases=cases,
                          cache_dir=cache_dir or Path(workdir) / "active" / "solver")
    y = objective_table(train, (reading,))[reading]
    yt = objective_table(test, (reading,))[reading]
    problem = Problem(names=names, low=tuple(bounds[n][0] for n in names), high=tuple(bounds[n][1] for n in names),
                      oracle=oracle, band=DesignBox(), band_vars=("OCA1", "OCA2"), cases=cases,
                      row_names=scenes.names, prior=(scenes.x, y), holdout=(scenes.inputs(test, lambda msg: None), yt))
    return problem, {"preset": preset, "reading": reading, "prior_solver_runs": len(train), "n_holdout": len(test)}


def mgn_base(workdir, problem: Problem, cache_path, *, reading: str = "area_mean"):
    """rows (n, P) -> (n,) the run's MGN objective [MPa] at each row's design (the box problem: one case),
    memoised in a JSON file at ``cache_path`` (one entry per design, nm keys) so the loop and a resume pay
    each rollout once."""
    if len(problem.cases) != 1 or problem.cases[0]:
        raise ValueError("mgn surrogate in the loop: only for the box problem (one drop case)")
    _, (train, _, _) = _splits(workdir)
    scene = Scene.from_dict(train[0].meta["scene"])
    part = scene.part_names.index("OLED")
    obj = MGNObjective(fit("mgn", train, workdir=Path(workdir)),
                       DesignMap.build(scene, solver_preset(train[0], workdir)), part=part, reading=reading)
    path = Path(cache_path)
    memo = json.loads(path.read_text()) if path.exists() else {}

    def base(rows):
        d = np.asarray(rows, float)[:, [problem.row_names.index(n) for n in problem.names]]
        keys = [",".join(str(int(round(v * 1e9))) for v in x) for x in d]
        todo = sorted({k for k in keys if k not in memo})
        if todo:
            got = obj(np.array([[int(v) * 1e-9 for v in k.split(",")] for k in todo]))
            memo.update({k: float(v) for k, v in zip(todo, got)})
            atomic_write_json(path, memo)
        return np.array([memo[k] for k in keys])
    return base


def _strategy_config(name: str, budget: int, seed: int, budgets: Sequence[int]) -> LoopConfig:
    kw = dict(STRATEGIES[name])
    if name == "lhs+mop":
        return LoopConfig(**kw, budget=budget, n_init=budget - 1, seed=seed)
    return LoopConfig(**kw, budget=max(budgets), seed=seed)


def compare(workdir, *, budgets: Sequence[int] = (8, 12, 16, 24), seeds: Sequence[int] = (0, 1),
            strategies: Sequence[str] = ("lhs+mop", "gp-ei", "auto-ei", "mgn-ei"), out_dir,
            reading: str = "area_mean", progress: bool = True) -> dict:
    """Run every strategy x seed on the box problem (logs under ``out_dir``/logs, resumable) and return
    {'reference', 'rows': [{strategy, budget, seed, mpa, gap_pct, design_um, holdout_mae_pct}], ...}."""
    unknown = [s for s in strategies if s not in STRATEGIES]
    if unknown:
        raise ValueError(f"strategies must be among {tuple(STRATEGIES)}, got {unknown}")
    out = Path(out_dir)
    problem, ctx = box_problem(workdir, reading=reading)
    rows, hits = [], []
    for name in strategies:
        base = mgn_base(workdir, problem, out / "logs" / "mgn_predictions.json", reading=reading) \
            if name == "mgn-ei" else None
        for seed in seeds:
            per_budget = budgets if name == "lhs+mop" else (max(budgets),)
            for b in per_budget:
                cfg = _strategy_config(name, b, seed, budgets)
                tag = f"{name}_s{seed}" + (f"_b{b}" if name == "lhs+mop" else "")
                log = run_loop(problem, cfg, out / "logs" / f"{tag}.json", base=base, progress=progress,
                               meta={"strategy": name, "workdir": str(workdir)})
                for bb in (b,) if name == "lhs+mop" else budgets:
                    best = best_at(log, bb)
                    last = [r for r in log["rounds"] if r["solver_runs"] <= bb][-1]
                    h = last.get("holdout_error")
                    rows.append({"strategy": name, "budget": bb, "seed": seed, "mpa": best["mpa"],
                                 "gap_pct": best.get("gap_pct"), "design_um": best["design_um"],
                                 "holdout_mae_pct": None if h is None else h["mae_pct"]})
            if name != "lhs+mop":
                hit = next((r["solver_runs"] for r in log["rounds"] if r["best"]["gap_pct"] <= HIT_PCT), None)
                hits.append({"strategy": name, "seed": seed, "runs": hit})
        if name == "lhs+mop":
            for seed in seeds:
                ok = [r["budget"] for r in rows if r["strategy"] == name and r["seed"] == seed
                      and r["gap_pct"] <= HIT_PCT]
                hits.append({"strategy": name, "seed": seed, "runs": min(ok) if ok else None,
                             "note": f"smallest of the budgets {list(budgets)}"})
    return {"reference": problem.reference, "context": ctx, "budgets": list(budgets), "seeds": list(seeds),
            "strategies": list(strategies), "rows": rows, "hit_pct": HIT_PCT, "runs_to_hit": hits}


def table_markdown(result: dict, command: str = "") -> str:
    """The comparison as a markdown table: per strategy and budget the best solver value's gap to the
    reference [%], mean over seeds (worst seed in brackets)."""
    ref = result["reference"]
    budgets = result["budgets"]
    lines = [f"Reference: {ref['mpa']:.4f} MPa at {ref['design_um']} µm (the solver, "
             f"{result['context']['preset']} preset, {result['context']['reading']}). Gap of the best solver value "
             f"found to it, mean over seeds {result['seeds']} (worst in brackets); "
             "negative = better than the reference.", ""]
    body = []
    for name in result["strategies"]:
        cells = []
        for b in budgets:
            g = [r["gap_pct"] for r in result["rows"] if r["strategy"] == name and r["budget"] == b]
            cells.append(f"{np.mean(g):+.2f} ({max(g):+.2f})" if g else "–")
        h = [r["holdout_mae_pct"] for r in result["rows"] if r["strategy"] == name and r["budget"] == max(budgets)
             and r["holdout_mae_pct"] is not None]
        runs = [x["runs"] for x in result["runs_to_hit"] if x["strategy"] == name]
        cells.append(", ".join("not reached" if r is None else str(r) for r in runs))
        cells.append(f"{np.mean(h):.3f}" if h else "–")
        body.append((name, *cells))
    lines += markdown.table(("strategy", *(f"{b} runs" for b in budgets),
                             f"solver runs to within {result['hit_pct']} % (per seed)",
                             "holdout error at the largest budget [%]"), body)
    if command:
        lines = [f"`{command}`", ""] + lines
    return "\n".join(lines) + "\n"
