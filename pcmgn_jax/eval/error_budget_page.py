"""The error budget (:mod:`pcmgn_jax.eval.error_budget`) rendered: a Markdown page of tables, one PNG figure, the JSON.

    write(out_dir, budget)   # out_dir/error_budget.{json,md,png}, committed together (pcmgn_jax.atomic.atomic_dir)

The figure: the section-mean stress over time [MPa] of the worst and the best test design (truth and every mode),
the per-frame section-mean error averaged over the designs [MPa] and the rigid ball's vertical position error [µm].
The caller picks the matplotlib backend (the entry point sets ``Agg``).
"""
from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from pcmgn_jax import markdown
from pcmgn_jax.atomic import atomic_dir, atomic_write_json, atomic_write_text

FILES = ("error_budget.md", "error_budget.png", "error_budget.json")   # the JSON last: the commit marker
STYLE = {"rollout": ("r-", "rollout"), "teacher_forced": ("b--", "teacher-forced (one step from the truth)"),
         "ball_on_truth": ("g:", "panel on the true ball path")}


def _f(x, fmt=".3g") -> str:
    return format(x, fmt) if np.isfinite(x) else "n/a"


def tables(b: dict) -> str:
    """The budget's Markdown tables (shares in percentage points of the rollout's mean |error|)."""
    r, part = b["modes"]["rollout"], b["part"]
    total = r["mean_abs_error_pct"]
    out = [f"{part} objective ({b['reading']} reading), {b['n_test']} test designs x {b['n_frames']} frames. "
           f"Rollout: mean |error| {total:.3g} % (worst {r['max_abs_error_pct']:.3g} %). Shares are mean_i sign(E_i) "
           "c_i [percentage points]: each table's shares sum to the mean |error|.", "",
           "**By mode** (what each prediction mode scores on the objective)", ""]
    out += markdown.table(("mode", "mean abs error [%]", "max abs error [%]", "signed errors [%]"),
                          [(m, _f(v["mean_abs_error_pct"]), _f(v["max_abs_error_pct"]),
                            ", ".join(f"{e:+.2f}" for e in v["error_pct"])) for m, v in b["modes"].items()])
    for title, key in (("By step of the prediction", "steps"),):
        out += ["", f"**{title}** (share of the rollout's {total:.3g} %)", ""]
        out += markdown.table(("part of the error", "share [pp]"), [(k, _f(v)) for k, v in b[key].items()])
    out += ["", "**By impact phase** (frames of each phase; share of each mode's mean |error|)", ""]
    modes = list(b["modes"])
    out += markdown.table(("phase", *modes), [(p, *(_f(b["modes"][m]["phases"][p]) for m in modes))
                                              for p in b["modes"]["rollout"]["phases"]])
    out += ["", f"**By node group of the {part} section** (share [pp]; stress MAE over the group's nodes, frames 1.. "
            "[MPa])", ""]
    groups = list(r["nodes"])
    out += markdown.table(("group", *(f"{m} share" for m in modes), *(f"{m} MAE" for m in modes)),
                          [(g, *(_f(b["modes"][m]["nodes"].get(g, np.nan)) for m in modes),
                            *(_f(b["modes"][m]["node_mae_mpa"].get(g, np.nan)) for m in modes)) for g in groups])
    out += ["", "**Pulse**: peak and effective width (ln J = ln P + ln W; share [pp]); peak frame error [frames] and "
            "peak value error [%] per design", ""]
    out += markdown.table(("mode", "peak share", "width share", "peak frame error", "peak value error [%]"),
                          [(m, _f(v["pulse"]["peak"]), _f(v["pulse"]["width"]),
                            ", ".join(f"{k:+d}" for k in v["pulse"]["peak_frame_error"]),
                            ", ".join(f"{e:+.2f}" for e in v["pulse"]["peak_error_pct"]))
                           for m, v in b["modes"].items()])
    out += ["", "**Per part** (stress MAE over the part's nodes, frames 1..; each part's own section mean over the "
            "window: its truth and its error, relative to that truth)", ""]
    out += markdown.table(("part", "section mean, truth [MPa]", *(f"{m} MAE [MPa]" for m in modes),
                           *(f"{m} mean abs / signed error [%]" for m in modes)),
                          [(n, _f(p["objective_true_mpa"]),
                            *(_f(b["modes"][m]["parts"][n]["stress_mae_mpa"]) for m in modes),
                            *(f"{_f(b['modes'][m]['parts'][n]['objective_abs_error_pct_mean'])} / "
                              f"{b['modes'][m]['parts'][n]['objective_error_pct_mean']:+.3g}" for m in modes))
                           for n, p in r["parts"].items()])
    return "\n".join(out) + "\n"


def figure(path, b: dict, times_us) -> None:
    """The budget's figure (module docstring) as a PNG at ``path``; ``times_us`` (T,) frame times [µs]."""
    err = np.abs(b["modes"]["rollout"]["error_pct"])
    picks = (("worst", int(np.argmax(err))), ("best", int(np.argmin(err))))
    fig, axes = plt.subplots(2, 2, figsize=(10, 6.4))
    for ax, (label, i) in zip(axes[0], picks):
        d = b["designs"]["rollout"][i]
        ax.plot(times_us, d["section_true_mpa"], "k-", lw=1.6, label=f"truth ({d['objective_true_mpa']:.3g} MPa)")
        for m, ds in b["designs"].items():
            ax.plot(times_us, ds[i]["section_pred_mpa"], STYLE[m][0], lw=1.1,
                    label=f"{STYLE[m][1]} ({ds[i]['error_pct']:+.2f} %)")
        ax.set(title=f"{label} design: {b['names'][i]}", xlabel="time [µs]",
               ylabel=f"{b['part']} section mean [MPa]")
        ax.legend(fontsize=7)
    for ax, key, ylabel in ((axes[1, 0], "per_frame_error_mpa", f"{b['part']} section-mean error [MPa]"),
                            (axes[1, 1], "per_frame_ball_error_um", "ball position error [µm]")):
        for m, v in b["modes"].items():
            ax.plot(times_us, v[key], STYLE[m][0], lw=1.1, label=STYLE[m][1])
        ax.axhline(0.0, color="0.6", lw=0.6)
        ax.set(xlabel="time [µs]", ylabel=ylabel, title="mean over the test designs" + (", signed" if "mpa" in key
                                                                                         else ""))
        ax.legend(fontsize=7)
    for ax in axes.ravel():
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def write(out_dir: str | Path, b: dict, times_us, *, header: str = "") -> Path:
    """``out_dir``/error_budget.{md,png,json} of the budget ``b`` written together (``header``: the page's first
    lines, e.g. the command). Returns ``out_dir``."""
    out_dir = Path(out_dir)
    with atomic_dir(out_dir, files=FILES) as tmp:
        atomic_write_text(tmp / FILES[0], (header + "\n\n" if header else "") + tables(b))
        figure(tmp / FILES[1], b, times_us)
        atomic_write_json(tmp / FILES[2], b)
    return out_dir
