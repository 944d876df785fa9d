"""Export a trajectory dataset in ANSYS formats: one run folder per trajectory, as a user with ANSYS data has.

  python -m experiments.export_ansys --data data/family_tiny --out exports/family_tiny
  python -m experiments.import_ansys --exports exports/family_tiny --out data/family_tiny_ansys   # and back

For every trajectory DATA/<split>/NAME.{xdmf,h5,json} this writes OUT/<split>/NAME/: ``model.cdb`` (MAPDL
archive, CDWRITE layout: NBLOCK/EBLOCK, PLANE182 with KEYOPT(3) from the analysis, no /UNITS line unless
--units_line), ``results/`` (Mechanical "Export -> Text File" tables deformation_x_000.txt ... and
times.txt [s]), ``scene.json`` (the trajectory's scene) and ``run.json`` (the --parts string, length unit,
fixed-node component and carried meta such as scene_params), plus OUT/README.md and OUT/export.json.
Material number = part id + 1; ANSYS node i + 1 = trajectory node i. Each run folder is written
atomically; rerunning skips runs already exported from the same trajectory with the same units.
See pcmgn_jax/data/exporters/ansys.py.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Optional

from pcmgn_jax import cli
from pcmgn_jax.data.exporters import export_dataset


@dataclass(frozen=True)
class ExportAnsysArgs:
    """Export every trajectory of a dataset folder as ANSYS-format run folders."""

    data: str
    """dataset folder: DATA/<split>/NAME.{xdmf,h5,json}"""
    out: str
    """output folder: OUT/<split>/NAME/{model.cdb, results/, scene.json, run.json}"""
    length_unit: str = "mm"
    """length unit of the archive and the tables (m, mm, um, ...)"""
    velocity_unit: str = "mm/s"
    """velocity unit of the tables (<length>/<s|ms|us>)"""
    stress_unit: str = "MPa"
    """stress unit of the tables (Pa, kPa, MPa, GPa, psi)"""
    units_line: bool = False
    """write a /UNITS line into model.cdb (CDWRITE writes none)"""
    splits: Optional[str] = None
    """comma list of splits to export (default: all)"""
    progress: bool = True
    """progress bar (--no_progress: off)"""


def main(argv: list[str] | None = None) -> int:
    try:
        args = cli.parse(ExportAnsysArgs, argv, description=__doc__, prog="python -m experiments.export_ansys")
        splits = [s.strip() for s in args.splits.split(",") if s.strip()] if args.splits else None
        counts = export_dataset(args.data, args.out, length_unit=args.length_unit,
                                velocity_unit=args.velocity_unit, stress_unit=args.stress_unit,
                                units_line=args.units_line, splits=splits, progress=args.progress)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"exported {counts['exported']} run(s), kept {counts['skipped']} up to date, into {args.out} "
          f"(see {args.out}/README.md)")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
