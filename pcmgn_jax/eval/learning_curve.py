"""Learning curves: the MGN's and the baselines' test errors against the number of solver runs.

    rows = curve_rows({8: [m], 24: [m_seed0, m_seed1], 48: [m]})   # evaluate()'s metrics.json per size
    text = curve_table(rows); curve_plot(rows, "curve.png"); crossings(rows)

A point is a training-set size n (solver runs: the MGN's n_train + n_val; the baselines in a metrics.json
are fitted on the run's n_train, so they see two runs fewer than the MGN's budget) and the metrics files
of the MGN seeds trained on it, all evaluated on the same test scenes. Per predictor and metric the
mean over the seeds (:func:`pcmgn_jax.eval.tasks.mean_rows`). :func:`crossings` names, per metric and
baseline, the sizes n at which the MGN is at least as accurate, or says it never is in the range.
"""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from pcmgn_jax import markdown
from pcmgn_jax.eval.tasks import METRICS, WINNER_METRICS, mean_rows
from pcmgn_jax.surrogates.kinds import by_rank, names

# plotted and tabulated, when present: the MGN and the kinds with ``curve`` (pcmgn_jax/surrogates/kinds.py), by rank
CURVE_PREDICTORS = ("MGN",) + tuple(by_rank(names(curve=True)))


def curve_rows(points: Mapping[int, Sequence[dict]]) -> dict[int, dict[str, dict[str, float]]]:
    """{n: {predictor: {metric: mean over the seeds}}}, n ascending. ValueError for a size < 1 or a
    point without metrics files, or files evaluated on different test sets (their n_test differs)."""
    rows = {}
    for n in sorted(points):
        files = list(points[n])
        if int(n) < 1 or not files:
            raise ValueError(f"learning curve: point n={n!r} needs n >= 1 and at least one metrics file")
        rows[int(n)] = mean_rows(files)
    tests = {m.get("n_test") for files in points.values() for m in files}
    if len(tests) > 1:
        raise ValueError(f"learning curve: the points were evaluated on different test sets (n_test {sorted(tests)})")
    return rows


def crossings(rows: Mapping[int, dict], mgn: str = "MGN") -> dict[str, dict[str, list[int]]]:
    """{metric: {baseline: the sizes n (ascending) where the MGN's error <= the baseline's; [] if none}}
    over the sizes where both report the metric."""
    out: dict[str, dict[str, list[int]]] = {}
    for key in WINNER_METRICS:
        for name in CURVE_PREDICTORS:
            if name == mgn:
                continue
            both = [n for n, r in rows.items() if key in r.get(mgn, {}) and key in r.get(name, {})]
            if both:
                out.setdefault(key, {})[name] = [n for n in both if rows[n][mgn][key] <= rows[n][name][key]]
    return out


def curve_table(rows: Mapping[int, dict]) -> str:
    """Markdown: per winner metric, one row per size n, one column per predictor (MGN seed range in
    brackets), then the crossings in words."""
    label = dict(METRICS)
    names = [p for p in CURVE_PREDICTORS if any(p in r for r in rows.values())]
    lines = []
    for key in WINNER_METRICS:
        body = []
        for n, r in rows.items():
            cells = []
            for p in names:
                v = r.get(p, {})
                s = f"{v[key]:.3g}" if key in v else "–"
                if f"{key}_seeds" in v:
                    s += " ({:.3g}–{:.3g})".format(*v[f"{key}_seeds"])
                cells.append(s)
            body.append([n, *cells])
        lines += [f"**{label[key]}**", "", *markdown.table(["solver runs", *names], body), ""]
    cross = crossings(rows)
    for key, per in cross.items():
        said = [f"{b}: at n = {', '.join(map(str, ns))}" + (" (every size)" if len(ns) == len(rows) else "")
                if ns else f"{b}: never (n ≤ {max(rows)})" for b, ns in per.items()]
        lines.append(f"- MGN at least as accurate on {label[key]}: " + "; ".join(said) + ".")
    return "\n".join(lines)


def curve_plot(rows: Mapping[int, dict], path) -> None:
    """Error against solver runs (log-log), one panel per winner metric, one line per predictor
    (the MGN's seed range as an error bar)."""
    import matplotlib.pyplot as plt
    from matplotlib import ticker
    label = dict(METRICS)
    colours = dict(zip(CURVE_PREDICTORS, ("tab:blue", "tab:green", "tab:olive", "tab:orange", "tab:gray")))
    fig, axes = plt.subplots(1, len(WINNER_METRICS), figsize=(4.2 * len(WINNER_METRICS), 3.8))
    handles = {}
    for ax, key in zip(axes, WINNER_METRICS):
        for p in CURVE_PREDICTORS:
            ns = [n for n, r in rows.items() if key in r.get(p, {})]
            if not ns:
                continue
            y = np.array([rows[n][p][key] for n in ns])
            lo = np.array([rows[n][p].get(f"{key}_seeds", [v, v])[0] for n, v in zip(ns, y)])
            hi = np.array([rows[n][p].get(f"{key}_seeds", [v, v])[1] for n, v in zip(ns, y)])
            handles[p] = ax.errorbar(ns, y, yerr=[y - lo, hi - y], marker="o", ms=4, capsize=3, color=colours[p],
                                     lw=2 if p == "MGN" else 1, ls="-" if p != "mop" else ":", label=p)
        ax.set(xscale="log", yscale="log", xlabel="solver runs (training scenes)", ylabel=label[key])
        ax.xaxis.set_major_locator(ticker.FixedLocator(list(rows)))
        ax.xaxis.set_major_formatter(ticker.FormatStrFormatter("%d"))
        ax.xaxis.set_minor_locator(ticker.NullLocator())
        ax.yaxis.set_major_formatter(ticker.FormatStrFormatter("%g"))
        ax.yaxis.set_minor_formatter(ticker.FormatStrFormatter("%g"))
        ax.tick_params(axis="y", which="minor", labelsize=7)
        ax.grid(alpha=0.3, which="both")
    fig.legend(list(handles.values()), list(handles), loc="upper center", ncol=len(handles), fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0, 1, 0.92))
    fig.savefig(path, dpi=110)
    plt.close(fig)
