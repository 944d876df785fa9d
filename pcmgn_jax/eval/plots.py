"""Matplotlib figures for an evaluation (PNG files). Inputs in SI; axes in mm / µm / MPa.

The backend is the caller's choice (experiments/ entry points select Agg; without a display matplotlib
falls back to Agg by itself); importing this module changes no global state.
"""
from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import PolyCollection

PHASE_COLORS = {"drop": "#dddddd", "contact": "#ffd9a8", "rebound_in_contact": "#b9e3b0", "separated": "#c6dbef"}


def _quads(points, cells, displacement, scale):
    xy = (points + scale * displacement) * 1e3  # mm
    return xy[cells]


def _mesh(ax, points, cells, displacement, nodal, *, scale, vmin=None, vmax=None, cmap="viridis"):
    cell_val = np.asarray(nodal)[cells].mean(axis=1)
    pc = PolyCollection(_quads(points, cells, displacement, scale), array=cell_val, cmap=cmap,
                        edgecolors="face", linewidths=0.1)
    pc.set_clim(vmin, vmax)
    ax.add_collection(pc)
    ax.autoscale_view()
    ax.set_aspect("equal")
    return pc


def deformed_mesh(path, points, cells, displacement, von_mises, *, title, scale=1.0):
    """One frame's deformed mesh (displacement x ``scale``) coloured by von Mises [MPa]."""
    fig, ax = plt.subplots(figsize=(8, 5))
    pc = _mesh(ax, points, cells, displacement, von_mises * 1e-6, scale=scale)
    fig.colorbar(pc, ax=ax, label="von Mises [MPa]")
    ax.set(xlabel="x [mm]", ylabel="y [mm]", title=f"{title} (displacement x{scale:g})")
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def compare_frames(path, points, cells, pred_u, true_u, pred_s, true_s, frames, *, scale=1.0, times_us=None):
    """Rows: prediction, ground truth, |error| of von Mises [MPa]; columns: frames. True scale by
    default (a magnified displacement would mostly show the ball's rigid drop); every row uses the
    ground truth's axis limits, so a diverging prediction cannot rescale the picture."""
    fig, axes = plt.subplots(3, len(frames), figsize=(4 * len(frames), 8), squeeze=False)
    for j, f in enumerate(frames):
        vmax = float(max(np.max(true_s[f]), np.max(pred_s[f]), 1.0)) * 1e-6
        err = np.abs(pred_s[f] - true_s[f]) * 1e-6
        for i, (u, s, lab, vm) in enumerate(((pred_u[f], pred_s[f] * 1e-6, "prediction", vmax),
                                              (true_u[f], true_s[f] * 1e-6, "ground truth", vmax),
                                              (true_u[f], err, "|error|", max(float(err.max()), 1e-9)))):
            ax = axes[i, j]
            pc = _mesh(ax, points, cells, u, s, scale=scale, vmin=0, vmax=vm,
                       cmap="magma" if i == 2 else "viridis")
            t = f" t={times_us[f]:.0f} µs" if times_us is not None else ""
            ax.set_title(f"{lab}, frame {f}{t}", fontsize=9)
            ax.tick_params(labelsize=7)
            fig.colorbar(pc, ax=ax, fraction=0.04).ax.tick_params(labelsize=7)
        lims = axes[1, j].get_xlim(), axes[1, j].get_ylim()
        for i in (0, 2):
            axes[i, j].set_xlim(*lims[0])
            axes[i, j].set_ylim(*lims[1])
    fig.suptitle(f"von Mises [MPa] on the deformed mesh (displacement x{scale:g})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


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
