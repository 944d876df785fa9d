"""Import ANSYS Mechanical text exports (+ a .cdb / Workbench .dat / meshio-readable mesh) into a trajectory file.

  python -m experiments.import_ansys --mesh model.cdb --results exports/ --out data/ansys/run01 \\
      --scene scenes/paper.toml --parts "ball=1,CG=2,OCA1=3,POL=4,OCA2=5,OLED=6,PLATE=7" \\
      --length_unit mm --output_dt 4e-6

See pcmgn_jax/data/importers/__init__.py for the file-naming convention of the result tables and the part
map. MAPDL archives carry no /UNITS line unless one was set: give --length_unit. --roi_radius / --roi_depth /
--roi_ball_height [m] crop the trajectory to the region of interest around the contact before it is written
(pcmgn_jax.geometry.roi_crop; meta "roi" keeps the node map). Nothing is written unless
the whole import succeeds (the trajectory is written atomically).
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Optional

from pcmgn_jax import cli
from pcmgn_jax.data.importers import import_ansys_text, parse_parts, read_mesh
from pcmgn_jax.geometry import RoiCropError
from pcmgn_jax.data.trajectory_io import write_trajectory
from pcmgn_jax.scene import Scene
from pcmgn_jax.trajectory import crop_trajectory


@dataclass(frozen=True)
class Args:
    """Import ANSYS Mechanical text exports and a mesh into one trajectory file (OUT.xdmf/.h5/.json)."""

    mesh: str
    """.cdb archive, Workbench input file (.dat with an NBLOCK) or meshio-readable mesh with part groups"""
    results: str
    """folder of exported tables (deformation_x_000.txt, ...)"""
    out: str
    """output path stem: writes OUT.xdmf, OUT.h5, OUT.json"""
    scene: Optional[str] = None
    """scene file (.toml/.json): part names, materials, analysis, design"""
    part_names: Optional[str] = None
    """comma list of part names by id if no --scene"""
    parts: Optional[str] = None
    """part map "ball=1,CG=2+8,OCA1=OCA_1" (int: material number, str: component / cell set); default: by name"""
    output_dt: Optional[float] = None
    """frame interval [s] if no times.txt"""
    length_unit: Optional[str] = None
    """mesh length unit (m, mm, um, ...); required for archives without /UNITS; meshio meshes: default m"""
    fixed: str = "bottom"
    """fixed nodes: bottom | none | node component name"""
    location_tol: Optional[float] = None
    """max |location - mesh| [m]"""
    ignore_unmapped: bool = False
    """drop cells that belong to no part"""
    roi_radius: Optional[float] = None
    """ROI: keep cells within this radius [m] of the contact (axisymmetric x <= r; plane strain |x - x_c| <= r,
    x_c = the ball's lowest node); unset: no limit"""
    roi_depth: Optional[float] = None
    """ROI: keep panel cells within this depth [m] below the panel top; unset: full thickness"""
    roi_ball_height: Optional[float] = None
    """ROI: keep ball cells within this height [m] above the ball's lowest point; unset: whole ball"""


def _crop(traj, args: Args):
    """The trajectory cropped by the --roi_* flags (unchanged if none is given); errors name the flag."""
    limits = {"radius": args.roi_radius, "depth": args.roi_depth, "ball_height": args.roi_ball_height}
    if all(v is None for v in limits.values()):
        return traj
    full = traj.n_nodes
    try:
        traj, _ = crop_trajectory(traj, **{k: float("inf") if v is None else v for k, v in limits.items()})
    except RoiCropError as err:
        raise ValueError(f"--roi_{err.param}={limits[err.param]}: {err}") from None
    print(f"region of interest: kept {traj.n_nodes} of {full} nodes", file=sys.stderr)
    return traj


def main(argv: list[str] | None = None) -> int:
    try:
        args = cli.parse(Args, argv, description=__doc__, prog="python -m experiments.import_ansys")
        scene = Scene.load(args.scene) if args.scene else None
        names = [s.strip() for s in args.part_names.split(",")] if args.part_names else None
        parts = parse_parts(args.parts) if args.parts else None
        mesh = read_mesh(args.mesh, scene=scene, part_names=None if scene else names, parts=parts,
                         length_unit=args.length_unit, ignore_unmapped=args.ignore_unmapped)
        for note in mesh.notes:
            print(f"note: {note}", file=sys.stderr)
        traj = import_ansys_text(
            mesh, args.results, scene=scene, part_names=names, output_dt=args.output_dt,
            fixed=None if args.fixed == "none" else args.fixed, location_tol=args.location_tol)
        traj = _crop(traj, args)
        digest = write_trajectory(traj, args.out)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}.xdmf/.h5/.json: {traj.n_nodes} nodes, {len(traj.cells)} cells, "
          f"{traj.n_frames} frames, sha256 {digest[:12]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
