"""Import ANSYS Mechanical text exports (+ a .cdb / Workbench .dat / meshio-readable mesh) into trajectory files.

One run:

  python -m experiments.import_ansys --mesh model.cdb --results exports/ --out data/ansys/run01 \\
      --scene scenes/paper.toml --parts "ball=1,CG=2,OCA1=3,POL=4,OCA2=5,OLED=6,PLATE=7" \\
      --length_unit mm --output_dt 4e-6

A whole dataset (every run folder EXPORTS/<split>/<run>/ holding model.cdb + results/, e.g. what
``python -m experiments.export_ansys`` writes) into DIR/<split>/<run>.xdmf/.h5/.json:

  python -m experiments.import_ansys --exports exports/mine --out data/mine \\
      --scene scenes/paper.toml --parts "ball=1,CG=2,OCA1=3,POL=4,OCA2=5,OLED=6,PLATE=7" --length_unit mm

With --exports, a run folder's own scene.json / scene.toml and run.json ("import": parts, part_names,
length_unit, fixed, output_dt, ...) win over the flags, which are the defaults for the runs that set
nothing (pcmgn_jax/data/importers/runs.py). Each run is written atomically; rerunning skips runs whose
output is valid and whose inputs and settings are unchanged; a failing run prints one line naming its
folder and the others go on (exit status 2 if any failed).

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
from pcmgn_jax.data.importers import apply_roi, import_ansys_dataset, import_ansys_text, parse_parts, read_mesh
from pcmgn_jax.data.trajectory_io import write_trajectory
from pcmgn_jax.scene import Scene


@dataclass(frozen=True)
class Args:
    """Import ANSYS Mechanical text exports and a mesh into one trajectory file (OUT.xdmf/.h5/.json), or a
    folder of such runs (--exports) into a dataset folder."""

    mesh: Optional[str] = None
    """one run: .cdb archive, Workbench input file (.dat with an NBLOCK) or meshio-readable mesh with part groups"""
    results: Optional[str] = None
    """one run: folder of exported tables (deformation_x_000.txt, ...)"""
    out: str = ""
    """one run: output path stem (writes OUT.xdmf, OUT.h5, OUT.json); with --exports: the dataset folder"""
    exports: Optional[str] = None
    """a dataset: folder EXPORTS/<split>/<run>/ of run folders (model.cdb + results/ [+ scene.json, run.json])"""
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
    fixed: Optional[str] = None
    """fixed nodes: bottom | none | node component name (default bottom)"""
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
    progress: bool = True
    """with --exports: progress bar (--no_progress: off)"""


def _roi(args: Args) -> dict:
    return {"radius": args.roi_radius, "depth": args.roi_depth, "ball_height": args.roi_ball_height}


def _crop(traj, args: Args):
    """The trajectory cropped by the --roi_* flags (unchanged if none is given); errors name the flag."""
    traj, note = apply_roi(traj, _roi(args))
    if note:
        print(note, file=sys.stderr)
    return traj


def _import_dataset(args: Args, scene, names, parts) -> int:
    if args.mesh or args.results:
        raise ValueError("--exports imports a whole folder of runs: drop --mesh / --results (one run)")
    if not args.out:
        raise ValueError("--exports needs --out DIR (writes DIR/<split>/<run>.xdmf/.h5/.json)")
    defaults = {"parts": parts, "part_names": names, "length_unit": args.length_unit, "fixed": args.fixed,
                "output_dt": args.output_dt, "location_tol": args.location_tol,
                "ignore_unmapped": args.ignore_unmapped or None}
    report = import_ansys_dataset(args.exports, args.out, defaults=defaults, scene=scene, roi=_roi(args),
                                  progress=args.progress)
    total = len(report.imported) + len(report.skipped) + len(report.failed)
    print(f"{args.out}: imported {len(report.imported)}, kept {len(report.skipped)} up to date, "
          f"{len(report.failed)} failed, of {total} run(s)")
    if report.failed:
        print(f"error: {len(report.failed)} run(s) failed (listed above): "
              f"{', '.join(str(r) for r, _ in report.failed[:5])}{' ...' if len(report.failed) > 5 else ''}; "
              "fix them and rerun (finished runs are kept)", file=sys.stderr)
        return 2
    return 0


def main(argv: list[str] | None = None) -> int:
    try:
        args = cli.parse(Args, argv, description=__doc__, prog="python -m experiments.import_ansys")
        scene = Scene.load(args.scene) if args.scene else None
        names = [s.strip() for s in args.part_names.split(",")] if args.part_names else None
        parts = parse_parts(args.parts) if args.parts else None
        if args.exports:
            return _import_dataset(args, scene, names, parts)
        if not (args.mesh and args.results and args.out):
            raise ValueError("give --mesh, --results and --out (one run), or --exports and --out (a dataset)")
        mesh = read_mesh(args.mesh, scene=scene, part_names=None if scene else names, parts=parts,
                         length_unit=args.length_unit, ignore_unmapped=args.ignore_unmapped)
        for note in mesh.notes:
            print(f"note: {note}", file=sys.stderr)
        fixed = args.fixed or "bottom"
        traj = import_ansys_text(
            mesh, args.results, scene=scene, part_names=names, output_dt=args.output_dt,
            fixed=None if fixed == "none" else fixed, location_tol=args.location_tol)
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
