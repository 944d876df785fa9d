"""Mesh-refinement series of one panel design, in the built-in solver and in CalculiX (issue 43).

  python -m experiments.mesh_series                                   # built-in solver, 8 meshes x 2 elements (~20 min)
  python -m experiments.mesh_series --ccx_meshes cpu@0.5,cpu          # also CalculiX on those (hours for the finer)

One design (default: the paper's physics-constrained optimum, 145.207 / 99.322 µm) on meshes coarse to fine
(``PRESET@F`` is the preset refined by F, pcmgn_jax.sim.mesh ``named_spec``). Per mesh: the
nodes (full mesh, region of interest), the elements through the OLED, the end of the objective's section (its
last node under 3 mm), the objective's readings (pcmgn_jax/metrics.py), the area mean over the fixed
section 0 <= x <= --section_x_mm (pcmgn_jax/eval/calculix_check.py ``section_weights``), the peak contact
force (mean over a 4 µs frame interval) and the contact duration. The built-in solver runs at its production
penalty (--penalty_factor 1); a mesh in --ccx_meshes also runs in CalculiX and in the built-in solver at
--ccx_penalty_factor (0.1, docs/results/calculix.md). Rows are cached as JSON under OUT/rows/ (a rerun skips
them); writes OUT.json, OUT.md and OUT.png. Heavy: run it under ``flock /tmp/heavy.lock nice -n 5``.
"""
from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

from pcmgn_jax import cli, markdown


@dataclass(frozen=True)
class DesignSectionArgs:
    """The flags a study of one design on several meshes shares (this series, experiments.calculix_locking)."""

    design: str = "145.207,99.322"
    """the design [µm], 'T1,T2'"""
    section_x_mm: float = 2.4
    """end of the fixed OLED section [mm] (inside every mesh's region of interest)"""


@dataclass(frozen=True)
class SeriesArgs(DesignSectionArgs):
    """Mesh-refinement series of one design in both codes."""
    # cli.check_bounds: {flag: (lowest value, inclusive[, highest])}
    BOUNDS: ClassVar[dict] = {"section_x_mm": (0, False), "penalty_factor": (0, False),
                              "ccx_penalty_factor": (0, False), "increments_per_frame": (1, True),
                              "min_increment_ratio": (0, False), "timeout_s": (0, False)}

    meshes: str = "cpu@0.5,cpu@0.5:layers+far,cpu,cpu_fine,paper,cpu@2,paper@2,cpu@4"
    """built-in solver meshes: presets, cpu_fine, or PRESET@F (refined by F)"""
    elements: str = "q4i,q4"
    """the built-in solver's elements, each a row per mesh (pcmgn_jax.sim.fem.Q4_ELEMENTS: q4i the default, q4 the
full-integration element that locks)"""
    ccx_meshes: str = ""
    """meshes also run in CalculiX (and in the built-in solver at --ccx_penalty_factor)"""
    penalty_factor: float = 1.0
    """the built-in solver's contact penalty factor in the series"""
    ccx_penalty_factor: float = 0.1
    """the contact penalty factor of the CalculiX rows, in both codes"""
    ccx_elements: str = "C3D8"
    """CalculiX's elements, each a row: C3D8 (full integration, the built-in Q4's counterpart), C3D8I \
(incompatible modes; ccx does not allow it in *DYNAMIC: experiments.calculix_locking compares the two statically)"""
    increments_per_frame: int = 2
    """ccx's largest increment = output_dt / this"""
    min_increment_ratio: float = 0.05
    """ccx's smallest increment / its largest (the series' CalculiX rows: 0.005)"""
    slave_faces: bool = True
    """CalculiX rows: the ball's faces as the contact's slave surface (--no_slave_faces: its nodes, ~10x stiffer
    springs, how the committed C3D8 row was made; docs/results/calculix.md)"""
    timeout_s: float = 7200.0
    """per ccx run"""
    out: str = "results/calculix/mesh_series"
    """output stem (.json, .md, .png) and row cache folder (OUT/rows/, ccx runs in OUT/runs/)"""


def row(args, name: str, code: str, element: str = "C3D8") -> dict:
    """One mesh's figures in one code ('builtin' with the Q4 ``element``, 'builtin_ccx_penalty' (q4, the C3D8
    counterpart) or 'calculix' with the ccx ``element``), cached as JSON."""
    from pcmgn_jax import metrics
    from pcmgn_jax.atomic import atomic_write_json
    from pcmgn_jax.data.exporters.calculix import CalculixSettings
    from pcmgn_jax.eval.calculix_check import impact_figures, section_weights
    from pcmgn_jax.eval.calculix_runs import run_builtin, run_calculix
    from pcmgn_jax.scene import default_scene
    from pcmgn_jax.sim.mesh import mesh_spec

    design = [float(v) * 1e-6 for v in args.design.split(",")]
    penalty = args.penalty_factor if code == "builtin" else args.ccx_penalty_factor
    tag = ((f"{code}_{element}" + ("_faces" if args.slave_faces else "")) if code == "calculix"
           else f"{code}_{element}" if code == "builtin" else code)
    design_tag = "_".join(args.design.split(","))
    cache = Path(args.out) / "rows" / f"{name.replace(':', '-')}_{tag}_{design_tag}_p{penalty:g}.json"
    if cache.is_file():
        return json.loads(cache.read_text())
    scene = default_scene().with_design(*design)
    spec = mesh_spec(name)
    if code == "calculix":
        settings = CalculixSettings(increments_per_frame=args.increments_per_frame, penalty_factor=penalty,
                                    element=element, min_increment_ratio=args.min_increment_ratio,
                                    slave_faces=args.slave_faces)
        traj, extra, wall = run_calculix(Path(args.out) / "runs" / f"{name}_{element}", scene, spec, settings,
                                         args.timeout_s)
        force = extra["force_N"]
    else:
        traj, force, wall, _ = run_builtin(scene, spec, penalty, element if code == "builtin" else "q4")
    figs = impact_figures(traj, force)
    oled = list(traj.meta["part_names"]).index("OLED")
    w_area = metrics.objective_weights(traj.points, traj.cells, traj.cell_part, traj.node_part, part=oled)
    w_fixed = section_weights(traj.points, traj.cells, traj.cell_part, part=oled, x_end=args.section_x_mm * 1e-3)
    rec = {"mesh": name, "code": tag, "element": element if code != "builtin_ccx_penalty" else "q4",
           "penalty_factor": penalty, "design_um": [d * 1e6 for d in design],
           "full_nodes": int(traj.meta["solver"]["full_mesh_nodes"]), "roi_nodes": int(traj.n_nodes),
           "oled_elements": int(spec.layer_elems["OLED"]), "h_contact_um": spec.h_contact * 1e6,
           "section_end_mm": float(traj.points[w_area > 0, 0].max() * 1e3),
           "objective_fixed_section_mpa": float(metrics.oled_objective(traj.von_mises, w_fixed)),
           "section_x_mm": args.section_x_mm, "wall_s": wall, **figs}
    if code == "calculix":   # the row cache's name does not hold these: record them with the figures
        rec["ccx_settings"] = {"increments_per_frame": args.increments_per_frame,
                               "min_increment_ratio": args.min_increment_ratio, "slave_faces": args.slave_faces}
    cache.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(cache, rec)
    return rec


def report(args, rows: list[dict], command: str) -> list[str]:
    """OUT.json and OUT.md; returns the markdown lines."""
    from pcmgn_jax.atomic import atomic_write_json, atomic_write_text

    x = args.section_x_mm
    head = ["mesh", "code", "penalty", "nodes (full / ROI)", "OLED elements", "h_contact [µm]", "section end [mm]",
            "area mean [MPa]", f"area mean, x <= {x:g} mm [MPa]", "node mean [MPa]", "disc mean [MPa]",
            "peak force [N]", "contact [µs]", "wall [s]"]
    notes = [f"{r['mesh']} {r['code']}: ccx increments per frame {r['ccx_settings']['increments_per_frame']}, "
             f"smallest increment ratio {r['ccx_settings']['min_increment_ratio']:g}"
             for r in rows if "ccx_settings" in r]
    body = [[r["mesh"], r["code"], f"{r['penalty_factor']:g}", f"{r['full_nodes']:,} / {r['roi_nodes']:,}",
             r["oled_elements"], f"{r['h_contact_um']:.2f}", f"{r['section_end_mm']:.3f}",
             f"{r['objective_area_mean_mpa']:.4f}", f"{r['objective_fixed_section_mpa']:.4f}",
             f"{r['objective_node_mean_mpa']:.4f}", f"{r['objective_disc_mean_mpa']:.4f}", f"{r['peak_force_N']:.3f}",
             f"{r['contact_duration_s'] * 1e6:.0f}", f"{r['wall_s']:.0f}" if r["wall_s"] is not None else "–"]
            for r in rows]
    lines = [f"Command: `{command}`", "", f"Design {args.design} µm. Fixed section: OLED at 0 <= x <= {x:g} mm.", "",
             *markdown.table(head, body)]
    lines += [""] + notes if notes else []
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(f"{args.out}.json", {"command": command, "design_um": args.design, "section_x_mm": x,
                                           "rows": rows})
    atomic_write_text(f"{args.out}.md", "\n".join(lines) + "\n", parents=True)
    return lines


def plot(rows: list[dict], png: str, section_x_mm: float) -> None:
    """The objective's readings, the peak force and the contact duration against the region's node count, one
    marker per code and element."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(12, 6.4))
    axes = axes.ravel()
    keys = (("objective_fixed_section_mpa", f"OLED area mean, x ≤ {section_x_mm:g} mm [MPa]"),
            ("objective_area_mean_mpa", "OLED area mean (the objective's section) [MPa]"),
            ("objective_node_mean_mpa", "OLED node mean [MPa]"), ("peak_force_N", "peak contact force [N]"),
            ("contact_us", "contact duration [µs]"), ("objective_disc_mean_mpa", "OLED disc mean [MPa]"))
    rows = [{**r, "contact_us": r["contact_duration_s"] * 1e6} for r in rows]
    styles = {"builtin_q4i": ("o", "built-in q4i (penalty 1)"), "builtin_q4": ("^", "built-in q4 (penalty 1)"),
              "builtin_ccx_penalty": ("s", "built-in q4 (ccx penalty)"),
              "calculix_C3D8": ("x", "CalculiX C3D8, node slaves"), "calculix_C3D8_faces": ("x", "CalculiX C3D8"),
              "calculix_C3D8I_faces": ("+", "CalculiX C3D8I")}
    for code, (marker, label) in styles.items():
        sel = [r for r in rows if r["code"] == code]
        if not sel:
            continue
        for ax, (k, title) in zip(axes, keys):
            ax.plot([r["roi_nodes"] for r in sel], [r[k] for r in sel], marker, label=label)
            if code == "builtin_q4i":
                for r in sel:
                    ax.annotate(r["mesh"], (r["roi_nodes"], r[k]), fontsize=7, xytext=(3, 3),
                                textcoords="offset points")
            ax.set_title(title, fontsize=9)
    for ax in axes:
        ax.set_xscale("log")
        ax.set_xlabel("nodes in the region of interest")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    args = cli.parse(SeriesArgs, argv, description=__doc__, prog="python -m experiments.mesh_series")
    import matplotlib
    matplotlib.use("Agg")   # files only; set here, in the entry point

    from pcmgn_jax.data.calculix import CalculixNotFoundError, find_ccx

    command = "python -m experiments.mesh_series " + " ".join(sys.argv[1:] if argv is None else argv)
    from pcmgn_jax.sim.fem import Q4_ELEMENTS

    q4s = [e.strip() for e in args.elements.split(",") if e.strip()]
    bad = [e for e in q4s if e not in Q4_ELEMENTS]
    if bad or not q4s:
        print(f"error: --elements {args.elements!r}: each must be one of {Q4_ELEMENTS}", file=sys.stderr)
        return 2
    todo = [(m.strip(), "builtin", e) for e in q4s for m in args.meshes.split(",") if m.strip()]
    ccx = [m.strip() for m in args.ccx_meshes.split(",") if m.strip()]
    if ccx:
        try:
            find_ccx()
        except CalculixNotFoundError as err:
            print(f"error: {err}", file=sys.stderr)
            return 2
    elements = [e.strip() for e in args.ccx_elements.split(",") if e.strip()]
    if not set(elements) <= {"C3D8", "C3D8I"}:
        print(f"error: --ccx_elements {args.ccx_elements!r}: each must be C3D8 or C3D8I", file=sys.stderr)
        return 2
    todo += [(m, "builtin_ccx_penalty", "") for m in ccx] + [(m, "calculix", e) for m in ccx for e in elements]
    from pcmgn_jax.sim.mesh import named_spec
    for name, _, _ in todo:
        named_spec(name)            # every mesh name checked before the first row is solved (ValueError: status 2)
    rows = []
    for name, code, element in todo:
        rows.append(row(args, name, code, element or "C3D8"))
        r = rows[-1]
        print(f"{name:10s} {r['code']:20s} area {r['objective_area_mean_mpa']:.4f} "
              f"fixed {r['objective_fixed_section_mpa']:.4f} "
              f"node {r['objective_node_mean_mpa']:.4f} force {r['peak_force_N']:.3f} N", flush=True)
        report(args, rows, command)   # after every row: a long run keeps what it has
    print("\n".join(report(args, rows, command)))
    plot(rows, f"{args.out}.png", args.section_x_mm)
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
