"""Where a run's objective error comes from: the budget of the objective error over frames, nodes and parts.

The objective (:func:`pcmgn_jax.metrics.oled_objective`, the section's area mean by default) is a weighted sum of
the nodal von Mises stress averaged over the T frames of the window, so its error is exactly additive:

    J_pred - J_true = (1/T) sum_t e(t),   e(t) = sum_n w_n (s_pred - s_true)(t, n)   [MPa]

Every split below is such a sum, in % of J_true (signed), and adds up to the signed objective error E:

- ``modes``: how the prediction was made. ``rollout`` (the free rollout from frame 0, as the evaluation scores it),
  ``teacher_forced`` (every frame one model step from the TRUE previous frame: the training's inputs,
  :func:`pcmgn_jax.mgn.formulation.training_sample`), and for a quasi-static panel ``ball_on_truth`` (the panel's
  fields read at the true ball's state, no ball error at all). E_rollout = E_map + (E_tf - E_map) + (E_rollout - E_tf):
  the panel map's error, the one-step ball error, the drift.
- ``phases``: the frames of each impact phase (:func:`pcmgn_jax.eval.evaluate.impact_phases`).
- ``nodes``: the section's interior nodes and its interface nodes (nodes of the part's cells that also belong to a
  cell of another part: the rows shared with the neighbouring layers).
- ``pulse``: J = P W / T with P the peak section mean [MPa] and W = sum_t s(t) / P the pulse's effective width
  [frames], so ln(J_pred / J_true) = ln(P_pred / P_true) + ln(W_pred / W_true) exactly: peak and width shares of E.

Over designs, a split's "share of the mean |E|" is mean_i sign(E_i) c_i,p [percentage points]: the shares of a
split sum to mean_i |E_i|, the evaluation's ``oled_objective_area_rel_error_pct_mean``.
Per part (every part's own section mean, relative to that mean): stress MAE [MPa] and objective error [%].
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from pcmgn_jax import metrics
from pcmgn_jax.eval.evaluate import boundary, impact_phases
from pcmgn_jax.mgn.contact import contact_parts
from pcmgn_jax.mgn.formulation import is_ball, previous_displacement, training_sample
from pcmgn_jax.mgn.inputs import graph_inputs
from pcmgn_jax.mgn.rollout import rollout_designs
from pcmgn_jax.scene import Scene
from pcmgn_jax.surrogates.correction import ball_path
from pcmgn_jax.surrogates.registry import fit

MODES = ("rollout", "teacher_forced", "ball_on_truth")
PHASES = ("drop", "contact", "rebound_in_contact", "separated")


# ---- predictions ------------------------------------------------------------------------------------------------

def predictions(workdir: str | Path, trajs: Sequence, *, which: str = "best", batch: int = 8) -> dict:
    """{mode: (u list of (T, N, 2) [m], von Mises list of (T, N) [Pa])} of the run's model on ``trajs`` (the modes of
    the module docstring; ``ball_on_truth`` only for a quasi-static panel). Frame 0 is the truth in every mode."""
    mgn = fit("mgn", (), workdir=workdir, ref=trajs[0], which=which, batch=batch)
    if mgn.residual_of:
        raise ValueError(f"error budget: the run {workdir} predicts the {mgn.residual_of} baseline's residual; "
                         "its one-step predictions would need the baseline's fields too (not supported)")
    u, vm = mgn.rollout_trajectories(trajs)
    out = {"rollout": ([np.asarray(a) for a in u], [np.asarray(a) for a in vm])}
    sim = mgn.sim
    form, dt, n = sim.spec.formulation, sim.spec.dt, trajs[0].n_frames - 1
    graphs = [graph_inputs(t, t.meta["scene"], scene_features=form.scene_features, levels=form.hierarchy_levels,
                           radius=sim.index.radius, capacity=sim.index.capacity,
                           identity=form.part_identity)._asdict() for t in trajs]
    steps = []   # one design per (trajectory, frame k): its true state at k, rolled one step to k + 1
    for t, g in zip(trajs, graphs):
        ball = is_ball(t.node_type)
        for k in range(n):
            s = training_sample(form, ball, points=t.points, u_prev=previous_displacement(t.displacement, t.velocity,
                                                                                          k, dt),
                                u=t.displacement[k], u_next=t.displacement[k + 1], vm_next=t.von_mises[k + 1],
                                vm=t.von_mises[k], dt=dt)
            steps.append(dict(g, u0=s["u"], v0=s["v"], vm0=t.von_mises[k]))
    one = rollout_designs(sim.spec, 1, sim.params, sim.stats, steps, batch_size=4 * batch,
                          note="the teacher-forced steps").rollouts
    tf_u, tf_vm = [], []
    for i, t in enumerate(trajs):
        rs = one[i * n:(i + 1) * n]
        tf_u.append(np.concatenate([t.displacement[:1], [np.asarray(r.displacement[1]) for r in rs]]))
        tf_vm.append(np.concatenate([t.von_mises[:1], [np.asarray(r.von_mises[1]) for r in rs]]))
    out["teacher_forced"] = (tf_u, tf_vm)
    if form.panel_model == "quasi_static":
        path = [dict(g, u0=t.displacement[0], v0=t.velocity[0], vm0=t.von_mises[0],
                     **dict(zip(("ball_u", "ball_v"), ball_path(t, t.displacement, dt))))
                for t, g in zip(trajs, graphs)]
        res = rollout_designs(sim.spec, n, sim.params, sim.stats, path, batch_size=batch,
                              note="the rollout on the true ball path").rollouts
        out["ball_on_truth"] = ([np.asarray(r.displacement) for r in res], [np.asarray(r.von_mises) for r in res])
    return out


# ---- the splits of one trajectory -------------------------------------------------------------------------------

def section_mean(von_mises, weights) -> np.ndarray:
    """(T,) the weighted section mean [MPa] of every frame of ``von_mises`` (T, N) [Pa]: the objective's
    (:func:`pcmgn_jax.metrics.oled_objective`) reading of each frame on its own."""
    return np.asarray(metrics.oled_objective(np.asarray(von_mises, np.float64)[:, None, :], weights))


def interface_nodes(cells, cell_part, part: int) -> np.ndarray:
    """(N,) bool: nodes of ``part``'s cells that also belong to a cell of another part (the rows it shares with
    its neighbours); the rest of the part's cell nodes are its interior."""
    cells, cell_part = np.asarray(cells), np.asarray(cell_part)
    n = int(cells.max()) + 1
    own, other = np.zeros(n, bool), np.zeros(n, bool)
    own[cells[cell_part == part].ravel()] = True
    other[cells[cell_part != part].ravel()] = True
    return own & other


def node_groups(traj, part: int) -> dict[str, np.ndarray]:
    """{group: (N,) bool} of the section's nodes: ``interior`` and ``interface <neighbour>`` per neighbouring part
    (the neighbour whose cell holds the node). The groups partition the nodes of ``part``'s cells."""
    names = list(traj.meta.get("part_names") or [])
    cells, cp = np.asarray(traj.cells), np.asarray(traj.cell_part)
    iface = interface_nodes(cells, cp, part)
    own = np.zeros(traj.n_nodes, bool)
    own[cells[cp == part].ravel()] = True
    groups = {"interior": own & ~iface}
    for k in sorted(set(np.unique(cp).tolist()) - {part}):
        touch = np.zeros(traj.n_nodes, bool)
        touch[cells[cp == k].ravel()] = True
        sel = iface & touch & ~np.any(list(groups.values()), axis=0)
        if sel.any():
            groups[f"interface {names[k] if k < len(names) else k}"] = sel
    return groups


def pulse(s) -> dict:
    """Peak frame, peak value P [MPa] and effective width W = sum(s) / P [frames] of a section-mean series (T,)."""
    s = np.asarray(s, np.float64)
    k = int(np.argmax(s))
    return dict(peak_frame=k, peak_mpa=float(s[k]), width_frames=float(s.sum() / s[k]) if s[k] > 0 else 0.0)


def trajectory_budget(traj, u_pred, vm_pred, *, part: int, phases: dict, reading: str = metrics.DEFAULT_OBJECTIVE
                      ) -> dict:
    """One prediction's splits (module docstring) of its objective error on ``traj``: u_pred (T, N, 2) [m], vm_pred
    (T, N) [Pa], ``phases`` {phase: (first, last) or (None, None)} covering the frames."""
    w = metrics.objective_weights(traj.points, traj.cells, traj.cell_part, traj.node_part, part=part, reading=reading)
    true_vm, vm_pred = np.asarray(traj.von_mises, np.float64), np.asarray(vm_pred, np.float64)
    s_t, s_p = section_mean(true_vm, w), section_mean(vm_pred, w)
    j_t, j_p = float(metrics.oled_objective(true_vm, w)), float(metrics.oled_objective(vm_pred, w))
    T, e = len(s_t), s_p - s_t
    pct = 100.0 / (T * j_t)                                  # a sum of e(t) [MPa] -> % of J_true
    phase = {p: float(e[a:b + 1].sum() * pct) if a is not None else 0.0
             for p, (a, b) in ((p, phases.get(p, (None, None))) for p in PHASES)}
    node_err = (vm_pred - true_vm).mean(axis=0) * 1e-6 * w   # each node's share of J_pred - J_true [MPa]
    groups = {g: m & (w > 0) for g, m in node_groups(traj, part).items()}   # the section's nodes
    abs_err = metrics.stress_errors_mpa(vm_pred[None], true_vm[None])[0]   # (T-1, N) frames 1..
    nodes = {g: dict(contribution_pct=float(node_err[m].sum() * T * pct), stress_mae_mpa=float(abs_err[:, m].mean()),
                     weight=float(w[m].sum())) for g, m in groups.items()}
    pt, pp = pulse(s_t), pulse(s_p)
    total = (j_p - j_t) / j_t * 100.0
    log_j = np.log(j_p / j_t) if j_p > 0 else np.nan
    share = (lambda x: float(total * x / log_j)) if np.isfinite(log_j) and abs(log_j) > 1e-12 else (lambda x: 0.0)
    pulse_split = dict(peak_pct=share(np.log(pp["peak_mpa"] / pt["peak_mpa"])) if pp["peak_mpa"] > 0 else np.nan,
                       width_pct=share(np.log(pp["width_frames"] / pt["width_frames"])) if pp["width_frames"] > 0
                       else np.nan)
    ball = is_ball(traj.node_type)
    ball_err = np.abs(np.asarray(u_pred)[:, ball, 1].mean(1) - np.asarray(traj.displacement)[:, ball, 1].mean(1))
    return dict(objective_true_mpa=j_t, objective_pred_mpa=j_p, error_pct=total, phases=phase, nodes=nodes,
                pulse=dict(true=pt, pred=pp, peak_frame_error=pp["peak_frame"] - pt["peak_frame"],
                           peak_error_pct=(pp["peak_mpa"] - pt["peak_mpa"]) / pt["peak_mpa"] * 100.0, **pulse_split),
                section_true_mpa=s_t.tolist(), section_pred_mpa=s_p.tolist(),
                ball_error_um=(ball_err * 1e6).tolist())


def part_errors(traj, vm_pred, *, reading: str = metrics.DEFAULT_OBJECTIVE) -> dict:
    """{part name: stress MAE [MPa] over its nodes, frames 1.., and its own section mean's objective: truth [MPa],
    signed error [% of the truth]} (a part without a section at x < the objective's x_max is left out)."""
    names = list(traj.meta.get("part_names") or [])
    true_vm, vm_pred = np.asarray(traj.von_mises, np.float64), np.asarray(vm_pred, np.float64)
    err = metrics.stress_errors_mpa(vm_pred[None], true_vm[None])[0]
    out = {}
    for k, name in enumerate(names):
        try:
            w = metrics.objective_weights(traj.points, traj.cells, traj.cell_part, traj.node_part, part=k,
                                          reading=reading)
        except ValueError:
            continue
        j_t, j_p = float(metrics.oled_objective(true_vm, w)), float(metrics.oled_objective(vm_pred, w))
        out[name] = dict(stress_mae_mpa=float(err[:, np.asarray(traj.node_part) == k].mean()), objective_true_mpa=j_t,
                         objective_error_pct=(j_p - j_t) / j_t * 100.0)
    return out


# ---- over designs -----------------------------------------------------------------------------------------------

def shares(errors, contributions: dict) -> dict:
    """{name: mean_i sign(E_i) c_i [percentage points]} from signed errors E_i (B,) and {name: (B,) contributions}
    summing to E_i: their shares of mean_i |E_i|."""
    sign = np.sign(np.asarray(errors, np.float64))
    return {k: float(np.mean(sign * np.asarray(v, np.float64))) for k, v in contributions.items()}


def mode_split(per_mode: dict) -> dict:
    """{step: (B,) contributions} of the rollout's signed errors: panel map (``ball_on_truth``), one-step ball error
    (teacher-forced minus map) and drift (rollout minus teacher-forced); without a map mode, one step + drift."""
    e = {m: np.array([b["error_pct"] for b in v]) for m, v in per_mode.items()}
    out = {}
    if "ball_on_truth" in e:
        out["panel map (ball on the true path)"] = e["ball_on_truth"]
        out["one-step ball error"] = e["teacher_forced"] - e["ball_on_truth"]
    else:
        out["one step from the true state"] = e["teacher_forced"]
    out["drift (rollout - teacher-forced)"] = e["rollout"] - e["teacher_forced"]
    return out


def budget(trajs: Sequence, preds: dict, *, part_name: str = "OLED", reading: str = metrics.DEFAULT_OBJECTIVE
           ) -> dict:
    """The error budget of ``preds`` ({mode: (u list, vm list)}, :func:`predictions`) on ``trajs``: per design and
    mode the splits of :func:`trajectory_budget`, per mode the per-part errors, the per-frame curves and the shares of
    the mean |E| of every split (module docstring)."""
    scene = Scene.from_dict(trajs[0].meta["scene"])
    names = list(trajs[0].meta.get("part_names") or scene.part_names)
    if part_name not in names:
        raise ValueError(f"error budget: no part named {part_name!r} in {names}")
    part = names.index(part_name)
    _, panel_part = contact_parts(scene)
    phases = [impact_phases(t, *boundary(t, panel_part)) for t in trajs]
    per = {m: [trajectory_budget(t, u, v, part=part, phases=p, reading=reading)
               for t, u, v, p in zip(trajs, *preds[m], phases)] for m in MODES if m in preds}
    modes = {}
    for m, bs in per.items():
        err = np.array([b["error_pct"] for b in bs])
        e_t = np.array([np.subtract(b["section_pred_mpa"], b["section_true_mpa"]) for b in bs])
        parts = [part_errors(t, v, reading=reading) for t, v in zip(trajs, preds[m][1])]
        modes[m] = dict(
            error_pct=err.tolist(), mean_abs_error_pct=float(np.abs(err).mean()), max_abs_error_pct=float(
                np.abs(err).max()),
            phases=shares(err, {p: [b["phases"][p] for b in bs] for p in PHASES}),
            nodes=shares(err, {g: [b["nodes"].get(g, {}).get("contribution_pct", 0.0) for b in bs]
                               for g in dict.fromkeys(g for b in bs for g in b["nodes"])}),
            node_mae_mpa={g: float(np.mean([b["nodes"][g]["stress_mae_mpa"] for b in bs if g in b["nodes"]]))
                          for g in dict.fromkeys(g for b in bs for g in b["nodes"])},
            pulse=dict(shares(err, {k: [b["pulse"][f"{k}_pct"] for b in bs] for k in ("peak", "width")}),
                       peak_frame_error=[b["pulse"]["peak_frame_error"] for b in bs],
                       peak_error_pct=[b["pulse"]["peak_error_pct"] for b in bs]),
            per_frame_error_mpa=e_t.mean(0).tolist(), per_frame_abs_error_mpa=np.abs(e_t).mean(0).tolist(),
            per_frame_ball_error_um=np.mean([b["ball_error_um"] for b in bs], axis=0).tolist(),
            parts={n: dict(stress_mae_mpa=float(np.mean([p[n]["stress_mae_mpa"] for p in parts])),
                           objective_true_mpa=float(np.mean([p[n]["objective_true_mpa"] for p in parts])),
                           objective_error_pct_mean=float(np.mean([p[n]["objective_error_pct"] for p in parts])),
                           objective_abs_error_pct_mean=float(np.mean([abs(p[n]["objective_error_pct"])
                                                                       for p in parts])))
                   for n in names if all(n in p for p in parts)})
    err = np.array([b["error_pct"] for b in per["rollout"]])
    return dict(part=part_name, reading=reading, n_test=len(trajs), n_frames=trajs[0].n_frames,
                names=[t.meta.get("name", str(i)) for i, t in enumerate(trajs)],
                phases=[{k: list(v) for k, v in p.items()} for p in phases], modes=modes,
                steps=shares(err, mode_split(per)), designs={m: per[m] for m in per})
