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
from pcmgn_jax.opt.objectives import FieldObjective
from pcmgn_jax.opt.scenes import PAPER_STACK, ParameterBox, family_of, query, scene_at, solve_scene, stack_box
from pcmgn_jax.opt.spread import SPREAD_OF
from pcmgn_jax.scene import Scene
from pcmgn_jax.surrogates.kinds import AUTO, KINDS
from pcmgn_jax.surrogates.registry import fit


class StackObjective(FieldObjective):
    """Designs (B, D) [SI] of a :class:`~pcmgn_jax.opt.scenes.ParameterBox` -> the OLED objective (B,) [MPa]
    of ``model`` (a fitted kind): a response surface reads its objective surface at the rows, any other kind
    predicts fields on each row's own mesh (:func:`pcmgn_jax.opt.scenes.query`) and the objective is read
    there. The cache, the GA's resume file and ``n_evals`` are :class:`FieldObjective`'s; no gradient."""

    def __init__(self, kind: str, model, box: ParameterBox, *, scene0: Scene, family, ref, preset: str,
                 part: int, reading: str = metrics.DEFAULT_OBJECTIVE):
        super().__init__(model, None, part=part, reading=reading, resolution=1e-12)
        self.kind, self.box, self.scene0, self.family, self.ref, self.preset = kind, box, scene0, family, ref, preset
        self.name = kind

    def fingerprint(self) -> str:
        import jax
        h = hashlib.sha256(self.name.encode())
        h.update(repr((self.box.names, sorted(self.box.base.items()))).encode())
        sim = getattr(self.surrogate, "sim", None)
        scenes = getattr(getattr(self.surrogate, "objective", None), "scenes", None)
        arrays = jax.tree.leaves((sim.params, sim.stats)) if sim is not None else \
            [scenes.x] if scenes is not None else []
        for a in arrays:
            h.update(np.ascontiguousarray(np.asarray(a)).tobytes())
        return h.hexdigest()[:16]

    def queries(self, designs) -> list:
        out = []
        for i, x in enumerate(np.atleast_2d(np.asarray(designs, float))):
            row = self.box.row(x)
            out.append(query(scene_at(self.scene0, row, self.family), self.ref, self.preset, scene_params=row,
                             name=f"candidate {i}"))
        return out

    def _objectives(self, designs) -> np.ndarray:
        d = np.atleast_2d(np.asarray(designs, float))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")      # extrapolation notes of the surfaces: the box is the family's
            if KINDS[self.kind].objective_surface:
                surface = self.surrogate.objective
                return np.asarray(surface.predict(_surface_inputs(surface, self.box, d))[self.reading], float)
            return np.asarray(self.surrogate.predict_objective(self.queries(d), reading=self.reading), float)

    def value_and_grad(self, designs):
        raise SettingError("method", "a stack search has no gradient (every candidate has its own mesh): use 'ga'")


def _surface_inputs(surface, box: ParameterBox, designs) -> np.ndarray:
    """(B, P) inputs of an objective ``surface`` (its ``names`` order) at designs (B, D) [SI] of ``box``: each
    design's full row (:meth:`ParameterBox.row`)."""
    rows = [box.row(x) for x in np.atleast_2d(np.asarray(designs, float))]
    return np.array([[r[n] for n in surface.names] for r in rows])


def _fit(kind: str, train, run_dir: Path, which: str, reading: str):
    """The surrogate ``kind`` fitted for a stack search; ValueError naming why it cannot answer."""
    spec = KINDS[kind]
    if spec.family == "mgn":
        return fit(kind, train, workdir=run_dir, ref=train[0], which=which)
    if spec.fields == "shared":
        if not spec.objective_surface:
            raise ValueError(f"{kind}: per-node regression needs one shared mesh; every stack has its own "
                             "(use mgn, kriging, mop, auto or nearest)")
        return fit(kind, train, readings=(reading,), fields=False)
    return fit(kind, train)


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
    try:
        model = _fit(kind, train, run_dir, which, objective)
        obj = StackObjective(kind, model, box, scene0=scene0, family=family, ref=train[0], preset=preset,
                             part=-1, reading=objective)
        base = np.array([box.base[n] for n in box.names])
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
        traj, _ = solve_scene(scene_at(scene0, row, family), preset)
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
    the same training stacks as a proxy (named as such; opt.spread's rule for surrogates without one)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        surface = (model if kind == SPREAD_OF else fit(SPREAD_OF, train, readings=(reading,), fields=False)).objective
        _, sd = surface.predict(_surface_inputs(surface, obj.box, x), return_std=True)
    source = f"{kind} posterior std" if kind == SPREAD_OF else \
        f"proxy: the kriging std of the same training stacks ({kind} has no spread of its own here)"
    return {"predicted_std_mpa": float(sd[reading][0]), "spread": {"std_mpa": float(sd[reading][0]), "source": source}}
