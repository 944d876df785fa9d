"""How each reading of the design objective converges with the mesh (docs/design.md §8, issue 13).

  python -m experiments.objective_convergence            # cpu, cpu_fine, paper at (100, 100) and (145.2, 99.3) µm

Runs the built-in solver at each mesh and design (cached under results/objective_convergence/solver/),
and writes results/objective_convergence.{json,md}: every reading per mesh, and its change against the
finest mesh. ``cpu_fine`` is the cpu preset with the contact size and the layer element counts halved /
doubled (a mesh between cpu and paper); ``PRESET@F`` is the preset refined by F (``cpu@2``, ``paper@2``).
"""
from __future__ import annotations

import sys
from dataclasses import dataclass

from pcmgn_jax import cli, markdown


@dataclass(frozen=True)
class ConvergenceArgs:
    designs: str = "100,100;145.2,99.3"        # designs in µm
    meshes: str = "cpu,cpu_fine,paper"         # meshes, coarse to fine (the last is the reference)
    out: str = "results/objective_convergence"  # output stem (.json, .md) and solver cache folder


def main(argv=None) -> int:
    args = cli.parse(ConvergenceArgs, argv, description=__doc__, prog="python -m experiments.objective_convergence")
    from pathlib import Path

    from pcmgn_jax.atomic import atomic_write_json
    from pcmgn_jax.data.designs import parse_designs
    from pcmgn_jax.data.family import Design
    from pcmgn_jax.metrics import OBJECTIVES
    from pcmgn_jax.opt.check import solver_objectives
    from pcmgn_jax.scene import default_scene
    from pcmgn_jax.sim.mesh import named_spec

    scene = default_scene()
    designs = parse_designs(args.designs, dim=2)
    meshes = [m.strip() for m in args.meshes.split(",")]
    for m in meshes:
        named_spec(m)               # every name checked before the first solver run
    rows = []
    for d in designs:
        for m in meshes:
            r = solver_objectives(scene, Design.of(None, d, scene.design_layers), named_spec(m),
                                  Path(args.out) / "solver", label=m)
            rows.append({"mesh": m, **r})
            print(f"{m:9s} {d * 1e6} µm: " + ", ".join(f"{k} {r[k]:.4f}" for k in OBJECTIVES), flush=True)
    ref = {tuple(r["design_um"]): r for r in rows if r["mesh"] == meshes[-1]}
    body = []
    for r in rows:
        f = ref[tuple(r["design_um"])]
        body.append((f"{r['design_um'][0]:.1f}, {r['design_um'][1]:.1f}", r["mesh"], r["n_nodes"],
                     *(f"{r[k]:.4f} ({(r[k] / f[k] - 1) * 100:+.1f} %)" for k in OBJECTIVES),
                     f"{r['solver_seconds']:.0f}"))
    lines = markdown.table(("design [µm]", "mesh", "nodes (ROI)", *(f"{k} [MPa] (vs {meshes[-1]})" for k in OBJECTIVES),
                            "solver [s]"), body)
    # which readings agree on the better of the designs, per mesh
    order = {m: {k: min(((r[k], tuple(r["design_um"])) for r in rows if r["mesh"] == m))[1] for k in OBJECTIVES}
             for m in meshes}
    lines += ["", "Better design per reading and mesh: " + "; ".join(
        f"{m}: " + ", ".join(f"{k} {order[m][k]}" for k in OBJECTIVES) for m in meshes)]
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(f"{args.out}.json", {"rows": rows, "better_design": {m: {k: list(v) for k, v in o.items()}
                                                                          for m, o in order.items()},
                                           "command": "python -m experiments.objective_convergence"})
    Path(f"{args.out}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
