"""Search the design box for the lowest objective: a genetic algorithm (pymoo), a multi-start projected
gradient descent, and multi-start SLSQP (scipy: sequential quadratic programming with the bounds and the
sum band as constraints, quasi-Newton curvature from the exact gradients). All take an objective of
:mod:`pcmgn_jax.opt.objectives`; designs [m].
"""
from __future__ import annotations

import time

import numpy as np

from pcmgn_jax.opt.problem import DesignBox


def ga(objective, box: DesignBox, *, pop: int = 100, gens: int = 50, seed: int = 0,
       progress: bool = True) -> dict:
    """pymoo's single-objective GA with its constraint handling (feasibility first, then objective);
    each generation's designs go to the objective as one batch. The paper's budget is 100 x 50. ``box``: a
    :class:`DesignBox` or any box with its ``dim``, ``low``, ``high``, ``n_constraints`` and ``constraints``
    (a stack search's :class:`pcmgn_jax.opt.scenes.ParameterBox`: bounds only; its values in SI, so the
    result's ``x_um`` fields hold SI x 1e6 there).

    Returns {x (D,) [m], f [MPa], n_evals, seconds, history: per generation best f and feasible best x,
    final_population (P, D) [m]}."""
    from pymoo.algorithms.soo.nonconvex.ga import GA
    from pymoo.core.callback import Callback
    from pymoo.core.problem import Problem
    from pymoo.optimize import minimize
    from tqdm.auto import tqdm

    scale = 1e6  # pymoo works in µm: O(100) variables for its operators' default step sizes

    class _Problem(Problem):
        def __init__(self):
            super().__init__(n_var=box.dim, n_obj=1, n_ieq_constr=box.n_constraints, xl=box.low * scale,
                             xu=box.high * scale)

        def _evaluate(self, X, out, *args, **kwargs):
            d = np.asarray(X, float) / scale
            out["F"] = objective(d)[:, None]
            if box.n_constraints:
                out["G"] = box.constraints(d) * scale

    bar = tqdm(total=gens, unit="gen", desc=f"GA {getattr(objective, 'name', '')}", disable=not progress,
               dynamic_ncols=True)

    class _Record(Callback):
        def __init__(self):
            super().__init__()
            self.best = []

        def notify(self, algorithm):
            opt = algorithm.opt[0]
            self.best.append({"f": float(opt.F[0]), "x_um": [float(v) for v in opt.X],
                              "feasible": bool(float(opt.CV[0]) <= 0)})
            bar.update(1)
            bar.set_postfix(f=f"{opt.F[0]:.4f}")

    rec = _Record()
    t0 = time.perf_counter()
    try:
        res = minimize(_Problem(), GA(pop_size=pop, eliminate_duplicates=True), ("n_gen", gens), seed=seed,
                       callback=rec, verbose=False)
    finally:
        bar.close()
    seconds = time.perf_counter() - t0
    if res.X is None:
        raise RuntimeError("GA: no feasible design found")
    x = np.asarray(res.X, float).reshape(-1) / scale
    return {"x": x, "f": float(np.asarray(res.F).reshape(-1)[0]), "n_evals": int(objective.n_evals),
            "seconds": seconds, "history": rec.best,
            "final_population": (np.asarray(res.pop.get("X"), float) / scale).tolist()}


def gradient(objective, box: DesignBox, *, starts: int = 4, iters: int = 20, step: float = 0.1,
             min_step: float = 2e-3, seed: int = 0, progress: bool = True) -> dict:
    """Multi-start projected gradient descent in box-scaled coordinates z = d / (high - low).

    Every start moves by ``step`` along the normalised negative gradient, projected onto the feasible
    set; an improving move is kept and the step grows x1.25, a worsening one is rejected and the step
    halves; a start stops below ``min_step`` (x (high - low): 0.2 µm by default) or after ``iters``
    evaluations. All live starts are evaluated as one batch per iteration.
    Returns {x, f, n_evals, seconds, paths: per start the accepted designs [µm] and values}."""
    from tqdm.auto import tqdm

    span = box.high - box.low
    x = box.starts(starts, seed)
    t0 = time.perf_counter()
    n0 = objective.n_evals
    f, g = objective.value_and_grad(x)
    h = np.full(starts, step)
    paths = [[{"x_um": (xi * 1e6).tolist(), "f": float(fi)}] for xi, fi in zip(x, f)]
    live = np.ones(starts, bool)
    for _ in tqdm(range(iters - 1), desc=f"gradient {getattr(objective, 'name', '')}", disable=not progress,
                  dynamic_ncols=True):
        if not live.any():
            break
        gz = g * span                                             # d f / d z
        norm = np.linalg.norm(gz, axis=1, keepdims=True)
        direction = np.where(norm > 0, gz / np.where(norm > 0, norm, 1.0), 0.0)
        trial = box.project(x - (h[:, None] * direction) * span)
        idx = np.flatnonzero(live & (np.abs(trial - x).max(axis=1) > 0))
        live[np.setdiff1d(np.flatnonzero(live), idx)] = False     # no feasible descent move left
        if not len(idx):
            break
        ft, gt = objective.value_and_grad(trial[idx])
        for k, i in enumerate(idx):
            if ft[k] < f[i]:
                x[i], f[i], g[i] = trial[i], ft[k], gt[k]
                h[i] *= 1.25
                paths[i].append({"x_um": (x[i] * 1e6).tolist(), "f": float(f[i])})
            else:
                h[i] *= 0.5
            live[i] = h[i] >= min_step
    best = int(np.argmin(f))
    return {"x": x[best].copy(), "f": float(f[best]), "n_evals": int(objective.n_evals - n0),
            "seconds": time.perf_counter() - t0, "paths": paths}


def slsqp(objective, box: DesignBox, *, starts: int = 2, iters: int = 20, ftol: float = 1e-5, seed: int = 0,
          screen: int = 0, progress: bool = True) -> dict:
    """Multi-start SLSQP (``scipy.optimize.minimize``) in box coordinates z = (d - low) / (high - low),
    the bounds and the sum band as linear constraints, ``objective.value_and_grad`` for value and exact
    gradient in one call. A quasi-Newton method needs fewer gradient evaluations than the fixed-step
    descent of :func:`gradient` on a smooth 2-variable landscape, which is what an MGN gradient costs
    (~3.5 rollouts each). ``iters`` caps SLSQP's iterations per start, ``ftol`` [MPa] its stopping
    tolerance on the objective. ``screen`` > ``starts``: first evaluate that many seeded designs (values
    only, one batch: a rollout costs ~1/3.5 of a value and gradient) and start from the best ``starts``
    of them. ``box``: a :class:`DesignBox` or a box of bounds only (a stack search's
    :class:`pcmgn_jax.opt.scenes.ParameterBox`, SI: its ``x_um`` fields hold SI x 1e6). Returns the keys of
    :func:`gradient` (paths: per start the iterates; ``screened``: the screened designs [µm] and values)."""
    from scipy.optimize import minimize
    from tqdm.auto import tqdm

    span = box.high - box.low
    t0 = time.perf_counter()
    n0 = objective.n_evals
    screened = None
    if screen > starts:
        cand = box.starts(screen, seed)
        fc = np.asarray(objective(cand), float)
        d0 = cand[np.argsort(fc)[:starts]]
        screened = [{"x_um": (x * 1e6).tolist(), "f": float(f)} for x, f in zip(cand, fc)]
    else:
        d0 = box.starts(starts, seed)
    bar = tqdm(total=starts, desc=f"slsqp {getattr(objective, 'name', '')}", disable=not progress, dynamic_ncols=True)
    memo: dict[bytes, tuple[float, np.ndarray]] = {}

    def fun(z):
        d = np.clip(box.low + np.asarray(z, float) * span, box.low, box.high)   # SLSQP may step 1e-16 out
        # keyed at 1e-15 m: SLSQP, its callback and the z <-> d round trip hand back the same iterate
        # with other last bits, and an MGN value and gradient costs ~3.5 rollouts
        key = tuple(np.round(d / 1e-15).astype(np.int64).tolist())
        if key not in memo:
            f, g = objective.value_and_grad(d[None])
            memo[key] = (float(f[0]), np.asarray(g[0], float) * span)
        return memo[key]

    # the sum band as SLSQP's g(z) >= 0: DesignBox.constraints is g <= 0 [m], linear in z; a box of bounds only
    # (a stack's ParameterBox, n_constraints 0) gives scipy no constraint at all (its default, ())
    dg = np.stack([span * np.ones(box.dim), -span * np.ones(box.dim)])
    cons = [{"type": "ineq", "fun": lambda z: -box.constraints(box.low + z * span)[0], "jac": lambda z: dg}] \
        if box.n_constraints else ()
    results, paths = [], []
    for d in d0:
        z0 = (d - box.low) / span
        path = [z0.copy()]
        res = minimize(fun, z0, jac=True, method="SLSQP", bounds=[(0.0, 1.0)] * box.dim, constraints=cons,
                       callback=lambda zk: path.append(np.array(zk, float)),
                       options={"maxiter": iters, "ftol": ftol})
        x = box.project(box.low + np.asarray(res.x, float) * span)[0]
        results.append((fun((x - box.low) / span)[0], x))
        paths.append([{"x_um": ((box.low + z * span) * 1e6).tolist(), "f": fun(z)[0]} for z in path])
        bar.update(1)
    bar.close()
    best = int(np.argmin([f for f, _ in results]))
    return {"x": results[best][1].copy(), "f": float(results[best][0]), "n_evals": int(objective.n_evals - n0),
            "seconds": time.perf_counter() - t0, "paths": paths, "screened": screened}
