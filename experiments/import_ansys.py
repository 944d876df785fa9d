"""Import ANSYS Mechanical text exports (+ a .cdb or meshio-readable mesh) into a trajectory file.

  python -m experiments.import_ansys --mesh model.cdb --results exports/ --out data/ansys/run01 \\
      --scene scenes/paper.toml --parts "ball=1,CG=2,OCA1=3,POL=4,OCA2=5,OLED=6,PLATE=7" --output_dt 4e-6

See pcmgn_jax/data/importers.py for the file-naming convention of the result tables and the part map.
Nothing is written unless the whole import succeeds.
"""
from __future__ import annotations

import argparse
import sys

from pcmgn_jax.data.importers import import_ansys_text, parse_parts
from pcmgn_jax.scene import Scene
from pcmgn_jax.data.trajectory_io import write_trajectory


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mesh", required=True, help=".cdb archive or meshio-readable mesh with part groups")
    ap.add_argument("--results", required=True, help="folder of exported tables (deformation_x_000.txt, ...)")
    ap.add_argument("--out", required=True, help="output path stem: writes OUT.xdmf, OUT.h5, OUT.json")
    ap.add_argument("--scene", default=None, help="scene file (.toml/.json): part names, materials, design")
    ap.add_argument("--part_names", default=None, help="comma list of part names by id if no --scene")
    ap.add_argument("--parts", default=None, help='part map "ball=1,CG=2+8,OCA1=OCA_1" (int: material '
                                                  'number, str: component / cell set); default: by name')
    ap.add_argument("--output_dt", type=float, default=None, help="frame interval [s] if no times.txt")
    ap.add_argument("--length_unit", default=None, help="mesh length unit (cdb default: /UNITS or m)")
    ap.add_argument("--fixed", default="bottom", help="fixed nodes: bottom | none | node component name")
    ap.add_argument("--location_tol", type=float, default=None, help="max |location - mesh| [m]")
    ap.add_argument("--ignore_unmapped", action="store_true", help="drop cells that belong to no part")
    args = ap.parse_args(argv)
    try:
        scene = Scene.load(args.scene) if args.scene else None
        names = [s.strip() for s in args.part_names.split(",")] if args.part_names else None
        mesh_kw = {"length_unit": args.length_unit} if args.length_unit else {}
        traj = import_ansys_text(
            args.mesh, args.results, scene=scene, part_names=names,
            parts=parse_parts(args.parts) if args.parts else None, output_dt=args.output_dt,
            fixed=None if args.fixed == "none" else args.fixed, location_tol=args.location_tol,
            ignore_unmapped=args.ignore_unmapped, **mesh_kw)
        digest = write_trajectory(traj, args.out)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}.xdmf/.h5/.json: {traj.n_nodes} nodes, {len(traj.cells)} cells, "
          f"{traj.n_frames} frames, sha256 {digest[:12]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
