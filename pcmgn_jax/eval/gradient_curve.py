"""Does a gradient buy solver runs? Gradient-enhanced kriging (the ``gek`` kind) against plain kriging and the
nearest training design: the objective's test error against the solver cost of the training data.

    doc = load_gradients("grads.json")                       # pcmgn_jax.data.gradients.design_gradients
    res = gradient_curve("data/family", doc, sizes=(6, 12, 25, 50, 100), n_test=20)
    write_gradient_curve(res, "results/gek/b")               # gradient_curve.{json,md,png}

A point is a kind fitted on the first n training designs of a generated dataset (a random subset of its
hypercube), scored on its first ``n_test`` test designs by the evaluation's objective error
(:func:`pcmgn_jax.metrics.relative_error_pct` of the ``reading``). Its cost is counted in solves: n for the
kinds fitted on values; n × the gradient's measured cost in solves (value included,
:func:`pcmgn_jax.data.gradients.cost_in_solves`) for gek, which is fitted only at sizes the gradient file
covers. Nothing is chosen on the test designs: gek's settings are fixed in :class:`surface_fit.GEK`. A kind
that refuses a size (a ValueError or SettingError from its fit or its answer: too few samples for its
parameters, or the nearest scene asked for a test stack whose layer list no training stack has) is no
point: it is recorded under ``not_applicable`` with its reason, and the curve goes on.
"""
from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pcmgn_jax import markdown
from pcmgn_jax.atomic import atomic_write_json, atomic_write_text
from pcmgn_jax.data.gradients import aligned_gradients, cost_in_solves
from pcmgn_jax.data.splits import load_splits, split_designs
from pcmgn_jax.metrics import oled_objective_of, relative_error_pct
from pcmgn_jax.surrogates.kinds import KINDS, names
from pcmgn_jax.surrogates.registry import fit_objective

CURVE_KINDS = names(gradient_curve=True)   # the kinds drawn (pcmgn_jax/surrogates/kinds.py), in the registry's order


def gradient_curve(dataset_dir: str | os.PathLike, doc: dict[str, Any], *, sizes: Sequence[int], n_test: int,
                   progress=print) -> dict[str, Any]:
    """The curve (module docstring): {'points': [{kind, n, solves, error_pct_mean, error_pct_max,
    fit_seconds}], 'not_applicable': [{kind, n, reason}], 'cost_in_solves', 'reading', ...}. ValueError
    naming a size the dataset cannot hold."""
    reading = doc["reading"]
    n_max = max(sizes)
    train, _, test = load_splits(dataset_dir, n_train=n_max, n_val=0, n_test=n_test)
    designs = split_designs(dataset_dir, "train")[:n_max]
    truth = np.array([float(oled_objective_of(t, reading=reading)) for t in test])
    ratio = cost_in_solves(doc)
    points, refused = [], []
    for n in sorted(sizes):
        for kind in CURVE_KINDS:
            options, solves = {"queries": test, "readings": (reading,)}, float(n)
            if KINDS[kind].gradients:
                if n > len(doc["records"]):
                    continue
                options["gradients"], solves = {reading: aligned_gradients(doc, designs[:n])}, n * ratio
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")   # test designs outside a small sample's box: expected here
                try:
                    s = fit_objective(kind, train[:n], **options)   # a surface without its field surface
                    pred = np.asarray(s.predict_objective(test, reading=reading))
                except ValueError as e:                             # SettingError is one
                    refused.append({"kind": kind, "n": n, "reason": str(e)})
                    if progress is not None:
                        progress(f"{kind:8s} n={n:4d}: not applicable: {e}")
                    continue
            err = relative_error_pct(pred, truth)
            points.append({"kind": kind, "n": n, "solves": solves, "error_pct_mean": float(err.mean()),
                           "error_pct_max": float(err.max()), "fit_seconds": float(s.fit_seconds)})
            if progress is not None:
                progress(f"{kind:8s} n={n:4d} ({solves:7.1f} solves): {err.mean():.3f} % (worst {err.max():.3f})")
    return {"dataset": str(dataset_dir), "reading": reading, "n_test": n_test, "cost_in_solves": ratio,
            "gradients": len(doc["records"]), "parameters": doc["names"], "points": points,
            "not_applicable": refused}


def curve_table(res: dict[str, Any]) -> list[str]:
    """Markdown lines: one row per size, per kind its error (worst) and solver cost ('n/a' where the kind
    refused the size, :func:`gradient_curve`'s ``not_applicable``)."""
    refused = res.get("not_applicable", [])
    kinds = [k for k in CURVE_KINDS if any(p["kind"] == k for p in res["points"] + refused)]
    rows = []
    for n in sorted({p["n"] for p in res["points"] + refused}):
        got = {p["kind"]: p for p in res["points"] if p["n"] == n}
        na = {p["kind"] for p in refused if p["n"] == n}
        rows.append([n] + [f"{got[k]['error_pct_mean']:.3g} ({got[k]['error_pct_max']:.3g}); {got[k]['solves']:.0f}"
                           if k in got else "n/a" if k in na else "–" for k in kinds])
    return markdown.table(["designs", *[f"{k}: error % (worst); solves" for k in kinds]], rows)


def curve_plot(res: dict[str, Any], path) -> None:
    """Objective error against solver cost (log-log), one line per kind, each point labelled by its size."""
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(5.6, 4.0))
    for kind, colour in zip(CURVE_KINDS, ("tab:gray", "tab:green", "tab:purple", "tab:orange")):
        pts = [p for p in res["points"] if p["kind"] == kind]
        if not pts:
            continue
        ax.plot([p["solves"] for p in pts], [p["error_pct_mean"] for p in pts], marker="o", color=colour, label=kind)
        for p in pts:
            ax.annotate(str(p["n"]), (p["solves"], p["error_pct_mean"]), fontsize=7, xytext=(3, 3),
                        textcoords="offset points")
    ax.set(xscale="log", yscale="log", xlabel="solver cost of the training data [solves]",
           ylabel=f"objective error, {res['reading']} [%]",
           title=f"gradient at {res['cost_in_solves']:.1f} solves; {res['n_test']} test designs")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_gradient_curve(res: dict[str, Any], out_dir: str | os.PathLike, command: str = "") -> Path:
    """``out_dir/gradient_curve.{json,md,png}`` (each written atomically); returns ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "gradient_curve.json", {"command": command, **res})
    head = [f"# Gradient-enhanced kriging against solver cost ({res['dataset']})", "",
            f"    {command}" if command else "", "",
            f"A gradient costs {res['cost_in_solves']:.2f} solves (value included, measured); "
            f"{res['gradients']} gradients; parameters {', '.join(res['parameters'])}.", ""]
    why = [f"- {p['kind']} at {p['n']} designs: not applicable: {p['reason']}" for p in res.get("not_applicable", [])]
    tail = [""] + why if why else []
    atomic_write_text(out / "gradient_curve.md", "\n".join(head + curve_table(res) + tail) + "\n")
    curve_plot(res, out / "gradient_curve.png")
    return out
