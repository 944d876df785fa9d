"""``experiments.optimize`` on a panel-stack run: search a stack's scene parameters on a surrogate
and re-check the optimum with the solver.

    out = optimize_stack(run_dir, cfg, train, surrogate="kriging", pop=20, gens=10,
                         layers=("CG", "OCA1", "POL", "OCA2", "OLED", "PLATE"), search=None)

The layer list is chosen (``layers``, default the paper's six), not searched; the searched numbers and their
box are :func:`pcmgn_jax.opt.scenes.stack_box`'s (every layer's thickness and log10 modulus by default, the
family's ranges), the rest held at the stack's nominal row. Every candidate is a scene of its own mesh, so
the search is the GA only (no design map, no gradient through the mesh). A surrogate that cannot answer
a stack of these layers is refused by name before the search: per-node regressions (``poly2``, ``rbf``: one
shared mesh), the nearest scene when no training stack has these layers. Objectives in MPa, parameters SI.
"""
from __future__ import annotations

import hashlib
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
from pcmgn_jax.surrogates.kinds import AUTO, KINDS
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
        raise SettingError("method", "a stack search has no gradient (every candidate has its own mesh): use 'ga'")


def _fit(kind: str, train, run_dir: Path, which: str, reading: str, probe):
    """The surrogate ``kind`` fitted for a stack search (``probe``: the query trajectory of the nominal stack, so a
    per-node regression sees a mesh of its own); ValueError naming why it cannot answer."""
    if KINDS[kind].family == "mgn":
        return fit(kind, train, workdir=run_dir, ref=train[0], which=which)
    return fit_objective(kind, train, readings=(reading,), queries=[probe])


def optimize_stack(run_dir: Path, cfg, train: Sequence, *, surrogate: str, method: str, objective: str, pop: int,
                   gens: int, seed: int, which: str, check: bool, progress: bool, layers: Sequence[str] = PAPER_STACK,
                   search_names: Sequence[str] | None = None, preset: str, resume: Path | None = None,
                   record: dict | None = None, command: str = "") -> dict:
    """The stack search (module docstring): its result dict (``optimum``: {name: value} [SI] of the full
    row, ``searched``, ``predicted_mpa`` and its spread, the solver's check). ValueError naming a method
    other than ga, a surrogate that cannot answer, or a bad parameter name (:func:`stack_box`)."""
    if method != "ga":
        raise SettingError("method", f"{method!r}: a stack search has no gradient (every candidate has its own "
                                     "mesh); use 'ga'")
    family = family_of(train[0])
    box = stack_box(layers, search_names)
    notes = _unseen(layers, train)
    for note in notes:
        print(f"note: {note}")
    scene0 = Scene.from_dict(train[0].meta["scene"])
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
    same = [t for t in train if list(t.meta.get("part_names") or ()) == list(q.meta["part_names"])]
    best = min(((float(metrics.oled_objective_of(t, reading=objective)), t.meta.get("name", "?")) for t in same),
               default=None)
    out["dataset_best"] = None if best is None else {
        "mpa": best[0], "name": best[1], "of": f"the {len(same)} training stacks of these layers (their other "
                                              "numbers differ from the searched row's)"}
    # the GA's history in SI, by name (search.ga writes its values x 1e6 as x_um)
    out["history"] = [{"f": h["f"], "x": dict(zip(box.names, (v / 1e6 for v in h["x_um"]))), "feasible": h["feasible"]}
                      for h in res.get("history") or []]
    return out


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
