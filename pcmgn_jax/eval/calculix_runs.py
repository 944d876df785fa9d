"""The built-in solver against CalculiX, run: one scene in each code, the cases of ``python -m
experiments.calculix_check`` (Hertz and the panel designs in both codes) and their report (check.json, check.md).

    traj, extra, wall = run_calculix(folder, scene, preset, settings)   # ccx, reused while its deck is unchanged
    traj, force, wall, result = run_builtin(scene, preset, penalty_factor=1.0)

The figures and the comparison they are scored by: :mod:`pcmgn_jax.eval.calculix_check`. ``args`` of the cases
and the report: the check's settings (``experiments.calculix_check.CheckArgs``: preset, frames, penalty
factors, increments per frame, slave faces, time-out, the Hertz case's mesh)."""
from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from pcmgn_jax import markdown
from pcmgn_jax.atomic import atomic_write_json, atomic_write_text
from pcmgn_jax.data.calculix import frd_trajectory, run_ccx
from pcmgn_jax.data.exporters.calculix import CCX_COUNTERPART, CalculixSettings, calculix_mesh, inp_text
from pcmgn_jax.eval.calculix_check import CHECKED, compare, field_errors, impact_figures
from pcmgn_jax.scene import Scene, default_scene
from pcmgn_jax.sim import solver
from pcmgn_jax.sim.hertz import TARGET_MATERIALS, hertz_impact, hertz_mesh_spec, hertz_scene


def run_calculix(folder: Path, scene: Scene, preset, settings: CalculixSettings, timeout: float | None = None):
    """CalculiX run of ``scene`` on ``preset``'s mesh in ``folder``: (trajectory, :func:`frd_trajectory`'s extra,
    wall time [s] or None); reused when folder/job.inp holds the same deck and job.frd exists. ``timeout`` [s]."""
    deck = inp_text(scene, calculix_mesh(scene, preset), settings, title=f"pcmgn_jax scene, design {scene.design}")
    inp, frd = folder / "job.inp", folder / "job.frd"
    wall = None
    if not (inp.is_file() and frd.is_file() and inp.read_text() == deck):
        folder.mkdir(parents=True, exist_ok=True)
        atomic_write_text(inp, deck)
        wall = run_ccx(inp, timeout=timeout)["wall_time_s"]
        (folder / "wall_time_s.txt").write_text(f"{wall}\n")
    elif (folder / "wall_time_s.txt").is_file():
        wall = float((folder / "wall_time_s.txt").read_text())
    traj, extra = frd_trajectory(frd, scene, preset, meta={"settings": dataclasses.asdict(settings)})
    return traj, extra, wall


def run_builtin(scene: Scene, preset, penalty_factor: float, element: str = solver.DEFAULT_SETTINGS.element):
    """The built-in solver's run of ``scene`` on ``preset``'s mesh at ``penalty_factor`` with the Q4 ``element``:
    (trajectory, the mean contact force per frame interval (T-1,) [N], wall time [s], the solver's RunResult)."""
    t0 = time.perf_counter()
    settings = solver.SolverSettings(penalty_factor=penalty_factor, element=element)
    res = solver.simulate([scene], preset, settings=settings)
    traj = solver.to_trajectories(res, [scene], preset, settings=settings)[0]
    # the frame interval's mean contact force: the same quantity as CalculiX's momentum difference
    return traj, res.force[0].mean(axis=1), time.perf_counter() - t0, res


def hertz_case(out: Path, args) -> dict[str, Any]:
    """Steel ball on a glass block (sim/hertz.py): CalculiX and the built-in solver against Hunter's theory."""
    scene = hertz_scene(radius=5e-3, velocity=0.62631, target="glass")
    e, nu, _ = TARGET_MATERIALS["glass"]
    theory = hertz_impact(radius=5e-3, velocity=0.62631, ball=scene.ball, youngs=e, poisson=nu)
    spec = dataclasses.replace(hertz_mesh_spec(theory, elems_per_radius=args.hertz_elems_per_radius),
                               growth=args.hertz_growth)
    window = scene.ball.gap / 0.62631 + 1.4 * theory["contact_time_s"]
    scene = dataclasses.replace(scene, output_dt=window / args.hertz_frames, n_frames=args.hertz_frames)
    settings = CalculixSettings(increments_per_frame=args.increments_per_frame,
                                penalty_factor=args.hertz_penalty_factor,
                                min_increment_ratio=args.hertz_min_increment_ratio,
                                slave_faces=args.slave_faces)
    tc, fc, wall_c = run_calculix(out / "runs" / "hertz", scene, spec, settings, args.timeout_s)
    tb, fb, wall_b, _ = run_builtin(scene, spec, args.hertz_penalty_factor)
    figs = {"calculix": impact_figures(tc, fc["force_N"]), "builtin": impact_figures(tb, fb)}
    ref = {"contact_duration_s": theory["contact_time_s"], "peak_force_N": theory["peak_force_N"]}
    vs_theory = {code: {k: figs[code][k] / v - 1.0 for k, v in ref.items()} for code in figs}
    return {"case": "hertz", "label": "hertz_glass", "theory": ref, "figures": figs, "vs_theory": vs_theory,
            "compare": compare(figs["calculix"], figs["builtin"]), "n_nodes_2d": tc.meta["solver"]["full_mesh_nodes"],
            "ccx_wall_s": wall_c, "builtin_wall_s": wall_b, "output_dt_s": scene.output_dt,
            "penalty_factor": args.hertz_penalty_factor, "elems_per_radius": args.hertz_elems_per_radius,
            "growth": args.hertz_growth,
            "goal_met": all(abs(v) <= 0.05 for v in vs_theory["calculix"].values())}


def panel_case(out: Path, args, design: list[float], label: str) -> dict[str, Any]:
    """One panel design in both codes on ``args.preset``: the built-in solver with ``q4``, C3D8's counterpart (the
    code check: the same element in both), also at penalty factor 1, and with ``q4i`` at penalty factor 1 (the
    production truth: what the element change moves)."""
    scene = default_scene().with_design(*design)
    if args.frames:
        scene = dataclasses.replace(scene, n_frames=int(args.frames))
    settings = CalculixSettings(increments_per_frame=args.increments_per_frame, penalty_factor=args.penalty_factor,
                                slave_faces=args.slave_faces)
    tc, extra, wall_c = run_calculix(out / "runs" / label, scene, args.preset, settings, args.timeout_s)
    tb, fb, wall_b, _ = run_builtin(scene, args.preset, args.penalty_factor, CCX_COUNTERPART[settings.element])
    figs = {"calculix": impact_figures(tc, extra["force_N"]), "builtin": impact_figures(tb, fb)}
    frd_vm = extra["von_mises_full"]["frd"][:, extra["node_map"]]
    figs["calculix_frd_stress"] = impact_figures(tc, extra["force_N"], von_mises=frd_vm)
    if args.penalty_factor != 1.0:
        tp, fp, _, _ = run_builtin(scene, args.preset, 1.0, CCX_COUNTERPART[settings.element])
        figs["builtin_penalty_1"] = impact_figures(tp, fp)
    ti, fi, _, _ = run_builtin(scene, args.preset, 1.0, "q4i")
    figs["builtin_q4i_penalty_1"] = impact_figures(ti, fi)
    start, end = figs["builtin"]["contact_start_s"], figs["builtin"]["contact_end_s"]
    if not np.isfinite(end):
        end = tb.times[-1]
    frames = [int(round((start + q * (end - start)) / scene.output_dt)) for q in (0.25, 0.5, 0.75)]
    cmp = compare(figs["calculix"], figs["builtin"])
    return {"case": "panel", "label": label, "design_um": [d * 1e6 for d in design], "preset": args.preset,
            "figures": figs, "compare": cmp, "fields": field_errors(tc, tb, frames),
            "force_N": {"calculix": extra["force_N"].tolist(), "builtin": fb.tolist()},
            "n_nodes_2d": tc.meta["solver"]["full_mesh_nodes"], "ccx_wall_s": wall_c, "builtin_wall_s": wall_b,
            "penalty_factor": args.penalty_factor, "output_dt_s": scene.output_dt,
            "goal_met": all(abs(cmp[k]["rel_diff"]) <= 0.05 for k in CHECKED if k in cmp)}


def _ranking(cases, key) -> dict[str, list[str]]:
    panel = [c for c in cases if c["case"] == "panel"]
    return {code: [c["label"] for c in sorted(panel, key=lambda c: c["figures"][code][key])]
            for code in ("calculix", "builtin")}


def write_report(out: Path, cases: list[dict], args, command: str) -> list[str]:
    """OUT/check.json and OUT/check.md (the tables of docs/results/calculix.md); returns the markdown lines."""
    pct = lambda x: f"{100 * x:+.1f} %"   # noqa: E731
    lines = [f"Command: `{command}`", ""]
    for c in cases:
        if c["case"] == "hertz":
            lines += markdown.table(["Hertz (steel on glass)", "theory", "CalculiX", "built-in"], (
                [f"{k} [{unit}]", f"{c['theory'][k] * s:.2f}",
                 f"{c['figures']['calculix'][k] * s:.2f} ({pct(c['vs_theory']['calculix'][k])})",
                 f"{c['figures']['builtin'][k] * s:.2f} ({pct(c['vs_theory']['builtin'][k])})"]
                for k, unit, s in (("peak_force_N", "N", 1.0), ("contact_duration_s", "µs", 1e6))))
            lines += ["", f"Hertz: {c['n_nodes_2d']} nodes, penalty factor {c['penalty_factor']}, frames of "
                      f"{c['output_dt_s'] * 1e6:.3f} µs; ccx {c['ccx_wall_s'] or float('nan'):.0f} s, built-in "
                      f"{c['builtin_wall_s']:.0f} s; goal (CalculiX within 5 % of theory) "
                      f"{'met' if c['goal_met'] else 'missed'}.", ""]
    panel = [c for c in cases if c["case"] == "panel"]
    if panel:
        keys = (("peak_force_N", "peak force [N]", 1.0), ("contact_duration_s", "contact [µs]", 1e6),
                ("peak_cg_von_mises_mpa", "peak CG vM [MPa]", 1.0), ("objective_area_mean_mpa", "area mean [MPa]", 1.0),
                ("objective_node_mean_mpa", "node mean [MPa]", 1.0),
                ("max_ball_approach_um", "ball approach [µm]", 1.0))
        body = []
        for c in panel:
            d = f"{c['design_um'][0]:.1f}, {c['design_um'][1]:.1f}"
            for code, name in (("builtin", "built-in q4"), ("calculix", "CalculiX C3D8"),
                               ("calculix_frd_stress", "CalculiX C3D8, ccx nodal stress"),
                               ("builtin_penalty_1", "built-in q4, penalty 1"),
                               ("builtin_q4i_penalty_1", "built-in q4i, penalty 1")):
                if code not in c["figures"]:
                    continue
                f = c["figures"][code]
                cells = []
                for k, _, s in keys:
                    cell = f"{f[k] * s:.3f}"
                    if code != "builtin":
                        cell += f" ({pct(f[k] / c['figures']['builtin'][k] - 1)})"
                    cells.append(cell)
                body.append([d, name, *cells])
        lines += markdown.table(["design [µm]", "code", *(k[1] for k in keys)], body)
        lines += ["", "Fields (CalculiX vs built-in, relative L2 over the region's nodes):", "",
                  *markdown.table(["design", "t [µs]", "displacement", "von Mises"], (
                      [c["label"], f"{f['time_us']:.0f}", f"{100 * f['displacement_rel_l2']:.1f} %",
                       f"{100 * f['von_mises_rel_l2']:.1f} %"] for c in panel for f in c["fields"]))]
        rank = {k: _ranking(cases, k) for k in ("objective_area_mean_mpa", "objective_node_mean_mpa")}
        lines += ["", "Ranking (best first): " + "; ".join(f"{k}: CalculiX {v['calculix']}, built-in {v['builtin']}"
                                                         for k, v in rank.items()),
                  "", "Goals (peak force, contact duration, objective readings within 5 %): " + ", ".join(
                      f"{c['label']} {'met' if c['goal_met'] else 'missed'}" for c in panel),
                  "CalculiX wall time per design [s]: " + ", ".join(
                      f"{c['label']} {c['ccx_wall_s'] or float('nan'):.0f}" for c in panel)]
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "check.json", {"command": command, "args": dict(vars(args)) if hasattr(args, "__dict__")
                                           else dataclasses.asdict(args), "cases": cases})
    atomic_write_text(out / "check.md", "\n".join(lines) + "\n", parents=True)
    return lines


def plot_forces(check_json: str | Path, png: str | Path) -> None:
    """Contact force per frame interval, CalculiX against the built-in solver, one panel per design."""
    import matplotlib.pyplot as plt

    panel = [c for c in json.loads(Path(check_json).read_text())["cases"] if c["case"] == "panel"]
    if not panel:
        return
    fig, axes = plt.subplots(1, len(panel), figsize=(4 * len(panel), 3.2), sharey=True, squeeze=False)
    for ax, c in zip(axes[0], panel):
        for code, style in (("builtin", "-"), ("calculix", "--")):
            f = np.asarray(c["force_N"][code])
            ax.plot((np.arange(len(f)) + 0.5) * c.get("output_dt_s", 4e-6) * 1e6, f, style,
                    label="built-in" if code == "builtin" else "CalculiX")
        ax.set_title(f"{c['design_um'][0]:.1f} / {c['design_um'][1]:.1f} µm", fontsize=9)
        ax.set_xlabel("t [µs]")
    axes[0][0].set_ylabel("contact force [N]")
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)
