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


def mesh_for(name: str):
    """A mesh by name: a preset, ``cpu_fine``, ``PRESET@F``: the preset refined by the factor F
    (:func:`pcmgn_jax.sim.mesh.refined`; ``cpu@0.5`` coarsens), or ``PRESET@F:ZONE`` with only one zone refined:
    ``far`` (the radial growth ratio to the power 1/F: the graded far field), ``layers`` (the element counts of
    the layers above the bottom one, x F) or ``plate`` (the bottom layer's count x F, its growth to the power 1/F)."""
    from pcmgn_jax.sim.mesh import mesh_spec, refined, with_spec
    if "@" in name:
        preset, _, rest = name.partition("@")
        factor, _, zone = rest.partition(":")
        try:
            f = float(factor)
            full = refined(preset, f)
            base = mesh_spec(preset)
        except ValueError as err:
            raise ValueError(f"mesh {name!r}: {err}") from None
        bottom = list(base.layer_elems)[-1] if base.layer_elems else None
        zones = {"": full,
                 "far": with_spec(base, growth=full.growth),
                 "layers": with_spec(base, layer_elems={k: full.layer_elems[k] if k != bottom else v
                                                        for k, v in base.layer_elems.items()}),
                 "plate": with_spec(base, bottom_growth=full.bottom_growth,
                                    layer_elems={k: full.layer_elems[k] if k == bottom else v
                                                 for k, v in base.layer_elems.items()})}
        if zone not in zones:
            raise ValueError(f"mesh {name!r}: zone must be one of far, layers, plate, got {zone!r}")
        return zones[zone]
    if name == "cpu_fine":
        base = mesh_spec("cpu")
        return with_spec("cpu", h_contact=base.h_contact / 2, h_layer=base.h_layer / 2,
                         layer_elems={k: 2 * v for k, v in base.layer_elems.items()})
    return name


def main(argv=None) -> int:
    args = cli.parse(ConvergenceArgs, argv, description=__doc__, prog="python -m experiments.objective_convergence")
    from pathlib import Path

    from pcmgn_jax.atomic import atomic_write_json
    from pcmgn_jax.data.designs import parse_designs
    from pcmgn_jax.metrics import OBJECTIVES
    from pcmgn_jax.opt.check import solver_objectives
    from pcmgn_jax.scene import default_scene

    scene = default_scene()
    designs = parse_designs(args.designs, dim=2)
    meshes = [m.strip() for m in args.meshes.split(",")]
    rows = []
    for d in designs:
        for m in meshes:
            r = solver_objectives(scene, d, mesh_for(m), Path(args.out) / "solver", label=m)
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
