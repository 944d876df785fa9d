"""The design-optimisation pipeline as a library call: ``pcmgn_jax.opt.run(workdir, ...)`` (paper §5).

Loads the run's splits, builds the surrogate objective (the run's model, ``mgn``, or a baseline fitted on
the training split, :mod:`pcmgn_jax.opt.objectives`), searches the design box (GA, projected gradient or
SLSQP, :mod:`pcmgn_jax.opt.search`), re-simulates the optimum with the built-in solver
(:func:`pcmgn_jax.opt.check.solver_objectives`, cached under RUN/optimize/solver/), maps the objective on
a grid and writes RUN/optimize/<tag>.json and .png (:func:`result_tag`). The GA is resumable through
RUN/optimize/<tag>.resume.json, removed when the result is written. ``experiments/optimize.py`` parses
flags and calls :func:`run`; the caller picks the matplotlib backend.
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from pcmgn_jax.lock import hold
from pcmgn_jax.surrogates.kinds import AUTO, KINDS, TRUTH, choices

# what the optimiser can search on: the kinds with ``optimise`` (pcmgn_jax/surrogates/kinds.py), ``solver`` (the
# solver itself with its exact gradient, pcmgn_jax/opt/truth.py) and ``auto`` (mop, its CoP table in the result)
SURROGATES = choices("optimise")


def result_tag(surrogate: str, method: str, objective: str, stack: Sequence[str] = (),
               params: Sequence[str] = ()) -> str:
    """The result's file stem under RUN/optimize, named by its search: ``<surrogate>_<method>[_<objective>]``
    (no suffix for the default ``area_mean``), on a panel-stack run ``[_<layer-list>]`` (a layer list other than
    the paper's six, its names joined by '-') and ``[_p<hash>]`` (the ``params`` searched, when named)."""
    import hashlib

    from pcmgn_jax.data.stack import variant_layers
    layers = [n.strip() for n in stack if n.strip()]
    names = ",".join(n.strip() for n in params if n.strip())
    return (f"{surrogate}_{method}" + ("" if objective == "area_mean" else f"_{objective}")
            + ("" if not layers or tuple(layers) == variant_layers(True, None) else "_" + "-".join(layers))
            + (f"_p{hashlib.sha256(names.encode()).hexdigest()[:8]}" if names else ""))


def replacing(path: Path, record: dict) -> str | None:
    """The line that says a result at ``path`` is replaced (its command, and the arguments ``record`` changes),
    or None when there is none: a second search never replaces the first's result silently."""
    import json
    try:
        old = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    args = old.get("args") or {}
    diff = sorted(k for k in set(args) | set(record) if k != "progress" and args.get(k) != record.get(k))
    return (f"note: replacing {path}, the result of `{old.get('command') or '?'}`"
            + (f" (this search differs in {', '.join(diff)})" if diff else " (the same search again)"))


def run(workdir: str | Path, *, surrogate: str = "kriging", method: str = "ga", objective: str = "area_mean",
        pop: int = 100, gens: int = 50, starts: int = 4, iters: int = 20, screen: int = 0, seed: int = 0,
        grid: int = -1, which: str = "best", check: bool = True, progress: bool = True,
        ensemble: Sequence[str | Path] = (), stack: Sequence[str] = (), params: Sequence[str] = (),
        command: str = "") -> dict:
    """Optimise the OCA thicknesses of the run in ``workdir`` on ``surrogate`` (:data:`SURROGATES`: mgn | nearest |
    poly2 | rbf | kriging | mop | solver | auto, auto = mop with its CoP table in the result; solver = every value a
    solver run with its exact gradient on the run's data's mesh preset, :mod:`pcmgn_jax.opt.truth`: gradient or
    slsqp only, resumable like the GA, its trace in the result, its check the search's own value)
    with ``method`` (ga | gradient | slsqp) for the OLED objective ``objective`` (area_mean | node_mean |
    disc_mean | peak, docs/design.md §8) and return the result dict written to RUN/optimize/<tag>.json.

    ``pop`` / ``gens``: GA budget; ``starts`` / ``iters``: gradient and SLSQP starts and evaluations
    (iterations) per start; ``screen``: SLSQP only, seeded designs screened for the start; ``seed``: GA /
    starts seed; ``grid``: n x n objective map (-1: 21, mgn 7, solver none: each point a solver run; 0 or 1:
    none); ``which``: mgn checkpoint; ``check``: re-run the solver at the optimum; ``ensemble``: run folders
    whose MGNs join the run's for the spread of an mgn optimum (:mod:`pcmgn_jax.opt.spread`; without: a residual GP's);
    ``command``: recorded in the result. A panel-stack run is searched over its scene parameters
    instead (:mod:`pcmgn_jax.opt.stack_search`: GA on a surrogate; slsqp or gradient on the solver,
    :mod:`pcmgn_jax.opt.truth_stack`): ``stack`` (the layer names, top to bottom; () the paper's six) and
    ``params`` (the parameter names to search; () every layer's thickness and modulus); both are refused on
    other runs. Designs in the result
    in µm, objectives in MPa. Raises ``ValueError`` for ``screen`` without slsqp or data without a solver
    preset; :class:`pcmgn_jax.mgn.checkpoint.MissingRun` (one line, nothing written) when ``workdir`` is no run
    folder, holds no config.json or (``mgn``) no checkpoint. RUN/optimize is locked while it runs
    (:func:`pcmgn_jax.lock.hold`: one optimisation writes there at a time)."""
    from pcmgn_jax.mgn.checkpoint import require_run  # here, not at the top: `import pcmgn_jax.opt` stays light
    if surrogate not in SURROGATES:
        raise ValueError(f"surrogate must be one of {SURROGATES}, got {surrogate!r}")
    for name, value in (("ensemble", ensemble), ("stack", stack), ("params", params)):
        if isinstance(value, str):
            raise TypeError(f"{name}={value!r}: give a sequence of names, not a string (a command line splits "
                            "its comma list)")
    if surrogate == TRUTH and method == "ga":
        raise ValueError("surrogate='solver' with method='ga': every GA candidate would be a solver run (5,000 at the "
                         "paper's 100 x 50); use method='slsqp' (or 'gradient') with the solver's exact gradient")
    require_run(workdir, checkpoint=surrogate == "mgn")
    for member in ensemble:
        require_run(member, checkpoint=True)      # an ensemble member is checked before the search, not after
    with hold(Path(workdir) / "optimize", "optimize"):
        return _optimize(workdir, surrogate=surrogate, method=method, objective=objective, pop=pop, gens=gens,
                         starts=starts, iters=iters, screen=screen, seed=seed, grid=grid, which=which, check=check,
                         progress=progress, ensemble=tuple(str(m) for m in ensemble), stack=tuple(stack),
                         params=tuple(params), command=command)


def _optimize(workdir: str | Path, *, surrogate: str, method: str, objective: str, pop: int, gens: int, starts: int,
              iters: int, screen: int, seed: int, grid: int, which: str, check: bool, progress: bool,
              ensemble: tuple[str, ...], stack: tuple[str, ...], params: tuple[str, ...], command: str) -> dict:
    """:func:`run` once the run is checked and RUN/optimize locked."""
    import numpy as np

    from pcmgn_jax import metrics
    from pcmgn_jax.atomic import atomic_write_json
    from pcmgn_jax.eval import plots
    from pcmgn_jax.opt import search
    from pcmgn_jax.opt.check import solver_objectives, solver_preset
    from pcmgn_jax.opt.objectives import FieldObjective, MGNObjective
    from pcmgn_jax.opt.problem import DesignBox
    from pcmgn_jax.opt.scenes import PAPER_STACK, family_of, is_stack
    from pcmgn_jax.opt.spread import optimum_spread
    from pcmgn_jax.opt.stack_search import optimize_stack
    from pcmgn_jax.scene import Scene
    from pcmgn_jax.sim.design_map import DesignMap
    from pcmgn_jax.surrogates.inputs import design_of
    from pcmgn_jax.surrogates.mgn import run_splits
    from pcmgn_jax.surrogates.registry import fit, fit_objective

    record = {"workdir": str(workdir), "surrogate": surrogate, "method": method, "objective": objective,
              "pop": pop, "gens": gens, "starts": starts, "iters": iters, "screen": screen, "seed": seed,
              "grid": grid, "which": which, "check": check, "progress": progress, "ensemble": ",".join(ensemble)}
    if screen and method != "slsqp":
        raise ValueError(f"screen={screen}: only for method='slsqp' (got method={method!r})")
    run_dir = Path(workdir)
    cfg, train, val, test = run_splits(run_dir)
    ref = train[0]
    scene = Scene.from_dict(ref.meta["scene"])
    preset = solver_preset(ref, cfg.resolved_dataset_dir)
    tag = result_tag(surrogate, method, objective, stack, params)
    if is_stack(family_of(ref)):
        dest = plots.ensure_dir(run_dir / "optimize")
        record.update(stack=",".join(stack), params=",".join(params))   # the result's record: as the flags were
        if note := replacing(dest / f"{tag}.json", record):
            print(note)
        out = optimize_stack(run_dir, cfg, train, surrogate=surrogate, method=method, objective=objective, pop=pop,
                             gens=gens, seed=seed, which=which, check=check, progress=progress,
                             layers=stack or PAPER_STACK, search_names=params or None,
                             preset=preset, resume=dest / f"{tag}.resume.json", record=record, command=command,
                             starts=starts, iters=iters, screen=screen)
        atomic_write_json(dest / f"{tag}.json", out)
        (dest / f"{tag}.resume.json").unlink(missing_ok=True)
        return out
    if stack or params:
        raise ValueError(f"stack={stack} / params={params}: only for a panel-stack run; {run_dir} is not one (its "
                         f"data's meta.family is {ref.meta.get('family')!r})")
    part = scene.part_names.index("OLED")
    box = DesignBox(dim=len(scene.design_layers))
    dmap = DesignMap.build(scene, preset)
    kw = {"part": part, "reading": objective}
    kind = "mop" if surrogate == AUTO else surrogate   # auto: MOP's choice by leave-one-out CoP
    if surrogate == TRUTH:
        from pcmgn_jax.opt.truth import SolverObjective
        obj = SolverObjective(scene, preset, box, **kw)
    elif KINDS[kind].family == "mgn":   # its exact gradient through the rollout and the design map
        obj = MGNObjective(fit(kind, train, workdir=run_dir, ref=ref, which=which), dmap, names=scene.design_layers,
                           **kw)
    else:   # a response surface read at the designs, any other kind's fields at them (objectives.FieldObjective)
        obj = FieldObjective(fit_objective(kind, train, readings=(objective,), part=part), dmap,
                             names=scene.design_layers, **kw)

    dest = plots.ensure_dir(run_dir / "optimize")
    if note := replacing(dest / f"{tag}.json", record):
        print(note)
    resume = dest / f"{tag}.resume.json"
    loaded = 0
    budget = {"pop": pop, "gens": gens} if method == "ga" else {"starts": starts, "iters": iters,
                                                                **({"screen": screen} if screen else {})}
    resumable = method == "ga" or surrogate == TRUTH
    if resumable:
        # the values go to a resume file as they come: a killed search run again replays them and goes on
        loaded = obj.persist(resume, {"surrogate": surrogate, "method": method, "seed": seed, "preset": preset,
                                      **({"pop": pop, "gens": gens, "which": which} if method == "ga" else
                                         {"starts": starts, "iters": iters, "screen": screen})})
        if loaded:
            print(f"{resume}: resuming with {loaded} evaluations done ({obj.prior_seconds:.0f} s of search)")
    if method == "ga":
        res = search.ga(obj, box, pop=pop, gens=gens, seed=seed, progress=progress)
    else:
        kw = {"starts": starts, "iters": iters, "seed": seed, "progress": progress}
        if method == "gradient":
            res = search.gradient(obj, box, **kw)
        else:
            res = search.slsqp(obj, box, screen=screen, **kw)
    if resumable:
        obj.stop_timing()
        res["seconds"] = obj.search_seconds()   # this run's and the killed runs' before it
        res["n_evals"] = obj.n_evals            # the killed runs' evaluations too
    x = res["x"]

    # the dataset's own solver-evaluated designs (every split the run sees), for the "beats the data" check
    data = [(design_of(t), float(metrics.oled_objective_of(t, part=part, reading=objective)))
            for t in [*train, *val, *test]]
    feas = [(d, f) for d, f in data if box.violation(d)[0] <= 1e-12]
    best_d, best_f = min(feas, key=lambda p: p[1]) if feas else (None, None)

    out = {"surrogate": surrogate, "surrogate_fingerprint": obj.fingerprint(), "method": method,
           "objective": objective, "budget": budget,
           "optimum_um": (x * 1e6).tolist(), "predicted_mpa": res["f"], "search_seconds": res["seconds"],
           "n_evals": res["n_evals"], "preset": preset, "units": {"objective": "MPa", "design": "µm"},
           "dataset_best": None if best_d is None else {"design_um": (best_d * 1e6).tolist(), "mpa": best_f},
           "command": command, "args": record, **({"resumed": {"evals_loaded": loaded}} if loaded else {})}
    spread = optimum_spread(surrogate, obj, x, train, part=part, reading=objective,
                            members=list(ensemble))
    out.update(predicted_std_mpa=spread["std_mpa"], spread=spread)
    if surrogate in ("mop", "auto"):   # why MOP chose its model: every candidate's CoP
        out["cop"] = obj.surrogate.objective.model.report()
    if surrogate == TRUTH:   # the search's value at the optimum is a solver run: no second one
        out.update(solver_mpa=res["f"], rel_error_pct=0.0, beats_dataset_best=None if best_f is None else
                   bool(res["f"] <= best_f), solver_check={
                       **obj.check(x), "how": "the search's own value at the optimum: every evaluation is a run of "
                       "the solver (float64, at the fixed dt); no second solver run (same_run: the host solver's "
                       "own stable step there gives the same substeps)"},
                   solver_runs=obj.n_solver_runs, trace=obj.trace)
    elif not check:
        out.update(solver_mpa=None, unchecked="the solver was not run at the optimum (--no_check): a prediction, "
                                              "not a solver-checked design")
    else:
        chk = solver_objectives(scene, obj.designs(x)[0], preset, cache_dir=run_dir / "optimize" / "solver")
        out.update(solver_mpa=chk[objective], solver_all_readings_mpa={k: chk[k] for k in metrics.OBJECTIVES},
                   solver_seconds=chk["solver_seconds"],
                   rel_error_pct=float(metrics.relative_error_pct(res["f"], chk[objective])),
                   beats_dataset_best=None if best_f is None else bool(chk[objective] <= best_f))
    out["history"] = res.get("history") or res.get("paths")
    if res.get("screened"):
        out["screened"] = res["screened"]

    n = grid if grid >= 0 else (0 if surrogate == TRUTH else 7 if surrogate == "mgn" else 21)
    if n > 1:
        designs, ok = box.grid(n)
        f = np.full(len(designs), np.nan)
        f[ok] = obj(designs[ok])
        out["grid"] = {"designs_um": (designs * 1e6).tolist(), "mpa": [None if np.isnan(v) else v for v in f]}
        pop_um = np.asarray(res["final_population"]) * 1e6 if "final_population" in res else None
        paths = [[p["x_um"] for p in path] for path in res["paths"]] if "paths" in res else None
        plots.objective_map(dest / f"{tag}.png", designs * 1e6, f, ok, title=f"{surrogate} {method}, "
                            f"{objective} [MPa]", points_um=pop_um, points_label="final population",
                            paths_um=paths, optimum_um=x * 1e6, solver_um=x * 1e6 if check else None,
                            dataset_um=np.asarray([d for d, _ in data]) * 1e6)
    atomic_write_json(dest / f"{tag}.json", out)
    resume.unlink(missing_ok=True)   # the result is written: a new run of the command searches afresh
    return out
