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


def budget_of(d: dict) -> str:
    """The search budget in words: GA population × generations, starts × iterations, screening."""
    b = d.get("budget", {})
    if d["method"] == "ga":
        return f"{b['pop']} × {b['gens']}" + (" (paper)" if (b["pop"], b["gens"]) == (100, 50) else "")
    text = f"{b['starts']} start{'s' if b['starts'] != 1 else ''} × {b['iters']}"
    return text + (f", {b['screen']} screened" if b.get("screen") else "")


def rows(paths) -> list[str]:
    """The markdown table of the optimize JSONs ``paths`` (see the module docstring), as lines.
    Raises ``ValueError`` naming a file that is not an optimize result, or when ``paths`` is empty."""
    results = []
    for p in paths:
        try:
            d = json.loads(Path(p).read_text())
        except (OSError, ValueError) as e:
            raise ValueError(f"{p}: not a result of experiments.optimize ({e})") from e
        if isinstance(d, dict) and "optimum" in d:
            raise ValueError(f"{p}: a stack search's result (its optimum is a row of scene parameters, "
                             "pcmgn_jax/opt/stack_search.py); this table is of design-layer optima")
        missing = [k for k in ("method", "optimum_um", "predicted_mpa") if not isinstance(d, dict) or k not in d]
        if missing:
            raise ValueError(f"{p}: not a result of experiments.optimize (no {', '.join(map(repr, missing))})")
        results.append((Path(p), d))
    if not results:
        raise ValueError("no optimize results given (--files)")
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
