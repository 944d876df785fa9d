"""Roll out a trained run on the test split and write ``eval/metrics.json`` + PNG plots.

Metrics (SI in, reports in µm and MPa), over frames 1..T-1 of full rollouts from frame 0:
  position_mae_um / position_rmse_um   |x_pred - x_true| per node and component
  stress_mae_mpa / stress_rmse_mpa     von Mises
  per_frame_*_mean / *_std             per-frame MAE, mean and std across test trajectories
  penetration_*                        fit-free (ball boundary nodes below the CG top polyline,
                                       pcmgn_jax.train.penetration.penetration_stats), prediction and truth
  rollout_seconds_per_trajectory       wall time of the batched jitted rollout (compile excluded)
  phases                               frame ranges of drop / contact / rebound in contact / separated

Phases from ground truth: contact while the ball's lowest boundary node is at or below the CG top
(the CG top surface interpolated at that node's x) + ``contact_tol`` [m]; rebound when the ball's mean
vertical velocity turns upward; separated after the last contact frame.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Sequence

import jax
import numpy as np

from pcmgn_jax.eval import plots
from pcmgn_jax.config import TrainConfig
from pcmgn_jax.mgn.rollout import rollout_checked
from pcmgn_jax.train.loop import contact_parts, load_for_inference
from pcmgn_jax.data.trajectory_io import atomic_write_json


def boundary(ref, panel_part: int):
    """(ball bottom nodes, CG top nodes sorted by x) from the reference mesh."""
    try:
        from pcmgn_jax.train.penetration import boundary_nodes
        # x_max inside the region of interest (its far edge leaves cut edges, not surfaces)
        bn = boundary_nodes(ref.points, ref.node_part, ball_part=0, panel_part=panel_part, cells=ref.cells,
                            cell_part=ref.cell_part, x_max=0.8 * float(np.max(ref.points[:, 0])))
        return np.asarray(bn.ball), np.asarray(bn.panel)
    except ImportError:  # pragma: no cover - penetration module missing
        from pcmgn_jax.mgn.contact import surface_nodes
        b = surface_nodes(ref.points, ref.cells, ref.cell_part, 0, facing="down")
        p = surface_nodes(ref.points, ref.cells, ref.cell_part, panel_part, facing="up")
        return b[np.argsort(ref.points[b, 0])], p[np.argsort(ref.points[p, 0])]


def penetration(ball_xy, panel_xy) -> dict:
    """Fit-free penetration stats [µm] of frames (T, Mb, 2), (T, Mp, 2)."""
    try:
        from pcmgn_jax.train.penetration import penetration_stats
        return penetration_stats(ball_xy, panel_xy)
    except ImportError:  # pragma: no cover  TODO: local fallback (vertical gap to the interpolated CG top)
        depth = np.stack([np.maximum(np.interp(b[:, 0], p[:, 0], p[:, 1]) - b[:, 1], 0)
                          for b, p in zip(ball_xy, panel_xy)]) * 1e6
        per = depth.max(axis=1)
        return dict(max_um=float(per.max()), mean_um=float(depth[depth > 0].mean()) if np.any(depth > 0) else 0.0,
                    frames_with_penetration=int(np.sum(per > 0)), per_frame_max_um=per)


def impact_phases(traj, ball_nodes, panel_nodes, *, contact_tol: float = 0.25e-6) -> dict:
    """{phase: (first_frame, last_frame) or (None, None)} from a ground-truth trajectory."""
    pos = traj.positions
    T = pos.shape[0]
    in_contact = np.zeros(T, bool)
    for t in range(T):
        b = pos[t, ball_nodes]
        k = np.argmin(b[:, 1])
        p = pos[t, panel_nodes]
        o = np.argsort(p[:, 0])
        y_cg = np.interp(b[k, 0], p[o, 0], p[o, 1])
        in_contact[t] = b[k, 1] <= y_cg + contact_tol
    ball = traj.node_part == 0
    vy = np.asarray(traj.velocity)[:, ball, 1].mean(axis=1)
    label = np.full(T, "drop", object)
    if in_contact.any():
        first, last = int(np.argmax(in_contact)), int(T - 1 - np.argmax(in_contact[::-1]))
        for t in range(first, last + 1):
            label[t] = "rebound_in_contact" if vy[t] > 0 else "contact"
        label[last + 1:] = "separated"
    out = {}
    for name in ("drop", "contact", "rebound_in_contact", "separated"):
        idx = np.flatnonzero(label == name)
        out[name] = (int(idx[0]), int(idx[-1])) if len(idx) else (None, None)
    return out


def predict_trajectories(workdir: str | Path, trajs: Sequence, *, cfg: TrainConfig | None = None,
                         which: str = "best", batch: int = 4):
    """Roll the trained model of ``workdir`` out from frame 0 of each trajectory (same topology).

    Returns (displacement (B,T,N,2) [m], von_mises (B,T,N) [Pa], rollout seconds summed over the
    trajectories (compilation excluded), setup). Used by evaluation and the ParaView export."""
    workdir = Path(workdir)
    cfg = cfg or TrainConfig.load(workdir / "config.json")
    ref = trajs[0]
    setup, params, meta = load_for_inference(workdir, cfg, ref, which=which)
    s = setup
    T = ref.n_frames
    index = s.index
    preds = {"displacement": [], "von_mises": []}
    seconds = 0.0
    for i in range(0, len(trajs), batch):
        chunk = trajs[i:i + batch]
        args = [np.stack([getattr(t, f)[0] if f != "points" else t.points for t in chunk]).astype(np.float32)
                for f in ("points", "displacement", "velocity", "von_mises")]
        if i == 0:  # compile (and size the contact buffer) outside the timing
            _, index = rollout_checked(s.spec.sim, T - 1, params, s.stats, s.topology, index, *args, batched=True)
        t0 = time.perf_counter()
        res, index = rollout_checked(s.spec.sim, T - 1, params, s.stats, s.topology, index, *args, batched=True)
        jax.block_until_ready(res)
        seconds += time.perf_counter() - t0
        preds["displacement"].append(np.asarray(res.displacement, np.float64))
        preds["von_mises"].append(np.asarray(res.von_mises, np.float64))
    setup = setup._replace(index=index)
    return (np.concatenate(preds["displacement"]), np.concatenate(preds["von_mises"]), seconds, setup)


def oled_objective(scene, ref, pred_u, pred_vm, trajs, *, layer: str = "OLED", x_max: float = 3e-3) -> dict:
    """The design objective of DESIGN §8 on truth and prediction: mean von Mises [MPa] of the
    ``layer`` nodes with reference x < ``x_max`` [m], averaged over all frames, per trajectory,
    and the surrogate's relative error on it [%]. Empty dict if the scene has no such layer."""
    if layer not in scene.part_names:
        return {}
    sel = (np.asarray(ref.node_part) == scene.part_names.index(layer)) & (np.asarray(ref.points)[:, 0] < x_max)
    if not sel.any():
        return {}
    truth = np.array([np.asarray(t.von_mises, np.float64)[:, sel].mean() for t in trajs]) * 1e-6
    pred = np.asarray(pred_vm, np.float64)[:, :, sel].mean(axis=(1, 2)) * 1e-6
    rel = np.abs(pred - truth) / np.maximum(np.abs(truth), 1e-12) * 100.0
    return dict(oled_objective_true_mpa=truth.tolist(), oled_objective_pred_mpa=pred.tolist(),
                oled_objective_rel_error_pct_mean=float(rel.mean()),
                oled_objective_rel_error_pct_max=float(rel.max()))


def evaluate(workdir: str | Path, *, test_trajs: Sequence, cfg: TrainConfig | None = None,
             which: str = "best", batch: int = 4, plot: bool = True) -> dict:
    """Roll out every test trajectory; write WORKDIR/eval/metrics.json and PNGs; return the metrics."""
    workdir = Path(workdir)
    ref = test_trajs[0]
    T = ref.n_frames
    pu, ps, seconds, s = predict_trajectories(workdir, test_trajs, cfg=cfg, which=which, batch=batch)
    index = s.index
    tu = np.stack([np.asarray(t.displacement, np.float64) for t in test_trajs])
    ts = np.stack([np.asarray(t.von_mises, np.float64) for t in test_trajs])
    pos_err = np.abs(pu - tu)[:, 1:] * 1e6        # (B, T-1, N, 2) µm
    s_err = np.abs(ps - ts)[:, 1:] * 1e-6          # (B, T-1, N) MPa
    pf_pos = np.abs(pu - tu).mean(axis=(2, 3)) * 1e6   # (B, T)
    pf_s = np.abs(ps - ts).mean(axis=2) * 1e-6
    _, panel_part = contact_parts(s.scene)
    bnodes, pnodes = boundary(ref, panel_part)
    pen_pred, pen_true = [], []
    for b in range(len(test_trajs)):
        xy = np.asarray(test_trajs[b].points)[None] + pu[b]
        pen_pred.append(penetration(xy[:, bnodes], xy[:, pnodes]))
        xyt = test_trajs[b].positions
        pen_true.append(penetration(xyt[:, bnodes], xyt[:, pnodes]))
    phases = impact_phases(ref, bnodes, pnodes)
    objective = oled_objective(s.scene, ref, pu, ps, test_trajs)
    metrics = dict(
        position_mae_um=float(pos_err.mean()), position_rmse_um=float(np.sqrt(np.mean(pos_err ** 2))),
        stress_mae_mpa=float(s_err.mean()), stress_rmse_mpa=float(np.sqrt(np.mean(s_err ** 2))),
        penetration_max_um=float(max(p["max_um"] for p in pen_pred)),
        penetration_mean_um=float(np.mean([p["mean_um"] for p in pen_pred])),
        penetration_frames=int(sum(p["frames_with_penetration"] for p in pen_pred)),
        penetration_max_um_truth=float(max(p["max_um"] for p in pen_true)),
        penetration_frames_truth=int(sum(p["frames_with_penetration"] for p in pen_true)),
        rollout_seconds_per_trajectory=seconds / len(test_trajs),
        n_test=len(test_trajs), n_frames=T, n_nodes=ref.n_nodes, checkpoint=which,
        contact_capacity=int(index.capacity),
        per_frame_position_mae_um_mean=pf_pos.mean(0).tolist(), per_frame_position_mae_um_std=pf_pos.std(0).tolist(),
        per_frame_stress_mae_mpa_mean=pf_s.mean(0).tolist(), per_frame_stress_mae_mpa_std=pf_s.std(0).tolist(),
        phases={k: list(v) for k, v in phases.items()},
        window_has_all_phases=all(v[0] is not None for v in phases.values()),
        **objective,
    )
    out = plots.ensure_dir(workdir / "eval")
    atomic_write_json(out / "metrics.json", metrics)
    if plot:
        _plots(out, ref, test_trajs[0], pu[0], ps[0], bnodes, pnodes, pf_pos, pf_s, phases)
    return metrics


def _plots(out, ref, traj, pu, ps, bnodes, pnodes, pf_pos, pf_s, phases):
    times_us = np.asarray(traj.times) * 1e6
    T = len(times_us)
    peak = int(np.argmax(np.asarray(traj.von_mises).max(axis=1)))
    frames = sorted({max(1, T // 4), peak, min(T - 1, (3 * T) // 4), T - 1})
    plots.deformed_mesh(out / "deformed_mesh_pred.png", traj.points, traj.cells, pu[peak], ps[peak],
                        title=f"prediction, frame {peak} (peak stress)")
    plots.compare_frames(out / "pred_truth_error.png", traj.points, traj.cells, pu, traj.displacement, ps,
                         np.asarray(traj.von_mises), frames, times_us=times_us)
    xy_p = traj.points[None] + pu
    xy_t = traj.positions
    plots.contact_zoom(out / "contact_zoom.png", xy_p[peak, bnodes], xy_p[peak, pnodes], xy_t[peak, bnodes],
                       xy_t[peak, pnodes], peak)
    plots.mae_vs_frame(out / "mae_vs_frame.png", times_us, pf_pos.mean(0), pf_pos.std(0), pf_s.mean(0),
                       pf_s.std(0), phases)
