"""Matplotlib figures for an evaluation (PNG files). Inputs in SI; axes in mm / µm / MPa.

Stress colours use a log scale (:func:`stress_norm`: :data:`STRESS_DECADES` decades below the frame's
maximum), so the OLED layer's ~0.1-3 MPa reads beside the cover glass's ~700 MPa; the evaluation figure adds
a strip of the OLED layer's stress along x (prediction vs truth) and marks each frame's largest error.

The backend is the caller's choice (experiments/ entry points select Agg; without a display matplotlib
falls back to Agg by itself); importing this module changes no global state.
"""
from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import PolyCollection
from matplotlib.colors import LogNorm

from pcmgn_jax import metrics

PHASE_COLORS = {"drop": "#dddddd", "contact": "#ffd9a8", "rebound_in_contact": "#b9e3b0", "separated": "#c6dbef"}
STRESS_DECADES = 4   # the log colour scale's range below its maximum: 700 MPa (cover glass) down to 0.07 MPa
NEGATIVE_NOTE = 0.01  # note a predicted von Mises below -1 % of the frame's maximum on the figure


def stress_norm(vmax_mpa: float, *, decades: float = STRESS_DECADES) -> LogNorm:
    """The log colour scale of a stress field [MPa]: ``vmax_mpa`` / 10**decades .. ``vmax_mpa``; values
    below (zero included) take the lowest colour."""
    vmax = max(float(vmax_mpa), 1e-9)
    return LogNorm(vmin=vmax / 10.0 ** decades, vmax=vmax, clip=True)


def _quads(points, cells, displacement, scale):
    xy = (points + scale * displacement) * 1e3  # mm
    return xy[cells]


def _mesh(ax, points, cells, displacement, nodal, *, scale, vmin=None, vmax=None, cmap="viridis", norm=None):
    cell_val = np.asarray(nodal)[cells].mean(axis=1)
    pc = PolyCollection(_quads(points, cells, displacement, scale), array=cell_val, cmap=cmap, norm=norm,
                        edgecolors="face", linewidths=0.1)
    if norm is None:
        pc.set_clim(vmin, vmax)
    ax.add_collection(pc)
    ax.autoscale_view()
    ax.set_aspect("equal")
    return pc


def deformed_mesh(path, points, cells, displacement, von_mises, *, title, scale=1.0):
    """One frame's deformed mesh (displacement x ``scale``) coloured by von Mises [MPa], log scale."""
    fig, ax = plt.subplots(figsize=(8, 5))
    s = np.asarray(von_mises) * 1e-6
    pc = _mesh(ax, points, cells, displacement, s, scale=scale, norm=stress_norm(s.max()))
    fig.colorbar(pc, ax=ax, label="von Mises [MPa], log scale")
    ax.set(xlabel="x [mm]", ylabel="y [mm]", title=f"{title} (displacement x{scale:g})")
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def _max_error(ax, points, u, err_mpa, node_part, part_names) -> dict:
    """Mark the node of largest |error| (deformed position) on ``ax``; its frame-free description."""
    k = int(np.argmax(err_mpa))
    x, y = (np.asarray(points[k]) + np.asarray(u[k])) * 1e3
    part = (part_names[int(node_part[k])] if node_part is not None and part_names is not None
            and int(node_part[k]) < len(part_names) else None)
    ax.plot([x], [y], "o", ms=11, mfc="none", mec="cyan", mew=1.5)
    ax.annotate(f"max {err_mpa[k]:.3g} MPa" + (f" ({part})" if part else "") + f"\nat x={x:.2f}, y={y:.2f} mm",
                xy=(x, y), xytext=(0.03, 0.06), textcoords="axes fraction", color="cyan", fontsize=7,
                arrowprops={"arrowstyle": "->", "color": "cyan", "lw": 0.8})
    return {"node": k, "x_mm": float(x), "y_mm": float(y), "mpa": float(err_mpa[k]), "part": part}


def _along_x(points, values, sel):
    """(x [mm], mean over the layer's nodes at each x) of nodal ``values`` on the nodes ``sel``."""
    x = np.round(np.asarray(points)[sel, 0], 9)
    xs, inv = np.unique(x, return_inverse=True)
    return xs * 1e3, np.bincount(inv, weights=np.asarray(values)[sel]) / np.bincount(inv)


def compare_frames(path, points, cells, pred_u, true_u, pred_s, true_s, frames, *, scale=1.0, times_us=None,
                   node_part=None, part_names=None, layer="OLED") -> dict:
    """Rows: prediction, ground truth, |error| of von Mises [MPa] on the deformed mesh, all on log colour
    scales (:func:`stress_norm`; prediction and truth share the frame's scale, the error its own), the
    largest error's node circled and named; with ``node_part`` (N,) and ``part_names`` holding ``layer``,
    a fourth row: ``layer``'s stress along x (mean through its thickness), prediction vs truth, linear.
    Columns: frames. True scale by default (a magnified displacement would mostly show the ball's rigid
    drop); every row uses the ground truth's axis limits, so a diverging prediction cannot rescale the
    picture. A predicted von Mises below 0 (by more than :data:`NEGATIVE_NOTE` of the frame's maximum) is
    noted on the prediction's panel. Returns {"stress_norm": "log", "decades": ..., "max_error": [per frame:
    frame, node, x_mm, y_mm, mpa, part], "pred_min_mpa": [per frame]}."""
    strip = (node_part is not None and part_names is not None and layer in list(part_names)
             and np.any(np.asarray(node_part) == list(part_names).index(layer)))
    rows = 4 if strip else 3
    fig, axes = plt.subplots(rows, len(frames), figsize=(4.2 * len(frames), 2.75 * rows + 0.5), squeeze=False,
                             gridspec_kw={"height_ratios": [1, 1, 1, 0.8][:rows]})
    info = {"stress_norm": "log", "decades": STRESS_DECADES, "max_error": [], "pred_min_mpa": []}
    for j, f in enumerate(frames):
        vmax = float(max(np.max(true_s[f]), np.max(pred_s[f]), 1.0)) * 1e-6
        err = np.abs(pred_s[f] - true_s[f]) * 1e-6
        t = f", t={times_us[f]:.0f} µs" if times_us is not None else ""
        for i, (u, s, lab, norm) in enumerate(((pred_u[f], pred_s[f] * 1e-6, "prediction", stress_norm(vmax)),
                                               (true_u[f], true_s[f] * 1e-6, "ground truth", stress_norm(vmax)),
                                               (true_u[f], err, "|error|", stress_norm(max(float(err.max()), 1e-9),
                                                                                       decades=3)))):
            ax = axes[i, j]
            pc = _mesh(ax, points, cells, u, s, scale=scale, norm=norm, cmap="magma" if i == 2 else "viridis")
            ax.set_title(f"{lab}, frame {f}{t}", fontsize=9)
            ax.set_xlabel("x [mm]", fontsize=7)
            ax.set_ylabel("y [mm]", fontsize=7)
            ax.tick_params(labelsize=7)
            cb = fig.colorbar(pc, ax=ax, fraction=0.04)
            cb.set_label("|error| [MPa], log" if i == 2 else "von Mises [MPa], log", fontsize=7)
            cb.ax.tick_params(labelsize=7)
        lims = axes[1, j].get_xlim(), axes[1, j].get_ylim()
        for i in (0, 2):
            axes[i, j].set_xlim(*lims[0])
            axes[i, j].set_ylim(*lims[1])
        info["max_error"].append({"frame": int(f), **_max_error(axes[2, j], points, true_u[f], err, node_part,
                                                                part_names)})
        low = float(np.min(pred_s[f])) * 1e-6
        info["pred_min_mpa"].append(low)
        if low < -NEGATIVE_NOTE * vmax:      # von Mises is >= 0; a log scale would hide a negative prediction
            axes[0, j].text(0.03, 0.06, f"predicted min {low:.3g} MPa\n(< 0: drawn as the lowest colour)",
                            transform=axes[0, j].transAxes, color="cyan", fontsize=7)
        if strip:
            ax = axes[3, j]
            sel = np.asarray(node_part) == list(part_names).index(layer)
            for s, style, lab in ((true_s[f], "k-", "truth"), (pred_s[f], "r--", "prediction")):
                ax.plot(*_along_x(points, np.asarray(s) * 1e-6, sel), style, lw=1.2, label=lab)
            ax.set_xlim(*lims[0])
            ax.axhline(0.0, color="0.6", lw=0.6)
            ax.set_title(f"{layer} layer, frame {f}{t}", fontsize=9)
            ax.set_xlabel("x [mm]", fontsize=7)
            ax.set_ylabel(f"{layer} von Mises [MPa]", fontsize=7)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
            if j == 0:
                ax.legend(fontsize=7)
    fig.suptitle(f"von Mises [MPa] on the deformed mesh (displacement x{scale:g})\n"
                 f"log colour scales over {STRESS_DECADES} decades; circle: largest |error|", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return info


def objective_vs_time(path, traj, pred_vm, *, times_us=None, phases=None,
                      readings=(metrics.DEFAULT_OBJECTIVE, "node_mean")) -> dict:
    """The OLED objective's integrand over time, prediction vs truth: each frame's section mean of von Mises
    [MPa] (:func:`pcmgn_jax.metrics.oled_objective_of` on that one frame; the objective is its mean over
    the window, given in the legend), one panel per reading; ``pred_vm`` (T, N) [Pa] on ``traj``'s mesh.
    Returns {reading: {"pred_mpa": (T,), "true_mpa": (T,), "objective_pred_mpa", "objective_true_mpa"}}."""
    times_us = np.asarray(traj.times) * 1e6 if times_us is None else np.asarray(times_us)
    pred_vm = np.asarray(pred_vm)
    fig, axes = plt.subplots(len(readings), 1, figsize=(9, 2.6 * len(readings) + 0.6), sharex=True, squeeze=False)
    out = {}
    for ax, r in zip(axes[:, 0], readings):
        per_frame = {k: np.asarray(metrics.oled_objective_of(traj, vm[:, None, :], reading=r))  # (T,): frame by frame
                     for k, vm in (("pred", pred_vm), ("true", np.asarray(traj.von_mises)))}
        obj = {k: float(metrics.oled_objective_of(traj, vm, reading=r))
               for k, vm in (("pred", pred_vm), ("true", np.asarray(traj.von_mises)))}
        for name, (a, b) in (phases or {}).items():
            if a is not None and b is not None and b >= a:
                ax.axvspan(times_us[a], times_us[min(b, len(times_us) - 1)], color=PHASE_COLORS[name], alpha=0.5,
                           label=name.replace("_", " "))
        err = float(metrics.relative_error_pct(obj["pred"], obj["true"]))
        ax.plot(times_us, per_frame["true"], "k-", lw=1.4, label=f"truth (objective {obj['true']:.4g} MPa)")
        ax.plot(times_us, per_frame["pred"], "r--", lw=1.4,
                label=f"prediction (objective {obj['pred']:.4g} MPa, error {err:.2g} %)")
        ax.set_ylabel(f"OLED {r.replace('_', ' ')} [MPa]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="lower center", ncol=2)
        out[r] = {"pred_mpa": per_frame["pred"], "true_mpa": per_frame["true"], "objective_pred_mpa": obj["pred"],
                  "objective_true_mpa": obj["true"]}
    axes[-1, 0].set_xlabel("time [µs]")
    fig.suptitle("OLED objective over time: each frame's section mean of von Mises (the objective: its time mean)",
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return out


def contact_zoom(path, pred_xy_ball, pred_xy_panel, true_xy_ball, true_xy_panel, frame, *, x_max_mm=0.5):
    """Ball bottom and CG top near the axis at one frame: prediction vs ground truth [µm vs mm]."""
    fig, ax = plt.subplots(figsize=(8, 4.5))
    y0 = true_xy_panel[:, 1].max()
    for xy, style, lab in ((true_xy_ball, "k-", "ball (truth)"), (true_xy_panel, "k--", "CG top (truth)"),
                           (pred_xy_ball, "r-", "ball (pred)"), (pred_xy_panel, "r--", "CG top (pred)")):
        order = np.argsort(xy[:, 0])
        sel = xy[order, 0] * 1e3 <= x_max_mm
        ax.plot(xy[order, 0][sel] * 1e3, (xy[order, 1][sel] - y0) * 1e6, style, marker=".", ms=3, label=lab)
    ax.set(xlabel="x [mm]", ylabel="y - undeformed CG top [µm]", title=f"contact zoom, frame {frame}")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def mae_vs_frame(path, times_us, pos_mean, pos_std, s_mean, s_std, phases):
    """Per-frame MAE (mean ± std over test trajectories) with the impact phases shaded."""
    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for ax, m, s, lab in ((axes[0], pos_mean, pos_std, "position MAE [µm]"),
                          (axes[1], s_mean, s_std, "stress MAE [MPa]")):
        for name, (a, b) in phases.items():
            if a is not None and b is not None and b >= a:
                ax.axvspan(times_us[a], times_us[min(b, len(times_us) - 1)], color=PHASE_COLORS[name],
                           alpha=0.6, label=name.replace("_", " "))
        ax.plot(times_us, m, "b-")
        ax.fill_between(times_us, m - s, m + s, color="b", alpha=0.2)
        ax.set_ylabel(lab)
    axes[0].legend(fontsize=8, loc="upper left")
    axes[1].set_xlabel("time [µs]")
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def ensure_dir(path) -> Path:
    p = Path(path)
    p.mkdir(parents=True, exist_ok=True)
    return p


def objective_map(path, grid_um, grid_f, feasible, *, title, points_um=None, points_label="population",
                  paths_um=None, optimum_um=None, solver_um=None, dataset_um=None):
    """The objective [MPa] over the design box (grid_um (n*n, 2) [µm], grid_f (n*n,), infeasible cells
    hatched out) with a GA population or gradient paths, the optimum and the solver-checked point."""
    n = int(round(np.sqrt(len(grid_f))))
    gx = np.asarray(grid_um)[:, 0].reshape(n, n)
    gy = np.asarray(grid_um)[:, 1].reshape(n, n)
    f = np.where(np.asarray(feasible), np.asarray(grid_f, float), np.nan).reshape(n, n)
    fig, ax = plt.subplots(figsize=(5.6, 4.6))
    cs = ax.contourf(gx, gy, f, levels=20, cmap="viridis")
    fig.colorbar(cs, ax=ax, label="objective [MPa]")
    if dataset_um is not None and len(dataset_um):
        ax.scatter(*np.asarray(dataset_um).T, s=14, marker="s", facecolors="none", edgecolors="w",
                   label="dataset designs (solver)")
    if points_um is not None and len(points_um):
        ax.scatter(*np.asarray(points_um).T, s=8, c="k", alpha=0.5, label=points_label)
    for i, p in enumerate(paths_um or []):
        p = np.asarray(p)
        ax.plot(p[:, 0], p[:, 1], "-o", ms=2, lw=1, c="tab:orange", label="gradient paths" if i == 0 else None)
    if optimum_um is not None:
        ax.plot(*optimum_um, "r*", ms=14, label="optimum (surrogate)")
    if solver_um is not None:
        ax.plot(*solver_um, "wx", ms=10, mew=2, label="solver-checked")
    ax.set(xlabel="T1 (OCA1) [µm]", ylabel="T2 (OCA2) [µm]", title=title)
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
