"""Trust figures: does a surrogate's spread rank its real error?

    rep = ensemble_report(["runs/a", "runs/b", ...], {"test": test, "extrap": extrap}, train)
    rep["sets"]["test"]["objective"]["spearman"]     # ρ(per-design spread, per-design |objective error|)

For every set of trajectories with known truth, three spreads are set beside the errors they should rank:

- ``ensemble``     K >= 2 trained MGNs (seeds, formulations): per design the members' objective std (ddof 1)
                   against the absolute error of the members' mean; per node the std of the displacement
                   over members (the norm of the per-component stds, mean over frames) [µm] against the
                   mean's displacement error there [µm], pooled over the set's designs
- ``kriging``      the GP response surface of the objective over the training designs: its posterior std
                   against its own error, and against the ensemble mean's
- ``residual_gp``  a GP fitted to the ensemble mean's objective residuals on the training designs (the
                   alternative when members collapse): its std against the ensemble mean's error

Spearman's ρ (:func:`spearman`) is None, with the reason, for fewer than 3 samples or a constant side.
``spread_over_error``: mean spread / mean absolute error, the collapse figure (well below 1: the members
agree with each other far more than with the truth). Objectives in MPa, errors in % of the truth.
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
from scipy.stats import spearmanr

from pcmgn_jax import markdown, metrics
from pcmgn_jax.surrogates.inputs import TrainingScenes
from pcmgn_jax.surrogates.objective import objective_of_fields
from pcmgn_jax.surrogates.registry import fit
from pcmgn_jax.surrogates.surface_fit import fit_gp, objective_table


def spearman(spread, error) -> dict:
    """{'rho', 'p', 'n'} Spearman's rank correlation of spread and error (1-D, same length); 'rho' None
    with 'why' when it is undefined (n < 3, or a side constant)."""
    s, e = np.asarray(spread, float).reshape(-1), np.asarray(error, float).reshape(-1)
    if s.shape != e.shape:
        raise ValueError(f"spearman: spread {s.shape} and error {e.shape} differ in shape")
    n = int(len(s))
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(e))):
        raise ValueError("spearman: non-finite spread or error")
    if n < 3:
        return {"rho": None, "p": None, "n": n, "why": f"{n} samples (needs >= 3)"}
    if np.ptp(s) == 0 or np.ptp(e) == 0:
        return {"rho": None, "p": None, "n": n, "why": "the spread or the error is constant"}
    r = spearmanr(s, e)
    return {"rho": float(r.statistic), "p": float(r.pvalue), "n": n}


class ResidualSpread:
    """The MGN's spread without an ensemble: a GP (kriging) fitted to the model's objective residuals
    (truth - prediction) [MPa] on its training scenes, over the scene parameters; its posterior std at a
    query scene is the spread, its mean a correction. ``f_train`` (B,): the model's objective on ``train``
    (one rollout a scene). The one definition: the ensemble report, ``experiments.evaluate --mgn_spread``
    and the explorer use it."""

    source = "GP of the MGN's objective residuals on its training scenes"

    def __init__(self, train: Sequence, f_train, *, reading: str = metrics.DEFAULT_OBJECTIVE,
                 part: int | None = None):
        self.scenes = TrainingScenes(train)
        truth = objective_table(train, (reading,), part=part)[reading]
        self.residual_mpa = truth - np.asarray(f_train, float)
        self.gp = fit_gp(self.scenes.x, {"r": self.residual_mpa}, names=self.scenes.names)

    @property
    def warnings(self) -> list:
        return list(self.gp.warnings)

    def predict(self, trajs) -> tuple[np.ndarray, np.ndarray]:
        """(residual mean, std) (B,) [MPa] at the scenes of ``trajs`` (out-of-box queries are warned about
        under :attr:`warnings`)."""
        m, s = self.gp.predict(self.scenes.inputs(trajs, self.gp.box.note), return_std=True)
        return np.asarray(m["r"], float), np.asarray(s["r"], float)


def residual_spread_record(spread: ResidualSpread, trajs, pred_mpa, *, reading: str = metrics.DEFAULT_OBJECTIVE,
                           part: int | None = None) -> dict:
    """The spread beside each prediction of a set with truth: per design the MGN's objective [MPa], the
    residual GP's std [MPa], the real error [%], Spearman ρ of std against error, and the error after the
    GP's mean correction."""
    truth = objective_table(trajs, (reading,), part=part)[reading]
    pred = np.asarray(pred_mpa, float)
    rm, rs = spread.predict(trajs)
    err = np.asarray(metrics.relative_error_pct(pred, truth), float)
    corrected = np.asarray(metrics.relative_error_pct(pred + rm, truth), float)
    return {"source": f"{spread.source} ({len(spread.residual_mpa)})", "reading": reading,
            "names": [str(t.meta.get("name", i)) for i, t in enumerate(trajs)],
            "objective_mpa": pred.tolist(), "std_mpa": rs.tolist(), "error_pct": err.tolist(),
            "spearman_error": spearman(rs, err), "corrected_mean_error_pct": float(corrected.mean()),
            "train_residual_rms_mpa": float(np.sqrt(np.mean(spread.residual_mpa ** 2))), "warnings": spread.warnings}


def member_predictions(workdirs: Sequence, sets: Mapping[str, Sequence], ref, part: int | None = None) -> list[dict]:
    """Per member {set: (u list (T, N, 2) [m], objective (B,) [MPa], vm list (T, N) [Pa])}, each member's
    rollouts of every set; ``part``: the objective's part id (default the OLED, by name)."""
    out = []
    for w in workdirs:
        m = fit("mgn", workdir=Path(w), ref=ref)
        got = {}
        for name, trajs in sets.items():
            u, vm = m.rollout_trajectories(trajs)
            got[name] = ([np.asarray(a) for a in u], objective_of_fields(trajs, vm, part=part),
                         [np.asarray(a) for a in vm])
        out.append(got)
    return out


def _node_figures(us: list[list[np.ndarray]], trajs) -> tuple[np.ndarray, np.ndarray]:
    """(spread, error) per node [µm], pooled over designs: members' displacement std and the mean's error."""
    spread, err = [], []
    for b, t in enumerate(trajs):
        stack = np.stack([u[b] for u in us])                       # (K, T, N, 2) [m]
        sd = np.sqrt((stack.std(0, ddof=1) ** 2).sum(-1)).mean(0)  # (N,)
        e = np.linalg.norm(stack.mean(0) - np.asarray(t.displacement), axis=-1).mean(0)
        spread.append(sd * 1e6)
        err.append(e * 1e6)
    return np.concatenate(spread), np.concatenate(err)


def _collapse(spread, err) -> float | None:
    m = float(np.mean(err))
    return None if m <= 0 else float(np.mean(spread)) / m


def ensemble_report(workdirs: Sequence, sets: Mapping[str, Sequence], train: Sequence, *,
                    reading: str = metrics.DEFAULT_OBJECTIVE, part: int | None = None) -> dict:
    """The module's figures for every set (``sets``: name -> trajectories with truth), the members being
    the runs ``workdirs`` (one is allowed: no ensemble figures then), ``train`` the runs' training
    trajectories (kriging and the residual GP are fitted on them); ``part``: the objective's part id
    (default the OLED, found by name)."""
    if reading != metrics.DEFAULT_OBJECTIVE:
        raise ValueError(f"ensemble report: only the {metrics.DEFAULT_OBJECTIVE} reading, got {reading!r}")
    K = len(workdirs)
    preds = member_predictions(workdirs, {**sets, "_train": train}, train[0], part)
    krig = fit("kriging", train, readings=(reading,), part=part, fields=False).objective
    resid = ResidualSpread(train, np.mean([p["_train"][1] for p in preds], axis=0), reading=reading, part=part)
    out = {"members": [str(w) for w in workdirs], "n_members": K, "reading": reading,
           "n_train": len(train), "sets": {}}
    for name, trajs in sets.items():
        truth = objective_table(trajs, (reading,), part=part)[reading]
        f = np.stack([p[name][1] for p in preds])              # (K, B) [MPa]
        mean = f.mean(0)
        err = np.asarray(metrics.relative_error_pct(mean, truth), float)
        member_err = [float(np.mean(metrics.relative_error_pct(fk, truth))) for fk in f]
        rec = {"n": len(trajs), "names": [str(t.meta.get("name", i)) for i, t in enumerate(trajs)],
               "truth_mpa": truth.tolist(), "mean_mpa": mean.tolist(), "error_pct": err.tolist(),
               "member_error_pct": member_err, "mean_error_pct": float(err.mean())}
        true_u = [np.asarray(t.displacement) for t in trajs]
        true_vm = [np.asarray(t.von_mises) for t in trajs]
        fields = [metrics.field_metrics(p[name][0], p[name][2], true_u, true_vm) for p in preds]
        rec["member_fields"] = [{k: m[k] for k in ("position_mae_um", "stress_mae_mpa")} for m in fields]
        if K >= 2:   # the members' mean as a predictor of its own (K rollouts a design)
            mu = [np.mean([p[name][0][b] for p in preds], 0) for b in range(len(trajs))]
            mv = [np.mean([p[name][2][b] for p in preds], 0) for b in range(len(trajs))]
            m = metrics.field_metrics(mu, mv, true_u, true_vm)
            # (the objective is linear in the stress: the mean fields' objective is the members' mean objective)
            rec["mean_fields"] = {"position_mae_um": m["position_mae_um"], "stress_mae_mpa": m["stress_mae_mpa"]}
            sd = f.std(0, ddof=1)
            sd_pct = 100 * sd / truth
            ns, ne = _node_figures([p[name][0] for p in preds], trajs)
            rec["ensemble"] = {"spread_mpa": sd.tolist(), "spread_pct": sd_pct.tolist(),
                               "spearman": spearman(sd, err), "spread_over_error": _collapse(sd_pct, err),
                               "node_position": {"spearman": spearman(ns, ne), "spread_over_error": _collapse(ns, ne),
                                                 "mean_spread_um": float(ns.mean()), "mean_error_um": float(ne.mean())}}
        km, ks = krig.predict_trajectories(trajs, return_std=True)
        kerr = np.asarray(metrics.relative_error_pct(km[reading], truth), float)
        rec["kriging"] = {"mean_mpa": km[reading].tolist(), "std_mpa": ks[reading].tolist(),
                          "error_pct": kerr.tolist(), "mean_error_pct": float(kerr.mean()),
                          "spearman_own_error": spearman(ks[reading], kerr),
                          "spearman_mgn_error": spearman(ks[reading], err)}
        rm, rs = resid.predict(trajs)
        corrected = np.asarray(metrics.relative_error_pct(mean + rm, truth), float)
        rec["residual_gp"] = {"std_mpa": rs.tolist(), "spearman_mgn_error": spearman(rs, err),
                              "corrected_error_pct": corrected.tolist(),
                              "corrected_mean_error_pct": float(corrected.mean()),
                              "spearman_corrected_error": spearman(rs, corrected)}
        out["sets"][name] = rec
    out["warnings"] = list(krig.warnings) + list(resid.warnings)
    return out


def report_markdown(rep: dict, command: str = "") -> str:
    """One table per report: per set, Spearman ρ of each spread against the error it should rank."""
    def rho(d):
        return "–" if d is None else ("n/a" if d["rho"] is None else f"{d['rho']:+.2f}")
    lines = ([f"`{command}`", ""] if command else []) + [
        f"Members: {', '.join(rep['members'])} (K = {rep['n_members']}); kriging and the residual GP fitted on "
        f"{rep['n_train']} training designs. ρ: Spearman between the spread and the absolute objective error "
        "per design (node: per-node displacement spread vs error, pooled).", ""]
    spreads, fields = [], []
    for name, s in rep["sets"].items():
        e = s.get("ensemble")
        ratio = "–" if not e or e["spread_over_error"] is None else f"{e['spread_over_error']:.2f}"
        spreads.append((name, s["n"], f"{s['mean_error_pct']:.2f}",
                        ", ".join(f"{v:.2f}" for v in s["member_error_pct"]), rho(e and e["spearman"]), ratio,
                        rho(e and e["node_position"]["spearman"]),
                        f"{rho(s['kriging']['spearman_own_error'])} ({s['kriging']['mean_error_pct']:.2f})",
                        rho(s["kriging"]["spearman_mgn_error"]), rho(s["residual_gp"]["spearman_mgn_error"]),
                        f"{s['residual_gp']['corrected_mean_error_pct']:.2f}"))
        mf = s.get("mean_fields")
        fields.append((name, ", ".join(format(m["position_mae_um"], ".3f") for m in s["member_fields"]),
                       ", ".join(format(m["stress_mae_mpa"], ".2f") for m in s["member_fields"]),
                       "–" if not mf else format(mf["position_mae_um"], ".3f"),
                       "–" if not mf else format(mf["stress_mae_mpa"], ".2f"), f"{s['mean_error_pct']:.2f}"))
    lines += markdown.table(("set", "designs", "MGN mean error [%]", "members' errors [%]", "ρ ensemble",
                             "spread / error", "ρ node position", "ρ kriging std vs own error (error %)",
                             "ρ kriging std vs MGN error", "ρ residual GP std vs MGN error",
                             "MGN + residual GP error [%]"), spreads)
    lines += ["", "Fields of the members and of their mean (a predictor of its own, K rollouts a design):", ""]
    lines += markdown.table(("set", "members' position MAE [µm]", "members' stress MAE [MPa]",
                             "mean's position MAE [µm]", "mean's stress MAE [MPa]", "mean's objective error [%]"),
                            fields)
    return "\n".join(lines) + "\n"
