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
the whole import succeeds (the trajectory is written atomically). The imports:
pcmgn_jax/data/importers/exports.py; this module parses flags and reports.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Optional

from pcmgn_jax import cli
from pcmgn_jax.data.importers import parse_parts
from pcmgn_jax.data.importers.exports import import_exports, import_files
from pcmgn_jax.errors import SettingError
from pcmgn_jax.scene import Scene


@dataclass(frozen=True)
class Args:
    """Import ANSYS Mechanical text exports and a mesh into one trajectory file (OUT.xdmf/.h5/.json), or a
    folder of such runs (--exports) into a dataset folder."""

    # one run: .cdb archive, Workbench input file (.dat with an NBLOCK) or meshio-readable mesh with part groups
    mesh: Optional[str] = None
    results: Optional[str] = None  # one run: folder of exported tables (deformation_x_000.txt, ...)
    out: str = ""  # one run: output path stem (writes OUT.xdmf, OUT.h5, OUT.json); with --exports: the dataset folder
    # a dataset: folder EXPORTS/<split>/<run>/ of run folders (model.cdb + results/ [+ scene.json, run.json])
    exports: Optional[str] = None
    scene: Optional[str] = None  # scene file (.toml/.json): part names, materials, analysis, design
    part_names: Optional[str] = None  # comma list of part names by id if no --scene
    # part map "ball=1,CG=2+8,OCA1=OCA_1" (int: material number, str: component / cell set); default: by name
    parts: Optional[str] = None
    output_dt: Optional[float] = None  # frame interval [s] if no times.txt
    # mesh length unit (m, mm, um, ...); required for archives without /UNITS; meshio meshes: default m
    length_unit: Optional[str] = None
    fixed: Optional[str] = None  # fixed nodes: bottom | none | node component name (default bottom)
    location_tol: Optional[float] = None  # max |location - mesh| [m]
    ignore_unmapped: bool = False  # drop cells that belong to no part
    # ROI: keep cells within this radius [m] of the contact (axisymmetric x <= r; plane strain |x - x_c| <= r, x_c = the
    # ball's lowest node); unset: no limit
    roi_radius: Optional[float] = None
    # ROI: keep panel cells within this depth [m] below the panel top; unset: full thickness
    roi_depth: Optional[float] = None
    # ROI: keep ball cells within this height [m] above the ball's lowest point; unset: whole ball
    roi_ball_height: Optional[float] = None
    progress: bool = True  # with --exports: progress bar (--no_progress: off)


def main(argv: list[str] | None = None) -> int:
    try:
        args = cli.parse(Args, argv, description=__doc__, prog="python -m experiments.import_ansys")
        settings = {"scene": Scene.load(args.scene) if args.scene else None,
                    "part_names": [s.strip() for s in args.part_names.split(",")] if args.part_names else None,
                    "parts": parse_parts(args.parts) if args.parts else None, "length_unit": args.length_unit,
                    "fixed": args.fixed, "output_dt": args.output_dt, "location_tol": args.location_tol,
                    "ignore_unmapped": args.ignore_unmapped,
                    "roi": {"radius": args.roi_radius, "depth": args.roi_depth, "ball_height": args.roi_ball_height}}
        if args.exports:
            if args.mesh or args.results:
                raise ValueError("--exports imports a whole folder of runs: drop --mesh / --results (one run)")
            return _report(args.out, import_exports(args.exports, args.out, progress=args.progress, **settings))
        if not (args.mesh and args.results and args.out):
            raise ValueError("give --mesh, --results and --out (one run), or --exports and --out (a dataset)")
        traj, digest = import_files(args.mesh, args.results, args.out, **settings)
    except ValueError as err:
        print(f"error: {err.as_flag() if isinstance(err, SettingError) else err}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}.xdmf/.h5/.json: {traj.n_nodes} nodes, {len(traj.cells)} cells, "
          f"{traj.n_frames} frames, sha256 {digest[:12]}")
    return 0


def _report(out: str, report) -> int:
    """Print what a dataset import did; 2 if any run failed."""
    total = len(report.imported) + len(report.skipped) + len(report.failed)
    print(f"{out}: imported {len(report.imported)}, kept {len(report.skipped)} up to date, "
          f"{len(report.failed)} failed, of {total} run(s)")
    if report.failed:
        print(f"error: {len(report.failed)} run(s) failed (listed above): "
              f"{', '.join(str(r) for r, _ in report.failed[:5])}{' ...' if len(report.failed) > 5 else ''}; "
              "fix them and rerun (finished runs are kept)", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
