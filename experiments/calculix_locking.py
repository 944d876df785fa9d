"""Shear locking of the full-integration brick on the series' meshes: the panel under a static pressure in
CalculiX, C3D8 against C3D8I (issue 43).

  python -m experiments.calculix_locking                       # cpu@0.5, cpu, cpu@2, cpu@4 x C3D8, C3D8I (~1 min)

ccx does not allow ``C3D8I`` in ``*DYNAMIC`` (its incompatible modes carry no mass; the impact run on
``cpu@0.5`` stops at 127 µs, docs/results/calculix.md), so the two elements are compared where ccx allows both:
one linear static step of the same wedge model (pcmgn_jax/data/exporters/calculix.py ``static_inp_text``:
the ball held, no contact), a uniform pressure --force_n / (pi r^2) on the top layer's faces within
--radius_um of the axis. Per mesh and element: the loaded zone's mean deflection (the pressure's
work-conjugate: compliance = that / force), the top centre's deflection, the OLED's von Mises (the built-in
solver's recovery from CalculiX's displacements) as its area mean over the fixed section x <= --section_x_mm
(pcmgn_jax/eval/calculix_check.py ``section_weights``) and the objective's readings, and the peak cover-glass
von Mises. A locking element reads a stiffer panel on coarse meshes, converging from one side as the mesh
refines; a locking-free one reads nearly the fine mesh's figures already on the coarse mesh. Writes OUT.json
and OUT.md (decks and results under OUT/runs/, not committed). Heavy: run it under ``flock /tmp/heavy.lock nice -n 5``.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from typing import ClassVar

from experiments.mesh_series import DesignSectionArgs
from pcmgn_jax import cli, markdown


@dataclass(frozen=True)
class LockingArgs(DesignSectionArgs):
    """The panel's static stiffness in CalculiX, C3D8 against C3D8I, on several meshes."""
    # cli.check_bounds: {flag: (lowest value, inclusive[, highest])}
    BOUNDS: ClassVar[dict] = {"section_x_mm": (0, False), "force_n": (0, False), "radius_um": (0, False),
                              "timeout_s": (0, False)}

    meshes: str = "cpu@0.5,cpu,cpu@2,cpu@4"
    """meshes: presets, cpu_fine, or PRESET@F (pcmgn_jax.sim.mesh named_spec)"""
    elements: str = "C3D8,C3D8I"
    """CalculiX elements"""
    builtin_elements: str = "q4,q4i"
    """the built-in solver's elements (pcmgn_jax.sim.fem.Q4_ELEMENTS), each a static row of the same model on the
same mesh (pcmgn_jax.sim.static): q4 is C3D8's counterpart, q4i C3D8I's"""
    force_n: float = 25.0
    """total load [N] (about the impact's peak contact force)"""
    radius_um: float = 250.0
    """loaded radius [µm] (a node radius of every mesh here: their contact zones are uniform to 0.5 mm)"""
    timeout_s: float = 900.0
    """per ccx run"""
    out: str = "results/calculix/locking"
    """output stem (.json, .md) and folder of the ccx runs"""


def row(args, name: str, element: str) -> dict:
    """One mesh and element (a CalculiX element, or ``builtin_`` + a built-in element): the static figures."""
    import math
    from pathlib import Path

    from pcmgn_jax.atomic import atomic_write_text
    from pcmgn_jax.data.calculix import run_ccx, static_fields
    from pcmgn_jax.data.exporters.calculix import CalculixSettings, calculix_mesh, static_inp_text
    from pcmgn_jax.scene import default_scene
    from pcmgn_jax.sim.mesh import mesh_spec
    from pcmgn_jax.sim.static import static_pressure

    scene = default_scene().with_design(*[float(v) * 1e-6 for v in args.design.split(",")])
    spec = mesh_spec(name)
    radius = args.radius_um * 1e-6
    pressure = args.force_n / (math.pi * radius**2)
    if element.startswith("builtin_"):
        t0 = time.perf_counter()
        mesh, u, vm = static_pressure(scene, spec, pressure=pressure, radius=radius,
                                      element=element.removeprefix("builtin_"))
        wall = time.perf_counter() - t0
    else:
        mesh = calculix_mesh(scene, spec)
        folder = Path(args.out) / "runs" / f"{name.replace(':', '-')}_{element}"
        folder.mkdir(parents=True, exist_ok=True)
        atomic_write_text(folder / "job.inp", static_inp_text(scene, mesh, CalculixSettings(element=element),
                                                              pressure=pressure, radius=radius))
        run = run_ccx(folder / "job.inp", timeout=args.timeout_s)
        u, vm = static_fields(run["frd"], scene, spec, ccx_element=element)
        wall = run["wall_time_s"]
    return {"mesh": name, "element": element, "full_nodes": int(mesh.n_nodes), "h_contact_um": spec.h_contact * 1e6,
            "far_growth": spec.growth, "pressure_pa": pressure, "loaded_faces_radius_um": args.radius_um,
            **_figures(args, scene, mesh, u, vm, radius), "wall_s": wall}


def _figures(args, scene, mesh, u, vm, radius: float) -> dict:
    """The static figures of one displacement field u (N, 2) [m] and its von Mises vm (N,) [Pa]."""
    import numpy as np

    from pcmgn_jax import metrics
    from pcmgn_jax.eval.calculix_check import section_weights

    top = np.asarray(mesh.panel_top)
    top = top[np.argsort(mesh.points[top, 0])]
    x, uy = mesh.points[top, 0], u[top, 1]
    # the pressure's work-conjugate deflection: its mean over the loaded disc (trapezoid rule in r dr, exact
    # for the piecewise linear field the faces carry)
    inside = x <= radius * (1 + 1e-9)
    xs, us = x[inside], uy[inside]
    loaded_mean = float(np.sum((xs[1:] - xs[:-1]) * (xs[1:] * us[1:] + xs[:-1] * us[:-1]) / 2) / (radius**2 / 2))
    oled = list(scene.part_names).index("OLED")
    cg = list(scene.part_names).index("CG")
    w_fixed = section_weights(mesh.points, mesh.cells, mesh.cell_part, part=oled, x_end=args.section_x_mm * 1e-3)
    w_area = metrics.objective_weights(mesh.points, mesh.cells, mesh.cell_part, mesh.node_part, part=oled)
    node_oled = mesh.node_part == oled
    return {"loaded_mean_deflection_um": -loaded_mean * 1e6, "compliance_um_per_n": -loaded_mean * 1e6 / args.force_n,
            "top_centre_deflection_um": float(-uy[0] * 1e6),
            "oled_fixed_section_mpa": float(w_fixed @ vm / 1e6), "oled_area_mean_mpa": float(w_area @ vm / 1e6),
            "oled_node_mean_mpa": float(vm[node_oled].mean() / 1e6),
            "peak_cg_von_mises_mpa": float(vm[mesh.node_part == cg].max() / 1e6)}


def report(args, rows: list[dict], command: str) -> list[str]:
    """OUT.json and OUT.md; returns the markdown lines."""
    from pathlib import Path

    from pcmgn_jax.atomic import atomic_write_json, atomic_write_text

    ref = {r["element"]: r for r in rows if r["mesh"] == rows[-1]["mesh"]}   # the last mesh: the finest
    twin = {(r["mesh"], r["element"]): r for r in rows}
    lines = [f"Command: `{command}`", "",
             f"Design {args.design} µm; static pressure {args.force_n:g} N over r <= {args.radius_um:g} µm; "
             f"fixed OLED section x <= {args.section_x_mm:g} mm. In brackets: CalculiX rows against the same "
             f"element on {rows[-1]['mesh']}; built-in rows against CalculiX's counterpart (q4: C3D8, q4i: C3D8I) "
             "on the same mesh.", ""]
    head = ["mesh", "element", "nodes (2D)", "far growth", "loaded-zone deflection [µm]", "top centre [µm]",
            f"OLED, x <= {args.section_x_mm:g} mm [MPa]", "OLED area mean [MPa]", "OLED node mean [MPa]",
            "peak CG vM [MPa]", "wall [s]"]
    body = []
    for r in rows:
        base = ref.get(r["element"], r)
        if r["element"].startswith("builtin_"):
            from pcmgn_jax.data.exporters.calculix import CCX_COUNTERPART

            ccx = {v: k for k, v in CCX_COUNTERPART.items()}[r["element"].removeprefix("builtin_")]
            base = twin.get((r["mesh"], ccx), r)

        def cell(key, fmt="{:.3f}"):
            text = fmt.format(r[key])
            return text if base is r else f"{text} ({100 * (r[key] / base[key] - 1):+.1f} %)"

        body.append([r["mesh"], r["element"], f"{r['full_nodes']:,}", f"{r['far_growth']:.3f}",
                     cell("loaded_mean_deflection_um"), cell("top_centre_deflection_um"),
                     cell("oled_fixed_section_mpa", "{:.4f}"), cell("oled_area_mean_mpa", "{:.4f}"),
                     cell("oled_node_mean_mpa", "{:.4f}"), cell("peak_cg_von_mises_mpa", "{:.1f}"),
                     f"{r['wall_s']:.1f}"])
    lines += markdown.table(head, body)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(f"{args.out}.json", {"command": command, "args": vars(args) if hasattr(args, "__dict__")
                                           else {}, "rows": rows})
    atomic_write_text(f"{args.out}.md", "\n".join(lines) + "\n", parents=True)
    return lines


def main(argv=None) -> int:
    args = cli.parse(LockingArgs, argv, description=__doc__, prog="python -m experiments.calculix_locking")
    from pcmgn_jax.data.calculix import CalculixNotFoundError, find_ccx

    try:
        find_ccx()
    except CalculixNotFoundError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    command = cli.command_line("experiments.calculix_locking", argv)
    rows = []
    for name in [m.strip() for m in args.meshes.split(",") if m.strip()]:
        builtin = [f"builtin_{e.strip()}" for e in args.builtin_elements.split(",") if e.strip()]
        for element in [e.strip() for e in args.elements.split(",") if e.strip()] + builtin:
            rows.append(row(args, name, element))
            r = rows[-1]
            print(f"{name:10s} {element:12s} deflection {r['loaded_mean_deflection_um']:.3f} µm  OLED fixed "
                  f"{r['oled_fixed_section_mpa']:.4f} MPa  {r['wall_s']:.1f} s", flush=True)
            report(args, rows, command)
    print("\n".join(report(args, rows, command)))
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
