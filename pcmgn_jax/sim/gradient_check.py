"""The solver's design gradient as a report: value, gradient per named parameter, their wall times and the
process's peak memory, and optionally a central finite-difference step study of the same run
(:mod:`pcmgn_jax.sim.differentiable`, at its fixed dt). ``experiments.gradient`` writes it as JSON.

Accuracy measure. The parameters have different units, so the components are compared as theta_k df/dtheta_k
[Pa] (the objective's change per relative change of the parameter): the error of component k at a step is
|theta_k (g_k - fd_k)| / ||theta * g|| (the issue's "relative to the gradient's norm", on the scaled
gradient). A central difference of relative step h moves theta_k by h |theta_k| each way.
"""
from __future__ import annotations

import resource
import time
from collections.abc import Sequence

import jax
import numpy as np

from pcmgn_jax.scene import Scene
from pcmgn_jax.sim import differentiable as dsim
from pcmgn_jax.sim.mesh import MeshSpec


def _timed(fn, *args):
    """(result, wall [s]) of ``fn(*args)`` with the result on the host."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return out, time.perf_counter() - t0


def peak_rss_mb() -> float:
    """The process's peak resident memory [MB] so far (Linux ru_maxrss, KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def unit(name: str) -> str:
    """The SI unit of d(objective [Pa]) / d(parameter ``name``)."""
    field = name.partition(".")[2]
    return {"thickness": "Pa/m", "radius": "Pa/m", "youngs": "Pa/Pa", "poisson": "Pa", "density": "Pa/(kg/m^3)",
            "velocity": "Pa/(m/s)"}[field]


def fd_study(value, theta: np.ndarray, grad: np.ndarray, names: Sequence[str], steps: Sequence[float],
             which: Sequence[str] | None = None) -> dict:
    """Central differences of ``value`` (theta (1, P) -> (1,) [Pa]) for the parameters ``which`` (default all)
    at each relative step; per parameter: fd [SI] per step and its error against ``grad`` relative to the
    scaled gradient's norm (module docstring), in %; ``converged``: the two smallest steps agree within
    0.1 % of the norm (else the difference does not settle: a kink or round-off)."""
    scaled = grad * theta
    norm = float(np.linalg.norm(scaled))
    out = {}
    for name in (names if which is None else which):
        k = list(names).index(name)
        fds = []
        for h in steps:
            probes = []
            for sign in (1.0, -1.0):
                t = theta.copy()
                t[k] += sign * h * abs(theta[k])
                probes.append(float(np.asarray(value(t[None]))[0]))
            fds.append((probes[0] - probes[1]) / (2 * h * abs(theta[k])))
        err = [abs(theta[k] * (grad[k] - f)) / norm * 100 for f in fds]
        settle = float(abs(theta[k] * (fds[-1] - fds[-2])) / norm * 100) if len(fds) > 1 else None
        out[name] = {"gradient": float(grad[k]), "fd": dict(zip(map(str, steps), map(float, fds))),
                     "error_pct_of_norm": dict(zip(map(str, steps), map(float, err))),
                     "fd_change_pct_of_norm": settle, "converged": bool(settle is not None and settle < 0.1)}
    return out


def gradient_report(scene: Scene, preset: str | MeshSpec, *, names=None, reading: str = "area_mean",
                    fd_steps: Sequence[float] = (), fd_params: Sequence[str] | None = None) -> dict:
    """The objective [Pa] of ``scene`` and its gradient over ``names`` (default
    :func:`pcmgn_jax.sim.parameters.default_names`) in float64, the wall times of the value and of value and
    gradient (each the second call, after its compilation) and their ratio, the peak memory; with
    ``fd_steps`` the finite-difference study of :func:`fd_study`."""
    with jax.enable_x64(True):
        gs = dsim.setup([scene], preset, names=names, reading=reading)
        value, both = dsim.value_fn(gs), dsim.value_and_grad_fn(gs)
        _, compile_value = _timed(value, gs.theta)
        v, wall_value = _timed(value, gs.theta)
        _, compile_grad = _timed(both, gs.theta)
        (v2, g), wall_grad = _timed(both, gs.theta)
        theta, grad = gs.theta[0], np.asarray(g)[0]
        report = {
            "objective_pa": float(np.asarray(v)[0]), "reading": reading,
            "parameters": {n: {"value": float(t), "gradient": float(d), "unit": unit(n),
                               "scaled_gradient_pa": float(t * d)} for n, t, d in zip(gs.pmap.names, theta, grad)},
            "dt_s": gs.dt, "n_substeps_per_frame": gs.n_sub, "n_frames": gs.n_frames, "n_nodes": gs.mesh.n_nodes,
            "wall_value_s": wall_value, "wall_value_and_grad_s": wall_grad,
            "cost_ratio": wall_grad / wall_value, "first_call_value_s": compile_value,
            "first_call_value_and_grad_s": compile_grad, "peak_rss_mb": peak_rss_mb(),
            "value_agrees": float(abs(np.asarray(v2)[0] - np.asarray(v)[0]) / abs(np.asarray(v)[0])),
        }
        if fd_steps:
            report["fd"] = fd_study(value, theta, grad, gs.pmap.names, fd_steps, fd_params)
            errs = [min(r["error_pct_of_norm"].values()) for r in report["fd"].values()]
            report["fd_max_error_pct_of_norm"] = float(max(errs))
    return report


def accuracy_table(reports: Sequence[dict]) -> list[str]:
    """Markdown lines: per report (design) and parameter of its step study, the scaled gradient theta_k g_k
    [MPa], the error of the central difference at each step [% of the scaled norm], and whether the differences
    settled; then the cost and memory of each report."""
    from pcmgn_jax import markdown

    rows = []
    for r in reports:
        design = ", ".join(f"{t:.0f}" for t in r["design_um"])
        for name, s in r.get("fd", {}).items():
            scaled = r["parameters"][name]["scaled_gradient_pa"] * 1e-6
            errs = " / ".join(f"{e:.3f}" for e in s["error_pct_of_norm"].values())
            rows.append([r["preset"], design, r["reading"], name, f"{scaled:+.4f}", errs,
                         "yes" if s["converged"] else f"no ({s['fd_change_pct_of_norm']:.2f})"])
    steps = " / ".join(next((list(s["fd"]) for r in reports for s in r.get("fd", {}).values()), []))
    lines = markdown.table(["preset", "design [µm]", "reading", "parameter", "θ·∂f/∂θ [MPa]",
                            f"FD error, steps {steps} [% of norm]", "FD settled (change %)"], rows)
    cost = [[r["preset"], ", ".join(f"{t:.0f}" for t in r["design_um"]), r["reading"], r["n_nodes"],
             f"{r['n_frames']} × {r['n_substeps_per_frame']}", f"{r['objective_pa'] * 1e-6:.4f}",
             f"{r['wall_value_s']:.2f}", f"{r['wall_value_and_grad_s']:.2f}", f"{r['cost_ratio']:.2f}",
             f"{r['peak_rss_mb']:.0f}"] for r in reports]
    head = ["preset", "design [µm]", "reading", "nodes", "frames × substeps", "objective [MPa]", "value [s]",
            "value + gradient [s]", "ratio", "peak RSS [MB]"]
    return lines + [""] + markdown.table(head, cost)
