"""Roll out a trained run on a set of trajectories and write ``eval/metrics.json`` + PNG plots,
beside the baselines (:mod:`pcmgn_jax.eval.baselines`) fitted on the run's training split.

Metrics (definitions in :mod:`pcmgn_jax.metrics`; SI in, reports in µm and MPa), over frames
1..T-1 of full rollouts from frame 0:
  position_mae_um / position_rmse_um   |u_pred - u_true| per node and component
  stress_mae_mpa / stress_rmse_mpa     von Mises
  per_frame_*_mean / *_std             per-frame MAE, mean and std across test trajectories
  oled_objective_*                     docs/design.md §8's objective in the paper's reading (node mean): truth,
                                       prediction, error; oled_objective_area_*: the section's area mean
  baselines                            the same summary keys for none / nearest / poly2 / rbf / kriging /
                                       mop / rom (:mod:`pcmgn_jax.eval.baselines`), or {"not_applicable": why}
  penetration_*                        fit-free (ball boundary nodes below the CG top polyline,
                                       pcmgn_jax.metrics.penetration_stats), prediction and truth
  rollout_seconds_per_trajectory       wall time of the batched jitted rollout (compile excluded); a
                                       residual_of run adds the baseline's prediction and the projection
                                       (whose first call on a mesh compiles: benchmarks time it warm)
  residual_of, residual_ball           the baseline the network corrects ("" = none) and who moved the ball
  phases                               per trajectory: frame ranges of drop / contact / rebound / separated
  warnings                             "stack range: ..." per stack scene number outside the stack family's
                                       ranges (pcmgn_jax.data.stack.range_warnings); [] otherwise

Phases from ground truth: contact while the ball's lowest boundary node is at or below the CG top
(the CG top surface interpolated at that node's x) + ``contact_tol`` [m]; rebound when the ball's mean
vertical velocity turns upward; separated after the last contact frame.
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from pcmgn_jax import markdown, metrics
from pcmgn_jax.atomic import atomic_write_json
from pcmgn_jax.config import TrainConfig
from pcmgn_jax.data.stack import stack_warnings
from pcmgn_jax.eval import plots
from pcmgn_jax.eval.baselines import BASELINES, READING_KEYS, baseline_metrics, objective_scores
from pcmgn_jax.eval.ensemble import ResidualSpread, residual_spread_record
from pcmgn_jax.geometry import roi_boundary_nodes
from pcmgn_jax.mgn.contact import contact_parts
from pcmgn_jax.provenance import code_version
from pcmgn_jax.scene import Scene
from pcmgn_jax.surrogates.objective import objective_of_fields
from pcmgn_jax.surrogates.registry import fit


def boundary(ref, panel_part: int):
    """(ball bottom nodes, CG top nodes sorted by x) from the reference mesh, inside the region of
    interest (its far edge leaves cut edges, not surfaces)."""
    bn = roi_boundary_nodes(ref, panel_part)
    return np.asarray(bn.ball), np.asarray(bn.panel)


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


def _scores(scene: Scene, trajs, pred_u, pred_vm, bnodes, pnodes) -> dict:
    """The metrics of one predictor on ``trajs``: pred_u (B,T,N,2) [m], pred_vm (B,T,N) [Pa], or lists of
    per-trajectory arrays when the meshes differ; ``bnodes``/``pnodes``: each trajectory's boundary nodes."""
    true_u = [np.asarray(t.displacement, np.float64) for t in trajs]
    true_vm = [np.asarray(t.von_mises, np.float64) for t in trajs]
    out = metrics.field_metrics(pred_u, pred_vm, true_u, true_vm)
    names = [tuple(t.meta.get("part_names") or scene.part_names) for t in trajs]
    pooled = tuple(dict.fromkeys(n for ns in names for n in ns))   # stacks of several layer lists: parts by name
    node_parts = [np.array([pooled.index(n) for n in ns])[np.asarray(t.node_part)] for ns, t in zip(names, trajs)]
    out["per_part"] = metrics.per_part_metrics(pred_u, pred_vm, true_u, true_vm, node_parts, pooled)
    pen = []
    for b, t in enumerate(trajs):
        xy = np.asarray(t.points)[None] + np.asarray(pred_u[b])
        pen.append(metrics.penetration_stats(xy[:, bnodes[b]], xy[:, pnodes[b]]))
    out.update(metrics.penetration_summary(pen))
    if all("OLED" in ns for ns in names):
        # the paper's reading (node average) under the historical keys; the optimiser's default
        # (section area mean) under oled_objective_area_*; each trajectory on its own mesh, the OLED found by
        # name in each (a stack's OLED is not always the same part id)
        part = scene.part_names.index("OLED") if len(set(names)) == 1 else None
        pred = {r: objective_of_fields(trajs, pred_vm, part=part, reading=r) for r in READING_KEYS}
        out.update(objective_scores(trajs, pred, part=part))
    return out


def summary_table(m: dict) -> str:
    """A Markdown table of the model's and the baselines' summary metrics (from ``evaluate``)."""
    cols = ("position_mae_um", "stress_mae_mpa", "oled_objective_rel_error_pct_mean",
            "oled_objective_area_rel_error_pct_mean", "penetration_max_um")
    head = ("predictor", "position MAE [µm]", "stress MAE [MPa]", "OLED objective error, node mean [%]",
            "OLED objective error, area mean [%]", "max penetration [µm]")
    preds = [("MGN", m)] + [(k, v) for k, v in m.get("baselines", {}).items()]
    rows = [(name, f"n/a: {v['not_applicable']}", "", "", "", "") if "not_applicable" in v
            else (name, *(f"{v[c]:.4g}" if c in v else "-" for c in cols)) for name, v in preds]
    rows.append(("ground truth", "", "", "", "", f"{m.get('penetration_max_um_truth', float('nan')):.4g}"))
    return "\n".join(markdown.table(head, rows))


def evaluate(workdir: str | Path, *, test_trajs: Sequence, train_trajs: Sequence = (), which: str = "best",
             batch: int = 4, plot: bool = True, name: str | None = None, contact_projection: str = "",
             mgn_spread: bool = False, residual_ball: str = "", baselines: bool = True) -> dict:
    """Roll the run's model out on ``test_trajs`` and score it beside the baselines fitted on
    ``train_trajs`` (the run's training split). Writes WORKDIR/eval[/name]/metrics.json and PNGs.
    ``contact_projection``: "on" / "off" overrides the run's formulation in the rollouts (the projection
    is rollout-only, so the same checkpoint serves both); "" keeps it. ``mgn_spread``: also roll the model
    out on ``train_trajs`` and put the std of a GP of its objective residuals there beside each test
    prediction (``mgn_spread`` in metrics.json, :class:`pcmgn_jax.eval.ensemble.ResidualSpread`).
    ``residual_ball``: "baseline" / "network" overrides a ``residual_of`` run's ``residual_ball`` (rollout-only).
    ``baselines=False``: score the model only (they do not depend on it: runs of one recipe on one dataset share
    them; metrics.json then has no "baselines")."""
    workdir = Path(workdir)
    ref = test_trajs[0]
    T = ref.n_frames
    scene = Scene.from_dict(ref.meta["scene"])
    cfg = None
    if contact_projection or residual_ball:  # rollout-only fields: the same checkpoint serves both
        cfg = TrainConfig.load(workdir / "config.json")
        if contact_projection:
            cfg = cfg.replace(formulation=cfg.formulation.replace(contact_projection=contact_projection == "on"))
        if residual_ball:
            cfg = cfg.replace(residual_ball=residual_ball)
    mgn = fit("mgn", train_trajs, workdir=workdir, ref=ref, which=which, batch=batch, cfg=cfg)
    pu, ps = mgn.rollout_trajectories(test_trajs)
    _, panel_part = contact_parts(scene)
    bnodes, pnodes = zip(*[boundary(t, panel_part) for t in test_trajs])
    m = _scores(scene, test_trajs, pu, ps, bnodes, pnodes)
    truth_pen = metrics.penetration_summary(
        [metrics.penetration_stats(t.positions[:, b], t.positions[:, p])
         for t, b, p in zip(test_trajs, bnodes, pnodes)],
        suffix="_truth")
    phases = [impact_phases(t, b, p) for t, b, p in zip(test_trajs, bnodes, pnodes)]
    m.update(truth_pen, rollout_seconds_per_trajectory=mgn.rollout_seconds / len(test_trajs),
             n_test=len(test_trajs), n_frames=T, n_nodes=ref.n_nodes,
             n_nodes_per_trajectory=[t.n_nodes for t in test_trajs], checkpoint=which,
             contact_projection=bool(mgn.sim.config.formulation.contact_projection), residual_of=mgn.residual_of,
             residual_ball=mgn.sim.config.residual_ball if mgn.residual_of else None,
             contact_capacity=int(mgn.sim.index.capacity), code=code_version(),
             phases=[{k: list(v) for k, v in p.items()} for p in phases],
             window_has_all_phases=all(v[0] is not None for p in phases for v in p.values()))
    # a stack scene outside the stack family's ranges (the model is answered there all the same): named here
    m["warnings"] = stack_warnings(test_trajs)
    if train_trajs and baselines:
        m["baselines"] = baseline_metrics(train_trajs, test_trajs,
                                           lambda u, vm: _scores(scene, test_trajs, u, vm, bnodes, pnodes),
                                           kinds=BASELINES)
    if mgn_spread and train_trajs and "OLED" in scene.part_names:
        stacks = {tuple(t.meta.get("part_names") or scene.part_names) for t in list(train_trajs) + list(test_trajs)}
        part = scene.part_names.index("OLED") if len(stacks) == 1 else None   # None: by name, per trajectory
        _, tv = mgn.rollout_trajectories(train_trajs)
        spread = ResidualSpread(train_trajs, objective_of_fields(train_trajs, tv, part=part), part=part)
        # the test predictions' objective, as _scores computed it above
        m["mgn_spread"] = residual_spread_record(spread, test_trajs, m["oled_objective_area_pred_mpa"], part=part)
    out = plots.ensure_dir(workdir / "eval" / name if name else workdir / "eval")
    atomic_write_json(out / "metrics.json", m)
    if plot:
        _plots(out, test_trajs[0], np.asarray(pu[0]), np.asarray(ps[0]), bnodes[0], pnodes[0], m, phases[0])
    return m


def _plots(out, traj, pu, ps, bnodes, pnodes, m, phases):
    times_us = np.asarray(traj.times) * 1e6
    T = len(times_us)
    peak = int(np.argmax(np.asarray(traj.von_mises).max(axis=1)))
    frames = sorted({max(1, T // 4), peak, min(T - 1, (3 * T) // 4), T - 1})
    plots.deformed_mesh(out / "deformed_mesh_pred.png", traj.points, traj.cells, pu[peak], ps[peak],
                        title=f"prediction, frame {peak} (peak stress)")
    names = list(traj.meta.get("part_names") or [])
    plots.compare_frames(out / "pred_truth_error.png", traj.points, traj.cells, pu, traj.displacement, ps,
                         np.asarray(traj.von_mises), frames, times_us=times_us, node_part=traj.node_part,
                         part_names=names)
    if "OLED" in names:
        plots.objective_vs_time(out / "oled_objective_vs_time.png", traj, ps, times_us=times_us, phases=phases)
    xy_p = traj.points[None] + pu
    xy_t = traj.positions
    plots.contact_zoom(out / "contact_zoom.png", xy_p[peak, bnodes], xy_p[peak, pnodes], xy_t[peak, bnodes],
                       xy_t[peak, pnodes], peak)
    curves = [np.asarray(m[f"per_frame_{k}_{s}"]) for k in ("position_mae_um", "stress_mae_mpa")
              for s in ("mean", "std")]
    plots.mae_vs_frame(out / "mae_vs_frame.png", times_us, *curves, phases)
