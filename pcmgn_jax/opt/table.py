"""The design-optimisation results as one markdown table like the paper's Table 8: a row per result JSON
of :func:`pcmgn_jax.opt.run` (``experiments.optimize``), best solver-checked optimum first, beside the best
of the dataset's own solver-evaluated designs; each row's command is listed under the table.

A row names its file relative to the folder all the files share, so results of two models in two folders
(the same file names) stay apart; a surrogate's fingerprint (its parameters' hash) follows its name.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

from pcmgn_jax import markdown
from pcmgn_jax.errors import SettingError


def budget_of(d: dict) -> str:
    """The search budget in words: GA population × generations, starts × iterations, screening."""
    b = d.get("budget", {})
    if d["method"] == "ga":
        return f"{b['pop']} × {b['gens']}" + (" (paper)" if (b["pop"], b["gens"]) == (100, 50) else "")
    text = f"{b['starts']} start{'s' if b['starts'] != 1 else ''} × {b['iters']}"
    return text + (f", {b['screen']} screened" if b.get("screen") else "")


def read_result(path, required=("method", "optimum_um", "predicted_mpa")) -> dict:
    """The design-layer result JSON of ``experiments.optimize`` at ``path``; ValueError naming the file when it
    cannot be read, is a stack search's (its optimum a row of scene parameters) or lacks a ``required`` key."""
    try:
        d = json.loads(Path(path).read_text())
    except (OSError, ValueError) as e:
        raise ValueError(f"{path}: not a result of experiments.optimize ({e})") from e
    if isinstance(d, dict) and "optimum" in d:
        raise ValueError(f"{path}: a stack search's result (its optimum is a row of scene parameters, "
                         "pcmgn_jax/opt/stack_search.py); this table is of design-layer optima")
    missing = [k for k in required if not isinstance(d, dict) or k not in d]
    if missing:
        raise ValueError(f"{path}: not a result of experiments.optimize (no {', '.join(map(repr, missing))})")
    return d


def rows(paths) -> list[str]:
    """The markdown table of the optimize JSONs ``paths`` (see the module docstring), as lines.
    Raises ``ValueError`` naming a file that is not an optimize result, or when ``paths`` is empty."""
    results = [(Path(p), read_result(p)) for p in paths]
    if not results:
        raise SettingError("files", "no optimize results given")
    results.sort(key=lambda r: (r[1].get("solver_mpa") is None, r[1].get("solver_mpa") or 0.0))
    root = Path(os.path.commonpath([p.resolve().parent for p, _ in results]))
    name = {p: p.resolve().relative_to(root).as_posix() for p, _ in results}
    # the same dataset best at the table's precision (results written months apart differ in last bits)
    best = {None if not d.get("dataset_best") else
            (round(d["dataset_best"]["mpa"], 4), *(round(x, 1) for x in d["dataset_best"]["design_um"]))
            for _, d in results}
    lines = []
    if len(best) == 1 and results[0][1].get("dataset_best"):
        db = results[0][1]["dataset_best"]
        lines += [f"Best of the dataset's own solver-evaluated designs: {db['mpa']:.4f} MPa at "
                  f"{db['design_um'][0]:.1f} / {db['design_um'][1]:.1f} µm "
                  f"(objective `{results[0][1]['objective']}`).", ""]
    body = []
    for p, d in results:
        fp = d.get("surrogate_fingerprint")
        solver = d.get("solver_mpa")
        beats = d.get("beats_dataset_best")
        body.append((f"`{name[p]}`", f"{d['surrogate']}{f' `{fp[:8]}`' if fp else ''}", d["method"], budget_of(d),
                     f"{d['optimum_um'][0]:.1f} / {d['optimum_um'][1]:.1f}", f"{d['predicted_mpa']:.4f}",
                     *(("–", "–") if solver is None else (f"{solver:.4f}", f"{d['rel_error_pct']:.2f}")),
                     f"{d['search_seconds']:.1f}", f"{d['n_evals']:,}",
                     "–" if beats is None else ("yes" if beats else "no")))
    lines += markdown.table(("file", "surrogate", "method", "budget", "optimum T1 / T2 [µm]", "predicted [MPa]",
                             "solver [MPa]", "error [%]", "search [s]", "evaluations", "beats dataset best"), body)
    lines += ["", "Commands:", ""] + [f"- `{name[p]}`: `{d['command']}`" for p, d in results]
    return lines


def best_so_far(trace) -> list[dict]:
    """Per evaluation of a solver search's trace (:mod:`pcmgn_jax.opt.truth`), in order: its number (1-based),
    the search's wall time at its end [s] and the best value so far [MPa] (each value a solver run)."""
    best, out = float("inf"), []
    for i, e in enumerate(trace, 1):
        best = min(best, float(e["mpa"]))
        out.append({"evals": i, "seconds": float(e["seconds"]), "best_mpa": best})
    return out


def trace_rows(results: dict, train_seconds: dict, tol_pct: float = 0.5) -> list[str]:
    """Markdown lines: per result (``{name: optimize JSON}``) its solver-checked optimum [MPa], evaluations, search,
    training (``train_seconds`` [s] by name, else –) and total wall time [s]; then, per solver trace and per
    other result, the evaluations and wall time [s] after which the trace's best is within ``tol_pct`` % of that
    result's solver-checked optimum (– when it never is)."""
    body = []
    for name, d in results.items():
        train = train_seconds.get(name)
        solver = d.get("solver_mpa")
        body.append((f"`{name}`", d["surrogate"], d["method"], "–" if solver is None else f"{solver:.4f}",
                     " / ".join(f"{v:.1f}" for v in d["optimum_um"]), f"{d['n_evals']:,}", f"{d['search_seconds']:.0f}",
                     "–" if train is None else f"{train:.0f}", f"{d['search_seconds'] + (train or 0.0):.0f}"))
    lines = markdown.table(("result", "surrogate", "method", "solver-checked optimum [MPa]", "optimum T1 / T2 [µm]",
                            "evaluations", "search [s]", "training [s]", "total [s]"), body)
    reach = []
    for name, d in results.items():
        if "trace" not in d:
            continue
        curve = best_so_far(d["trace"])
        for other, o in results.items():
            if other == name or o.get("solver_mpa") is None:
                continue
            hit = next((c for c in curve if c["best_mpa"] <= o["solver_mpa"] * (1 + tol_pct / 100)), None)
            reach.append((f"`{name}`", f"`{other}` {o['solver_mpa']:.4f}",
                          "–" if hit is None else f"{hit['evals']}", "–" if hit is None else f"{hit['seconds']:.0f}"))
    if reach:
        lines += ["", *markdown.table(("solver trace", f"within {tol_pct:g} % of [MPa]", "after evaluations",
                                       "after [s]"), reach)]
    return lines
