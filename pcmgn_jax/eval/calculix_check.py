"""The built-in solver against CalculiX on the same mesh and model (docs/results/calculix.md).

:func:`impact_figures` reads one code's run the same way for both: the contact force on the ball as the
mean over each frame interval [N] (CalculiX: from the ball's momentum, :func:`pcmgn_jax.data.calculix.ball_force`;
built-in: the mean of its per-substep contact force over the frame, the same quantity), the contact start /
end (first and last interval with a force above 1e-3 of the peak, so both codes are read at one 4 us grid),
the peak cover-glass von Mises, the OLED objective's readings (:mod:`pcmgn_jax.metrics`) and the
maximum approach. :func:`field_errors` compares the fields at given frames. :func:`compare` puts two
runs side by side with relative differences. :func:`section_weights` is the mesh-refinement series' fixed
section: the area mean over exactly 0 <= x <= x_end, whatever the mesh's grading.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from pcmgn_jax import metrics
from pcmgn_jax.sim.output import contact_phases
from pcmgn_jax.trajectory import Trajectory

__all__ = ["CHECKED", "compare", "contact_window", "field_errors", "impact_figures", "section_weights"]

#: the figures :func:`compare` checks against the 5 % agreement goal
CHECKED = ("peak_force_N", "contact_duration_s", "objective_area_mean_mpa", "objective_node_mean_mpa")


def contact_window(force: np.ndarray, dt: float, threshold: float = 1e-3) -> dict[str, float]:
    """Contact start / end [s] (start of the first, end of the last interval whose mean force exceeds
    ``threshold`` x peak), duration [s], peak force [N] and its interval's mid time [s] from a per-interval
    force (T-1,) [N]. The end is NaN when the force is still on at the last interval."""
    ph = contact_phases(np.asarray(force, np.float64), dt, threshold)   # the solver's one rule, per interval
    start = ph["contact_start_s"] - dt        # contact_phases times an interval by its end
    end = ph["separation_s"]
    return {"contact_start_s": start, "contact_end_s": end, "contact_duration_s": end - start,
            "peak_force_N": ph["peak_force_N"], "peak_force_time_s": ph["peak_force_time_s"] - 0.5 * dt}


def impact_figures(traj: Trajectory, force: np.ndarray, *, von_mises: np.ndarray | None = None) -> dict[str, Any]:
    """One run's figures: :func:`contact_window` of ``force`` (T-1,) [N], ``peak_cg_von_mises_mpa`` (max over
    frames and the top layer's nodes), ``objective_<reading>_mpa`` for every reading of
    :data:`pcmgn_jax.metrics.OBJECTIVES` (on the trajectory's own von Mises unless ``von_mises`` (T, N)
    [Pa] is given) and ``max_ball_approach_um`` (largest downward ball displacement in the region)."""
    dt = float(traj.times[1] - traj.times[0])
    vm = traj.von_mises if von_mises is None else von_mises
    out: dict[str, Any] = contact_window(force, dt)
    names = list(traj.meta.get("part_names") or [])
    top = 1
    out["peak_cg_von_mises_mpa"] = float(np.max(vm[:, traj.node_part == top]) * 1e-6)
    if "OLED" in names:
        for reading in metrics.OBJECTIVES:
            out[f"objective_{reading}_mpa"] = float(metrics.oled_objective_of(traj, vm, reading=reading))
    ball = traj.node_part == 0
    out["max_ball_approach_um"] = float(-traj.displacement[:, ball, 1].min() * 1e6)
    return out


def field_errors(a: Trajectory, b: Trajectory, frames: Sequence[int]) -> list[dict[str, float]]:
    """Per frame: relative L2 difference of the displacement and of the von Mises field between ``a`` and
    ``b`` (reference ``b``) over the region's nodes, and each run's max von Mises [MPa]."""
    if a.points.shape != b.points.shape or not np.allclose(a.points, b.points, rtol=0, atol=1e-12):
        raise ValueError("field_errors: the two trajectories are not on the same nodes")
    out = []
    for k in frames:
        du = np.linalg.norm(a.displacement[k] - b.displacement[k]) / max(np.linalg.norm(b.displacement[k]), 1e-30)
        dv = np.linalg.norm(a.von_mises[k] - b.von_mises[k]) / max(np.linalg.norm(b.von_mises[k]), 1e-30)
        out.append({"frame": int(k), "time_us": float(a.times[k] * 1e6), "displacement_rel_l2": float(du),
                    "von_mises_rel_l2": float(dv), "max_von_mises_mpa_a": float(a.von_mises[k].max() * 1e-6),
                    "max_von_mises_mpa_b": float(b.von_mises[k].max() * 1e-6)})
    return out


def compare(ccx: Mapping[str, Any], builtin: Mapping[str, Any], keys: Sequence[str] | None = None) -> dict[str, Any]:
    """{key: {"calculix", "builtin", "rel_diff"}} for the numeric figures both runs have; rel_diff =
    calculix / builtin - 1."""
    keys = keys or [k for k in builtin if k in ccx and isinstance(builtin[k], (int, float))]
    out = {}
    for k in keys:
        a, b = float(ccx[k]), float(builtin[k])
        out[k] = {"calculix": a, "builtin": b, "rel_diff": a / b - 1.0 if b else float("nan")}
    return out


def section_weights(points, cells, cell_part, *, part: int, x_end: float) -> np.ndarray:
    """(N,) nodal weights (summing to 1) of the area mean over the section of ``part`` at 0 <= x <= ``x_end`` [m]
    exactly: a cell that straddles x_end counts with its part at x <= x_end, the bilinear shape functions
    integrated exactly over the clipped rectangle. The objective's ``area_mean``
    (:func:`pcmgn_jax.metrics.objective_weights`) keeps the cells wholly at x <= 3 mm instead, so its section
    ends at the mesh's last node under 3 mm, which moves with the grading; with ``x_end`` on a node the two agree.
    Needs the part's cells to be axis-aligned rectangles (the panel's layers) reaching x_end; ValueError otherwise."""
    pts = np.asarray(points, np.float64)
    cells = np.asarray(cells)[np.asarray(cell_part) == part]
    if not len(cells):
        raise ValueError(f"section_weights: no cell of part {part}")
    xy = pts[cells]                                                   # (E, 4, 2)
    lo, hi = xy.min(axis=1), xy.max(axis=1)                           # (E, 2) corners
    tol = 1e-9 * float(np.abs(pts).max())
    at_lo = np.abs(xy - lo[:, None]) <= tol
    at_hi = np.abs(xy - hi[:, None]) <= tol
    if not np.all(at_lo ^ at_hi) or np.any(at_lo.sum(axis=1) != 2):
        raise ValueError(f"section_weights: the cells of part {part} are not axis-aligned rectangles")
    if hi[:, 0].max() < x_end - tol:
        raise ValueError(f"section_weights: part {part} ends at x = {hi[:, 0].max():.4e} m, "
                         f"short of x_end = {x_end:.4e} m")
    x0, x1 = lo[:, 0], hi[:, 0]
    xc = np.clip(x_end, x0, x1)
    left = (x1 * (xc - x0) - 0.5 * (xc ** 2 - x0 ** 2)) / (x1 - x0)   # int over [x0, xc] of (x1 - x) / (x1 - x0)
    right = (0.5 * (xc ** 2 - x0 ** 2) - x0 * (xc - x0)) / (x1 - x0)  # ... of (x - x0) / (x1 - x0)
    w = np.where(at_lo[..., 0], left[:, None], right[:, None]) * (0.5 * (hi[:, 1] - lo[:, 1]))[:, None]
    out = np.zeros(len(pts))
    np.add.at(out, cells.ravel(), w.ravel())
    return out / out.sum()
