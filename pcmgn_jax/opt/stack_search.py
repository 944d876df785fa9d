"""``experiments.optimize`` on a panel-stack run: search a stack's scene parameters on a surrogate
and re-check the optimum with the solver, or on the solver itself with its exact gradient.

    out = optimize_stack(run_dir, cfg, train, surrogate="kriging", method="ga", pop=20, gens=10,
                         layers=("CG", "OCA1", "POL", "OCA2", "OLED", "PLATE"), search_names=None, ...)
    out = optimize_stack(run_dir, cfg, train, surrogate="solver", method="slsqp", starts=1, iters=30, ...)

The layer list is chosen (``layers``, default the paper's six), not searched; the searched numbers and their
box are :func:`pcmgn_jax.opt.scenes.stack_box`'s (every layer's thickness and log10 modulus by default, the
family's ranges), the rest held at the stack's nominal row. On a surrogate every candidate is a scene of its
own mesh, so the search is the GA only (no design map, no gradient through the mesh). A surrogate that cannot
answer a stack of these layers is refused by name before the search: per-node regressions (``poly2``, ``rbf``:
one shared mesh), the nearest scene when no training stack has these layers.

``surrogate="solver"`` (design on the truth, :mod:`pcmgn_jax.opt.truth_stack`): every evaluation is a run of
the differentiable solver with its exact gradient, on the mesh pinned at the nominal stack and one fixed time
step, for ``method`` 'slsqp' or 'gradient' (``starts`` / ``iters`` / ``screen`` as for the paper's box); the GA
on the solver is refused (every candidate a solver run). Its result holds the trace of every evaluation and
its check is its own value at the optimum (``solver_check``: whether that is the host solver's own run; where
it is not and ``check``, the host solver is run once there). Objectives in MPa, parameters SI.
"""
from __future__ import annotations

import hashlib
import time
import warnings
from pathlib import Path
from typing import Sequence

import numpy as np

from pcmgn_jax import metrics
from pcmgn_jax.errors import SettingError
from pcmgn_jax.opt import search
from pcmgn_jax.opt.objectives import FieldObjective, fitted_arrays
from pcmgn_jax.opt.scenes import PAPER_STACK, ParameterBox, family_of, query, solve_scene, stack_box
from pcmgn_jax.opt.spread import design_spread
from pcmgn_jax.scene import Scene
from pcmgn_jax.surrogates.kinds import AUTO, KINDS, TRUTH
from pcmgn_jax.surrogates.registry import fit, fit_objective


class StackObjective(FieldObjective):
    """Designs (B, D) [SI] of a :class:`~pcmgn_jax.opt.scenes.ParameterBox` -> the OLED objective (B,) [MPa]
    of ``model`` (a fitted kind) at each row's :class:`~pcmgn_jax.data.family.Design` (:meth:`designs`: the
    box's full row): a response surface reads its objective at the designs, any other kind predicts fields on
    each design's own mesh (:func:`pcmgn_jax.opt.scenes.query`) and the objective is read there. The cache, the
    GA's resume file and ``n_evals`` are :class:`FieldObjective`'s; no gradient."""

    def __init__(self, kind: str, model, box: ParameterBox, *, scene0: Scene, family, ref, preset: str,
                 part: int, reading: str = metrics.DEFAULT_OBJECTIVE):
        super().__init__(model, None, part=part, reading=reading, resolution=1e-12, names=box.names)
        self.kind, self.box, self.scene0, self.family, self.ref, self.preset = kind, box, scene0, family, ref, preset
        self.name = kind

    def fingerprint(self) -> str:
        h = hashlib.sha256(self.name.encode())
        h.update(repr((self.box.names, sorted(self.box.base.items()))).encode())
        for a in fitted_arrays(self.surrogate) or []:
            h.update(np.ascontiguousarray(np.asarray(a)).tobytes())
        return h.hexdigest()[:16]

    def designs(self, x) -> list:
        """The :class:`~pcmgn_jax.data.family.Design` of each row of x (B, D) [SI]: the box's full row."""
        return [self.box.design(r, self.family) for r in np.atleast_2d(np.asarray(x, float))]

    def queries(self, designs) -> list:
        return [query(d, self.scene0, self.ref, self.preset, name=f"candidate {i}")
                for i, d in enumerate(self.designs(designs))]

    def _objectives(self, designs) -> np.ndarray:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")      # extrapolation notes of the surfaces: the box is the family's
            if self.surrogate.objective_surface:
                return super()._objectives(designs)
            return np.asarray(self.surrogate.predict_objective(self.queries(designs), reading=self.reading), float)

    def value_and_grad(self, designs):
        raise SettingError("method", "a stack search has no gradient on a surrogate (every candidate has its own "
                                     "mesh): use 'ga', or the surrogate 'solver' for 'slsqp' / 'gradient'")


def _fit(kind: str, train, run_dir: Path, which: str, reading: str, probe):
    """The surrogate ``kind`` fitted for a stack search (``probe``: the query trajectory of the nominal stack, so a
    per-node regression sees a mesh of its own); ValueError naming why it cannot answer."""
    if KINDS[kind].family == "mgn":
        return fit(kind, train, workdir=run_dir, ref=train[0], which=which)
    return fit_objective(kind, train, readings=(reading,), queries=[probe])


def optimize_stack(run_dir: Path, cfg, train: Sequence, *, surrogate: str, method: str, objective: str, pop: int,
                   gens: int, seed: int, which: str, check: bool, progress: bool, layers: Sequence[str] = PAPER_STACK,
                   search_names: Sequence[str] | None = None, preset: str, resume: Path | None = None,
                   record: dict | None = None, command: str = "", starts: int = 1, iters: int = 20,
                   screen: int = 0) -> dict:
    """The stack search (module docstring): its result dict (``optimum``: {name: value} [SI] of the full
    row, ``searched``, ``predicted_mpa`` and its spread, the solver's check). SettingError naming ``method``
    when it does not fit the surrogate (a surrogate: 'ga' only; the solver: 'slsqp' or 'gradient' only);
    ValueError naming a surrogate that cannot answer or a bad parameter name (:func:`stack_box`)."""
    truth = surrogate == TRUTH
    if truth and method not in ("slsqp", "gradient"):
        raise SettingError("method", f"{method!r} with the surrogate 'solver': every candidate would be a solver "
                                     "run; use 'slsqp' or 'gradient' (the solver's exact gradient)")
    if not truth and method != "ga":
        raise SettingError("method", f"{method!r}: a stack search has no gradient on a surrogate (every candidate "
                                     "has its own mesh); use 'ga', or the surrogate 'solver' for 'slsqp' / 'gradient'")
    family = family_of(train[0])
    box = stack_box(layers, search_names)
    scene0 = Scene.from_dict(train[0].meta["scene"])
    if truth:
        return _solver_search(box, family, scene0, train, layers=layers, method=method, objective=objective,
                              starts=starts, iters=iters, screen=screen, seed=seed, check=check, progress=progress,
                              preset=preset, resume=resume, record=record, command=command)
    notes = _unseen(layers, train)
    for note in notes:
        print(f"note: {note}")
    kind = "mop" if surrogate == AUTO else surrogate
    base = np.array([box.base[n] for n in box.names])
    try:
        probe = query(box.design(base, family), scene0, train[0], preset, name="the nominal stack")
        model = _fit(kind, train, run_dir, which, objective, probe)
        obj = StackObjective(kind, model, box, scene0=scene0, family=family, ref=train[0], preset=preset,
                             part=-1, reading=objective)
        obj(base[None])                        # a refusal (e.g. no training stack of these layers) says so now
    except ValueError as err:
        raise ValueError(f"{surrogate} cannot answer a stack of {list(layers)} here: {err}") from None
    loaded = 0
    if resume is not None:
        loaded = obj.persist(resume, {"surrogate": surrogate, "method": "ga", "pop": pop, "gens": gens, "seed": seed,
                                      "preset": preset, "which": which, "layers": list(layers)})
    res = search.ga(obj, box, pop=pop, gens=gens, seed=seed, progress=progress)
    obj.stop_timing()
    x = np.asarray(res["x"], float)
    row = box.row(x)
    out = {"surrogate": surrogate, "surrogate_fingerprint": obj.fingerprint(), "method": method,
           "objective": objective, "budget": {"pop": pop, "gens": gens}, "stack": list(layers),
           "searched": {n: [float(lo), float(hi)] for n, lo, hi in zip(box.names, box.low, box.high)},
           "optimum": row, "predicted_mpa": float(res["f"]), "search_seconds": obj.search_seconds(),
           "n_evals": int(obj.n_evals), "preset": preset,
           "units": {"objective": "MPa", "optimum": "SI: thickness m, log10_youngs log10 Pa, ball.radius m, "
                                                    "ball.velocity m/s"},
           "nominal_mpa": float(obj(base[None])[0]), "command": command, "args": record or {},
           **({"resumed": {"evals_loaded": loaded}} if loaded else {}), **({"warnings": notes} if notes else {})}
    out.update(_spread(kind, model, obj, x, train, objective))
    q = obj.queries(x[None])[0]
    if check:
        traj, _ = solve_scene(obj.designs(x)[0].scene(scene0), preset)
        f = {r: float(metrics.oled_objective_of(traj, reading=r)) for r in metrics.OBJECTIVES}
        out.update(solver_mpa=f[objective], solver_all_readings_mpa=f,
                   rel_error_pct=float(metrics.relative_error_pct(res["f"], f[objective])))
    else:
        out.update(solver_mpa=None, unchecked="the solver was not run at the optimum (--no_check): a prediction")
    out["dataset_best"] = _dataset_best(train, q.meta["part_names"], objective)
    # the GA's history in SI, by name (search.ga writes its values x 1e6 as x_um)
    out["history"] = [{"f": h["f"], "x": dict(zip(box.names, (v / 1e6 for v in h["x_um"]))), "feasible": h["feasible"]}
                      for h in res.get("history") or []]
    return out


def _dataset_best(train: Sequence, part_names, objective: str) -> dict | None:
    """The lowest objective [MPa] among the training stacks of the layers ``part_names`` (None: none)."""
    same = [t for t in train if list(t.meta.get("part_names") or ()) == list(part_names)]
    best = min(((float(metrics.oled_objective_of(t, reading=objective)), t.meta.get("name", "?")) for t in same),
               default=None)
    return None if best is None else {
        "mpa": best[0], "name": best[1], "of": f"the {len(same)} training stacks of these layers (their other "
                                              "numbers differ from the searched row's)"}


def _solver_search(box: ParameterBox, family, scene0: Scene, train: Sequence, *, layers: Sequence[str], method: str,
                   objective: str, starts: int, iters: int, screen: int, seed: int, check: bool, progress: bool,
                   preset: str, resume: Path | None, record: dict | None, command: str) -> dict:
    """The stack search on the solver (module docstring; :mod:`pcmgn_jax.opt.truth_stack`): SLSQP or the
    projected gradient, every evaluation a solver run with its exact gradient; the result as the paper box's
    solver search writes it (trace, ``solver_check``, ``solver_runs``) with the stack search's keys."""
    from pcmgn_jax.opt.truth_stack import StackSolverObjective
    obj = StackSolverObjective(scene0, family, preset, box, reading=objective)
    budget = {"starts": starts, "iters": iters, **({"screen": screen} if screen else {})}
    loaded = 0
    if resume is not None:
        loaded = obj.persist(resume, {"surrogate": TRUTH, "method": method, "seed": seed, "preset": preset,
                                      "layers": list(layers), "params": list(box.names), **budget})
        if loaded:
            print(f"{resume}: resuming with {loaded} evaluations done ({obj.prior_seconds:.0f} s of search)")
    kw = {"starts": starts, "iters": iters, "seed": seed, "progress": progress}
    res = search.gradient(obj, box, **kw) if method == "gradient" else search.slsqp(obj, box, screen=screen, **kw)
    obj.stop_timing()
    x, f = np.asarray(res["x"], float), float(res["f"])
    truth = obj.surrogate
    key = obj._key(truth.nominal)
    if key in obj.grads:                        # the nominal stack: the search's value, else one more run (no trace)
        nominal, grad = obj.cache[key], obj.grads[key]
    else:
        v, g = truth.value_and_grad(truth.nominal)
        nominal, grad = v * 1e-6, g * 1e-6
    chk = {**obj.check(x), "how": "the search's own value at the optimum: every evaluation is a run of the solver "
           "(float64, at the fixed dt, on the mesh pinned at the nominal stack); same_run: the host solver's own "
           "mesh and stable step there are those (else, with check, host_mpa: the host solver's run there)"}
    if check and not chk["same_run"]:
        t0 = time.perf_counter()
        traj, _ = solve_scene(truth.scene(x), preset)
        host = {r: float(metrics.oled_objective_of(traj, reading=r)) for r in metrics.OBJECTIVES}
        chk.update(host_mpa=host[objective], host_all_readings_mpa=host, host_seconds=time.perf_counter() - t0,
                   host_rel_diff_pct=float(metrics.relative_error_pct(f, host[objective])))
    best = _dataset_best(train, truth.scene(x).part_names, objective)

    def si(points):     # the searches write x 1e6 as x_um (their µm of the paper's box): SI by name here
        return [{"f": p["f"], "x": dict(zip(box.names, (v / 1e6 for v in p["x_um"])))} for p in points]
    return {"surrogate": TRUTH, "surrogate_fingerprint": obj.fingerprint(), "method": method, "objective": objective,
            "budget": budget, "stack": list(layers),
            "searched": {n: [float(lo), float(hi)] for n, lo, hi in zip(box.names, box.low, box.high)},
            "optimum": box.row(x), "predicted_mpa": f, "search_seconds": obj.search_seconds(),
            "n_evals": int(obj.n_evals), "preset": preset,
            "units": {"objective": "MPa", "optimum": "SI: thickness m, log10_youngs log10 Pa, ball.radius m, "
                      "ball.velocity m/s", "gradient": "MPa per unit of each searched number (per m, per decade)"},
            "nominal_mpa": float(nominal), "nominal_grad_mpa": dict(zip(box.names, map(float, grad))),
            "command": command, "args": record or {}, **({"resumed": {"evals_loaded": loaded}} if loaded else {}),
            "predicted_std_mpa": 0.0, "spread": {"std_mpa": 0.0, "source": "none: the solver's own run at the "
                                                 "optimum (no surrogate)"},
            "solver_mpa": f, "rel_error_pct": 0.0, "solver_check": chk, "solver_runs": obj.n_solver_runs,
            "dataset_best": best, "beats_dataset_best": None if best is None else bool(f <= best["mpa"]),
            "history": [si(path) for path in res["paths"]], **({"screened": si(res["screened"])}
                                                                 if res.get("screened") else {}),
            "trace": obj.trace}


def _unseen(layers: Sequence[str], train: Sequence) -> list[str]:
    """A note when no training stack has the layer list ``layers`` (every prediction then extrapolates to it)."""
    trained = {tuple(n for n in t.meta.get("part_names") or () if n != "ball") for t in train}
    if tuple(layers) in trained:
        return []
    return [f"no training stack of this run has the layers {','.join(layers)} (trained: "
            f"{sorted({len(t) for t in trained})} layers): every prediction extrapolates to this layer list"]


def _spread(kind: str, model, obj: StackObjective, x, train, reading: str) -> dict:
    """{'predicted_std_mpa', 'spread'} at the optimum: kriging's own posterior std, else the kriging std of
    the same training stacks as a proxy (named as such; :func:`pcmgn_jax.opt.spread.design_spread`)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sd, own = design_spread(model, obj.designs(x), train, reading=reading)
    source = f"{kind} posterior std" if own else \
        f"proxy: the kriging std of the same training stacks ({kind} has no spread of its own here)"
    return {"predicted_std_mpa": float(sd[0]), "spread": {"std_mpa": float(sd[0]), "source": source}}
