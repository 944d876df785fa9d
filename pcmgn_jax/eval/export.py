"""ParaView export of a prediction next to its ground truth.

:func:`export_comparison` writes one XDMF time series (``PATH.xdmf`` + ``PATH.h5``, meshio format,
HDF5 referenced by relative name) on the reference mesh with, per frame (SI units):

  displacement_true (N, 3) [m]     ground truth (z = 0)   -> "Warp By Vector" shows the true shape
  displacement_pred (N, 3) [m]     prediction             -> "Warp By Vector" shows the predicted shape
  displacement_error (N, 3) [m]    pred - true
  position_abs_error (N,) [m]      |pred - true|
  von_mises_true, von_mises_pred, von_mises_abs_error (N,) [Pa]
  node_part, node_type (N,); cell data ``part`` (E,)

plus ``PATH.json`` with a summary (position MAE/RMSE [µm], stress MAE/RMSE [MPa], per frame too).
Files are written into a temporary directory, fsynced and moved in (HDF5, XDMF, then JSON;
:func:`pcmgn_jax.atomic.atomic_dir`).
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from pcmgn_jax.atomic import atomic_dir, to_jsonable
from pcmgn_jax.data.trajectory_io import trajectory_paths, write_xdmf_series
from pcmgn_jax.metrics import field_metrics
from pcmgn_jax.trajectory import Trajectory

__all__ = ["comparison_summary", "export_comparison"]

COMPARISON_FORMAT = "pcmgn_jax.comparison"


def comparison_summary(truth: Trajectory, pred_disp: np.ndarray, pred_vm: np.ndarray) -> dict[str, Any]:
    """Errors of a prediction (:func:`pcmgn_jax.metrics.field_metrics`, the evaluation's definitions):
    position [µm] and von Mises [MPa] MAE/RMSE over frames 1.., and per frame."""
    m = field_metrics(np.asarray(pred_disp, np.float64)[None], np.asarray(pred_vm, np.float64)[None],
                      np.asarray(truth.displacement, np.float64)[None], np.asarray(truth.von_mises, np.float64)[None])
    return {**{k: m[k] for k in ("position_mae_um", "position_rmse_um", "stress_mae_mpa", "stress_rmse_mpa")},
            "per_frame": {"position_mae_um": m["per_frame_position_mae_um_mean"],
                          "stress_mae_mpa": m["per_frame_stress_mae_mpa_mean"]}}


def export_comparison(truth: Trajectory, pred: np.ndarray, pred_von_mises: np.ndarray,
                      path: str | os.PathLike, *, pred_kind: str = "positions") -> Path:
    """Write truth, prediction and |error| side by side to ``path``.xdmf/.h5/.json; return the .xdmf path.

    pred: (T, N, 2) predicted world positions [m] (``pred_kind='positions'``) or displacements [m]
    (``pred_kind='displacement'``); pred_von_mises: (T, N) [Pa]; T, N as in ``truth``.
    """
    if pred_kind not in ("positions", "displacement"):
        raise ValueError(f"pred_kind must be 'positions' or 'displacement', got {pred_kind!r}")
    truth.validate("truth")
    t, n = truth.n_frames, truth.n_nodes
    pred = np.asarray(pred, dtype=np.float64)
    vm = np.asarray(pred_von_mises, dtype=np.float64)
    if pred.shape != (t, n, 2):
        raise ValueError(f"prediction {pred_kind} has shape {pred.shape}, expected {(t, n, 2)}")
    if vm.shape != (t, n):
        raise ValueError(f"pred_von_mises has shape {vm.shape}, expected {(t, n)}")
    for name, arr in ((pred_kind, pred), ("pred_von_mises", vm)):
        if not np.all(np.isfinite(arr)):
            bad = np.argwhere(~np.isfinite(arr))[0].tolist()
            raise ValueError(f"{name} has a non-finite value at index {bad} (frame, node, ...)")
    disp = pred - truth.points[None].astype(np.float64) if pred_kind == "positions" else pred
    true_d = np.asarray(truth.displacement, np.float64)
    true_vm = np.asarray(truth.von_mises, np.float64)
    xdmf, h5, side = trajectory_paths(path)
    xdmf.parent.mkdir(parents=True, exist_ok=True)
    summary = {"format": COMPARISON_FORMAT, "units": {"fields": "SI (m, Pa)", "summary": "µm, MPa"},
               "truth_meta": truth.meta, "times": np.asarray(truth.times, np.float64).tolist(),
               **comparison_summary(truth, disp, vm)}
    with atomic_dir(xdmf.parent, files=(h5.name, xdmf.name, side.name)) as tmp:   # the summary JSON last
        write_xdmf_series(
            tmp / xdmf.name, np.asarray(truth.points, np.float64), truth.cells, truth.times,
            frame_data={"displacement_true": true_d, "displacement_pred": disp,
                        "displacement_error": disp - true_d,
                        "position_abs_error": np.linalg.norm(disp - true_d, axis=-1),
                        "von_mises_true": true_vm, "von_mises_pred": vm,
                        "von_mises_abs_error": np.abs(vm - true_vm)},
            static_point_data={"node_part": truth.node_part, "node_type": truth.node_type},
            cell_data={"part": truth.cell_part})
        (tmp / side.name).write_text(json.dumps(to_jsonable(summary, str(side)), indent=1))
    return xdmf
